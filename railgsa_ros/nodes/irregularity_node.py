"""irregularity_node: live vertical track irregularity from car-body acceleration.

Subscribes ``imu/data`` (sensor_msgs/Imu) and optionally ``odom`` (nav_msgs/Odometry, speed =
twist.twist.linear.x); publishes ``track/irregularity`` (geometry_msgs/PointStamped, stamp = the
IMU sample's stamp, frame ``track``, x = chainage m, z = irregularity m, +z up) and
``/diagnostics``. A thin adapter over :class:`railgsa_ros.inverse.pipeline.InversionPipeline`;
see docs/nodes.md for topics, parameters, QoS and diagnostics.

Processing: the IMU callback takes the message it was called for plus every message already
waiting in the reader history and pushes them through the pipeline as one batch. At light load
each sample is processed as it arrives (lowest latency); under load the batches grow and the cost
per sample falls (benchmarks/bench_node_latency.py measured this against per-message and timer
processing).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import fields
import sys
import time
from typing import Any

from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, Output, vertical
from railgsa_ros.inverse.sanitize import REASONS, frame_mask
from railgsa_ros.nodes.diagnostics import (
    ERROR,
    OK,
    STALE,
    WARN,
    Deltas,
    DiagnosticsPublisher,
    LatencyWindow,
    Report,
)
from railgsa_ros.nodes.imu_conversion import NS_PER_S, ImuBatch, imu_batch, odom_speed
from railgsa_ros.nodes.params import ParamSpec, declare, merged
from railgsa_ros.nodes.qos import (
    MIN_SENSOR_DEPTH,
    OUTPUT_DEPTH,
    SENSOR_DEPTH,
    output_qos,
    sensor_qos,
)
from railgsa_ros.vehicle import PARAM_NAMES, PARAM_UNITS, VehicleParams, load_vehicle

NODE_NAME = 'irregularity_node'
OUTPUT_FRAME = 'track'
MAX_BATCH = 2000  # messages taken from the reader history per callback
_AXIS_INDEX = {'x': 0, 'y': 1, 'z': 2}

_VEHICLE_BOUNDS = {'m_s': (100.0, 1e5), 'm_us': (10.0, 1e4), 'k_s': (1e4, 1e8),
                   'k_us': (1e6, 1e10), 'c': (1e2, 1e7)}
_VEHICLE_DOCS = {'m_s': 'sprung (car-body) mass', 'm_us': 'unsprung (wheelset) mass',
                 'k_s': 'suspension stiffness', 'k_us': 'wheel-rail contact stiffness',
                 'c': 'suspension damping'}


def _inversion_specs() -> tuple[ParamSpec, ...]:
    """One spec per InversionConfig field: default, description, bounds and choices from it."""
    return tuple(ParamSpec(f.name, f.default, f.metadata['doc'], f.metadata['bounds'],
                           f.metadata['choices']) for f in fields(InversionConfig))


def _vehicle_specs() -> tuple[ParamSpec, ...]:
    """m_s, m_us, k_s, k_us, c with the paper's Table 1 defaults (VehicleParams)."""
    table1 = VehicleParams()
    return tuple(ParamSpec(n, getattr(table1, n), f'{_VEHICLE_DOCS[n]}, {PARAM_UNITS[n]}',
                           _VEHICLE_BOUNDS[n]) for n in PARAM_NAMES)


NODE_SPECS = (
    ParamSpec('vehicle_file', '', 'YAML file with a "vehicle:" section; when set, its values '
              'replace m_s, m_us, k_s, k_us, c at start-up', read_only=True),
    ParamSpec('use_odom', True, 'take the speed from odom (twist.twist.linear.x); speed_mps is '
              'the fallback while no odometry arrives', read_only=True),
    ParamSpec('odom_timeout_s', 1.0, 'odometry older than this (IMU stamp minus odom stamp) is '
              'missing, s', (0.01, 3600.0)),
    ParamSpec('wrong_frame_policy', 'reject', 'what to do with IMU samples whose frame_id is '
              'not frame_id (counted and warned once either way)', choices=('reject', 'accept')),
    ParamSpec('imu_qos_depth', SENSOR_DEPTH, 'imu/data reader history (BEST_EFFORT), samples',
              (MIN_SENSOR_DEPTH, 100_000), read_only=True),
    ParamSpec('output_qos_depth', OUTPUT_DEPTH, 'track/irregularity writer history (RELIABLE), '
              'samples', (1, 100_000), read_only=True),
    ParamSpec('hardware_id', 'imu', 'hardware_id on /diagnostics', read_only=True),
)
INVERSION_SPECS = _inversion_specs()
VEHICLE_SPECS = _vehicle_specs()
SPECS = INVERSION_SPECS + VEHICLE_SPECS + NODE_SPECS
MODEL_PARAMS = frozenset(s.name for s in INVERSION_SPECS + VEHICLE_SPECS)


def build_model(values: Mapping[str, Any], noise_variance: float | None = None
                ) -> InversionPipeline:
    """The pipeline for parameter ``values``; ConfigError (with the reason) if invalid."""
    config = InversionConfig.from_mapping({s.name: values[s.name] for s in INVERSION_SPECS})
    vehicle = VehicleParams(**{n: values[n] for n in PARAM_NAMES})
    return InversionPipeline(config, vehicle, noise_variance)


class IrregularityNode(Node):
    """The node; ConfigError from the constructor when the parameters are invalid."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._values = self._declare_parameters()
        self._noise_variance: float | None = None
        self._pipeline = build_model(self._values)
        self._candidate: InversionPipeline | None = None
        self._next_model: InversionPipeline | None = None
        self._retired: Counter[str] = Counter()  # counters of replaced pipelines
        self._counts: Counter[str] = Counter()   # node-level counts (malformed, rebuild, ...)
        self._odom: tuple[int, float] | None = None  # newest (stamp ns, speed m/s)
        self._odom_missing = False
        self._speed = float(self._values['speed_mps'])
        self._latency = LatencyWindow()
        self._deltas = {task: Deltas() for task in ('imu', 'inversion')}
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._create_interfaces()

    # ------------------------------------------------------------------ configuration
    def _declare_parameters(self) -> dict[str, Any]:
        """Declare every parameter and apply vehicle_file; ConfigError if invalid."""
        values = declare(self, SPECS)
        if values['vehicle_file']:
            vehicle = load_vehicle(values['vehicle_file']).as_dict()
            results = self.set_parameters([Parameter(n, value=vehicle[n]) for n in PARAM_NAMES])
            for name, result in zip(PARAM_NAMES, results, strict=True):
                if not result.successful:
                    raise ConfigError(f'{values["vehicle_file"]}: vehicle.{name}: {result.reason}')
            values.update(vehicle)
        return values

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Reject invalid values or combinations with the reason; build the new model early."""
        values, reason = merged(self._values, SPECS, params)
        self._candidate = None
        if reason is None and any(p.name in MODEL_PARAMS for p in params):
            try:
                self._candidate = build_model(values, self._noise_variance)
            except ConfigError as exc:
                reason = str(exc)
        return SetParametersResult(successful=reason is None, reason=reason or '')

    def _apply_parameters(self, params: list[Parameter]) -> None:
        """Accepted: store the values; a new model takes over at the next sample."""
        self._values, _ = merged(self._values, SPECS, params)
        if self._candidate is not None:
            self._next_model, self._candidate = self._candidate, None

    def _create_interfaces(self) -> None:
        """Subscriptions, publishers and the diagnostics reporter."""
        self._imu_sub = self.create_subscription(Imu, 'imu/data', self._on_imu,
                                                 sensor_qos(self._values['imu_qos_depth']))
        if self._values['use_odom']:
            self.create_subscription(Odometry, 'odom', self._on_odom, sensor_qos(50))
        self._pub = self.create_publisher(PointStamped, 'track/irregularity',
                                          output_qos(self._values['output_qos_depth']))
        self._out_msg = PointStamped()
        self._out_msg.header.frame_id = OUTPUT_FRAME
        self._diagnostics = DiagnosticsPublisher(self, self._values['hardware_id'])
        self._diagnostics.add('imu input', self._report_input)
        self._diagnostics.add('inversion', self._report_inversion)

    # ------------------------------------------------------------------ data path
    def _on_odom(self, msg: Odometry) -> None:
        """Keep the newest odometry speed."""
        sample = odom_speed(msg)
        if sample is None:
            self._counts['odom_malformed'] += 1
        elif self._odom is None or sample[0] >= self._odom[0]:
            self._odom = sample

    def _on_imu(self, msg: Imu) -> None:
        """This message and those waiting behind it, as one batch."""
        t_rx = time.monotonic()
        msgs = [msg]
        handle = self._imu_sub.handle
        with handle:
            while len(msgs) < MAX_BATCH:
                taken = handle.take_message(Imu, False)
                if taken is None:
                    break
                msgs.append(taken[0])
        self.process(msgs)
        self._latency.add(time.monotonic() - t_rx)

    def process(self, msgs: Sequence[Imu]) -> Output:
        """Convert, push through the pipeline, publish; returns what was published."""
        self._counts['received'] += len(msgs)
        batch = imu_batch(msgs)
        self._counts['malformed'] += int(batch.malformed.sum())
        good = ~batch.malformed
        if not good.any():
            return self._publish(self._switch_model())
        stamps, frames = batch.stamps_ns[good], batch.frame_ids[good]
        flushed = self._switch_model(batch)
        config = self._pipeline.config
        reject = self._values['wrong_frame_policy'] == 'reject'
        wrong = frame_mask(frames, config.frame_id)
        if wrong is not None and not wrong.all():
            self.get_logger().warning(f'IMU frame_id {frames[~wrong][0]!r} is not '
                                      f'{config.frame_id!r}: samples are '
                                      f'{"rejected" if reject else "accepted"}', once=True)
            if not reject:
                self._counts['wrong_frame_accepted'] += int((~wrong).sum())
        try:
            out = self._pipeline.push(stamps, vertical(batch.accel[good], config.accel_axis),
                                      self._speed_for(int(stamps[-1])),
                                      frames if reject else None)
        except Exception as exc:  # the node must survive anything the core trips on
            self._counts['internal_error'] += 1
            self.get_logger().error(f'inversion failed, filters reset: {exc!r}',
                                    throttle_duration_sec=1.0)
            self._retire(self._pipeline)
            self._pipeline = build_model(self._values, self._noise_variance)
            out = None
        return self._publish(self._join(flushed, out))

    def _speed_for(self, stamp_ns: int) -> float:
        """Newest odometry speed if fresh (m/s), else the speed_mps parameter."""
        odom = self._odom
        timeout_ns = self._values['odom_timeout_s'] * NS_PER_S
        fresh = odom is not None and stamp_ns - odom[0] <= timeout_ns
        self._odom_missing = self._values['use_odom'] and not fresh
        self._speed = odom[1] if fresh else float(self._values['speed_mps'])
        return self._speed

    def _switch_model(self, batch: ImuBatch | None = None) -> Output | None:
        """Apply a pending parameter change (flushing the old filters) or, for the Kalman
        method, the IMU-reported noise variance before the first sample; returns the flush."""
        if batch is not None and self._noise_variance is None and \
                self._pipeline.config.method == 'kalman':
            axis = _AXIS_INDEX[self._pipeline.config.accel_axis[-1]]
            reported = batch.accel_var[~batch.malformed, axis]
            reported = reported[np.isfinite(reported)]
            if reported.size:
                self._noise_variance = float(reported[0])
                if self._pipeline.counters.get('accepted', 0) == 0:
                    self._pipeline = build_model(self._values, self._noise_variance)
        if self._next_model is None:
            return None
        flushed = self._pipeline.flush()
        self._retire(self._pipeline)
        self._pipeline, self._next_model = self._next_model, None
        self._counts['rebuild'] += 1
        return flushed

    def _retire(self, pipeline: InversionPipeline) -> None:
        self._retired.update(pipeline.counters)

    @staticmethod
    def _join(*outs: Output | None) -> Output | None:
        outs = tuple(o for o in outs if o is not None and len(o))
        if len(outs) < 2:
            return outs[0] if outs else None
        return Output(*(np.concatenate(parts) for parts in zip(
            *((o.stamps_ns, o.chainage_m, o.u_m) for o in outs), strict=True)))

    def _publish(self, out: Output | None) -> Output | None:
        """One PointStamped per output sample, stamped with its IMU stamp."""
        if out is None or not len(out):
            return out
        sec, nsec = np.divmod(out.stamps_ns, NS_PER_S)
        msg, stamp, point = self._out_msg, self._out_msg.header.stamp, self._out_msg.point
        for s, ns, x, z in zip(sec.tolist(), nsec.tolist(), out.chainage_m.tolist(),
                               out.u_m.tolist(), strict=True):
            stamp.sec, stamp.nanosec, point.x, point.z = s, ns, x, z
            self._pub.publish(msg)
        self._counts['published'] += len(out)
        return out

    # ------------------------------------------------------------------ diagnostics
    def counters(self) -> dict[str, int]:
        """Cumulative counts by reason over the node's life (all pipelines)."""
        return dict(self._retired + Counter(self._pipeline.counters) + self._counts)

    def _report_input(self, elapsed_s: float) -> Report:
        totals = self.counters()
        reasons = (*REASONS, 'malformed')
        values: dict[str, object] = {'topic': self._imu_sub.topic_name}
        delta = self._deltas['imu'](totals)
        values['rate_hz'] = delta.get('received', 0) / elapsed_s
        for key in ('received', 'accepted', 'gap', 'reset', 'bridged', 'wrong_frame_accepted'):
            values[key] = totals.get(key, 0)
        values['rejected'] = sum(totals.get(r, 0) for r in reasons)
        values.update({f'rejected_{r}': totals.get(r, 0) for r in reasons})
        recent = {r: delta.get(r, 0) for r in (*reasons, 'gap', 'wrong_frame_accepted')
                  if delta.get(r, 0)}
        values['last_period'] = ', '.join(f'{k} {v}' for k, v in recent.items()) or 'clean'
        values['expected_frame_id'] = self._pipeline.config.frame_id
        if delta.get('received', 0) == 0:
            return Report(ERROR, 'no IMU input', values)
        if recent:
            return Report(WARN, 'bad input in the last period: ' + values['last_period'], values)
        return Report(OK, 'receiving', values)

    def _report_inversion(self, elapsed_s: float) -> Report:
        pipe, totals = self._pipeline, self.counters()
        delta = self._deltas['inversion'](totals)
        cfg = pipe.config
        values: dict[str, object] = {
            'method': cfg.method, 'band': cfg.band,
            'band_delay_samples': pipe.delay_samples,
            'band_delay_s': pipe.delay_samples / cfg.rate_hz,
            'stability_margin_per_s': pipe.stability_margin,
            'published': totals.get('published', 0),
            'output_rate_hz': delta.get('published', 0) / elapsed_s,
            'rebuilds': totals.get('rebuild', 0), 'redesigns': totals.get('redesign', 0),
            'internal_errors': totals.get('internal_error', 0),
            'speed_mps': self._speed,
            'speed_source': 'odom' if self._values['use_odom'] and not self._odom_missing
            else 'parameter',
            'odom_malformed': totals.get('odom_malformed', 0),
        }
        values.update(self._latency.take())
        if delta.get('internal_error', 0):
            return Report(ERROR, 'inversion failed and was reset', values)
        if delta.get('received', 0) == 0:
            return Report(STALE, 'no input: nothing to invert', values)
        if self._odom_missing:
            return Report(WARN, f'no odometry: using speed_mps = {self._speed:g} m/s', values)
        return Report(OK, f'{cfg.method}, band {cfg.band}', values)


def main(args: list[str] | None = None) -> int:
    """Run the node until SIGINT/SIGTERM; exit code 0, or 2 with one line for bad parameters."""
    rclpy.init(args=args)
    node = None
    try:
        node = IrregularityNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except ConfigError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
