"""railgsa fleet end to end on simulated passes over one line, against the simulation's truth.

Five passes over the same 2.5 km German-low line, 30 days apart, at 23-30 m/s and 200 Hz, from
different start positions, with different vehicles (parameters within a few %) and odometry
scale errors of a few tenths of a percent; a dip that deepens by 0.04 mm/day and a second one
that appears from the fourth pass on; plus one corrupt bag. Ingested by ``railgsa fleet ingest``
on a 2-worker LocalCluster (127.0.0.1) that the test starts and passes by ``--scheduler``
(``test_fleet_workflow.py`` runs the built-in one).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import json

import numpy as np
import pytest

from railgsa_ros.bag import write_run
from railgsa_ros.cli.main import main
from railgsa_ros.fleet import db
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.scenario import DEFAULT_START_NS, run_scenario
from railgsa_ros.track import german_psd, save_csv, synthesize
from railgsa_ros.vehicle import VehicleParams

DAY_NS = 86400 * 10**9
DAYS = np.array([0, 30, 60, 90, 120])
STARTS = [50.0, 120.0, 0.0, 200.0, 30.0]  # true line position of each pass's first sample, m
SPEEDS = [25.0, 28.0, 23.5, 30.0, 26.0]  # m/s
ODO_ERR = [0.002, 0.004, -0.003, 0.0, -0.004]  # odometry reads (1 + e) x the true speed
GROW_AT, GROW_D0, GROW_RATE = 600.0, 6e-3, 4e-5  # dip start (m), depth (m), m/day
NEW_AT, NEW_DEPTH, NEW_FROM = 900.0, 7e-3, 3  # appears from pass index 3
DIP_M = 8.0


@dataclass
class Series:
    bags: list
    broken: object
    truth_depth: dict  # defect name -> (days, band-filtered truth depth (m)) per pass
    truth_x: dict  # defect name -> true position of the band-filtered peak (m, line)


def _truth_peak(run, centre):
    """(position, depth) of the D1-filtered truth's deepest point within +-6 m of centre."""
    x = np.arange(run.chainage_m[0], run.chainage_m[-1], 0.05)
    band = band_distance(np.interp(x, run.chainage_m, run.truth_u_m), 0.05, 'd1')
    near = np.abs(x - centre) < 6
    k = np.argmin(band[near])
    return x[near][k], -band[near][k]


@pytest.fixture(scope='module')
def series(tmp_path_factory):
    root = tmp_path_factory.mktemp('fleet')
    x, u = synthesize(lambda w: german_psd(w, 'low'), 2500.0, 0.05, seed=5)
    rng = np.random.default_rng(17)
    bags, depth, pos = [], {'grow': [], 'new': []}, {'grow': [], 'new': []}
    for i, day in enumerate(DAYS):
        keep = x >= STARTS[i]
        save_csv(root / f'line{i}.csv', x[keep], u[keep])
        defects = f'dip@{GROW_AT}:len={DIP_M}:depth={GROW_D0 + GROW_RATE * day}'
        if i >= NEW_FROM:
            defects += f',dip@{NEW_AT}:len=6:depth={NEW_DEPTH}'
        theta = VehicleParams().as_array() * (1 + 0.03 * rng.standard_normal(5))
        run = run_scenario(f'file:{root}/line{i}.csv', SPEEDS[i], 45.0, 200.0, 'adxl355', seed=i,
                           defects=defects, vehicle=VehicleParams(*theta),
                           start_ns=DEFAULT_START_NS + day * DAY_NS)
        for name, centre in (('grow', GROW_AT + DIP_M / 2), ('new', NEW_AT + 3)):
            px, pd = _truth_peak(run, centre)
            depth[name].append(pd)
            if name == 'grow' or i >= NEW_FROM:
                pos[name].append(px)
        odometry = replace(run, speed_mps=run.speed_mps * (1 + ODO_ERR[i]))  # wheel diameter
        bags.append(write_run(root / f'pass{i}.mcap', odometry))
    broken = root / 'broken.mcap'
    broken.write_bytes(b'\x89MCAP0\r\n' + bytes(range(256)) * 8)
    return Series(bags, broken, {k: (DAYS, np.array(v)) for k, v in depth.items()},
                  {k: float(np.mean(v)) for k, v in pos.items()})


@pytest.fixture(scope='module')
def ingested(series, tmp_path_factory):
    """The batch ingested with ``--scheduler`` on a 2-worker LocalCluster (127.0.0.1) that the
    test starts: exit code, database path, and whether the passes ran on that cluster."""
    from dask.distributed import LocalCluster

    path = tmp_path_factory.mktemp('db') / 'fleet.duckdb'
    bags = [str(b) for b in series.bags[:2]] + [str(series.broken)] + \
        [str(b) for b in series.bags[2:]]
    with LocalCluster(n_workers=2, threads_per_worker=1, host='127.0.0.1',
                      dashboard_address='127.0.0.1:0', silence_logs=40) as cluster:
        assert cluster.scheduler_address.startswith('tcp://127.0.0.1:')
        code = main(['fleet', 'ingest', *bags, '--db', str(path), '--scheduler',
                     cluster.scheduler_address, '--line', 'L1', '--track', '1'])
        ran_there = 'analyse_or_fail' in cluster.scheduler.task_prefixes
    return code, path, ran_there


def _frame(x_true):
    """A true line position in the frame of the line's first pass (its odometry from its start)."""
    return (x_true - STARTS[0]) * (1 + ODO_ERR[0])


def test_failing_bag_is_reported_and_the_rest_ingested(ingested, series, capsys):
    code, path, ran_there = ingested
    assert code == 1  # some bag failed
    assert ran_there  # on the cluster given by --scheduler
    con = db.connect(path, read_only=True)
    rows = con.execute('SELECT bag, status, message FROM passes ORDER BY pass_id').fetchall()
    assert [r[1] for r in rows].count('ok') == 5
    failed = [r for r in rows if r[1] == 'failed']
    assert len(failed) == 1 and failed[0][0].endswith('broken.mcap') and failed[0][2]
    assert '\n' not in failed[0][2]


def test_alignment_recovers_each_pass_frame(ingested):
    """Each pass's odometry is mapped onto the first pass's frame: scale and offset as simulated.
    The offset also carries each vehicle's own phase shift of the reconstruction (parameters a few
    % off the nominal ones move D1 features by about 0.1 m), which no single pass can measure:
    hence the 0.25 m floor."""
    _, path, _ = ingested
    con = db.connect(path, read_only=True)
    rows = con.execute("""SELECT a.offset_m, a.scale, a.offset_sd_m, a.scale_sd FROM alignments a
                          JOIN passes p USING (pass_id) WHERE p.status = 'ok'
                          ORDER BY p.start_time""").fetchall()
    for i, (offset, scale, offset_sd, scale_sd) in enumerate(rows):
        true_scale = (1 + ODO_ERR[0]) / (1 + ODO_ERR[i])
        assert abs(scale - true_scale) < max(4 * scale_sd, 2e-5), i
        assert abs(offset - _frame(STARTS[i])) < max(4 * offset_sd, 0.25), i


def test_growing_defect_and_its_rate(ingested, series):
    _, path, _ = ingested
    con = db.connect(path, read_only=True)
    rows = con.execute('SELECT x_m, passes, new, rate_mm_per_year, rate_se_mm_per_year, '
                       'depth_m, depth_sd_m, x_sd_m FROM defects WHERE abs(x_m - ?) < 3',
                       [_frame(series.truth_x['grow'])]).fetchall()
    assert len(rows) == 1
    x_m, passes, new, rate, se, depth, depth_sd, x_sd = rows[0]
    assert 0 < x_sd < 0.5  # the passes' scatter (no GNSS: the frame pass has an SD of 0)
    assert passes == 5 and not new
    days, truth = series.truth_depth['grow']
    truth_rate = np.polyfit(days, truth, 1)[0] * 365.25e3  # mm/year
    assert abs(rate - truth_rate) < 3 * se
    assert se < 0.25 * truth_rate  # the stated uncertainty says something
    assert abs(x_m - _frame(series.truth_x['grow'])) < 0.5
    assert abs(depth - truth[-1]) < 3 * depth_sd


def test_new_defect_is_flagged(ingested, series):
    _, path, _ = ingested
    con = db.connect(path, read_only=True)
    rows = con.execute('SELECT x_m, first_seen FROM defects WHERE new').fetchall()
    assert len(rows) == 1
    x_m, first_seen = rows[0]
    assert abs(x_m - _frame(series.truth_x['new'])) < 0.5
    assert first_seen.date() == db.timestamp(DEFAULT_START_NS + DAYS[NEW_FROM] * DAY_NS).date()


def test_query_lists_the_defects_between_km(ingested, series, capsys):
    _, path, _ = ingested
    capsys.readouterr()
    a = _frame(series.truth_x['grow']) / 1000 - 0.01
    assert main(['fleet', 'query', '--db', str(path), '--line', 'L1', '--from-km', str(a),
                 '--to-km', str(a + 0.02), '--json']) == 0
    found = json.loads(capsys.readouterr().out)
    assert len(found) == 1 and found[0]['passes'] == 5
    assert main(['fleet', 'query', '--db', str(path), '--line', 'L1', '--from-km', '0',
                 '--to-km', '3', '--csv']) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith('line,track,defect_id,km') and len(lines) >= 3
    assert main(['fleet', 'query', '--db', str(path), '--line', 'L1', '--from-km', '1.2',
                 '--to-km', '1.3']) == 0  # inside the line, no defect there
    assert json.loads(capsys.readouterr().out) == []


@pytest.mark.parametrize('args, says', [
    (['--line', 'nope', '--from-km', '0', '--to-km', '3'], "known lines: 'L1'"),
    (['--line', 'L1', '--track', '2', '--from-km', '0', '--to-km', '3'], "its tracks: '1'"),
    (['--line', 'L1', '--from-km', '5', '--to-km', '6'], 'which covers km '),
    (['--line', 'L1', '--from-km', '-2', '--to-km', '-1'], 'lies outside line'),
])
def test_query_of_an_unknown_line_or_range_is_one_line_exit_2(ingested, capsys, args, says):
    _, path, _ = ingested
    capsys.readouterr()
    assert main(['fleet', 'query', '--db', str(path), *args]) == 2
    out, err = capsys.readouterr()
    assert out == '' and err.startswith('error: ') and err.count('\n') == 1 and says in err


def test_report_writes_html_with_figures(ingested, tmp_path):
    _, path, _ = ingested
    out = tmp_path / 'report'
    assert main(['fleet', 'report', '--db', str(path), '--out', str(out)]) == 0
    html = (out / 'report.html').read_text()
    for png in ('trends_L1_1.png', 'sections_L1_1.png'):
        assert (out / png).stat().st_size > 5000 and png in html
    assert 'NEW' in html and 'broken.mcap' in html and 'class="zoom profile"' in html
    assert str(path.parent) not in html  # bags by name: no machine's paths
    geo = json.loads((out / 'fleet.geojson').read_text())
    defects = [f for f in geo['features'] if f['properties']['kind'] == 'defect']
    con = db.connect(path, read_only=True)
    assert len(defects) == con.execute('SELECT count(*) FROM defects').fetchone()[0]


def test_a_stored_bag_is_skipped(ingested, series, capsys):
    _, path, _ = ingested
    capsys.readouterr()
    assert main(['fleet', 'ingest', str(series.bags[0]), '--db', str(path), '--line', 'L1']) == 0
    assert 'skipped' in capsys.readouterr().out
    con = db.connect(path, read_only=True)
    assert con.execute('SELECT count(*) FROM passes').fetchone()[0] == 6


def test_missing_or_busy_database_is_one_line_exit_2(ingested, tmp_path, capsys):
    _, path, _ = ingested
    args = ['--line', 'L1', '--from-km', '0', '--to-km', '1']
    assert main(['fleet', 'query', '--db', str(tmp_path / 'none.duckdb'), *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith('error: ') and err.count('\n') == 1
    writer = db.connect(path)  # holds the database open for writing
    try:
        assert main(['fleet', 'query', '--db', str(path), *args]) == 2
        err = capsys.readouterr().err
        assert err.startswith('error: ') and err.count('\n') == 1
    finally:
        writer.close()


def test_slow_stretches_are_left_out_of_the_pass(tmp_path):
    """A pass that brakes to a stand and restarts: its cells below the speed the input policy
    trusts (the band's noise floor, the minimum design speed) are invalid, the rest kept."""
    from railgsa_ros.fleet.passes import PassOptions, analyse_pass, trusted_speeds

    speed = np.array([25.0, 25.0, 0.0, 0.0, 25.0, 25.0])
    run = run_scenario('german-low', speed, 60.0, 200.0, 'adxl355', seed=2)
    result = analyse_pass(write_run(tmp_path / 'stop.mcap', run), PassOptions())
    slowest, _ = trusted_speeds(PassOptions().config.with_(
        inversion=PassOptions().config.inversion.with_(rate_hz=200.0)), VehicleParams(),
        run.accel_covariance)
    assert slowest >= PassOptions().config.inversion.min_design_speed_mps
    assert np.all(result.speed_mps[result.valid] >= slowest)
    slow = result.speed_mps < slowest
    assert slow.sum() > 100 and not result.valid[slow].any()
    assert result.valid.sum() * 0.25 > 0.5 * (run.chainage_m[-1] - run.chainage_m[0])


def test_local_cluster_listens_on_loopback_only():
    """Every listening socket of the LocalCluster (scheduler, nannies, workers, HTTP) is on
    127.0.0.1 (ss -ltnp, matched by process id)."""
    import os
    import shutil
    import subprocess

    from railgsa_ros.fleet.ingest import dask_client

    if shutil.which('ss') is None:
        pytest.skip('ss (iproute2) not installed')
    with dask_client(None, 2) as client:
        pids = {os.getpid(), *client.run(os.getpid).values()}
        pids |= set(client.run(os.getppid).values())  # the nannies
        listing = subprocess.run(['ss', '-ltnpH'], capture_output=True, text=True,
                                 check=True).stdout.splitlines()
    ours = [row.split()[3] for row in listing if any(f'pid={p},' in row for p in pids)]
    assert len(ours) >= 5  # scheduler (2), 2 workers, 2 nannies at least
    assert all(local.startswith('127.0.0.1:') for local in ours), ours


def test_a_defect_growing_past_the_threshold_is_not_new(ingested, series, tmp_path):
    """Detected from 0.7 x the alert limit (5.6 mm), the growing dip (4.2 -> 7.4 mm in D1) is
    first found in a later pass: not NEW, and its trend still uses every pass."""
    import shutil

    from railgsa_ros.fleet.condition import update_line
    from railgsa_ros.standards.en13848 import Limits, en13848_table

    _, path, _ = ingested
    copy = shutil.copy(path, tmp_path / 'copy.duckdb')
    con = db.connect(copy)
    update_line(con, 'L1', '1', 0.25, Limits(en13848_table(), 'd1'), None, fraction=0.7)
    rows = con.execute('SELECT new, passes, first_seen FROM defects WHERE abs(x_m - ?) < 3',
                       [_frame(series.truth_x['grow'])]).fetchall()
    con.close()
    assert len(rows) == 1
    new, passes, first_seen = rows[0]
    assert not new and passes == 5
    assert first_seen > db.timestamp(DEFAULT_START_NS + DAYS[0] * DAY_NS + DAY_NS)
