"""railgsa fleet after a crash, with copies of bags and with a damaged database.

Two simulated passes over one 0.8 km German-low line 30 days apart, each with an 8 mm dip (a
followed defect), ingested on one 2-worker LocalCluster (127.0.0.1) that the tests pass by
``--scheduler``. The crash is a real SIGKILL of an ingest subprocess inside its line update.
"""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys

import numpy as np
import pytest

from railgsa_ros.bag import write_run
from railgsa_ros.cli.main import main
from railgsa_ros.fleet import db
from railgsa_ros.scenario import DEFAULT_START_NS, run_scenario

DAY_NS = 86400 * 10**9
LINE = ['--line', 'L', '--track', '1']
# an ingest that dies (SIGKILL) when the line update writes its first defect: after the old
# defects were deleted and the new detections written, before the defects are
KILLED_IN_UPDATE = """
import os, signal, sys
from railgsa_ros.fleet import condition
from railgsa_ros.cli.main import main

def die(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGKILL)

condition._store_defect = die
sys.exit(main(sys.argv[1:]))
"""


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """Two passes (bag A, bag B) over the same line, 30 days apart."""
    root = tmp_path_factory.mktemp('passes')
    out = []
    for i in range(2):
        run = run_scenario('german-low', 25.0, 32.0, 200.0, 'adxl355', seed=i, line_seed=7,
                           defects='dip@300:len=8:depth=0.008',
                           start_ns=DEFAULT_START_NS + 30 * i * DAY_NS)
        out.append(write_run(root / f'pass{i}.mcap', run))
    return out


@pytest.fixture(scope='module')
def scheduler():
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, host='127.0.0.1',
                      dashboard_address='127.0.0.1:0', silence_logs=40) as cluster:
        yield cluster.scheduler_address


def _ingest(bag: Path, path: Path, scheduler: str) -> int:
    return main(['fleet', 'ingest', str(bag), '--db', str(path), '--scheduler', scheduler, *LINE])


def _condition(path: Path) -> tuple[dict, list]:
    """The line's fused profile (columns) and defect rows, read back."""
    con = db.connect(path, read_only=True)
    try:
        fused = db.fetch(con, 'SELECT cell, u_m, sd_m, passes FROM fused ORDER BY cell')
        defects = con.execute('SELECT * FROM defects ORDER BY defect_id').fetchall()
    finally:
        con.close()
    return fused, defects


def _same(a: tuple[dict, list], b: tuple[dict, list]) -> None:
    """Equal to rounding (DuckDB's parallel sums add in any order); NaN equals NaN."""
    (fa, da), (fb, db_) = a, b
    assert fa.keys() == fb.keys()
    for k in fa:
        np.testing.assert_allclose(fa[k], fb[k], rtol=1e-9, atol=1e-15)
    assert len(da) == len(db_)
    for ra, rb in zip(da, db_, strict=True):
        for va, vb in zip(ra, rb, strict=True):
            if isinstance(va, float):
                np.testing.assert_allclose(va, vb, rtol=1e-9, atol=1e-15)
            else:
                assert va == vb


def test_sigkill_in_the_line_update_leaves_the_line_as_it_was_and_a_rerun_repairs_it(
        bags, scheduler, tmp_path, capsys):
    """Killed inside the update after pass B was stored: the fused profile and defects are the
    ones of pass A alone (the update is one transaction); the re-run skips bag B, says it
    repairs the line, and the line equals the one of an ingest that was not killed (before: the
    defects were left empty and the re-run only said ``skipped``)."""
    killed, clean = tmp_path / 'killed.duckdb', tmp_path / 'clean.duckdb'
    assert _ingest(bags[0], killed, scheduler) == 0
    after_a = _condition(killed)
    assert after_a[0]['cell'].size > 2000 and len(after_a[1]) >= 1  # the dip is followed
    shutil.copy(killed, clean)
    assert _ingest(bags[1], clean, scheduler) == 0
    expected = _condition(clean)
    assert expected[1][0][9] == 2  # the defect seen by both passes

    env = {**os.environ, 'PYTHONPATH': str(Path(__file__).resolve().parents[1])}
    proc = subprocess.run([sys.executable, '-c', KILLED_IN_UPDATE, 'fleet', 'ingest',
                           str(bags[1]), '--db', str(killed), '--scheduler', scheduler, *LINE],
                          env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert proc.stdout.startswith('ok ')  # pass B was stored before the update
    _same(_condition(killed), after_a)

    capsys.readouterr()
    assert _ingest(bags[1], killed, scheduler) == 0
    out = capsys.readouterr().out
    assert 'skipped' in out and 'repaired' in out and 'from its 2 stored passes' in out
    _same(_condition(killed), expected)
    assert _ingest(bags[1], killed, scheduler) == 0  # now current: nothing to repair
    assert 'repaired' not in capsys.readouterr().out


@pytest.fixture(scope='module')
def one_pass(bags, scheduler, tmp_path_factory):
    """A database holding bag A."""
    path = tmp_path_factory.mktemp('one') / 'fleet.duckdb'
    assert _ingest(bags[0], path, scheduler) == 0
    return path


BLOCK = 256 * 1024  # DuckDB's block size; the file starts with three 4 KiB headers
TABLES = ('passes', 'fused', 'defects')  # what query, report and ingest read


def _blocks(path: Path) -> list[int]:
    """The blocks that hold the tables' data."""
    con = db.connect(path, read_only=True)
    try:
        return sorted({b for t in TABLES for (b,) in con.execute(
            f'SELECT DISTINCT block_id FROM pragma_storage_info({t!r}) WHERE block_id >= 0'
        ).fetchall()})
    finally:
        con.close()


def test_a_corrupt_database_is_one_line_exit_2(bags, one_pass, tmp_path, capsys):
    """Each block of table data damaged in turn (64 bytes of 0xff near its start): query, report
    and ingest either do not need the block (exit 0) or say in one line that the database is
    damaged (exit 2); before, a damaged data block gave a traceback in query and report."""
    blocks = _blocks(one_pass)
    assert len(blocks) >= 3
    refused = {'query': 0, 'report': 0, 'ingest': 0}
    for k in blocks:
        path = tmp_path / f'damaged{k}.duckdb'
        shutil.copy(one_pass, path)
        with path.open('r+b') as f:
            f.seek(3 * 4096 + k * BLOCK + 64)
            f.write(b'\xff' * 64)
        for name, argv in (
                ('query', ['fleet', 'query', '--db', str(path), '--line', 'L', '--from-km', '0',
                           '--to-km', '1']),
                ('report', ['fleet', 'report', '--db', str(path), '--out',
                            str(tmp_path / f'report{k}')]),
                ('ingest', ['fleet', 'ingest', str(bags[0]), '--db', str(path), *LINE])):
            capsys.readouterr()
            code = main(argv)
            err = capsys.readouterr().err
            assert code in (0, 2), (name, k)
            if code == 2:
                refused[name] += 1
                assert err.startswith(f'error: {path}: ') and err.count('\n') == 1, err
                assert 'damaged database' in err or 'cannot open' in err, err
                assert 'Traceback' not in err
    assert all(n >= 1 for n in refused.values()), refused


def test_a_copy_of_a_stored_bag_is_skipped_with_a_message(bags, one_pass, scheduler, tmp_path,
                                                          capsys):
    """Bag A copied under another name into another directory is skipped, naming the pass it
    copies; of bag B and its copy in one batch only B is ingested (before: each copy was a new
    pass, and the trend counted it twice)."""
    from railgsa_ros.bag.digest import bag_digest

    path = tmp_path / 'fleet.duckdb'
    shutil.copy(one_pass, path)
    (tmp_path / 'elsewhere').mkdir()
    copy_a = Path(shutil.copytree(bags[0], tmp_path / 'elsewhere' / 'monday'))
    copy_b = Path(shutil.copytree(bags[1], tmp_path / 'elsewhere' / 'tuesday'))
    assert bag_digest(copy_a) == bag_digest(bags[0]) != bag_digest(bags[1])
    capsys.readouterr()
    assert _ingest(copy_a, path, scheduler) == 0
    out = capsys.readouterr().out
    assert f'skipped   -        {copy_a}: same content as pass 1 ({bags[0]}): a copy' in out
    assert main(['fleet', 'ingest', str(bags[1]), str(copy_b), '--db', str(path),
                 '--scheduler', scheduler, *LINE]) == 0
    out = capsys.readouterr().out
    assert f'{copy_b}: same content as {bags[1]} of this batch: a copy' in out
    con = db.connect(path, read_only=True)
    try:
        rows = con.execute('SELECT bag, digest FROM passes ORDER BY pass_id').fetchall()
        passes = con.execute('SELECT passes FROM defects').fetchall()
    finally:
        con.close()
    assert rows == [(str(bags[0]), bag_digest(bags[0])), (str(bags[1]), bag_digest(bags[1]))]
    assert passes == [(2,)]
