"""Shared node helpers: Imu/Odometry conversion (REP 145), parameter specs, diagnostics, QoS."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from railgsa_ros.bag.messages import typestore
from railgsa_ros.nodes.imu_conversion import imu_batch, odometry_speeds

NAN = float('nan')
TS = typestore()  # rosbags' serialiser: independent of the decoder under test


def imu_raw(sec: int = 5, nanosec: int = 250, frame: str = 'imu_link',
            acc: tuple[float, float, float] = (0.1, -0.2, 9.81),
            cov: list[float] | None = None, little_endian: bool = True) -> bytes:
    """A serialized sensor_msgs/Imu (any stamp fields, also invalid ones)."""
    t = TS.types
    vec, quat = t['geometry_msgs/msg/Vector3'], t['geometry_msgs/msg/Quaternion']
    msg = t['sensor_msgs/msg/Imu'](
        header=t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](
            sec=sec, nanosec=nanosec), frame_id=frame),
        orientation=quat(0.0, 0.0, 0.0, 1.0), orientation_covariance=np.full(9, -1.0),
        angular_velocity=vec(0.0, 0.0, 0.0), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vec(*acc),
        linear_acceleration_covariance=np.array(cov if cov is not None else [0.0] * 9))
    return bytes(TS.serialize_cdr(msg, 'sensor_msgs/msg/Imu', little_endian=little_endian))


def odom_raw(sec: int, nanosec: int, vx: float) -> bytes:
    t = TS.types
    vec = t['geometry_msgs/msg/Vector3']
    header = t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](
        sec=sec, nanosec=nanosec), frame_id='odom')
    pose = t['geometry_msgs/msg/Pose'](position=t['geometry_msgs/msg/Point'](1.0, 0.0, 0.0),
                                       orientation=t['geometry_msgs/msg/Quaternion'](
                                           0.0, 0.0, 0.0, 1.0))
    msg = t['nav_msgs/msg/Odometry'](
        header=header, child_frame_id='base_link',
        pose=t['geometry_msgs/msg/PoseWithCovariance'](pose=pose, covariance=np.zeros(36)),
        twist=t['geometry_msgs/msg/TwistWithCovariance'](
            twist=t['geometry_msgs/msg/Twist'](linear=vec(vx, 0.5, 0.0),
                                               angular=vec(0.0, 0.0, 0.1)),
            covariance=np.zeros(36)))
    return bytes(TS.serialize_cdr(msg, 'nav_msgs/msg/Odometry'))


def test_imu_batch_decodes_fields_and_drops_malformed_messages() -> None:
    good = [imu_raw(), imu_raw(sec=6, nanosec=999_999_999, acc=(0.0, 0.0, NAN), frame='ü_b')]
    bad = [imu_raw(sec=0, nanosec=0), imu_raw(frame=''), imu_raw(nanosec=1_000_000_000),
           imu_raw(sec=-3), imu_raw()[:100], b'', b'\x00\x07' + imu_raw()[2:], b'garbage!' * 5]
    batch, malformed = imu_batch([bad[0], good[0], *bad[1:5], good[1], *bad[5:]])
    assert malformed == len(bad) and len(batch) == 2
    assert batch.stamps_ns.tolist() == [5_000_000_250, 6_999_999_999]
    np.testing.assert_array_equal(batch.accel[0], [0.1, -0.2, 9.81])
    assert np.isnan(batch.accel[1, 2])  # NaN data is not malformed: the sanitiser counts it
    assert batch.frame_ids.tolist() == ['imu_link', 'ü_b'] and batch.stamps_ns.dtype == np.int64
    empty, none = imu_batch([])
    assert len(empty) == 0 and empty.accel.shape == (0, 3) and none == 0


def test_imu_batch_reads_big_endian_and_other_encodings_through_the_fallback() -> None:
    """Big-endian CDR is decoded vectorised; what is not plain CDR goes to the fallback in
    its place (here a stand-in that reads one foreign encapsulation), the rest is dropped."""
    foreign = b'\x00\x07' + imu_raw(sec=9)[2:]

    def fallback(raw: bytes) -> tuple:
        if raw[:2] != b'\x00\x07':
            raise ValueError('unreadable')
        return 9 * 10**9, 0, ('imu_link',), np.arange(37.0)
    raws = [imu_raw(sec=7, cov=[0] * 8 + [2e-4], little_endian=False), foreign, b'\x00\x01',
            imu_raw(sec=8)]
    batch, malformed = imu_batch(raws, fallback)
    assert malformed == 1 and batch.stamps_ns.tolist() == [7 * 10**9 + 250, 9 * 10**9,
                                                          8 * 10**9 + 250]
    np.testing.assert_array_equal(batch.covariance[0], [0] * 8 + [2e-4])  # as sent
    np.testing.assert_array_equal(batch.accel[1], [25.0, 26.0, 27.0])


def test_rclpy_serialized_messages_decode_like_their_fields() -> None:
    sensor_msgs = pytest.importorskip('sensor_msgs.msg')
    from rclpy.serialization import serialize_message

    m = sensor_msgs.Imu()
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = 7, 5, 'imu_link'
    m.linear_acceleration.z = 9.8
    m.linear_acceleration_covariance[8] = 2e-4
    batch, malformed = imu_batch([serialize_message(m)])
    assert malformed == 0 and batch.stamps_ns.tolist() == [7_000_000_005]
    assert batch.accel[0, 2] == 9.8
    np.testing.assert_array_equal(batch.covariance[0], [0] * 8 + [2e-4])  # as sent


def test_odometry_speeds() -> None:
    stamps, speeds, malformed = odometry_speeds(
        [odom_raw(2, 5, 12.5), odom_raw(0, 0, 1.0), odom_raw(2, 2_000_000_000, 1.0),
         odom_raw(3, 0, -3.0), odom_raw(4, 0, NAN), b'\x00\x01\x00\x00'])
    assert malformed == 3 and stamps.tolist() == [2_000_000_005, 3 * 10**9, 4 * 10**9]
    assert speeds[:2].tolist() == [12.5, -3.0]  # reversing is a speed too
    assert np.isnan(speeds[2])  # the policy counts NaN odometry, not the node


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


def stamped_raw(msgtype: str, stamp_ns: int, frame: str, xyz: tuple[float, ...]) -> bytes:
    """A serialized PointStamped or Vector3Stamped made by rosbags (independent of our codec)."""
    t = TS.types
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    body = t['geometry_msgs/msg/Point' if 'Point' in msgtype else 'geometry_msgs/msg/Vector3'](
        *xyz)
    header = t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](
        sec=sec, nanosec=nanosec), frame_id=frame)
    msg = t[msgtype](header, body)
    return bytes(TS.serialize_cdr(msg, msgtype))


@pytest.mark.ros
@pytest.mark.parametrize('count', [1, 3, 8, 9, 20])
@pytest.mark.parametrize('msgtype', ['geometry_msgs/msg/PointStamped',
                                     'geometry_msgs/msg/Vector3Stamped'])
def test_pacer_template_encodes_what_rosbags_serialises(count: int, msgtype: str) -> None:
    """The pacer's per-message template (up to SMALL_SLICE) and its vectorised path give the
    bytes of rosbags' serialiser, from three value columns (one of them uint8 quality codes)."""
    from railgsa_ros.bag.messages import LAYOUTS
    from railgsa_ros.nodes.pacing import Template

    rng = np.random.default_rng(count)
    stamps = 1_700_000_000 * 10**9 + np.cumsum(rng.integers(1, 10**9, count))
    columns = (rng.normal(size=count) * 1e3, rng.integers(0, 3, count).astype(np.uint8),
               np.where(rng.random(count) < 0.3, NAN, rng.normal(size=count) * 1e-3))
    got = Template(LAYOUTS[msgtype], 'track').encode(stamps, columns)
    want = [stamped_raw(msgtype, int(t), 'track', (float(x), float(y), float(z)))
            for t, x, y, z in zip(stamps, *columns, strict=True)]
    assert got == want


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
