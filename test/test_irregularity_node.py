"""irregularity_node in-process: outputs equal the offline pipeline one-to-one, parameters, bad
input counted by reason on /diagnostics, odometry, REP 145 covariance, sim time."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
import time
from typing import Any

import numpy as np
import pytest
from ros_helpers import (
    T0_NS,
    Collector,
    DiagnosticsLog,
    G,
    imu_msg,
    imu_msgs,
    odometry,
    point_row,
    publish_bursts,
    serialized,
    stamp_ns,
    values,
)
import yaml

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[1]
#: a short band delay (about 1.8 s) keeps the tests fast; no odometry unless a test wants it
#: reorder_window_s 0: these tests count each decision as its sample arrives (the re-order
#: window's latency and its replay equivalence: test_bag_order.py)
PARAMS = {'use_odom': False, 'speed_mps': 40.0, 'min_design_speed_mps': 40.0,
          'reorder_window_s': 0.0}
#: the Rig's node keeps the last D samples until a test flushes them (no idle flush), and its
#: reader and writer histories hold a whole test run (these tests are about decisions; the
#: transport at the default depths is test_no_lost_outputs.py's)
HOLD = {'idle_flush_s': 3600.0, 'imu_qos_depth': 20_000, 'output_qos_depth': 20_000}


@pytest.fixture(scope='module')
def run() -> Any:
    """6 s of German-low track at 40 m/s through an ideal 1 kHz IMU."""
    from railgsa_ros.scenario import run_scenario

    return run_scenario('german-low', speed_mps=40.0, duration_s=6.0, rate_hz=1000.0,
                        sensor='ideal', seed=1)


def _policy(params: dict[str, Any], noise_variance: float | None = None,
            vehicle: Any = None) -> Any:
    from railgsa_ros.input.options import InputOptions
    from railgsa_ros.input.stage import InputStage
    from railgsa_ros.inverse.config import InversionConfig

    cfg = {**PARAMS, **params}
    options = InputOptions.from_mapping(cfg)
    config = InversionConfig.from_mapping({k: v for k, v in cfg.items()
                                           if k not in ('use_odom', *options.__dict__)})
    return InputStage(config, vehicle, options=options, noise_variance=noise_variance)


def _accel(accel_z: np.ndarray) -> np.ndarray:
    acc = np.zeros((len(accel_z), 3))
    acc[:, 2] = accel_z
    return acc


def offline(stamps_ns: np.ndarray, accel_z: np.ndarray, variance: float | None = None,
            noise_variance: float | None = None, **params: Any) -> Any:
    """The core's input policy with the node's parameters on the same samples (no flush):
    an Output (stamps_ns, chainage_m, u_m with NaN where INVALID, quality). ``variance``: the
    reported covariance diagonal; ``noise_variance``: a fixed noise instead of the rule."""
    cov = np.zeros((len(stamps_ns), 9))
    if variance is not None:
        cov[:, 0::4] = variance
    return _policy(params, noise_variance).imu(stamps_ns, _accel(accel_z), None, cov)


def offline_flushed(stamps_ns: np.ndarray, accel_z: np.ndarray, **params: Any) -> Any:
    """The policy's push then flush (a stream that ended): (stamps, chainage, u)."""
    policy = _policy(params)
    outs = (policy.imu(stamps_ns, _accel(accel_z)), policy.flush())
    return tuple(np.concatenate([getattr(o, f) for o in outs])
                 for f in ('stamps_ns', 'chainage_m', 'u_m'))


class Rig:
    """An IrregularityNode plus a test node publishing imu/data (and odom) and recording
    track/irregularity and /diagnostics."""

    def __init__(self, ros_context: Any, spin: Callable, wait_for: Callable,
                 **params: Any) -> None:
        from geometry_msgs.msg import PointStamped
        from nav_msgs.msg import Odometry
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import Imu

        from railgsa_ros.nodes.irregularity_node import IrregularityNode
        from railgsa_ros.nodes.qos import output_qos, sensor_qos

        self.wait_for = wait_for
        overrides = [Parameter(k, value=v) for k, v in {**PARAMS, **HOLD, **params}.items()]
        self.node = spin(IrregularityNode(context=ros_context, parameter_overrides=overrides))
        self.test = Node('irregularity_test', context=ros_context)
        # (stamp, point.x, point.z, frame, point.y) of each output
        self.out = Collector(self.test, PointStamped, 'track/irregularity', output_qos(20_000),
                             lambda m: (stamp_ns(m.header), m.point.x, m.point.z,
                                        m.header.frame_id, int(m.point.y)))  # a whole run
        # per /diagnostics array: task -> (level, message, values)
        self.diag = DiagnosticsLog(self.test, 'irregularity_node: ',
                                   lambda s: (s.level, s.message, values(s)))
        self.imu = self.test.create_publisher(Imu, 'imu/data', sensor_qos())
        self.odom = self.test.create_publisher(Odometry, 'odom', output_qos(10))
        spin(self.test)
        assert wait_for(lambda: self.imu.get_subscription_count() > 0, 15.0)
        assert wait_for(lambda: self.node.count_subscribers('track/irregularity') > 0, 15.0)
        time.sleep(0.2)

    @property
    def quality(self) -> list[int]:
        """point.y of each output so far."""
        return [row[4] for row in self.out.snapshot()]

    def publish(self, msgs: list) -> None:
        """Publish in bursts (about 4 kHz) that the reader history (1000) absorbs."""
        publish_bursts(self.imu, msgs, 4000.0, burst=200)

    def outputs(self, count: int, timeout: float = 20.0) -> tuple[np.ndarray, ...]:
        """Wait for ``count`` outputs; stamps (int64), chainage, u, frame ids."""
        assert self.wait_for(lambda: len(self.out) >= count, timeout), \
            (len(self.out), count, self.node.counters().get('published'),
             self.node.counters())
        time.sleep(0.1)
        stamps, x, z, frames, _ = zip(*self.out.snapshot(), strict=True)
        return np.array(stamps, np.int64), np.array(x), np.array(z), frames

    def diagnostics(self, pred: Callable[[dict], bool], timeout: float = 10.0) -> dict:
        """The first /diagnostics statuses (task -> (level, message, values)) received that
        satisfy ``pred``."""
        assert self.wait_for(lambda: self.diag.first(pred) is not None, timeout), \
            self.diag.snapshot()[-1:] or 'no /diagnostics'
        return self.diag.first(pred)


@pytest.fixture
def rig(ros_context: Any, spin: Callable, wait_for: Callable) -> Iterator[Callable[..., Rig]]:
    """``rig(**params)`` -> a Rig with PARAMS overridden by params."""
    yield lambda **params: Rig(ros_context, spin, wait_for, **params)


def _counted(reason: str, count: int, received: int) -> Callable[[dict], bool]:
    """/diagnostics once ``received`` messages were taken in, ``count`` of them for reason."""
    return lambda d: (d['imu input'][2]['received'] == str(received)
                      and d['imu input'][2][reason] == str(count))


def test_outputs_equal_the_offline_pipeline_one_to_one(run: Any, rig: Callable) -> None:
    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    ref = offline(stamps, acc)
    assert 0 < len(ref) < len(stamps)  # the band delay holds the last D samples back
    r = rig()
    r.publish(imu_msgs(stamps, acc))
    got_t, got_x, got_z, frames = r.outputs(len(ref))
    np.testing.assert_array_equal(got_t, ref.stamps_ns)
    np.testing.assert_array_equal(got_t, stamps[:len(ref)])
    np.testing.assert_array_equal(got_z, ref.u_m)  # spectral: bit-identical for any batching
    # chainage is a running sum continued across pushes: equal to rounding (1e-14 relative)
    np.testing.assert_allclose(got_x, ref.chainage_m, rtol=1e-12, atol=1e-9)
    assert set(frames) == {'track'}
    d = r.diagnostics(lambda d: d['inversion'][2]['published'] == str(len(ref)))
    values = d['inversion'][2]
    assert values['band_delay_samples'] == str(len(stamps) - len(ref))
    assert values['method'] == 'spectral' and values['stability_margin_per_s'] == 'inf'
    busy = r.diagnostics(lambda d: d['inversion'][2]['latency_p50_ms'] != 'nan')['inversion'][2]
    assert float(busy['latency_max_ms']) >= float(busy['latency_p50_ms']) > 0
    assert d['imu input'][2]['accepted'] == str(len(stamps))
    assert d['imu input'][2]['rejected'] == '0'


def test_defaults_equal_config_file() -> None:
    from railgsa_ros.nodes.irregularity_node import NODE_NAME, SPECS

    doc = yaml.safe_load((REPO / 'config' / 'irregularity.yaml').read_text())
    params = doc[NODE_NAME]['ros__parameters']
    defaults = {s.name: s.default for s in SPECS}
    assert params and all(defaults[k] == v for k, v in params.items()), params


def test_docs_list_every_parameter() -> None:
    from railgsa_ros.nodes.irregularity_node import SPECS

    text = (REPO / 'docs' / 'nodes.md').read_text()
    assert [s.name for s in SPECS if f'| `{s.name}` |' not in text] == []


def test_parameter_changes_validated_and_applied_with_a_flush(run: Any, rig: Callable) -> None:
    from rclpy.parameter import Parameter

    r = rig()
    node = r.node
    rejected = {
        'gain': (-1.0, 'range'),
        'method': ('analytical', 'D = 0'),
        'band': ('none', 'spectral'),  # the spectral method needs a band
        'wrong_frame_policy': ('maybe', 'accept or reject'),
        'imu_qos_depth': (500, 'read-only'),
        'k_s': (1e12, 'range'),
    }
    for name, (value, why) in rejected.items():
        [result] = node.set_parameters([Parameter(name, value=value)])
        assert not result.successful and why in result.reason, (name, result.reason)
    assert node.get_parameter('method').value == 'spectral'

    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    half = 3000
    policy = _policy({})
    ref1 = policy.imu(stamps[:half], _accel(acc[:half]))
    tail = policy.rebuild(policy.config.with_(band_order=3))
    ref2 = policy.imu(stamps[half:], _accel(acc[half:]))
    r.publish(imu_msgs(stamps[:half], acc[:half]))
    assert r.wait_for(lambda: len(r.out) >= len(ref1), 10.0)  # all in before the change
    [result] = node.set_parameters([Parameter('band_order', value=3)])
    assert result.successful, result.reason
    r.publish(imu_msgs(stamps[half:], acc[half:]))
    want_t = np.concatenate([ref1.stamps_ns, tail.stamps_ns, ref2.stamps_ns])
    want_z = np.concatenate([ref1.u_m, tail.u_m, ref2.u_m])
    got_t, _, got_z, _ = r.outputs(len(want_t))
    np.testing.assert_array_equal(got_t, want_t)  # every stamp once, in order, across the swap
    np.testing.assert_array_equal(got_z, want_z)
    d = r.diagnostics(lambda d: d['inversion'][2]['published'] == str(len(want_t)))
    assert d['inversion'][2]['rebuilds'] == '1'


def test_invalid_start_parameters_raise_config_error(ros_context: Any) -> None:
    from rclpy.parameter import Parameter

    from railgsa_ros.errors import ConfigError
    from railgsa_ros.nodes.irregularity_node import IrregularityNode

    for name, value, why in (('method', 'banana', 'method'), ('rate_hz', 0.5, 'rate_hz'),
                             ('speed_mps', 'fast', 'expected a float'),
                             ('vehicle_file', '/nonexistent.yaml', 'nonexistent')):
        with pytest.raises(ConfigError, match=why):
            IrregularityNode(context=ros_context,
                             parameter_overrides=[Parameter(name, value=value)])


def test_integer_accepted_for_a_float_parameter(ros_context: Any) -> None:
    from rclpy.parameter import Parameter

    from railgsa_ros.nodes.irregularity_node import IrregularityNode

    node = IrregularityNode(context=ros_context, parameter_overrides=[
        Parameter('speed_mps', value=30), Parameter('gain', value=2000)])
    try:
        assert node.get_parameter('speed_mps').value == 30.0
        assert node.get_parameter('speed_mps').type_ == Parameter.Type.DOUBLE
        results = node.set_parameters([Parameter('speed_mps', value=25),
                                       Parameter('speed_mps', value='slow')])
        assert [r.successful for r in results] == [True, False]
        assert 'expected' in results[1].reason.lower() or 'type' in results[1].reason.lower()
        assert node.get_parameter('speed_mps').value == 25.0
    finally:
        node.destroy_node()


def test_vehicle_file_replaces_the_vehicle_parameters(run: Any, rig: Callable,
                                                     tmp_path: Path) -> None:
    from railgsa_ros.vehicle import VehicleParams

    vehicle = {'m_s': 12000.0, 'm_us': 1300.0, 'k_s': 1.8e6, 'k_us': 1.6e8, 'c': 9.0e4}
    path = tmp_path / 'vehicle.yaml'
    path.write_text(yaml.safe_dump({'vehicle': vehicle}))
    r = rig(vehicle_file=str(path), m_s=5000.0)
    assert {n: r.node.get_parameter(n).value for n in vehicle} == vehicle
    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    r.publish(imu_msgs(stamps, acc))
    ref = _policy({}, vehicle=VehicleParams(**vehicle)).imu(stamps, _accel(acc))
    nominal = offline(stamps, acc)
    got = r.outputs(len(ref))[2]
    np.testing.assert_array_equal(got, ref.u_m)
    n = min(len(ref), len(nominal))
    assert np.nanmax(np.abs(got[:n] - nominal.u_m[:n])) > 1e-3 * np.nanmax(np.abs(got))


@pytest.mark.parametrize(('case', 'reason'), [
    ('nan', 'rejected_nan'), ('inf', 'rejected_nan'), ('saturated', 'rejected_saturated'),
    ('huge', 'rejected_saturated'), ('out_of_order', 'rejected_out_of_order'),
    ('duplicate', 'rejected_duplicate'), ('wrong_frame', 'rejected_wrong_frame'),
    ('zero_stamp', 'rejected_malformed'), ('empty_frame', 'rejected_malformed'),
    ('bad_nanosec', 'rejected_malformed')])
def test_bad_input_counted_by_reason_and_node_keeps_running(case: str, reason: str, run: Any,
                                                            rig: Callable) -> None:
    from builtin_interfaces.msg import Time

    stamps, acc = run.stamps_ns[:2400] + T0_NS, run.accel[:2400, 2].copy()
    msgs = imu_msgs(stamps, acc)
    bad = [100, 101, 102]
    for i in bad:
        m = msgs[i]
        if case in ('nan', 'inf', 'saturated', 'huge'):
            m.linear_acceleration.z = {'nan': float('nan'), 'inf': -float('inf'),
                                       'saturated': 8 * G, 'huge': 1e300}[case]
        elif case == 'out_of_order':
            earlier = msgs[i - 50].header.stamp
            m.header.stamp = Time(sec=earlier.sec, nanosec=earlier.nanosec + 1)
        elif case == 'duplicate':
            m.header.stamp = Time(sec=msgs[99].header.stamp.sec,
                                  nanosec=msgs[99].header.stamp.nanosec)
        elif case == 'wrong_frame':
            m.header.frame_id = 'base_link'
        elif case == 'zero_stamp':
            m.header.stamp.sec = m.header.stamp.nanosec = 0
        elif case == 'empty_frame':
            m.header.frame_id = ''
        else:
            m.header.stamp.nanosec = 1_500_000_000
    r = rig(wrong_frame_policy='reject')
    r.publish(msgs)
    d = r.diagnostics(_counted(reason, len(bad), len(msgs)))
    values = d['imu input'][2]
    assert values['rejected'] == str(len(bad))
    assert values['accepted'] == str(len(msgs) - len(bad))
    why = reason.removeprefix('rejected_')  # the period with the rejections WARNs and says why
    r.diagnostics(lambda d: d['imu input'][0] == b'\x01' and why in d['imu input'][1])
    good = np.setdiff1d(np.arange(len(msgs)), bad)
    ref = offline(stamps[good], acc[good])
    got_t, _, got_z, _ = r.outputs(len(ref))
    np.testing.assert_array_equal(got_t, ref.stamps_ns)
    np.testing.assert_array_equal(got_z, ref.u_m)
    np.testing.assert_array_equal(r.quality[:len(ref)], ref.quality)
    assert np.all(np.isfinite(got_z) == (ref.quality != 2))  # NaN exactly where INVALID


def test_wrong_frame_accepted_by_policy(run: Any, rig: Callable) -> None:
    stamps, acc = run.stamps_ns[:2200] + T0_NS, run.accel[:2200, 2]
    r = rig(wrong_frame_policy='accept')
    r.publish(imu_msgs(stamps, acc, frame='imu_mount'))
    d = r.diagnostics(_counted('wrong_frame_accepted', len(stamps), len(stamps)))
    assert d['imu input'][2]['rejected_wrong_frame'] == '0'
    ref = offline(stamps, acc)
    np.testing.assert_array_equal(r.outputs(len(ref))[2], ref.u_m)


@pytest.mark.parametrize('policy', ['reset', 'bridge'])
def test_gap_reset_or_bridged_without_a_spike(policy: str, run: Any, rig: Callable) -> None:
    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    cut = np.r_[0:2500, 2530:len(stamps)]  # 30 ms missing: bridged (<= 50 ms) or reset
    r = rig(gap_policy=policy)
    r.publish(imu_msgs(stamps[cut], acc[cut]))
    d = r.diagnostics(_counted('gap', 1, len(cut)))
    assert d['imu input'][2]['reset'] == str(int(policy == 'reset'))
    assert d['imu input'][2]['bridged'] == str(30 if policy == 'bridge' else 0)  # 1 ms apart
    ref = offline(stamps[cut], acc[cut], gap_policy=policy)
    got_t, _, got_z, _ = r.outputs(len(ref), timeout=60.0)
    np.testing.assert_array_equal(got_t, ref.stamps_ns)
    np.testing.assert_array_equal(got_z, ref.u_m)
    assert set(got_t) <= set(stamps[cut])  # bridged samples are never published
    clean = offline(stamps, acc)
    finite = np.abs(got_z[np.isfinite(got_z)])
    assert np.all(finite <= 1.2 * np.nanmax(np.abs(clean.u_m)))  # no spike at the gap
    if policy == 'reset':  # the warm-up after the restart is INVALID, not published as valid
        after = (got_t >= stamps[2530]) & (got_t < stamps[2630])
        assert after.any() and np.isnan(got_z[after]).all()


def test_speed_from_odometry_invalid_and_a_diagnostic_until_known(run: Any,
                                                                 rig: Callable) -> None:
    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    r = rig(use_odom=True, speed_mps=25.0, odom_timeout_s=0.5)
    r.publish(imu_msgs(stamps[:1000], acc[:1000]))
    d = r.diagnostics(lambda d: d['input checks'][0] == b'\x01')
    assert 'no odometry' in d['input checks'][1] and 'INVALID' in d['input checks'][1]

    assert r.wait_for(lambda: r.odom.get_subscription_count() > 0, 10.0)
    policy = _policy({'use_odom': True, 'speed_mps': 25.0, 'odom_timeout_s': 0.5})
    parts = [policy.imu(stamps[:1000], _accel(acc[:1000]))]
    for k in range(1000, len(stamps), 100):  # odometry at 10 Hz from sample 1000 on
        r.odom.publish(odometry(stamps[k], 40.0))
        assert r.wait_for(lambda n=k: r.node.counters().get('odom_received', 0)
                          == (n - 1000) // 100 + 1, 5.0)
        r.publish(imu_msgs(stamps[k:k + 100], acc[k:k + 100]))
        parts += [policy.odometry([stamps[k]], [40.0]),
                  policy.imu(stamps[k:k + 100], _accel(acc[k:k + 100]))]
    ref = parts[0].concat(parts)
    got_t, got_x, got_z, _ = r.outputs(len(ref), timeout=60.0)
    np.testing.assert_array_equal(got_t, ref.stamps_ns)
    np.testing.assert_array_equal(r.quality[:len(ref)], ref.quality)
    np.testing.assert_array_equal(got_z, ref.u_m)
    np.testing.assert_allclose(got_x, ref.chainage_m, rtol=1e-12, atol=1e-9)
    unknown = got_t < stamps[1000]  # before the first odometry: no speed, INVALID, NaN
    assert np.all(np.asarray(r.quality[:len(ref)])[unknown] == 2)
    assert np.isnan(got_z[unknown]).all()
    assert np.isfinite(got_z[~unknown]).any()


@pytest.mark.parametrize(('variance', 'used'), [(4e-4, 4e-4), (0.0, None)])
def test_rep145_covariance_sets_the_kalman_noise(variance: float, used: float | None, run: Any,
                                                  rig: Callable) -> None:
    """A reported variance is the Kalman noise; an all-zero covariance (unknown) falls back to
    noise_std_mps2 (the reference: the policy with that noise fixed)."""
    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    r = rig(method='kalman')
    r.publish(imu_msgs(stamps, acc, variance=variance or None))
    fixed = used if used is not None else 0.005 ** 2  # noise_std_mps2 default
    ref = offline(stamps, acc, method='kalman', noise_variance=fixed)
    other = offline(stamps, acc, method='kalman', noise_variance=1e-2)
    got_z = r.outputs(len(ref))[2]
    scale = np.nanmax(np.abs(ref.u_m))
    np.testing.assert_allclose(got_z, ref.u_m, rtol=1e-9, atol=1e-12 * scale)
    assert np.nanmax(np.abs(other.u_m - ref.u_m)) > 1e-6 * scale


def test_absent_acceleration_is_rejected_as_nan(run: Any, rig: Callable) -> None:
    """REP 145: -1 in element 0 of the covariance means no acceleration estimate."""
    stamps, acc = run.stamps_ns[:600] + T0_NS, run.accel[:600, 2]
    r = rig()
    r.publish(imu_msgs(stamps, acc, absent=True))
    d = r.diagnostics(_counted('rejected_nan', len(stamps), len(stamps)))
    assert d['imu input'][2]['accepted'] == '0'
    d = r.diagnostics(lambda d: d['input checks'][0] == b'\x02')
    assert 'every IMU sample is rejected' in d['input checks'][1]


def test_sim_time_outputs_carry_imu_stamps(run: Any, rig: Callable) -> None:
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock

    r = rig(use_sim_time=True)
    clock = r.test.create_publisher(Clock, '/clock', 10)
    clock.publish(Clock(clock=Time(sec=1234)))
    stamps, acc = run.stamps_ns[:2000] + T0_NS, run.accel[:2000, 2]
    r.publish(imu_msgs(stamps, acc))
    ref = offline(stamps, acc)
    got_t = r.outputs(len(ref))[0]
    np.testing.assert_array_equal(got_t, stamps[:len(ref)])


def test_fuzzed_messages_never_raise_and_nan_only_when_invalid(ros_context: Any) -> None:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
    from rclpy.parameter import Parameter

    from railgsa_ros.nodes.irregularity_node import IrregularityNode

    overrides = {**PARAMS, 'method': 'feedback', 'band': 'none'}  # D = 0: every sample out
    node = IrregularityNode(context=ros_context, parameter_overrides=[
        Parameter(k, value=v) for k, v in overrides.items()])
    floats = st.floats(allow_nan=True, allow_infinity=True)
    message = st.tuples(st.integers(-3, 2**31 - 1), st.integers(0, 2**32 - 1),
                        st.sampled_from(['imu_link', '', 'base_link', 'imu_link ']),
                        floats, st.sampled_from([-1.0, 0.0, float('nan'), 1e-4]), floats)

    @settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
    @given(st.lists(message, min_size=1, max_size=12))
    def check(rows: list[tuple]) -> None:
        msgs = [imu_msg(sec, nsec, frame, (0.0, 0.0, z), [cov0] + [0.0] * 7 + [cov8])
                for sec, nsec, frame, z, cov0, cov8 in rows]
        out = node.process(serialized(msgs))  # u finite except where INVALID (NaN)
        assert out is None or np.all(np.isfinite(out.u_m) == (out.quality != 2))

    check()
    totals = node.counters()
    assert totals['received'] == sum(totals.get(k, 0) for k in (
        'accepted', 'malformed', 'nan', 'saturated', 'stuck', 'out_of_order', 'duplicate',
        'wrong_frame')) + node.policy.held  # each message once (or still held for the noise)
    assert totals.get('internal_error', 0) == 0 and totals.get('published', 0) > 0
    node.destroy_node()


def _rotated_to_minus_y(run: Any) -> np.ndarray:
    """The scenario's accelerations as a sensor mounted with its -y axis up (z -> -y)."""
    acc = np.zeros_like(run.accel)
    acc[:, 0], acc[:, 1], acc[:, 2] = run.accel[:, 0], -run.accel[:, 2], run.accel[:, 1]
    return acc


def test_gravity_on_minus_y_live_every_output_invalid_and_a_finding_naming_the_axis(
        rig: Callable) -> None:
    from railgsa_ros.scenario import run_scenario

    run = run_scenario('german-low', speed_mps=40.0, duration_s=3.0, rate_hz=1000.0,
                       sensor='adxl355', seed=2)  # a real sensor: the other axes are not stuck
    stamps, acc = run.stamps_ns + T0_NS, _rotated_to_minus_y(run)
    ref = _policy({}).imu(stamps, acc, None, np.zeros((len(stamps), 9)))
    assert len(ref) > 0 and np.all(ref.quality == 2)
    r = rig()
    r.publish(imu_msgs(stamps, acc))
    got_t, _, got_z, _ = r.outputs(len(ref))
    np.testing.assert_array_equal(got_t, ref.stamps_ns)
    assert r.quality[:len(ref)] == [2] * len(ref)  # every published sample INVALID
    assert np.isnan(got_z).all()
    d = r.diagnostics(lambda d: d['input checks'][0] == b'\x02'
                      and 'gravity' in d['input checks'][2])
    _, message, values = d['input checks']
    assert values['gravity'].startswith('ERROR') and "accel_axis to '-y'" in values['gravity']
    assert "'-y'" in message  # the worst finding is the status line
    inv = r.diagnostics(lambda d: d['inversion'][2]['published'] == str(len(ref)))['inversion']
    assert inv[2]['invalid'] == str(len(ref)) and inv[2]['valid'] == '0'


def test_tilted_sensor_live_equals_the_policy_and_reports_the_tilt(rig: Callable) -> None:
    """A sensor rolled 25 deg (docs/inversion.md, Mounting): the node publishes what the policy
    gives offline (projected on the estimate, DEGRADED while it settles, never VALID) and
    /diagnostics 'input checks' carries the 'mounting' finding with the angle."""
    from railgsa_ros.mount_sim import mounted
    from railgsa_ros.scenario import run_scenario

    run = run_scenario('german-low', speed_mps=40.0, duration_s=3.0, rate_hz=1000.0,
                       sensor='adxl355', seed=2)
    stamps, acc = run.stamps_ns + T0_NS, mounted(run.accel, 25.0, 0.0)
    ref = _policy({}).imu(stamps, acc, None, np.zeros((len(stamps), 9)))
    assert len(ref) > 0 and not np.any(ref.quality == 0)
    r = rig()
    r.publish(imu_msgs(stamps, acc))
    got_t, _, got_z, _ = r.outputs(len(ref))
    np.testing.assert_array_equal(got_t, ref.stamps_ns)
    np.testing.assert_array_equal(r.quality[:len(ref)], ref.quality)
    np.testing.assert_array_equal(got_z, ref.u_m)
    d = r.diagnostics(lambda d: 'mounting' in d['input checks'][2])
    finding = d['input checks'][2]['mounting']
    assert finding.startswith('WARN') and 'settles' in finding
    assert abs(float(finding.split('tilted ')[1].split()[0]) - 25.0) < 1.0


def test_rate_hz_disagreeing_with_the_data_live_is_an_error_and_invalid(run: Any,
                                                                        rig: Callable) -> None:
    """rate_hz 500 for 1 kHz data: docs/inversion.md, 'rate': INVALID from the end of the first
    block of 512 stamp steps on, ERROR naming the measured rate and the fix."""
    from railgsa_ros.input.monitors import RATE_BLOCK

    stamps, acc = run.stamps_ns[:3000] + T0_NS, run.accel[:3000, 2]
    ref = offline(stamps, acc, rate_hz=500.0)
    assert len(ref) > RATE_BLOCK + 1
    r = rig(rate_hz=500.0)
    r.publish(imu_msgs(stamps, acc))
    got_t, _, got_z, _ = r.outputs(len(ref))
    np.testing.assert_array_equal(got_t, ref.stamps_ns)
    quality = np.asarray(r.quality[:len(ref)])
    np.testing.assert_array_equal(quality, ref.quality)  # as the policy decides offline
    assert np.all(quality[RATE_BLOCK + 1:] == 2)  # the sample after the block on: INVALID
    assert np.isnan(got_z[RATE_BLOCK + 1:]).all()
    d = r.diagnostics(lambda d: 'rate' in d['input checks'][2])
    level, _, values = d['input checks']
    assert level == b'\x02' and values['rate'].startswith('ERROR')
    assert 'rate_hz 500' in values['rate'] and 'set rate_hz to 1000' in values['rate']


def test_quality_counts_on_diagnostics_equal_the_published_codes(run: Any,
                                                                 rig: Callable) -> None:
    """Odometry 40 m/s, a standstill, then 20 m/s (below min_design_speed_mps 40): VALID,
    INVALID and DEGRADED outputs; /diagnostics' valid/degraded/invalid = the point.y codes."""
    from collections import Counter

    from railgsa_ros.inverse.pipeline import Output

    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    odom_k = np.arange(0, len(stamps), 100)
    speeds = np.where(odom_k < 2000, 40.0, np.where(odom_k < 3000, 0.0, 20.0))
    params = {'use_odom': True, 'odom_timeout_s': 0.5}
    policy = _policy(params)
    ref = Output.concat([policy.odometry(stamps[odom_k], speeds),
                         policy.imu(stamps, _accel(acc))])
    want = Counter(ref.quality.tolist())
    assert want[0] > 0 and want[1] > 0 and want[2] > 0, want
    r = rig(**params)
    assert r.wait_for(lambda: r.odom.get_subscription_count() > 0, 10.0)
    for n, (k, v) in enumerate(zip(odom_k.tolist(), speeds.tolist(), strict=True)):
        r.odom.publish(odometry(stamps[k], v))
        assert r.wait_for(lambda n=n: r.node.counters().get('odom_received', 0) == n + 1, 5.0)
    r.publish(imu_msgs(stamps, acc))
    r.outputs(len(ref), timeout=60.0)
    d = r.diagnostics(lambda d: d['inversion'][2]['published'] == str(len(ref)))
    got = Counter(r.quality)
    assert sum(got.values()) == len(ref)
    values = d['inversion'][2]
    assert {q: int(values[q]) for q in ('valid', 'degraded', 'invalid')} == \
        {'valid': got[0], 'degraded': got[1], 'invalid': got[2]}
    np.testing.assert_array_equal(r.quality[:len(ref)], ref.quality)


def test_grid_topic_equals_invert_grid(rig: Callable, tmp_path: Path) -> None:
    """publish_grid: track/irregularity_grid through the node (ended by the idle flush) equals
    ``railgsa invert --grid 0.25`` on a bag of the same samples (12 s at 40 m/s, 500 Hz: the
    pre-band's window leaves VALID points), point for point (live = offline: the same GridStream
    objects)."""
    from geometry_msgs.msg import PointStamped

    from railgsa_ros.bag.run import write_run
    from railgsa_ros.cli.main import main
    from railgsa_ros.nodes.qos import output_qos
    from railgsa_ros.scenario import run_scenario

    run = run_scenario('german-low', speed_mps=40.0, duration_s=12.0, rate_hz=500.0,
                       sensor='ideal', seed=1)
    variance = 1e-6
    bag = write_run(tmp_path / 'bag', run, accel_variance=variance, offset_ns=T0_NS)
    params = tmp_path / 'params.yaml'
    params.write_text(yaml.safe_dump({'irregularity_node': {'ros__parameters': {
        'min_design_speed_mps': PARAMS['min_design_speed_mps'], 'rate_hz': 500.0}}}))
    csv = tmp_path / 'grid.csv'
    assert main(['invert', str(bag), '--csv', str(csv), '--grid', '0.25', '--speed',
                 str(PARAMS['speed_mps']), '--params', str(params)]) == 0
    rows = [line.split(',') for line in csv.read_text().splitlines()[1:]]
    want_t = np.array([int(t.split('.')[0]) * 1_000_000_000 + int(t.split('.')[1])
                       for t, *_ in rows], np.int64)
    want = np.array([[float(r[1]), float(r[3]), float(r[2])] for r in rows])  # x, y, z

    r = rig(publish_grid=True, idle_flush_s=0.5, rate_hz=500.0)
    grid = Collector(r.test, PointStamped, 'track/irregularity_grid', output_qos(20_000),
                     point_row)
    assert r.wait_for(lambda: r.node.count_subscribers('track/irregularity_grid') > 0, 15.0)
    time.sleep(0.2)
    r.publish(imu_msgs(run.stamps_ns + T0_NS, run.accel[:, 2], variance=variance))
    assert r.wait_for(lambda: len(grid) >= len(rows), 30.0), (len(grid), len(rows))
    time.sleep(0.2)
    got = grid.snapshot()
    stamps = np.array([g[0] for g in got], np.int64)
    values = np.array([g[1:] for g in got])
    assert len(rows) > 500 and (want[:, 1] == 0).any()  # VALID points exist
    np.testing.assert_array_equal(stamps, want_t)
    np.testing.assert_allclose(values[:, :2], want[:, :2], rtol=0, atol=5e-5)  # %.4f chainage
    np.testing.assert_allclose(values[:, 2], want[:, 2], rtol=1e-8, atol=0)  # %.9e u, NaN too
