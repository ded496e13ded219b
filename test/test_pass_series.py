"""railgsa simulate-passes: depths per the spec, one track, dates, odometry and GNSS vs truth."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from railgsa_ros.bag import read_imu, read_stamped
from railgsa_ros.bag.messages import ODOMETRY, ODOMETRY_FIELDS, POINT_STAMPED
from railgsa_ros.cli.main import main
from railgsa_ros.errors import ConfigError
from railgsa_ros.geo import default_line
from railgsa_ros.pass_series import SeriesSpec, parse_growing_defects, plan_series
from railgsa_ros.track import line_profile, parse_defects
from railgsa_ros.vehicle import VehicleParams

N = 4
DEFECTS = 'dip@400:len=8:depth=3e-3:growth=5e-5,dip@700:len=6:depth=4e-3:from=3,' \
          'joint@850:depths=1e-3/1.5e-3/2e-3/3e-3'
ARGS = ['--passes', str(N), '--section-km', '0.3-1.0', '--defects', DEFECTS, '--days', '10',
        '--speed-range', '22-30', '--stop-every', '0', '--rate', '200', '--seed', '4',
        '--gnss-rate', '5', '--gnss-noise', '2']


@pytest.fixture(scope='module')
def series(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('passes') / 'series'
    assert main(['simulate-passes', '--out', str(out), *ARGS]) == 0
    return out


def truths(out: Path) -> list[dict]:
    return [json.loads((out / 'truth' / f'pass_{i:02d}.json').read_text())
            for i in range(1, N + 1)]


def test_defect_depths_follow_the_spec_and_the_new_one_appears(series: Path):
    line, _ = line_profile('german-low', seed=4)  # the series seed is the line seed
    for t in truths(series):
        i, days = t['pass'] - 1, t['days']
        # days since the first pass's start, from the stamps: 10 per pass, hours of day vary
        assert days == pytest.approx((t['start_time_s'] - truths(series)[0]['start_time_s'])
                                     / 86400, abs=1e-9)
        assert abs(days - 10.0 * i) < 0.7
        grow, new, joint = t['defects']
        assert grow['depth_m'] == pytest.approx(3e-3 + 5e-5 * days, rel=1e-12)
        assert joint['depth_m'] == [1e-3, 1.5e-3, 2e-3, 3e-3][i]
        assert new['present'] == (i >= 2) and new['new'] == (i == 2)
        assert new['depth_m'] == (4e-3 if i >= 2 else 0.0)
        # the bag's truth topic minus the line profile is exactly the defects of the spec
        truth = read_stamped(series / t['bag'], '/track/irregularity_truth',
                             POINT_STAMPED.msgtype).values
        x, u = truth[:, 0], truth[:, 2]
        present = [d for d in t['defects'] if d['present']]
        spec = ','.join(f'{d["kind"]}@{d["start_m"]!r}:len={d["length_m"]!r}:'
                        f'depth={d["depth_m"]!r}' for d in present)
        expected = line(x) + sum(d(x) for d in parse_defects(spec))
        np.testing.assert_allclose(u, expected, rtol=0, atol=1e-12)
        step = np.diff(x).max()
        for d in t['defects']:  # the deepest sample of a cosine dip: within half a step
            near = np.abs(x - d['centre_m']) < 0.5 * d['length_m']
            deepest = -(u - line(x))[near].min()
            floor = d['depth_m'] * np.cos(np.pi * step / (2 * d['length_m'])) ** 2
            assert floor - 1e-12 <= deepest <= d['depth_m'] + 1e-12


def test_passes_share_the_track_and_differ_in_trains(series: Path):
    ts = truths(series)
    curves, vehicles = [], []
    for t in ts:
        truth = read_stamped(series / t['bag'], '/track/irregularity_truth',
                             POINT_STAMPED.msgtype).values
        curves.append((truth[:, 0], truth[:, 2]))
        vehicles.append(list(t['vehicle'].values()))
        assert t['start_m'] <= 300.0 and t['end_m'] >= 1000.0
        assert truth[0, 0] == pytest.approx(t['start_m'], abs=1e-9)
        assert abs(t['odom_scale_error']) <= 0.005
    x = np.linspace(320.0, 390.0, 500)  # before every defect: the same rails
    base = np.interp(x, *curves[0])
    for xs, us in curves[1:]:
        np.testing.assert_allclose(np.interp(x, xs, us), base, rtol=0, atol=1e-5)
    table = np.array(vehicles) / VehicleParams().as_array()
    assert np.all(np.abs(table - 1) <= 0.03 + 1e-12) and np.ptp(table, axis=0).min() > 0
    assert len({t['speed_profile'] for t in ts}) == N
    assert len({round(t['start_m'], 3) for t in ts}) == N


def test_dates_odometry_and_gnss_match_the_truth(series: Path):
    line = default_line(1200.0)
    for t in truths(series):
        bag = series / t['bag']
        imu = read_imu(bag)
        assert imu.stamps_ns[0] / 1e9 == pytest.approx(t['start_time_s'], abs=1e-3)
        # odometer = start + (1 + e) x the truth's distance, at every odometry sample
        truth = read_stamped(bag, '/track/irregularity_truth', POINT_STAMPED.msgtype)
        x = truth.values[:, 0]
        odom = read_stamped(bag, '/odom', ODOMETRY.msgtype)
        at = np.searchsorted(truth.stamps_ns, odom.stamps_ns)
        np.testing.assert_array_equal(truth.stamps_ns[at], odom.stamps_ns)
        odometer = odom.values[:, ODOMETRY_FIELDS['pose.pose.position'].start]
        np.testing.assert_allclose(odometer - x[0], t['odom_scale'] * (x[at] - x[0]),
                                   rtol=1e-12, atol=1e-9)
        # and its speed: the mean over the pass (whole ripple periods) against the truth's
        mean_truth = (x[-1] - x[0]) / ((truth.stamps_ns[-1] - truth.stamps_ns[0]) / 1e9)
        assert imu.speed_mps.mean() / mean_truth == pytest.approx(t['odom_scale'], abs=2e-4)
        fixes = []
        with AnyReader([bag]) as reader:
            conns = [c for c in reader.connections if c.topic == '/gnss/fix']
            for conn, stamp, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                fixes.append((stamp, msg.latitude, msg.longitude))
        stamps, lat, lon = np.array(fixes).T
        along, cross = line.locate(lat, lon)
        err = along - np.interp(stamps, truth.stamps_ns, x)
        assert np.sqrt(np.mean(err ** 2)) == pytest.approx(2.0, rel=0.3)
        assert np.sqrt(np.mean(cross ** 2)) == pytest.approx(2.0, rel=0.3)
        for d in t['defects']:
            lat_d, lon_d = line.position(np.array([d['centre_m']]))
            assert (d['lat_deg'], d['lon_deg']) == (float(lat_d[0]), float(lon_d[0]))
    first = truths(series)[0]['start_time_s']
    days = [(t['start_time_s'] - first) / 86400 for t in truths(series)]
    np.testing.assert_allclose(days, 10.0 * np.arange(N), atol=0.7)  # hours of day vary
    geometry = json.loads((series / 'line.geojson').read_text())['features'][0]
    lon_v, lat_v = np.array(geometry['geometry']['coordinates']).T
    assert geometry['properties'] == {'line_id': 'sim-1', 'start_m': 0.0}
    np.testing.assert_array_equal(lat_v, line.lat_deg[:lat_v.size])  # a prefix of every line
    np.testing.assert_array_equal(lon_v, line.lon_deg[:lon_v.size])
    rows = list(csv.DictReader((series / 'truth' / 'truth.csv').open()))
    assert sorted(p.name for p in series.glob('pass_*')) == [f'pass_{i:02d}' for i in
                                                              range(1, N + 1)]  # bags only
    assert len(rows) == 3 * N and {r['bag'] for r in rows} == {f'pass_{i:02d}' for i in
                                                                 range(1, N + 1)}


def test_a_stop_pass_stands_clear_of_the_defects():
    defects = 'dip@400:len=8:depth=3e-3:growth=5e-5,dip@1700:len=6:depth=4e-3:from=3'
    spec = SeriesSpec(6, (300.0, 3000.0), parse_growing_defects(defects, 6), stop_every=2,
                      seed=1)
    for plan in plan_series(spec):
        has_stop = 'stop:' in plan.speed_profile
        assert has_stop == ((plan.index + 1) % 2 == 0)
        if has_stop:  # the standstill: its chainage is clear of every defect by >= 150 m
            from railgsa_ros.speed_profile import parse_speed_profile

            profile = parse_speed_profile(plan.speed_profile)
            t = np.linspace(0, profile.duration_s, 200_001)
            v = profile(t)
            x = plan.start_m + np.concatenate([[0], np.cumsum(0.5 * (v[1:] + v[:-1])
                                                              * np.diff(t))])
            slow = x[v < 0.5 * v.max()]
            for g in spec.defects:
                gap = np.minimum(np.abs(slow - g.defect.start),
                                 np.abs(slow - g.defect.start - g.defect.length))
                assert gap.min() >= 150.0
            assert profile.distance_m == pytest.approx(plan.end_m - plan.start_m)


@pytest.mark.parametrize('spec, message', [
    ('dip@400:len=8:depth=3e-3:depths=1e-3/2e-3', 'gives 2 sizes for 4 passes'),
    ('dip@400:len=8:depth=3e-3:from=5', 'from= must be a pass number 1..4'),
    ('dip@400:len=8:depth=3e-3:growth=1e-4:depths=1/2/3/4', 'not both'),
    ('dip@400:len=8:depth=3e-3:growth=fast', 'must be numbers'),
    ('dip@4000:len=8:depth=3e-3', 'outside the section'),
    ('dip@400:len=8:depth=3e-3:growth=-1e-3', 'sizes must stay in'),
])
def test_bad_series_specs_name_the_problem(spec, message, tmp_path: Path, capsys):
    argv = ['simulate-passes', '--out', str(tmp_path / 's'), '--passes', '4', '--section-km',
            '0.3-1.0', '--defects', spec]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 's').exists()
    with pytest.raises(ConfigError):
        parse_growing_defects('crater@5', 2)


def test_fleet_ingest_places_the_series_defects_with_gnss(tmp_path: Path, capsys):
    """The chain end to end: a series ingested by railgsa fleet (one local worker) finds its
    dips where the truth puts them, within 1 m through the odometry errors, and flags the new
    one from the pass it appears in. The dips are deep (9-10 mm) so that the fleet's detection
    threshold is not what is tested here."""
    out = tmp_path / 'series'
    assert main(['simulate-passes', '--out', str(out), '--passes', '3', '--section-km',
                 '0.3-1.2', '--defects', 'dip@500:len=8:depth=9e-3:growth=5e-5,'
                 'dip@900:len=6:depth=10e-3:from=3', '--rate', '200', '--seed', '2',
                 '--sensor', 'bmi088',  # 0.5 % dropouts: gaps in every pass
                 '--stop-every', '0']) == 0
    db = tmp_path / 'fleet.duckdb'
    bags = sorted(str(p) for p in out.glob('pass_*'))
    assert main(['fleet', 'ingest', *bags, '--db', str(db), '--line-geometry',
                 str(out / 'line.geojson'), '--line', 'sim-1', '--workers', '1']) == 0
    capsys.readouterr()
    assert main(['fleet', 'query', '--db', str(db), '--line', 'sim-1', '--from-km', '0',
                 '--to-km', '2', '--json']) == 0
    found = json.loads(capsys.readouterr().out)
    last = json.loads((out / 'truth' / 'pass_03.json').read_text())
    for d in last['defects']:
        near = [f for f in found if abs(1e3 * f['km'] - d['centre_m']) < 1.0]
        assert len(near) == 1, (d['centre_m'], [f['km'] for f in found])
        assert near[0]['new'] == (d['first_pass'] == 3), found


def test_a_pass_with_a_stop_reviews_against_its_own_truth(tmp_path: Path):
    """Every third pass of the default series stands still: its truth topic repeats the
    chainage there. ``railgsa review --truth`` of such a bag compares instead of refusing it."""
    out = tmp_path / 'series'
    assert main(['simulate-passes', '--out', str(out), '--passes', '1', '--stop-every', '1',
                 '--section-km', '0.3-0.9', '--defects', '', '--rate', '200',
                 '--speed-range', '15-15']) == 0
    truth = json.loads((out / 'truth' / 'pass_01.json').read_text())
    assert 'stop:' in truth['speed_profile']
    bag = out / 'pass_01'
    assert main(['review', str(bag), '--out', str(tmp_path / 'review'), '--truth', str(bag),
                 '--no-uncertainty']) == 0
    assert (tmp_path / 'review' / 'truth.png').stat().st_size > 5000
