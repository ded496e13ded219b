"""Bags written by another rosbag2 tool (rosbags' own writer, MCAP and sqlite3) whose recorder
stamped the log time on receipt: /imu/data in log-time order, header stamps locally out of
order. invert, review and a replay through irregularity_node give the sorted bag's result; a
disorder beyond reorder_window_s is counted, reported and rejected, nothing else is lost."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from railgsa_ros.bag.run import RunEncoder
from railgsa_ros.cli.main import main
from railgsa_ros.scenario import run_scenario

rosbag2 = pytest.importorskip('rosbags.rosbag2')

MS = 1_000_000
N_NODE = 5000  # IMU messages replayed into the node
STORAGES = {'mcap': rosbag2.StoragePlugin.MCAP, 'sqlite3': rosbag2.StoragePlugin.SQLITE3}


@pytest.fixture(scope='module')
def run() -> Any:
    """12 s at 25 m/s over a track with a dip (ground truth of the simulation)."""
    return run_scenario('german-low', 25.0, 12.0, 1000.0, 'adxl355', 4,
                        defects='dip@150:len=6:depth=0.02')


def receipt(n: int, seed: int) -> np.ndarray:
    """Receipt delay (ns) of each IMU message: bursts of 10 from a driver (up to 9 ms behind
    the first of the burst), 0-3 ms of jitter, and a second thread: up to 20 ms of disorder."""
    rng = np.random.default_rng(seed)
    burst = (9 - np.arange(n) % 10) * MS
    return burst + rng.integers(0, 3 * MS, n) + np.where(rng.random(n) < 0.1, 8 * MS, 0)


def write_bag(path: Path, run: Any, storage: str, delay_ns: np.ndarray | None) -> Path:
    """/imu/data and /odom with rosbags' Writer: log time = header stamp + ``delay_ns`` for the
    IMU (None: equal, the sorted bag), messages written in log-time order."""
    from railgsa_ros.bag.messages import typestore

    enc = RunEncoder(run)
    msgs = enc.encode()
    topics = enc.topics()
    rows = []
    for key in ('imu', 'odom'):
        stamps, raws = msgs[key]
        log = stamps + (delay_ns if key == 'imu' and delay_ns is not None else 0)
        rows += [(int(t), key, raw) for t, raw in zip(log.tolist(), raws, strict=True)]
    rows.sort(key=lambda r: r[0])
    with rosbag2.Writer(path, version=9, storage_plugin=STORAGES[storage]) as writer:
        conns = {key: writer.add_connection(topics[key][0], topics[key][1],
                                            typestore=typestore()) for key in ('imu', 'odom')}
        for t, key, raw in rows:
            writer.write(conns[key], t, raw)
    return path


def invert(bag: Path, out: Path, capsys: Any) -> tuple[str, str]:
    assert main(['invert', str(bag), '--csv', str(out)]) == 0
    return out.read_text(), capsys.readouterr().err


@pytest.mark.parametrize('storage', list(STORAGES))
def test_local_disorder_inverts_as_the_sorted_bag(run: Any, storage: str, tmp_path: Path,
                                                  capsys: Any) -> None:
    delay = receipt(run.stamps_ns.size, 1)
    shuffled = write_bag(tmp_path / 'shuffled', run, storage, delay)
    log_order = np.argsort(run.stamps_ns + delay, kind='stable')
    assert np.count_nonzero(np.diff(run.stamps_ns[log_order]) < 0) > 0.3 * run.stamps_ns.size
    want, _ = invert(write_bag(tmp_path / 'sorted', run, storage, None), tmp_path / 's.csv',
                     capsys)
    got, err = invert(shuffled, tmp_path / 'j.csv', capsys)
    assert got == want  # every sample, bit for bit
    assert want.count('\n') == run.stamps_ns.size + 1  # nothing lost (header line)
    assert 'out_of_order' not in err and 'late' not in err
    assert ' reordered ' in err and 'warning' not in err


def test_disorder_beyond_the_window_is_counted_reported_and_rejected(run: Any, tmp_path: Path,
                                                                     capsys: Any) -> None:
    delay = receipt(run.stamps_ns.size, 2)
    late = np.array([2000, 4100, 7777])
    delay[late] = 80 * MS  # 80 ms behind: beyond the 50 ms window
    bag = write_bag(tmp_path / 'late', run, 'mcap', delay)
    got, err = invert(bag, tmp_path / 'l.csv', capsys)
    stamps = np.loadtxt(got.splitlines()[1:], delimiter=',', usecols=0, ndmin=1)
    want = np.delete(run.stamps_ns, late) / 1e9
    # exactly the late samples are missing (the CSV's time has 0.2 us resolution at 1.7e9 s)
    np.testing.assert_allclose(stamps, want, rtol=0, atol=1e-6)
    assert 'late 3' in err and 'out_of_order 3' in err
    warning = next(line for line in err.splitlines() if 'reorder_window_s' in line)
    assert warning.startswith('warning: 3 IMU samples arrived more than reorder_window_s '
                              '(50 ms) after a newer stamp'), warning
    assert 'rejected as out_of_order' in warning
    from railgsa_ros.review.build import build_review
    from railgsa_ros.review.results import ReviewOptions

    review = build_review(ReviewOptions(bag))  # the review's report and stderr carry it too
    assert warning.removeprefix('warning: ') in [f.message for f in review.run.findings]
    assert review.run.counters['late'] == 3


def _equal(a: Any, b: Any) -> None:
    """Dataclass trees equal field by field (arrays exactly, NaN where NaN)."""
    if hasattr(a, '__dataclass_fields__'):
        for f in fields(a):
            _equal(getattr(a, f.name), getattr(b, f.name))
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _equal(x, y)
    else:
        assert a == b or (a != a and b != b)


def test_review_of_a_disordered_sqlite3_bag_equals_the_sorted_one(run: Any,
                                                                   tmp_path: Path) -> None:
    from railgsa_ros.review.build import build_review
    from railgsa_ros.review.results import ReviewOptions

    shuffled = write_bag(tmp_path / 'shuffled', run, 'sqlite3', receipt(run.stamps_ns.size, 3))
    ref = build_review(ReviewOptions(write_bag(tmp_path / 'sorted', run, 'sqlite3', None)))
    got = build_review(ReviewOptions(shuffled))
    _equal(got.run.grid, ref.run.grid)
    _equal(got.exceedances, ref.exceedances)
    _equal(got.sections, ref.sections)
    assert got.run.counters['reordered'] > 0
    assert {k: v for k, v in got.run.counters.items() if k != 'reordered'} == ref.run.counters


@pytest.mark.ros
def test_a_replay_through_the_node_gives_the_offline_result(run: Any, tmp_path: Path,
                                                            ros_context: Any) -> None:
    """The disordered bag's IMU messages in log-time order (as `railgsa replay` publishes
    them) through irregularity_node in pushes of 1-15 messages: the policy's result on the
    sorted samples."""
    from rclpy.parameter import Parameter

    from railgsa_ros.input.options import InputOptions
    from railgsa_ros.input.stage import InputStage
    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.nodes.irregularity_node import IrregularityNode
    from railgsa_ros.playback.source import BagSource

    params = {'use_odom': False, 'speed_mps': 25.0}
    bag = write_bag(tmp_path / 'shuffled', run, 'mcap', receipt(run.stamps_ns.size, 4))
    raws = [data for _, _, data in BagSource(bag).messages(['/imu/data'])][:N_NODE]
    node = IrregularityNode(context=ros_context, parameter_overrides=[
        Parameter(k, value=v) for k, v in params.items()])
    try:
        outs, start, k = [], 0, 0
        while start < len(raws):
            size = 1 + k % 15
            outs.append(node.process(raws[start:start + size]))
            start, k = start + size, k + 1
        outs.append(node.flush('end'))
        counters = node.counters()
    finally:
        node.destroy_node()
    outs = [o for o in outs if o is not None and len(o)]
    policy = InputStage(InversionConfig(speed_mps=25.0), options=InputOptions(use_odom=False))
    cov = np.zeros((run.stamps_ns.size, 9))
    cov[:, 0::4] = run.accel_covariance
    order = np.sort(np.argsort(run.stamps_ns + receipt(run.stamps_ns.size, 4),
                               kind='stable')[:N_NODE])  # the samples of those messages
    ref = [policy.imu(run.stamps_ns[order], run.accel[order], None, cov[order]),
           policy.flush()]
    for name in ('stamps_ns', 'u_m'):
        np.testing.assert_array_equal(np.concatenate([getattr(o, name) for o in outs]),
                                      np.concatenate([getattr(o, name) for o in ref]))
    assert counters['reordered'] > 0 and counters.get('out_of_order', 0) == 0
    assert counters['accepted'] == N_NODE

