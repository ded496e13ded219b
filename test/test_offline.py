"""Constant-memory offline work against whole-array results and simulated truth: the chunked bag
reader, the review's streaming summaries, its memory bound, location with GNSS and a wrong wheel
diameter, the machine-readable outputs and the review's crash cases (issue #11)."""

from __future__ import annotations

import csv
from dataclasses import replace
from itertools import pairwise
import json
from pathlib import Path

import numpy as np
import pytest

from railgsa_ros.bag import BagWriter, RunEncoder, read_imu, write_run
from railgsa_ros.bag.reader import NAV_SAT_FIX, iter_imu
from railgsa_ros.cli.main import main
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.location import Reference, from_local, to_local
from railgsa_ros.offline import Source
from railgsa_ros.qos import record_qos
from railgsa_ros.review.build import build_review
from railgsa_ros.review.exceedances import find_exceedances
from railgsa_ros.review.results import ReviewOptions
from railgsa_ros.review.stream import run_stream
from railgsa_ros.scenario import run_scenario
from railgsa_ros.standards.en13848 import Limits, en13848_table
from railgsa_ros.standards.sampling import DX_M
from railgsa_ros.standards.sections import section_sd
from railgsa_ros.uncertainty import UncertaintyConfig
from railgsa_ros.uncertainty.parameters import table3

MM = 1e-3
DEFECTS = 'dip@150:len=6:depth=0.02,dip@300:len=6:depth=0.03,dip@520:len=8:depth=0.04'
CHEAP = UncertaintyConfig(rule='pem3', order=1, germ_samples=256, n_mc=1000,
                          window_length=10.0)


@pytest.fixture(scope='module')
def simulated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """30 s at 22 m/s (660 m) over German-low track with three dips."""
    run = run_scenario('german-low', 22.0, 30.0, 1000.0, 'adxl355', 3, defects=DEFECTS)
    return write_run(tmp_path_factory.mktemp('offline') / 'run', run), run


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_chunks_of_a_bag_are_the_whole_stream_in_log_time_order(simulated, tmp_path: Path,
                                                                storage: str) -> None:
    _, run = simulated
    bag = write_run(tmp_path / storage, run, storage=storage)
    whole = read_imu(bag)
    pieces = list(iter_imu(bag, chunk=4000))
    assert len(pieces) >= 4
    for name in ('stamps_ns', 'log_time_ns', 'accel', 'frame_ids', 'covariance',
                 'odom_stamps_ns', 'speed_mps'):
        joined = np.concatenate([getattr(p, name) for p in pieces])
        assert np.array_equal(joined, getattr(whole, name)), name
    for a, b in pairwise(pieces):
        logs = np.concatenate([a.log_time_ns, b.log_time_ns])
        assert np.all(np.diff(logs) >= 0)


def test_chunks_are_in_log_time_order_when_the_file_is_not(simulated, tmp_path: Path) -> None:
    """Odometry recorded after the IMU (later MCAP chunks hold earlier log times): the pieces
    still come in log-time order, through the chunk indexes, and hold every message."""
    _, run = simulated
    encoder = RunEncoder(run)
    topics = encoder.topics()
    batches = encoder.encode()
    bag = tmp_path / 'late_odometry'
    with BagWriter(bag, 'mcap') as writer:
        for key in ('imu', 'odom'):
            writer.add_topic(*topics[key])
        writer.write_batches({topics['imu'][0]: batches['imu']})
        writer.write_batches({topics['odom'][0]: batches['odom']})  # after every IMU message
    whole = read_imu(bag)
    pieces = list(iter_imu(bag, chunk=4000))
    assert len(pieces) >= 2  # the IMU waits for the odometry chunks (the reader's docstring)
    for name in ('stamps_ns', 'odom_stamps_ns', 'speed_mps'):
        assert np.array_equal(np.concatenate([getattr(p, name) for p in pieces]),
                              getattr(whole, name))
    for a, b in pairwise(pieces):
        assert max(a.log_time_ns.max(), a.odom_stamps_ns.max()) <= b.log_time_ns.min()


def _whole_run(bag: Path, config: UncertaintyConfig) -> tuple[Output, np.ndarray, Output]:
    """The old way: the whole bag in memory, one call of the input policy (independent of the
    driver); the outputs that are not INVALID, their speeds and all outputs."""
    stream = read_imu(bag)
    policy = InputStage(config.inversion)
    out = Output.concat([policy.odometry(stream.odom_stamps_ns, stream.speed_mps),
                         policy.imu(stream.stamps_ns, stream.accel, stream.frame_ids,
                                    stream.covariance), policy.flush()])
    keep = out.quality != Quality.INVALID
    valid = Output(*(getattr(out, f)[keep] for f in
                     ('stamps_ns', 'chainage_m', 'u_m', 'quality', 'speed_mps')))
    return valid, valid.speed_mps, out


def test_streamed_review_equals_the_whole_array_results(simulated) -> None:
    bag, _ = simulated
    limits = Limits(en13848_table(), 'd1')
    config = UncertaintyConfig().with_(inversion=UncertaintyConfig().inversion.with_(
        rate_hz=1000.0))
    runs = [run_stream(Source(bag), config, None, None, limits, rate_from_bag=False,
                       chunk=chunk)[0] for chunk in (2500, 10 ** 7)]
    out, speed, every = _whole_run(bag, config)
    expected = find_exceedances(out.chainage_m, out.u_m, speed, out.stamps_ns, limits)
    assert len(expected) >= 3
    whole_sections = section_sd(out.chainage_m, out.u_m, speed)
    for run in runs:  # chainage is a running sum: the same within 1e-12 for any chunking
        assert len(run.exceedances) == len(expected)
        for got, want in zip(run.exceedances, expected, strict=True):
            assert (got.level, got.confidence, got.peak_stamp_ns, got.peak_u_m) == \
                (want.level, want.confidence, want.peak_stamp_ns, want.peak_u_m)
            assert [got.start_m, got.end_m, got.peak_m] == pytest.approx(
                [want.start_m, want.end_m, want.peak_m], rel=1e-12)
        assert run.emitted == len(every) and run.last[0] == every.stamps_ns[-1]
        assert run.last[1] == pytest.approx(every.chainage_m[-1], rel=1e-12)
        k = int(np.argmax(np.abs(out.u_m)))
        assert (run.peak.stamp_ns, run.peak.value_m) == (out.stamps_ns[k], out.u_m[k])
        from railgsa_ros.standards.sections import grid_sections

        g = run.grid
        sections = grid_sections(g.x_m, g.u_m, g.valid, run.section_speeds)
        assert np.array_equal(sections.start_m, whole_sections.start_m)
        np.testing.assert_allclose(sections.sd_m, whole_sections.sd_m, rtol=1e-12)
        np.testing.assert_allclose(sections.speed_mps, whole_sections.speed_mps, rtol=1e-12)
    np.testing.assert_allclose(runs[0].grid.u_m, runs[1].grid.u_m, rtol=1e-9, atol=1e-15)


def _arrays(obj: object, seen: set[int] | None = None) -> list[np.ndarray]:
    """Every numpy array reachable from an object's attributes, lists, dicts and tuples."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return []
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return [obj]
    if isinstance(obj, dict):
        return [a for v in obj.values() for a in _arrays(v, seen)]
    if isinstance(obj, list | tuple):
        return [a for v in obj for a in _arrays(v, seen)]
    if hasattr(obj, '__dict__') and type(obj).__module__.startswith('railgsa_ros'):
        return [a for v in vars(obj).values() for a in _arrays(v, seen)]
    if hasattr(obj, '__dataclass_fields__'):
        return [a for f in obj.__dataclass_fields__ for a in _arrays(getattr(obj, f), seen)]
    return []


@pytest.mark.parametrize('rate_hz', [500.0, 2000.0])
def test_the_review_keeps_arrays_of_the_run_length_not_of_the_samples(tmp_path: Path,
                                                                     rate_hz: float) -> None:
    run = run_scenario('german-low', 25.0, 24.0, rate_hz, 'adxl355', 5)
    bag = write_run(tmp_path / 'run', run)
    review = build_review(ReviewOptions(bag, CHEAP, dists=table3()))
    cells = int(np.ceil(review.run.length_m / DX_M)) + 2
    samples = run.stamps_ns.size
    sizes = [a.shape[0] if a.ndim else 1 for a in _arrays(review.run)]
    assert len(review.run.grid) <= cells
    # nothing per sample: the largest array is the grid (or a sensitivity/worst vector)
    assert max(sizes) <= max(cells, review.run.design.points, 256)
    assert samples > 4 * cells if rate_hz == 2000.0 else samples > cells
    g = review.run.grid  # 21 bytes a cell
    assert sum(a.nbytes for a in (g.u_m, g.lower_m, g.upper_m, g.speed_mps, g.valid)) \
        <= 21 * cells


def _gnss_bag(path: Path, run: object, scale_error: float, sigma_m: float, rate_hz: float,
              seed: int) -> tuple[Path, tuple[float, float], float]:
    """A bag of a run whose odometry reads (1 + scale_error) times the speed, with NavSatFix
    fixes at rate_hz along a curve (radius 2 km) with sigma_m of noise per axis."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    fix_t, fix_s = store.types[NAV_SAT_FIX], store.types['sensor_msgs/msg/NavSatStatus']
    header_t = store.types['std_msgs/msg/Header']
    time_t = store.types['builtin_interfaces/msg/Time']
    origin, radius, heading = (48.1, 11.5), 2000.0, 0.3
    odometry = replace(run, speed_mps=np.asarray(run.speed_mps) * (1 + scale_error))
    encoder = RunEncoder(odometry)
    rng = np.random.default_rng(seed)
    t_fix = np.arange(run.stamps_ns[0], run.stamps_ns[-1], int(1e9 / rate_hz))
    s = np.interp(t_fix, run.stamps_ns, run.chainage_m - run.chainage_m[0])
    angle = heading + s / radius
    east = radius * (np.sin(angle) - np.sin(heading)) + rng.normal(0, sigma_m, s.size)
    north = radius * (np.cos(heading) - np.cos(angle)) + rng.normal(0, sigma_m, s.size)
    lat, lon = from_local(east, north, origin)
    with BagWriter(path, 'mcap') as writer:
        topics = encoder.topics()
        for key in ('imu', 'odom', 'truth'):
            writer.add_topic(*topics[key])
        writer.add_topic('/gnss/fix', NAV_SAT_FIX, record_qos(True, 10))
        batches = encoder.encode()
        raws = [bytes(store.serialize_cdr(fix_t(
            header_t(time_t(int(t // 10**9), int(t % 10**9)), 'gnss'),
            fix_s(0, 1), la, lo, 500.0, np.diag([sigma_m ** 2] * 3).ravel(), 2), NAV_SAT_FIX))
                for t, la, lo in zip(t_fix, lat, lon, strict=True)]
        writer.write_batches({**{topics[k][0]: batches[k] for k in ('imu', 'odom', 'truth')},
                              '/gnss/fix': (t_fix, raws)})
    return path, origin, heading


def _deepest(exceedances: list, x: float) -> object:
    """The exceedance of largest |peak| within 10 m of x (a dip, not its filter side lobes)."""
    near = [e for e in exceedances if abs(e.peak_m - x) < 10]
    assert near, x
    return max(near, key=lambda e: abs(e.peak_u_m))


def test_gnss_corrects_a_wheel_diameter_error_and_places_defects_within_1_m(tmp_path: Path
                                                                           ) -> None:
    run = run_scenario('german-low', 25.0, 60.0, 1000.0, 'adxl355', 7,
                       defects='dip@400:len=6:depth=0.03,dip@1100:len=8:depth=0.04')
    bag, origin, heading = _gnss_bag(tmp_path / 'gnss', run, 0.004, 2.0, 5.0, 1)
    options = ReviewOptions(bag, dists=None, reference=Reference('L1', '2', 'decreasing', 12.5))
    review = build_review(options)
    scale = review.location.scale
    assert scale.value == pytest.approx(1 / 1.004, abs=max(3 * scale.std, 2e-4))
    assert scale.std < 5e-4
    true_x = {403.0: 0.03, 1104.0: 0.04}  # dip centres: start + length / 2
    for x in true_x:
        assert abs(_deepest(review.exceedances, x).peak_m - x) < 1.0
    # without the correction the far dip is 4.4 m off
    plain = build_review(replace(options, gnss_topic='/none'))
    assert _deepest(plain.exceedances, 1104.0).peak_m - 1104.0 > 3.5
    # the defects' positions: on the curve within a few metres (fixes have 2 m of noise)
    lat, lon = review.location.lat_lon(np.array(list(true_x)))
    east, north = to_local(lat, lon, origin)
    s = np.array(list(true_x))
    angle = heading + s / 2000.0
    truth_e = 2000.0 * (np.sin(angle) - np.sin(heading))
    truth_n = 2000.0 * (np.cos(heading) - np.cos(angle))
    assert np.all(np.hypot(east - truth_e, north - truth_n) < 2.0)
    ref = review.location.reference
    km = ref.km(s)
    assert km == pytest.approx(12.5 - s / 1e3)
    assert ref.chainage(km) == pytest.approx(s)  # the figures' km axis maps back
    assert ref.label(1104.0) == 'km 11.396 (1104.0 m)'


def test_simulated_gnss_and_wheel_error_put_defects_within_1_m_of_the_truth(tmp_path: Path
                                                                          ) -> None:
    from railgsa_ros.geo import default_line

    bag = tmp_path / 'sim'
    dips = {803.0: 0.03, 1904.0: 0.04}  # dip centres (start + length / 2), m from the start
    assert main(['simulate', '--out', str(bag), '--speed', '30', '--duration', '80',
                 '--defects', 'dip@800:len=6:depth=0.03,dip@1900:len=8:depth=0.04',
                 '--odom-scale-error', '0.004', '--gnss', '--seed', '4']) == 0
    review = build_review(ReviewOptions(bag, dists=None))
    assert review.location.scale.value == pytest.approx(1 / 1.004, abs=3e-4)
    for x in dips:
        assert abs(_deepest(review.exceedances, x).peak_m - x) < 1.0
    lat, lon = review.location.lat_lon(np.array(list(dips)))
    true_lat, true_lon = default_line(2400.0).position(np.array(list(dips)))
    east, north = to_local(lat, lon, (float(true_lat[0]), float(true_lon[0])))
    true_e, true_n = to_local(true_lat, true_lon, (float(true_lat[0]), float(true_lon[0])))
    assert np.all(np.hypot(east - true_e, north - true_n) < 2.0)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_gnss_scale_and_positions_hold_when_the_train_brakes_to_a_stop(tmp_path: Path,
                                                                        storage: str) -> None:
    """Each fix is placed on the odometry chainage at its own stamp whatever the reader's
    batches (a sqlite3 bag is read in one: fixes were placed from the run's last odometry
    sample, at standstill, which gave a scale of 1.54 or no track at all)."""
    from railgsa_ros.geo import default_line
    from railgsa_ros.location import gnss_pass

    bag = tmp_path / 'brake'
    assert main(['simulate', '--out', str(bag), '--speed-profile',
                 'cruise:25:20s,brake:25-0:20s,stop:5s', '--odom-scale-error', '0.004',
                 '--gnss', '--seed', '3', '--storage', storage]) == 0
    start = int(read_imu(bag).stamps_ns[0])
    location = gnss_pass(bag, '/odom', '/gnss/fix', start, Reference())
    scale = location.scale
    assert scale.value == pytest.approx(1 / 1.004, abs=max(3 * scale.std, 5e-4))
    ground = np.array([100.0, 400.0, 700.0])  # m from the start (the run covers 750 m)
    lat, lon = location.lat_lon(ground)
    true_lat, true_lon = default_line(750.0).position(ground)
    origin = (float(true_lat[0]), float(true_lon[0]))
    east, north = to_local(lat, lon, origin)
    true_e, true_n = to_local(true_lat, true_lon, origin)
    assert np.all(np.hypot(east - true_e, north - true_n) < 3.0)


def test_invert_csv_has_km_and_positions_and_the_corrected_chainage(tmp_path: Path,
                                                                    capsys) -> None:
    from railgsa_ros.geo import default_line

    bag = tmp_path / 'sim'
    assert main(['simulate', '--out', str(bag), '--speed', '30', '--duration', '40',
                 '--odom-scale-error', '0.004', '--gnss', '--seed', '5']) == 0
    out = tmp_path / 'u.csv'
    assert main(['invert', str(bag), '--csv', str(out), '--km-origin', '7.5',
                 '--direction', 'decreasing']) == 0
    assert 'odometry scale 0.99' in capsys.readouterr().err
    with out.open(encoding='utf-8') as f:
        rows = list(csv.DictReader(f))
    chainage = np.array([float(r['chainage_m']) for r in rows])
    km = np.array([float(r['km']) for r in rows])
    np.testing.assert_allclose(km, 7.5 - chainage / 1e3, atol=1e-6)
    truth = read_imu(bag)  # the true distance: 30 m/s over the IMU stamps
    travelled = 30.0 * (truth.stamps_ns[-1] - truth.stamps_ns[0]) * 1e-9
    assert chainage[-1] == pytest.approx(travelled, abs=1.0)  # 4.8 m more without GNSS
    lat, lon = (np.array([float(r[k]) for r in rows]) for k in ('lat', 'lon'))
    true_lat, true_lon = default_line(1300.0).position(chainage[::500])
    east, north = to_local(lat[::500], lon[::500], (float(true_lat[0]), float(true_lon[0])))
    true_e, true_n = to_local(true_lat, true_lon, (float(true_lat[0]), float(true_lon[0])))
    assert np.all(np.hypot(east - true_e, north - true_n) < 3.0)


def test_review_writes_defects_sections_and_a_json_summary(tmp_path: Path, capsys) -> None:
    run = run_scenario('german-low', 25.0, 40.0, 1000.0, 'adxl355', 7,
                       defects='dip@400:len=6:depth=0.03')
    bag, _, _ = _gnss_bag(tmp_path / 'gnss', run, 0.0, 2.0, 5.0, 2)
    out = tmp_path / 'out'
    assert main(['review', str(bag), '--out', str(out), '--line', 'L1', '--track', '2',
                 '--km-origin', '3.2', '--json', '--no-progress',
                 '--params', str(_params(tmp_path))]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary['location']['line'] == 'L1' and summary['location']['gnss']
    with (out / 'defects.csv').open(encoding='utf-8') as f:
        defects = list(csv.DictReader(f))
    assert len(defects) == sum(sum(c.values()) for c in summary['exceedances'].values())
    dip = [d for d in defects if abs(float(d['chainage_m']) - 403.0) < 2]
    assert dip and float(dip[0]['km']) == pytest.approx(3.2 + float(dip[0]['chainage_m']) / 1e3,
                                                        abs=1e-4)
    assert float(dip[0]['depth_mm']) < -20 and dip[0]['line'] == 'L1'
    assert 0.0 <= float(dip[0]['exceedance_probability']) <= 1.0
    assert dip[0]['lat'] and dip[0]['time_utc'].startswith('2023-')
    geo = json.loads((out / 'review.geojson').read_text(encoding='utf-8'))
    kinds = [f['properties']['kind'] for f in geo['features']]
    assert geo['type'] == 'FeatureCollection' and kinds.count('defect') == len(defects)
    point = next(f for f in geo['features']
                 if f['properties'].get('stamp_ns') == int(dip[0]['stamp_ns']))
    assert point['geometry']['coordinates'] == pytest.approx([float(dip[0]['lon']),
                                                              float(dip[0]['lat'])])
    with (out / 'sections.csv').open(encoding='utf-8') as f:
        sections = list(csv.DictReader(f))
    assert [float(s['start_m']) for s in sections] == [0, 200, 400, 600, 800]
    assert summary['sections']['count'] == len(sections) == kinds.count('section')
    assert summary['worst_defect']['level'] in ('AL', 'IL', 'IAL')
    assert set(summary['files']) == {'report', 'defects_csv', 'sections_csv', 'geojson'}
    assert all(Path(p).is_file() for p in summary['files'].values())


def _params(tmp_path: Path) -> Path:
    """A params file with the location keys of the nodes (line overridden on the command line),
    and a cheap uncertainty design (a faster review)."""
    path = tmp_path / 'params.yaml'
    path.write_text('irregularity_node:\n  ros__parameters:\n    line: from-file\n'
                    '    direction: increasing\nuncertainty_node:\n  ros__parameters:\n'
                    '    rule: pem3\n    order: 1\n    germ_samples: 256\n    n_mc: 1000\n',
                    encoding='utf-8')
    return path


def test_a_run_shorter_than_200_m_gets_a_report(tmp_path: Path, capsys) -> None:
    # 160 m: the 100 m (5 s) of INVALID warm-up and tail leave 60 m of output
    run = run_scenario('german-low', 20.0, 8.0, 1000.0, 'adxl355', 1)
    bag = write_run(tmp_path / 'short', run)
    assert main(['review', str(bag), '--out', str(tmp_path / 'out'), '--no-uncertainty']) == 0
    assert 'report.html' in capsys.readouterr().out
    with (tmp_path / 'out' / 'sections.csv').open(encoding='utf-8') as f:
        assert list(csv.DictReader(f)) == []  # no 200 m section half covered
    # 80 m: every output INVALID (shorter than the band window): one line
    short = write_run(tmp_path / 'shorter', run_scenario('german-low', 20.0, 4.0, 1000.0,
                                                          'adxl355', 1))
    assert main(['review', str(short), '--out', str(tmp_path / 'o2'), '--no-uncertainty']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'INVALID' in err and not (tmp_path / 'o2').exists()


def test_a_few_zero_stamps_are_left_out_not_a_memory_error(tmp_path: Path, capsys) -> None:
    """Zero header stamps are malformed (counted and left out by the input policy, as by a
    node's intake); the review of the rest is written (before the policy: a 34,000 km
    chainage jump)."""
    run = run_scenario('german-low', 20.0, 20.0, 1000.0, 'adxl355', 1)
    stamps = run.stamps_ns.copy()
    stamps[[5000, 5001, 12000]] = 0
    bag = write_run(tmp_path / 'zeros', replace(run, stamps_ns=stamps))
    out = tmp_path / 'out'
    assert main(['review', str(bag), '--out', str(out), '--no-uncertainty', '--json',
                 '--no-progress']) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (out / 'report.html').is_file()
    # the bag's odometry starts at 5 s (the zero stamps upset its sampling): the first
    # odometry sample gives the speed back to odom_timeout_s (1 s) before it, before that the
    # speed is unknown (INVALID, the chainage holds), not the first odometry guessed further
    read = read_imu(bag)
    covered = (run.stamps_ns >= read.odom_stamps_ns.min() - InputOptions().odom_timeout_s * 1e9)
    assert summary['length_km'] * 1e3 == pytest.approx(
        run.chainage_m[-1] - run.chainage_m[covered][0], abs=1.0)


def test_negative_odometry_speed_gives_one_line(tmp_path: Path, capsys) -> None:
    run = run_scenario('german-low', 20.0, 20.0, 1000.0, 'adxl355', 1)
    bag = write_run(tmp_path / 'reverse', replace(run, speed_mps=-np.asarray(run.speed_mps)))
    assert main(['review', str(bag), '--out', str(tmp_path / 'out'), '--no-uncertainty']) == 2
    err = capsys.readouterr().err
    assert err.startswith('error: ') and err.count('\n') == 1 and str(bag) in err
