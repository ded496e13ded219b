"""uncertainty_node: band and sensitivity messages equal the offline streaming code, bad input
counted on /diagnostics, start-up errors; as a process next to irregularity_node: SIGKILL of the
uncertainty node leaves irregularity_node unaffected, SIGINT exits 0."""

from __future__ import annotations

from collections.abc import Callable, Iterator
import signal
import threading
import time
from typing import Any

import numpy as np
import pytest
from ros_helpers import (
    T0_NS,
    Collector,
    DiagnosticsLog,
    header_stamp,
    imu_msgs,
    odometry,
    publish_bursts,
    serialized,
    stamp_ns,
    vector_row,
)
from ros_helpers import values as status_values

pytestmark = pytest.mark.ros

#: a short band delay keeps the tests fast; 1 s windows; no odometry; no re-order window (the
#: references push without a flush; the window's replay equivalence: test_bag_order.py)
PARAMS = {'use_odom': False, 'speed_mps': 40.0, 'min_design_speed_mps': 40.0,
          'window_length': 1.0, 'n_mc': 4096, 'process_period_s': 0.02,
          'reorder_window_s': 0.0}
DEPTH = 5000  # listener history: a whole run, so that no burst of outputs overwrites another


@pytest.fixture(scope='module')
def run() -> Any:
    """4 s of German-low track at 40 m/s through an ideal 1 kHz IMU."""
    from railgsa_ros.scenario import run_scenario

    return run_scenario('german-low', speed_mps=40.0, duration_s=4.0, rate_hz=1000.0,
                        sensor='ideal', seed=2)


def offline_reference(stamps_ns: np.ndarray, accel_z: np.ndarray,
                      frame_ids: np.ndarray | None = None) -> Any:
    """offline_bands of the node's settings: fixed speed (use_odom false), accel on z."""
    from railgsa_ros.input.options import InputOptions
    from railgsa_ros.uncertainty import offline_bands

    accel = np.zeros((stamps_ns.size, 3))
    accel[:, 2] = accel_z
    config = node_config()
    config = config.with_(inversion=config.inversion.with_(speed_mps=40.0))
    return offline_bands(stamps_ns, accel, None, frame_ids, config=config,
                         options=InputOptions(use_odom=False))


def node_config() -> Any:
    """The node's UncertaintyConfig for PARAMS (what offline_bands must be given)."""
    from railgsa_ros.uncertainty import UncertaintyConfig

    return UncertaintyConfig.from_mapping({k: v for k, v in PARAMS.items()
                                           if k not in ('use_odom', 'process_period_s',
                                                        'reorder_window_s')})


class Listener:
    """A test node: publishes imu/data, records bands, sensitivities, irregularity and
    /diagnostics of ``node_name``."""

    def __init__(self, ros_context: Any, node_name: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PointStamped, Vector3Stamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from sensor_msgs.msg import Imu

        from railgsa_ros.nodes.qos import output_qos, sensor_qos

        self.node = Node('uncertainty_test', context=ros_context)
        self.band = Collector(self.node, Vector3Stamped, 'track/irregularity_band',
                              output_qos(DEPTH), vector_row)
        self.irregularity = Collector(self.node, PointStamped, 'track/irregularity',
                                      output_qos(DEPTH), header_stamp)
        self.sensitivity = Collector(self.node, DiagnosticArray, 'track/sensitivity',
                                     output_qos(100))
        # per /diagnostics array: task -> (level, values)
        self.diag = DiagnosticsLog(self.node, f'{node_name}: ',
                                   lambda s: (s.level, status_values(s)))
        self.imu = self.node.create_publisher(Imu, 'imu/data', sensor_qos())
        # its own executor thread: the node under test never delays the reading of its outputs
        self.executor = SingleThreadedExecutor(context=ros_context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.thread.join(5.0)
        self.node.destroy_node()

    def publish(self, msgs: list, rate_hz: float = 2000.0) -> None:
        """Publish in 10 ms bursts at about ``rate_hz``."""
        publish_bursts(self.imu, msgs, rate_hz)


@pytest.fixture
def listen(ros_context: Any) -> Iterator[Callable[[], Listener]]:
    """``listen()`` -> a Listener of uncertainty_node's /diagnostics, closed at teardown."""
    made: list[Listener] = []

    def make() -> Listener:
        made.append(Listener(ros_context, 'uncertainty_node'))
        return made[-1]
    yield make
    for listener in made:
        listener.close()


@pytest.fixture
def rig(ros_context: Any, spin: Callable, wait_for: Callable,
        listen: Callable[[], Listener]) -> Callable[..., tuple]:
    """``rig(**params)`` -> (UncertaintyNode in-process, Listener), connected."""
    from rclpy.parameter import Parameter

    from railgsa_ros.nodes.uncertainty_node import UncertaintyNode

    def make(**params: Any) -> tuple:
        params = {**PARAMS, 'output_qos_depth': DEPTH, **params}
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        node = spin(UncertaintyNode(context=ros_context, parameter_overrides=overrides))
        listener = listen()
        assert wait_for(lambda: listener.imu.get_subscription_count() > 0, 15.0)
        assert wait_for(lambda: node.count_subscribers('track/irregularity_band') > 0, 15.0)
        time.sleep(0.2)
        return node, listener
    return make


def test_band_and_sensitivity_equal_the_offline_streaming_code(run: Any, rig: Callable,
                                                               wait_for: Callable) -> None:
    from railgsa_ros.uncertainty import UncertaintyStream

    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    msgs = imu_msgs(stamps, acc)
    msgs[500].linear_acceleration.z = float('nan')  # rejected: nan
    msgs[900].header.frame_id = ''                  # malformed
    good = np.setdiff1d(np.arange(stamps.size), [500, 900])
    ref = offline_reference(stamps[good], acc[good])
    stream = UncertaintyStream(node_config())
    live = stream.push(stamps[good], acc[good], 40.0)  # what the node can emit without a flush
    node, listener = rig()
    listener.publish(msgs)
    count = len(live.band)
    assert 0 < count < good.size
    assert wait_for(lambda: len(listener.band) >= count, 30.0), (len(listener.band), count,
                                                                 node.counters())
    assert wait_for(lambda: len(listener.sensitivity) >= len(live.windows), 10.0)
    time.sleep(0.2)
    rows = listener.band.snapshot()
    got = np.array(rows)
    got_t = np.array([b[0] for b in rows], np.int64)  # float64 rounds 1.7e18 ns
    arrays = listener.sensitivity.snapshot()
    np.testing.assert_array_equal(got_t, ref.stamps_ns[:count])
    scale = np.nanmax(np.abs(ref.mean_m))
    for col, name in enumerate(('lower_m', 'mean_m', 'upper_m'), start=1):
        np.testing.assert_allclose(got[:, col], getattr(ref, name)[:count], rtol=0,
                                   atol=1e-12 * scale)
    assert len(arrays) == len(live.windows) >= 2  # two QoIs per 1 s window
    for msg, rec in zip(arrays, live.windows, strict=True):
        *params, summary = msg.status
        assert [s.name for s in params] == ['k_s', 'k_us', 'c'] and summary.name == 'summary'
        for i, status in enumerate(params):
            v = status_values(status)
            np.testing.assert_allclose([float(v['sobol_first']), float(v['sobol_total'])],
                                       [rec.sobol_first[i], rec.sobol_total[i]], rtol=1e-5,
                                       atol=1e-6)
            # delta bins surrogate samples: coefficients 1e-16 apart (other chunking) may move
            # a sample across a bin edge
            assert float(v['delta']) == pytest.approx(rec.delta[i], abs=1e-3)
        s = status_values(summary)
        assert s['qoi'] == rec.qoi and s['rule'] == 'pem5' and s['model_evaluations'] == '19'
        assert int(s['first_stamp_ns']) == rec.first_stamp_ns
        assert int(s['last_stamp_ns']) == rec.last_stamp_ns == stamp_ns(msg.header)
        assert float(s['chainage_end_m']) == pytest.approx(rec.chainage_end_m, rel=1e-5)
    def counted(d: dict) -> bool:
        return (d.get('imu input', (0, {}))[1].get('rejected') == '2'
                and d['uncertainty'][1].get('windows', '0') != '0')
    assert wait_for(lambda: listener.diag.first(counted), 10.0), listener.diag.snapshot()[-1:]
    diag = [listener.diag.first(counted)]
    values = diag[0]['imu input'][1]
    assert any(d['imu input'][0] == b'\x01' for d in listener.diag.snapshot())  # WARN then
    assert values['rejected_nan'] == values['rejected_malformed'] == '1'
    unc = diag[0]['uncertainty'][1]
    assert unc['rule_points'] == '19' and float(unc['window_compute_ms']) > 0
    assert 0 < float(unc['cpu_fraction_of_one_core']) < 2


def test_replayed_bag_gives_the_offline_bands(run: Any, rig: Callable, ros_context: Any,
                                               wait_for: Callable, tmp_path: Any) -> None:
    from rclpy.parameter import Parameter

    from railgsa_ros.bag import read_imu, write_run
    from railgsa_ros.nodes.bag_replay_node import BagReplayNode

    bag = write_run(tmp_path / 'run', run, offset_ns=T0_NS)
    recorded = read_imu(bag)
    ref = offline_reference(recorded.stamps_ns, recorded.accel[:, 2], recorded.frame_ids)
    node, listener = rig(qoi='')
    player = BagReplayNode(context=ros_context, parameter_overrides=[
        Parameter('bag_path', value=str(bag)), Parameter('rate', value=2.0),
        Parameter('topics', Parameter.Type.STRING_ARRAY, ['/imu/data']),
        Parameter('wait_for_subscribers', value=15.0)])
    try:
        assert player.play() == recorded.stamps_ns.size
    finally:
        player.destroy_node()
    count = recorded.stamps_ns.size - node.stream.delay_samples  # live: no flush
    assert wait_for(lambda: len(listener.band) >= count, 30.0), (len(listener.band), count)
    rows = listener.band.snapshot()
    got = np.array(rows)
    got_t = np.array([b[0] for b in rows], np.int64)
    np.testing.assert_array_equal(got_t, ref.stamps_ns[:count])
    np.testing.assert_allclose(got[:, 1:], np.stack([ref.lower_m, ref.mean_m, ref.upper_m],
                                                    axis=1)[:count],
                               rtol=0, atol=1e-12 * np.nanmax(np.abs(ref.mean_m)))


def test_internal_error_is_counted_and_the_stream_rebuilt(run: Any, rig: Callable) -> None:
    node, _ = rig()
    msgs = imu_msgs(run.stamps_ns[:100] + T0_NS, run.accel[:100, 2])
    policy = node.stream.policy
    calls = []

    def fail_once(*args: Any) -> Any:
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError('injected')
        return type(policy).imu(policy, *args)
    policy.imu = fail_once
    assert node.process(serialized(msgs)) is None
    assert node.counters()['internal_error'] == 1 and node.counters()['rebuild'] == 1
    node.process(serialized(imu_msgs(run.stamps_ns[100:3000] + T0_NS,
                                         run.accel[100:3000, 2])))
    assert node.counters()['published'] > 0


def test_odometry_speed_and_reported_kalman_noise_are_used(run: Any, rig: Callable,
                                                           wait_for: Callable) -> None:
    """The stream's policy takes the node's odometry and the IMU-reported variance: equal to a
    stream with the same odometry and that variance fixed."""

    from railgsa_ros.input.options import InputOptions
    from railgsa_ros.uncertainty import UncertaintyStream

    node, listener = rig(use_odom=True, method='kalman', band='none', qoi='',
                         odom_timeout_s=10.0)
    stamps, acc = run.stamps_ns[:2000] + T0_NS, run.accel[:2000, 2]

    msgs = imu_msgs(stamps, acc)
    for m in msgs:
        m.linear_acceleration_covariance[0] = 0.0
        m.linear_acceleration_covariance[8] = 4e-6
    node.process(serialized(msgs), serialized([odometry(stamps[0], 25.0)]))  # odometry first
    # newer than every sample: all decided
    node.process([], serialized([odometry(stamps[-1] + 1, 25.0)]))
    config = node_config().with_(qoi='', inversion=node_config().inversion.with_(
        method='kalman', band='none'))
    ref = UncertaintyStream(config, noise_variance=4e-6,
                            options=InputOptions(use_odom=True, odom_timeout_s=10.0,
                                                  reorder_window_s=0.0))
    accel = np.zeros((len(stamps), 3))
    accel[:, 2] = acc
    want = [ref.odometry([stamps[0]], [25.0]).band, ref.imu(stamps, accel).band,
            ref.odometry([stamps[-1] + 1], [25.0]).band]
    want = want[0].concat(want)
    assert len(want) == len(stamps)  # band none: every sample out
    assert wait_for(lambda: len(listener.band) >= len(want), 30.0)
    rows = listener.band.snapshot()
    got_t = np.array([b[0] for b in rows], np.int64)
    got_mean = np.array([b[2] for b in rows])
    np.testing.assert_array_equal(got_t, want.stamps_ns)
    np.testing.assert_allclose(got_mean, want.mean_m, rtol=1e-12, atol=0)


def test_invalid_start_parameters_raise_config_error(ros_context: Any, tmp_path: Any) -> None:
    from rclpy.parameter import Parameter

    from railgsa_ros.errors import ConfigError
    from railgsa_ros.nodes.uncertainty_node import UncertaintyNode

    bad_file = tmp_path / 'u.yaml'
    bad_file.write_text('parameters:\n  k_s: {dist: normal, mu: 1.0}\n')
    for name, value, match in (('order', 3, 'order'), ('qoi', 'max', 'qoi'),
                               ('uncertainty_file', str(bad_file), 'sigma')):
        with pytest.raises(ConfigError, match=match):
            UncertaintyNode(context=ros_context,
                            parameter_overrides=[Parameter(name, value=value)])


def test_parameters_are_read_only(rig: Callable) -> None:
    from rclpy.parameter import Parameter

    node, _ = rig()
    result = node.set_parameters([Parameter('germ_samples', value=2048)])[0]
    assert not result.successful and 'read-only' in result.reason


def test_killing_the_uncertainty_node_leaves_irregularity_node_unaffected(
        run: Any, listen: Callable, wait_for: Callable, start_node: Callable) -> None:
    def ros_args(names: Any) -> list[str]:
        return [a for k in names for a in ('-p', f'{k}:={str(PARAMS[k]).lower()}')]

    shared = ('use_odom', 'speed_mps', 'min_design_speed_mps')
    irregularity = start_node('railgsa_ros.nodes.irregularity_node', ros_args(shared))
    uncertainty = start_node('railgsa_ros.nodes.uncertainty_node', ros_args(PARAMS))
    listener = listen()
    assert wait_for(lambda: listener.imu.get_subscription_count() >= 2, 30.0), \
        (irregularity.running(), uncertainty.running())
    # the graph may still list readers of nodes destroyed by earlier tests: wait for the
    # process's own /diagnostics (it reports once active, i.e. subscribed)
    assert wait_for(lambda: len(listener.diag) > 0, 30.0), uncertainty.stop().stderr
    time.sleep(1.0)
    stamps = run.stamps_ns + T0_NS
    msgs = imu_msgs(stamps, run.accel[:, 2])
    half = 2600  # past the band delay of both nodes (about 1.8 s)
    listener.publish(msgs[:half], rate_hz=1000.0)
    assert wait_for(lambda: len(listener.band) > 0, 15.0), uncertainty.stop().stderr
    uncertainty.stop(signal.SIGKILL)
    band = np.array([b[0] for b in listener.band.snapshot()], np.int64)
    # the irregularity stamps, contiguous from the node's first sample (discovery may let the
    # node miss the first BEST_EFFORT messages after it reports: that is not what is tested)
    first = int(np.searchsorted(stamps, band[0]))
    np.testing.assert_array_equal(band, stamps[first:first + band.size])
    before = len(listener.irregularity)
    listener.publish(msgs[half:], rate_hz=1000.0)
    assert wait_for(lambda: len(listener.irregularity) >= before + len(msgs) - half, 20.0)
    time.sleep(0.2)
    got = np.array(listener.irregularity.snapshot(), np.int64)
    # every sample the irregularity node could emit arrived, in order, none missing
    first = int(np.searchsorted(stamps, got[0]))
    np.testing.assert_array_equal(got, stamps[first:first + got.size])
    assert got.size >= stamps.size - 2000 and irregularity.running()
    result = irregularity.stop(signal.SIGINT)
    assert result.rc == 0, result.stderr


def test_sigint_exits_zero(listen: Callable, wait_for: Callable, start_node: Callable) -> None:
    node = start_node('railgsa_ros.nodes.uncertainty_node', ['-p', 'use_odom:=false'])
    listener = listen()
    assert wait_for(lambda: len(listener.diag) > 0, 30.0), node.stop().stderr
    result = node.stop(signal.SIGINT)
    assert result.rc == 0, result.stderr
