"""irregularity_node as a separate process: 10 s at 1 kHz without loss (the last band delay
flushed when the input stops), SIGINT, bad parameters and params files."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import signal
import time
from typing import Any

import numpy as np
import pytest
from ros_helpers import T0_NS, Collector, imu_msgs, stamp_ns
from test_irregularity_node import PARAMS, offline_flushed

pytestmark = pytest.mark.ros

MODULE = 'railgsa_ros.nodes.irregularity_node'
ROS_ARGS = [a for k, v in PARAMS.items() for a in ('-p', f'{k}:={str(v).lower()}')]


@pytest.mark.slow
def test_ten_seconds_at_1khz_without_loss_then_sigint(ros_context: Any, spin: Callable,
                                                       wait_for: Callable,
                                                       start_node: Callable) -> None:
    from geometry_msgs.msg import PointStamped
    from rclpy.node import Node
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.qos import output_qos, sensor_qos
    from railgsa_ros.simulate import simulate
    from railgsa_ros.vehicle import VehicleParams

    n = 10_000
    x = np.arange(n) * 40.0 / 1000.0
    u = 1e-3 * np.sin(2 * np.pi * x / 7.0) + 5e-4 * np.sin(2 * np.pi * x / 19.0)
    acc = simulate(u, 1e-3, VehicleParams())[0] + 9.80665
    stamps = T0_NS + np.arange(n, dtype=np.int64) * 1_000_000
    msgs = imu_msgs(stamps, acc)
    ref_t, _, ref_z = offline_flushed(stamps, acc)  # the idle flush publishes the last D too

    proc = start_node(MODULE, ROS_ARGS)
    test = spin(Node('irregularity_process_test', context=ros_context))
    got = Collector(test, PointStamped, 'track/irregularity', output_qos(20_000),
                    lambda m: (stamp_ns(m.header), m.point.z))
    pub = test.create_publisher(Imu, 'imu/data', sensor_qos())
    assert wait_for(lambda: pub.get_subscription_count() > 0, 90.0), proc.stop().stderr
    assert wait_for(lambda: test.count_publishers('track/irregularity') > 0, 15.0)
    time.sleep(0.5)  # let the node's publisher match our reader too
    start = time.monotonic()
    for k, msg in enumerate(msgs):  # paced at 1 kHz on absolute deadlines
        delay = start + k * 1e-3 - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        pub.publish(msg)
    assert wait_for(lambda: len(got) >= n, 30.0), (len(got), n)
    time.sleep(0.2)
    result = proc.stop(signal.SIGINT)
    rows = got.snapshot()  # every sample exactly once, none lost, the values of the offline flush
    np.testing.assert_array_equal(np.array([g[0] for g in rows], np.int64), ref_t)
    np.testing.assert_array_equal(np.array([g[1] for g in rows]), ref_z)
    assert result.rc == 0, result.stderr
    assert 'Traceback' not in result.stderr, result.stderr


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signal_when_idle_exits_0_without_traceback(sig: int, ros_context: Any, spin: Callable,
                                                    wait_for: Callable,
                                                    start_node: Callable) -> None:
    from rclpy.node import Node

    proc = start_node(MODULE, ROS_ARGS)
    probe = spin(Node('irregularity_signal_probe', context=ros_context))
    assert wait_for(lambda: probe.count_publishers('track/irregularity') > 0, 90.0)
    result = proc.stop(sig)
    assert result.rc == 0, result.stderr
    assert 'Traceback' not in result.stderr, result.stderr


def test_invalid_parameter_exits_2_with_one_line(start_node: Callable) -> None:
    proc = start_node(MODULE, ['-p', 'band_order:=9'])
    proc.proc.wait(timeout=60.0)
    result = proc.stop()
    assert result.rc == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('error: '), result.stderr
    assert 'band_order' in lines[0]


@pytest.mark.parametrize('node', ['irregularity_node', 'uncertainty_node'])
@pytest.mark.parametrize(('content', 'expected'), [
    (None, 'cannot read'),
    ('irregularity_node: [unclosed\n', 'invalid YAML'),
    ('{node}:\n  ros__parameters:\n    spead_mps: 30.0\n', 'spead_mps'),
    ('other_node:\n  ros__parameters:\n    speed_mps: 30.0\n', 'no section for node {node}'),
], ids=['missing', 'malformed', 'unknown-key', 'wrong-section'])
def test_bad_params_file_exits_2_naming_the_file(node: str, content: str | None, expected: str,
                                                 tmp_path: Any, start_node: Callable) -> None:
    path = tmp_path / 'params.yaml'
    if content is not None:
        path.write_text(content.format(node=node))
    proc = start_node(f'railgsa_ros.nodes.{node}', ['--params-file', str(path)])
    assert proc.wait(60.0) == 2, proc.output()
    lines = proc.stop().stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'error: {path}'), lines
    assert expected.format(node=node) in lines[0], lines


def test_params_file_shared_by_both_nodes_is_accepted(tmp_path: Any, ros_context: Any,
                                                      spin: Callable, wait_for: Callable,
                                                      start_node: Callable) -> None:
    """A ``/**`` section may hold the other node's parameters (one file for both nodes)."""
    from rclpy.node import Node

    path = tmp_path / 'params.yaml'
    path.write_text('/**:\n  ros__parameters:\n    use_odom: false\n    rule: pem5\n'
                    'irregularity_node:\n  ros__parameters:\n    speed_mps: 30.0\n')
    proc = start_node(MODULE, ['--params-file', str(path)])
    probe = spin(Node('params_file_probe', context=ros_context))
    assert wait_for(lambda: probe.count_publishers('track/irregularity') > 0, 90.0), \
        proc.output()
    result = proc.stop(signal.SIGINT)
    assert result.rc == 0, result.stderr


def test_signals_during_a_burst_exit_0() -> None:
    """A few tries of benchmarks/stress_signals.py (50 there): SIGINT/SIGTERM at a random moment
    of a 60 000-message burst, both nodes; every try exits 0 without a traceback."""
    import subprocess
    import sys

    from railgsa_ros.system import ros_env

    script = Path(__file__).resolve().parents[1] / 'benchmarks' / 'stress_signals.py'
    tries = 4
    result = subprocess.run([sys.executable, str(script), '--tries', str(tries), '--seed', '11'],
                            capture_output=True, text=True, timeout=600, env=ros_env())
    assert result.stdout.strip().splitlines()[-1] == f'exit 0: {tries} of {tries}', \
        result.stdout + result.stderr
