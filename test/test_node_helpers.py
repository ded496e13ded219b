"""Shared node helpers: Imu/Odometry conversion (REP 145), parameter specs, diagnostics, QoS."""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from railgsa_ros.nodes.imu_conversion import imu_batch, odom_speed

NAN = float('nan')


def fake_imu(sec: int = 5, nanosec: int = 250, frame: str = 'imu_link',
             acc: tuple[float, float, float] = (0.1, -0.2, 9.81),
             cov: list[float] | None = None) -> SimpleNamespace:
    """A duck-typed Imu (as rosbags or rclpy messages look to the converter)."""
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec), frame_id=frame),
        linear_acceleration=SimpleNamespace(x=acc[0], y=acc[1], z=acc[2]),
        linear_acceleration_covariance=np.array(cov if cov is not None else [0.0] * 9))


def test_imu_batch_converts_fields_and_flags_malformed_messages() -> None:
    msgs = [fake_imu(), fake_imu(sec=6, nanosec=999_999_999, acc=(0.0, 0.0, NAN)),
            fake_imu(sec=0, nanosec=0), fake_imu(frame=''), fake_imu(nanosec=1_000_000_000),
            fake_imu(sec=-3), SimpleNamespace(header=None), 'not a message']
    batch = imu_batch(msgs)
    assert len(batch) == len(msgs)
    np.testing.assert_array_equal(batch.malformed, [False, False] + [True] * 6)
    assert batch.stamps_ns[:2].tolist() == [5_000_000_250, 6_999_999_999]
    np.testing.assert_array_equal(batch.accel[0], [0.1, -0.2, 9.81])
    assert np.isnan(batch.accel[1, 2])  # NaN data is not malformed: the sanitiser counts it
    assert batch.frame_ids[0] == 'imu_link' and batch.stamps_ns.dtype == np.int64
    empty = imu_batch([])
    assert len(empty) == 0 and empty.accel.shape == (0, 3)


def test_imu_batch_reads_rclpy_messages() -> None:
    sensor_msgs = pytest.importorskip('sensor_msgs.msg')
    m = sensor_msgs.Imu()
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = 7, 5, 'imu_link'
    m.linear_acceleration.z = 9.8
    m.linear_acceleration_covariance[8] = 2e-4
    batch = imu_batch([m])
    assert batch.stamps_ns.tolist() == [7_000_000_005] and batch.accel[0, 2] == 9.8
    np.testing.assert_array_equal(batch.covariance[0], [0] * 8 + [2e-4])  # as sent


def test_covariance_passed_on_as_sent_and_short_ones_malformed() -> None:
    """REP 145 rules are the input policy's: the converter keeps the 9 values as they came."""
    cov = [-1.0, 0, 0, 0, 2e-4, 0, 0, 0, NAN]
    np.testing.assert_array_equal(imu_batch([fake_imu(cov=cov)]).covariance[0], cov)
    assert imu_batch([fake_imu(cov=[1e-4] * 3)]).malformed.tolist() == [True]


def test_odom_speed() -> None:
    def odom(sec: int, nanosec: int, vx: float) -> SimpleNamespace:
        return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec,
                                                                            nanosec=nanosec)),
                               twist=SimpleNamespace(twist=SimpleNamespace(
                                   linear=SimpleNamespace(x=vx))))
    assert odom_speed(odom(2, 5, 12.5)) == (2_000_000_005, 12.5)
    assert odom_speed(odom(2, 5, -3.0)) == (2_000_000_005, -3.0)  # reversing is a speed too
    for bad in (odom(0, 0, 1.0), odom(2, 2_000_000_000, 1.0), object()):
        assert odom_speed(bad) is None
    stamp, speed = odom_speed(odom(2, 0, NAN))  # the policy counts NaN odometry, not the node
    assert stamp == 2_000_000_000 and np.isnan(speed)


# --------------------------------------------------------------------------- ROS helpers
@pytest.mark.ros
def test_param_spec_descriptor_and_choices() -> None:
    from railgsa_ros.nodes.params import ParamSpec

    f = ParamSpec('gain', 1000.0, 'feedback gain, s^2', (0.0, 1e6)).descriptor()
    [fr] = f.floating_point_range
    assert (fr.from_value, fr.to_value) == (0.0, 1e6)
    assert f.description == 'feedback gain, s^2' and not f.integer_range and not f.read_only
    i = ParamSpec('depth', 1000, 'history', (300, 5000), read_only=True).descriptor()
    assert (i.integer_range[0].from_value, i.integer_range[0].to_value) == (300, 5000)
    assert i.read_only
    c = ParamSpec('policy', 'reject', 'frames', choices=('reject', 'accept'))
    assert c.descriptor().additional_constraints == 'one of: reject, accept'
    assert c.check('accept') is None and 'one of reject, accept' in c.check('drop')


@pytest.mark.ros
def test_declare_and_merged(ros_context: Any) -> None:
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from railgsa_ros.errors import ConfigError
    from railgsa_ros.nodes.params import ParamSpec, declare, merged

    specs = (ParamSpec('rate', 100.0, 'Hz', (1.0, 1e3)),
             ParamSpec('mode', 'a', 'mode', choices=('a', 'b')))

    def node(**overrides: Any) -> Node:
        return Node('declare_test', context=ros_context,
                    parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
    assert declare(node(rate=250.0), specs) == {'rate': 250.0, 'mode': 'a'}
    assert declare(node(rate=5), specs)['rate'] == 5.0  # an integer for a float is accepted
    for overrides, why in (({'rate': 5000.0}, 'rate'), ({'rate': 'fast'}, 'float'),
                           ({'mode': 'c'}, 'one of a, b')):
        with pytest.raises(ConfigError, match=why):
            declare(node(**overrides), specs)
    values, reason = merged({'rate': 100.0, 'mode': 'a'}, specs,
                            [Parameter('rate', value=200.0), Parameter('mode', value='z'),
                             Parameter('use_sim_time', value=True)])
    assert values == {'rate': 200.0, 'mode': 'z'} and 'mode' in reason


@pytest.mark.ros
def test_qos_profiles() -> None:
    from rclpy.qos import ReliabilityPolicy

    from railgsa_ros.nodes.qos import output_qos, sensor_qos
    from railgsa_ros.qos import MIN_SENSOR_DEPTH

    assert sensor_qos().reliability == ReliabilityPolicy.BEST_EFFORT
    assert sensor_qos().depth >= MIN_SENSOR_DEPTH >= 300
    assert sensor_qos(500, 'reliable').reliability == ReliabilityPolicy.RELIABLE
    assert output_qos().reliability == ReliabilityPolicy.RELIABLE and output_qos(7).depth == 7


@pytest.mark.ros
def test_recording_subscribes_with_what_every_publisher_offers() -> None:
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from railgsa_ros.nodes.qos import bag_record, from_rclpy, to_rclpy
    from railgsa_ros.qos import Profile, recording

    latched = QoSProfile(depth=3, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    lossy = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    assert from_rclpy(latched) == Profile(True, 3, True)
    assert from_rclpy(to_rclpy(Profile(False, 9, True))) == Profile(False, 9, True)
    assert recording([from_rclpy(latched)], 100) == Profile(True, 100, True)
    assert recording([from_rclpy(latched), from_rclpy(lossy)], 100) == Profile(False, 100, False)
    record = bag_record(latched)
    assert (record.depth, record.reliability.value, record.durability.value) == (
        3, int(ReliabilityPolicy.RELIABLE), int(DurabilityPolicy.TRANSIENT_LOCAL))


@pytest.mark.ros
def test_deltas_latency_and_status() -> None:
    from railgsa_ros.nodes.diagnostics import WARN, Deltas, LatencyWindow, Report, make_status

    deltas = Deltas()
    assert deltas({'nan': 2, 'gap': 0}) == {'nan': 2, 'gap': 0}
    assert deltas({'nan': 5, 'gap': 1, 'saturated': 4}) == {'nan': 3, 'gap': 1, 'saturated': 4}
    window = LatencyWindow()
    assert np.isnan(window.take()['latency_p50_ms'])
    for ms in range(1, 101):
        window.add(ms * 1e-3)
    stats = window.take()
    assert stats['latency_p50_ms'] == pytest.approx(50.5)
    assert stats['latency_max_ms'] == pytest.approx(100.0)
    assert stats['latency_p99_ms'] == pytest.approx(np.percentile(np.arange(1, 101), 99))
    assert np.isnan(window.take()['latency_max_ms'])  # a new period starts empty
    status = make_status('n: task', 'imu', Report(WARN, 'why', {'rate_hz': 1 / 3, 'n': 7}))
    assert (status.level, status.name, status.hardware_id) == (WARN, 'n: task', 'imu')
    assert [(kv.key, kv.value) for kv in status.values] == [('rate_hz', repr(1 / 3)),
                                                            ('n', '7')]


@pytest.mark.ros
def test_diagnostics_publisher_survives_a_failing_task(ros_context: Any, spin: Callable,
                                                       wait_for: Callable) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node

    from railgsa_ros.nodes.diagnostics import ERROR, OK, DiagnosticsPublisher, Report

    node = spin(Node('diag_test', context=ros_context))
    got: list[DiagnosticArray] = []
    node.create_subscription(DiagnosticArray, '/diagnostics', got.append, 10)
    reporter = DiagnosticsPublisher(node, 'hw0', period_s=0.1)
    reporter.add('fine', lambda elapsed: Report(OK, f'{elapsed > 0}'))
    reporter.add('broken', lambda elapsed: 1 / 0)
    assert wait_for(lambda: len(got) >= 2, 10.0)
    fine, broken = got[-1].status
    assert (fine.name, fine.level, fine.message, fine.hardware_id) == \
        ('diag_test: fine', OK, 'True', 'hw0')
    assert broken.level == ERROR and 'ZeroDivisionError' in broken.message
    reporter.destroy()
