"""Never lose an output (issue 11, item 3): both nodes as processes with their default writer
history (1000), ``railgsa replay`` of a bag with a bridged dropout, a dropout that resets the
filters, a backward time jump and the end of the stream, at replay rate 5; a RELIABLE
subscriber with the README's QoS (KEEP_LAST 1000) in this process.

Independent truth: the header stamps written into the bag. Every accepted IMU sample (every
real sample the nodes received: bridged ones are interpolated and never published) must come
out exactly once on ``track/irregularity`` and on ``track/irregularity_band``, in order within
each stream, including the last band delay of each stream (flushed at the reset, the time jump
and, with no input for ``idle_flush_s``, at the end).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
import time
from typing import Any

import numpy as np
import pytest
from ros_helpers import Collector, DiagnosticsLog, header_stamp, values
from test_integration_replay import IRR_NODE, PARAMS, UNC_NODE, _logs, scenario, write_bag

from railgsa_ros.system import System

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[1]
IRR, BAND = '/track/irregularity', '/track/irregularity_band'
BRIDGED = (3000, 100)     # start sample, length of a 0.1 s dropout (bridged)
RESET = (8000, 1500)      # a 1.5 s dropout: longer than max_bridge_s (1.2 s), filters restart
JUMP = (14000, 100.0)     # from this sample on the stamps are 100 s earlier (a time reset)
RATE = 5.0                # replay rate (see the test)
N_RUN = 20_000            # samples of the simulated run (20 s at 1 kHz)


def faulty_bag(path: Path, rate: float) -> tuple[Path, np.ndarray]:
    """The 20 s run with the dropouts and the time jump, as a bag for ``rate``; returns the
    bag and the IMU header stamps it holds (arrival order)."""
    run = scenario(N_RUN / 1000.0)
    keep = np.ones(run.stamps_ns.size, bool)
    for start, length in (BRIDGED, RESET):
        keep[start:start + length] = False
    stamps = run.stamps_ns.copy()
    stamps[JUMP[0]:] -= round(JUMP[1] * 1e9)
    fields = ('stamps_ns', 'accel', 't_true_s', 'speed_mps', 'chainage_m', 'truth_u_m')
    arrived = replace(run, **{f: getattr(run, f)[keep] for f in fields})
    return write_bag(path, arrived, rate, imu_stamps_ns=stamps[keep]), stamps[keep]


class Reader:
    """RELIABLE, KEEP_LAST 1000, VOLATILE (the README's QoS) on both output topics: their
    header stamps."""

    def __init__(self, spin: Callable, context: Any) -> None:
        from geometry_msgs.msg import PointStamped, Vector3Stamped
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.node = spin(Node('no_loss_reader', context=context))
        self.stamps = {topic: Collector(self.node, msgtype, topic, qos, header_stamp)
                       for topic, msgtype in ((IRR, PointStamped), (BAND, Vector3Stamped))}

    def count(self, topic: str) -> int:
        return len(self.stamps[topic])

    def received(self, topic: str) -> np.ndarray:
        return np.array(self.stamps[topic].snapshot(), np.int64)


def diagnostics_after_flush(node: Any, timeout: float) -> dict[str, dict[str, str]]:
    """status name -> values of the first /diagnostics array of each node that reports the
    end-of-stream flush (``idle_flushes`` >= 1, idle_flush_s after the last input): before it
    the re-order window's last samples are held, received but not yet accepted (a snapshot
    taken right after the replay raced that flush)."""
    log = DiagnosticsLog(node, '', values, 50)
    deadline = time.monotonic() + timeout
    names = [f'{IRR_NODE}: inversion', f'{UNC_NODE}: uncertainty']

    def flushed() -> bool:
        latest = log.latest()
        return all(int(latest.get(n, {}).get('idle_flushes', 0)) >= 1 for n in names)
    while not flushed() and time.monotonic() < deadline:
        time.sleep(0.1)
    node.destroy_subscription(log.subscription)
    return log.latest()


# At 5x only: the resets, the time jump and the end flush are decided on header stamps (the
# same at any rate), the outputs leave 5x faster through the same default writer history
# (1000) to the same reader, so a loss at 1x is a loss at 5x; and RELIABLE inputs make every
# sent sample an accepted one, so the check covers every sample. The 1x BEST_EFFORT input path
# is test_integration_replay.py's rate1 (every sample's output exactly once).
def test_every_accepted_sample_has_one_output_through_resets_and_the_end(
        tmp_path: Path, ros_context: Any, spin: Callable, wait_for: Callable) -> None:
    rate = RATE
    bag, sent = faulty_bag(tmp_path / 'bag', rate)
    reader = Reader(spin, ros_context)
    # the nodes' writer histories stay at their default (1000, as the README's reader); faster
    # than real time the inputs are RELIABLE end to end (docs/integration.md)
    ros_args = ['-p', 'imu_qos_depth:=100000']
    reliable = rate != 1.0
    if reliable:
        ros_args += ['-p', 'imu_reliability:=reliable', '-p', 'odom_reliability:=reliable']
    with System(tmp_path / 'logs', cwd=REPO) as system:
        nodes = [system.node(name, ['--params-file', str(PARAMS[name]), *ros_args])
                 for name in (IRR_NODE, UNC_NODE)]
        for topic in (IRR, BAND):
            assert wait_for(lambda t=topic: reader.node.count_publishers(t) > 0, 120.0), \
                _logs(system)
        time.sleep(1.0)  # our reader matched the nodes' writers
        replay = system.command('replay', str(bag), '--topics', '/imu/data', '/odom',
                                '--wait-for-subscribers', '30', '--min-subscribers', '2',
                                '--rate', str(rate), *(['--reliable'] if reliable else []))
        assert replay.wait(sent.size / 1000.0 / rate + 60.0) == 0, _logs(system)
        # the end of the stream: idle_flush_s (2 s) later both nodes flush, paced
        diag = diagnostics_after_flush(reader.node, 20.0)
        accepted = {n: int(diag[f'{n}: imu input']['accepted']) for n in (IRR_NODE, UNC_NODE)}
        wait_for(lambda: reader.count(IRR) >= accepted[IRR_NODE]
                 and reader.count(BAND) >= accepted[UNC_NODE], 60.0)
        time.sleep(1.0)  # nothing more (no duplicate) arrives
        for node in nodes:
            assert node.running(), _logs(system)
    results = system.stop()
    for name in (IRR_NODE, UNC_NODE):
        assert results[name].rc == 0 and 'Traceback' not in results[name].stderr, \
            results[name].stderr
        counters = diag[f'{name}: imu input']
        assert int(counters['received']) == int(counters['accepted']), counters
        assert int(counters['reset']) == 1 and int(counters['time_reset']) == 1, counters
        assert int(counters['bridged']) == BRIDGED[1], counters
    for topic, name in ((IRR, IRR_NODE), (BAND, UNC_NODE)):
        got = reader.received(topic)
        print(f'\n{rate:g}x {topic}: {got.size} outputs of {accepted[name]} accepted samples '
              f'({sent.size} sent)')
        index = {int(t): k for k, t in enumerate(sent)}
        order = np.array([index.get(int(t), -1) for t in got])
        missing = np.setdiff1d(np.arange(sent.size), order)
        runs = np.split(missing, np.flatnonzero(np.diff(missing) > 1) + 1) if missing.size else []
        assert got.size == accepted[name], (got.size, accepted[name], [  # one per accepted
            (int(r[0]), int(r[-1])) for r in runs][:20])
        assert np.all(order >= 0) and np.all(np.diff(order) > 0)  # sent ones, once, in order
        if reliable:  # RELIABLE input: nothing lost on the way in either
            assert accepted[name] == sent.size
