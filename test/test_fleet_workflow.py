"""The README's fleet workflow, command for command, checked against the simulation's truth.

The commands are read from the README's "Fleet workflow" block and run as they stand (the
shell's glob expanded), with two options appended to ``simulate-passes`` to keep the series
short: the section 0.3-1.6 km (both default defects inside) and 200 Hz. Everything else is the
default: 5 weekly passes at 15-30 m/s, every third with a stop, vehicles within 3 %,
wheel-diameter errors up to 0.5 %, GNSS at 5 Hz with 2 m of noise, the default defects (a dip
growing 0.04 mm/day, a new one from pass 3), the default detection (half the alert limit) and
the built-in 2-worker LocalCluster on 127.0.0.1.
"""

from __future__ import annotations

import csv
import glob
import json
from pathlib import Path
import re
import shlex

import numpy as np
import pytest

from railgsa_ros.cli.main import main
from railgsa_ros.fleet import db
from railgsa_ros.fleet.fuse import PRIOR_SIGMA_M
from railgsa_ros.geo import geodetic_to_enu
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.review.truth import load_truth
from railgsa_ros.standards.sections import SECTION_M

README = Path(__file__).resolve().parents[1] / 'README.md'
SHORT = ['--section-km', '0.3-1.6', '--rate', '200']  # appended: argparse keeps the last value
GROW, NEW = 0, 1  # defect ids in the truth files


def readme_commands() -> list[list[str]]:
    """The ``railgsa`` command lines of the README's fleet workflow block (comments dropped,
    continuation lines joined), split as a shell would."""
    text = README.read_text()
    block = re.search(r'### Fleet workflow.*?```sh\n(.*?)```', text, re.S).group(1)
    lines = block.replace('\\\n', ' ').splitlines()
    return [shlex.split(line, comments=True) for line in lines if line.startswith('railgsa ')]


@pytest.fixture(scope='module')
def workflow(tmp_path_factory):
    """Run the README's commands in a fresh directory; their exit codes and outputs."""
    import contextlib
    import io
    import os

    root = tmp_path_factory.mktemp('workflow')
    commands = readme_commands()
    assert [c[1] for c in commands] == ['simulate-passes', 'fleet', 'fleet', 'fleet']
    outputs = []
    here = os.getcwd()
    os.chdir(root)
    try:
        for argv in commands:
            argv = argv[1:] + (SHORT if argv[1] == 'simulate-passes' else [])
            argv = [a for arg in argv for a in (sorted(glob.glob(arg)) if '*' in arg else [arg])]
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                code = main(argv)
            outputs.append((code, out.getvalue()))
    finally:
        os.chdir(here)
    truths = [json.loads(p.read_text()) for p in sorted((root / 'passes' / 'truth').glob(
        'pass_*.json'))]
    return root, outputs, truths


def _db(root):
    return db.connect(root / 'fleet.duckdb', read_only=True)


def _band(bag, lo_m, hi_m):
    """(chainage, D1-filtered truth) of a bag's truth topic on a 0.05 m grid over lo-hi m."""
    truth = load_truth(bag)
    x = np.arange(max(lo_m, truth.chainage_m[0]), min(hi_m, truth.chainage_m[-1]), 0.05)
    return x, band_distance(np.interp(x, truth.chainage_m, truth.u_m), 0.05, 'd1')


def test_every_command_succeeds(workflow):
    _, outputs, truths = workflow
    assert [code for code, _ in outputs] == [0, 0, 0, 0]
    assert len(truths) == 5 and outputs[1][1].count('ok ') == 5


def test_passes_are_anchored_by_gnss(workflow):
    root, _, truths = workflow
    rows = _db(root).execute("""SELECT a.method, a.scale, a.scale_sd FROM alignments a
                                JOIN passes p USING (pass_id) ORDER BY p.start_time""").fetchall()
    assert [r[0] for r in rows] == ['gnss'] + ['gnss+xcorr'] * 4
    # the first pass's fixes give the frame: its odometry scale within its stated SD
    (_, scale_1, sd_1), odom_1 = rows[0], truths[0]['odom_scale']
    assert abs(scale_1 * odom_1 - 1) < 4 * sd_1
    # the others relative to it by cross-correlation; their SD includes the frame's
    for (_, scale, sd), truth in zip(rows[1:], truths[1:], strict=True):
        relative = scale * truth['odom_scale'] / (scale_1 * odom_1) - 1
        assert abs(relative) < 2e-4 and sd >= sd_1


def test_defects_within_1_m_of_the_truth_and_the_new_one_flagged(workflow):
    root, _, truths = workflow
    found = _db(root).execute('SELECT x_m, lat, lon, new, first_seen FROM defects '
                              'ORDER BY x_m').fetchall()
    last = {d['id']: d for d in truths[-1]['defects']}
    assert len(found) == 2
    for (x_m, lat, lon, new, _), key in zip(found, (GROW, NEW), strict=True):
        assert abs(x_m - last[key]['centre_m']) < 1.0
        east, north, _ = geodetic_to_enu(lat, lon, 0.0, last[key]['lat_deg'],
                                         last[key]['lon_deg'])
        assert np.hypot(east, north) < 1.0
        assert new == (key == NEW)
    first = truths[last[NEW]['first_pass'] - 1]['date'][:10]
    assert found[1][4].date().isoformat() == first


def test_growth_rate_within_its_uncertainty(workflow):
    """The rate of the D1 depth (what EN 13848-5 limits) against the rate of the band-filtered
    truth's depth over the same dates: within 2 stated SEs, and significant."""
    root, _, truths = workflow
    centre = truths[0]['defects'][GROW]['centre_m']
    rate, se, passes = _db(root).execute('SELECT rate_mm_per_year, rate_se_mm_per_year, passes '
                                         'FROM defects WHERE abs(x_m - ?) < 2',
                                         [centre]).fetchone()
    bags = [root / 'passes' / t['bag'] for t in truths]
    depth = []
    for bag in bags:
        x, band = _band(bag, centre - 30, centre + 30)
        depth.append(-band[np.abs(x - centre) < 4].min())
    truth_rate = np.polyfit([t['days'] for t in truths], depth, 1)[0] * 365.25e3
    assert passes == 5
    assert abs(rate - truth_rate) <= 2 * se and se < 0.5 * truth_rate


def test_200_m_sections_match_the_truth(workflow):
    """Each pass's SD per 200 m section against the D1-filtered truth's over the same section:
    within the project's D1 accuracy target (an RMS error e changes an SD by at most e)."""
    root, _, truths = workflow
    con = _db(root)
    checked = 0
    for truth in truths:
        rows = con.execute("""SELECT s.start_m, s.sd_m FROM segments s JOIN passes p
                              USING (pass_id) WHERE p.bag LIKE ? AND s.coverage = 1""",
                           [f'%{truth["bag"]}']).fetchall()
        x, band = _band(root / 'passes' / truth['bag'], truth['start_m'], truth['end_m'])
        for start, sd in rows:
            inside = (x >= start) & (x < start + SECTION_M)
            if x[0] + 50 < start and start + SECTION_M < x[-1] - 50:  # clear of filter edges
                assert abs(sd - band[inside].std()) < PRIOR_SIGMA_M, (truth['bag'], start)
                checked += 1
    assert checked >= 15


def test_report_and_query(workflow):
    root, outputs, truths = workflow
    html = Path(outputs[2][1].strip())
    assert html == Path('fleet-report') / 'report.html'
    text = (root / html).read_text()
    assert 'NEW' in text and text.count('<img') == 2  # trends, sections
    assert 'class="zoom map"' in text and 'class="zoom profile"' in text  # GNSS: a map
    rows = list(csv.DictReader(outputs[3][1].splitlines()))
    truth_km = sorted(d['centre_km'] for d in truths[-1]['defects'])
    assert [abs(float(r['km']) - k) < 1e-3 for r, k in zip(rows, truth_km, strict=True)] \
        == [True, True]
    assert [r['new'] for r in rows] == ['False', 'True']
