"""railgsa fleet on ``railgsa simulate-passes`` bags with GNSS: defects placed against the truth.

Five passes 30 days apart over one line (the simulator's default geometry, GNSS at 5 Hz with
2 m noise), 23-30 m/s, 200 Hz, wheel-diameter errors up to 0.5 %, vehicles within 3 %: a dip
that deepens by 0.04 mm/day and one that appears from the fourth pass. The line geometry is
given to the fleet as the GeoJSON the simulator writes; positions are then in the line's own
chainage.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from railgsa_ros.cli.main import main
from railgsa_ros.fleet import db
from railgsa_ros.geo import geodetic_to_enu
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.review.truth import load_truth

DEFECTS = 'dip@600:len=8:depth=6e-3:growth=4e-5,dip@1000:len=6:depth=7e-3:from=4'
GROW, NEW = 0, 1  # defect ids in the truth files


@pytest.fixture(scope='module')
def fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp('gnss')
    out = root / 'passes'
    assert main(['simulate-passes', '--out', str(out), '--passes', '5', '--days', '30',
                 '--section-km', '0.3-1.3', '--defects', DEFECTS, '--speed-range', '23-30',
                 '--stop-every', '0', '--rate', '200', '--sensor', 'adxl355', '--seed', '3']) == 0
    truths = [json.loads(p.read_text()) for p in sorted((out / 'truth').glob('pass_*.json'))]
    geometry = out / 'line.geojson'  # written by simulate-passes
    bags = sorted(str(p) for p in out.glob('pass_*'))
    path = root / 'fleet.duckdb'
    assert main(['fleet', 'ingest', *bags, '--db', str(path), '--workers', '2', '--line',
                 'sim-1', '--line-geometry', str(geometry)]) == 0
    return path, truths, bags


def _band_depth(bag, centre_m):
    """Depth (m) of the D1-filtered truth profile of a bag at its deepest point near centre."""
    truth = load_truth(bag)
    x = np.arange(centre_m - 30, centre_m + 30, 0.05)
    band = band_distance(np.interp(x, truth.chainage_m, truth.u_m), 0.05, 'd1')
    return -band[np.abs(x - centre_m) < 4].min()


def test_passes_are_anchored_by_gnss(fleet):
    path, truths, _ = fleet
    con = db.connect(path, read_only=True)
    rows = con.execute("""SELECT a.method, a.scale, a.scale_sd FROM alignments a
                          JOIN passes p USING (pass_id) ORDER BY p.start_time""").fetchall()
    assert [r[0] for r in rows] == ['gnss'] + ['gnss+xcorr'] * 4
    # the first pass's fixes give the frame: its odometry scale within its stated SD
    (_, scale_1, sd_1), odom_1 = rows[0], truths[0]['odom_scale']
    assert abs(scale_1 * odom_1 - 1) < 4 * sd_1
    # the others relative to it by cross-correlation; their SD includes the frame's
    for (_, scale, sd), truth in zip(rows[1:], truths[1:], strict=True):
        relative = scale * truth['odom_scale'] / (scale_1 * odom_1) - 1
        assert abs(relative) < 2e-4 and sd >= sd_1


def test_defects_within_1_m_of_the_truth(fleet):
    path, truths, _ = fleet
    con = db.connect(path, read_only=True)
    found = con.execute('SELECT x_m, lat, lon, new FROM defects ORDER BY x_m').fetchall()
    last = {d['id']: d for d in truths[-1]['defects']}
    assert len(found) == 2
    for (x_m, lat, lon, new), key in zip(found, (GROW, NEW), strict=True):
        assert abs(x_m - last[key]['centre_m']) < 1.0
        east, north, _ = geodetic_to_enu(lat, lon, 0.0, last[key]['lat_deg'],
                                         last[key]['lon_deg'])
        assert np.hypot(east, north) < 1.0
        assert new == (key == NEW)


def test_growth_rate_within_its_uncertainty(fleet):
    path, truths, bags = fleet
    con = db.connect(path, read_only=True)
    centre = truths[0]['defects'][GROW]['centre_m']
    rate, se, passes = con.execute('SELECT rate_mm_per_year, rate_se_mm_per_year, passes '
                                   'FROM defects WHERE abs(x_m - ?) < 2', [centre]).fetchone()
    days = np.array([t['days'] for t in truths])
    depth = np.array([_band_depth(b, centre) for b in bags])
    truth_rate = np.polyfit(days, depth, 1)[0] * 365.25e3
    assert passes == 5
    assert abs(rate - truth_rate) < 3 * se and se < 0.25 * truth_rate
