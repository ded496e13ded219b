"""uncertainty_node: live uncertainty band and window sensitivities next to irregularity_node.

Subscribes ``imu/data`` (sensor_msgs/Imu) and optionally ``odom`` exactly as
``irregularity_node`` does, with the same inversion, vehicle and input parameters, and runs the
inverse for the rule's parameter points as one vectorised bank
(:class:`railgsa_ros.uncertainty.UncertaintyStream`). Publishes:

- ``track/irregularity_band`` (geometry_msgs/Vector3Stamped) per IMU sample: header.stamp = the
  IMU stamp (that of the matching ``track/irregularity`` message), frame ``track``,
  x = lower quantile, y = PCE mean, z = upper quantile of the irregularity, m (+z up);
- ``track/sensitivity`` (diagnostic_msgs/DiagnosticArray) per window and quantity of interest:
  one status per uncertain parameter (sobol_first, sobol_total, delta) and a ``summary`` status;
- ``/diagnostics``: input counts by reason, compute time per window, fraction of one core used.

Input polling: the imu/data subscription belongs to a helper node ``uncertainty_node_imu_reader``
that no executor spins, so the 1 kHz stream never wakes the executor; a steady-clock timer takes
every waiting message from the reader history (depth ``imu_qos_depth``) every
``process_period_s`` and processes them as one batch (measured: the per-message executor
dispatch is most of a Python node's cost at 1 kHz). All parameters are read-only: restart the
node to change them. See docs/uncertainty_node.md.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import fields, replace
import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
import numpy as np
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Imu

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import vertical
from railgsa_ros.inverse.sanitize import REASONS
from railgsa_ros.nodes.diagnostics import (
    ERROR,
    OK,
    STALE,
    WARN,
    Deltas,
    DiagnosticsPublisher,
    Report,
    make_status,
)
from railgsa_ros.nodes.imu_conversion import NS_PER_S, imu_batch, odom_speed
from railgsa_ros.nodes.irregularity_node import INVERSION_SPECS, NODE_SPECS, VEHICLE_SPECS
from railgsa_ros.nodes.params import ParamSpec, declare
from railgsa_ros.nodes.qos import output_qos, sensor_qos
from railgsa_ros.uncertainty import Band, Sensitivity, UncertaintyConfig, UncertaintyStream
from railgsa_ros.uq.uncertainty_file import load_uncertainty, table3
from railgsa_ros.vehicle import PARAM_NAMES, VehicleParams, load_vehicle

NODE_NAME = 'uncertainty_node'
OUTPUT_FRAME = 'track'
MAX_BATCH = 5000  # messages taken from the reader history per timer tick

_OWN_SPECS = tuple(ParamSpec(f.name, f.default, f.metadata['doc'], f.metadata['bounds'],
                             f.metadata['choices']) for f in fields(UncertaintyConfig)
                   if f.name != 'inversion')
_EXTRA_SPECS = (
    ParamSpec('uncertainty_file', '', 'YAML of uncertain parameters (schema of '
              'config/uncertainty.yaml); empty: Table 3 around the nominal vehicle'),
    ParamSpec('process_period_s', 0.05, 'buffered IMU samples are processed every this, s',
              (0.001, 1.0)),
    ParamSpec('sensitivity_qos_depth', 10, 'track/sensitivity writer history (RELIABLE)',
              (1, 10_000)),
)
#: irregularity_node's inversion, vehicle and input parameters (same names and defaults), then
#: the uncertainty parameters; all read-only.
SPECS = tuple(replace(s, read_only=True) for s in
              (*INVERSION_SPECS, *VEHICLE_SPECS, *NODE_SPECS, *_OWN_SPECS, *_EXTRA_SPECS))


def _never_called(_msg: Imu) -> None:
    """Callback of the polled subscription (its node is never spun)."""


def sensitivity_message(record: Sensitivity, hardware_id: str) -> DiagnosticArray:
    """track/sensitivity for one window and QoI: a status per parameter and a summary."""
    statuses = [make_status(name, hardware_id, Report(OK, record.qoi, {
        'sobol_first': record.sobol_first[i], 'sobol_total': record.sobol_total[i],
        'delta': record.delta[i]})) for i, name in enumerate(record.names)]
    statuses.append(make_status('summary', hardware_id, Report(
        OK, f'{record.qoi} over {record.samples} samples', {
            'qoi': record.qoi, 'qoi_mean_m': record.mean_m, 'qoi_std_m': record.std_m,
            'first_stamp_ns': record.first_stamp_ns, 'last_stamp_ns': record.last_stamp_ns,
            'chainage_start_m': record.chainage_start_m,
            'chainage_end_m': record.chainage_end_m, 'samples': record.samples,
            'peak_stamp_ns': record.peak_stamp_ns, 'model_evaluations': record.evaluations,
            'rule': record.rule, 'order': record.order,
            'compute_ms': record.compute_s * 1e3})))
    msg = DiagnosticArray(status=statuses)
    msg.header.frame_id = OUTPUT_FRAME
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(record.last_stamp_ns, NS_PER_S)
    return msg


class UncertaintyNode(Node):
    """The node; ConfigError from the constructor when the parameters are invalid."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = self._values = declare(self, SPECS)
        inversion = {s.name: values[s.name] for s in INVERSION_SPECS}
        self.config = UncertaintyConfig.from_mapping(
            {**inversion, **{s.name: values[s.name] for s in _OWN_SPECS}})
        self.vehicle = load_vehicle(values['vehicle_file']) if values['vehicle_file'] else \
            VehicleParams(**{n: values[n] for n in PARAM_NAMES})
        self.dists = load_uncertainty(values['uncertainty_file']) if \
            values['uncertainty_file'] else table3(self.vehicle)
        self._noise_variance: float | None = None
        self.stream = UncertaintyStream(self.config, self.vehicle, self.dists)
        self._retired: Counter[str] = Counter()
        self._counts: Counter[str] = Counter()
        self._odom: tuple[int, float] | None = None
        self._speed = float(values['speed_mps'])
        self._window_ms = (float('nan'), 0.0)  # last, max compute time per window
        self._cpu = (time.monotonic(), time.process_time())
        self._deltas = {task: Deltas() for task in ('imu', 'uncertainty')}
        self._create_interfaces()
        design = self.stream.design
        self.get_logger().info(
            f'{design.points} rule points ({self.config.rule}, order {self.config.order}, '
            f'{design.fit}) over {", ".join(design.names)}; band delay '
            f'{self.stream.delay_samples} samples')

    def _create_interfaces(self) -> None:
        values = self._values
        self._reader = Node(f'{NODE_NAME}_imu_reader', context=self.context,
                            namespace=self.get_namespace())
        self._imu_sub = self._reader.create_subscription(Imu, 'imu/data', _never_called,
                                                         sensor_qos(values['imu_qos_depth']))
        if values['use_odom']:
            self.create_subscription(Odometry, 'odom', self._on_odom, sensor_qos(50))
        self._band_pub = self.create_publisher(Vector3Stamped, 'track/irregularity_band',
                                               output_qos(values['output_qos_depth']))
        self._gsa_pub = self.create_publisher(DiagnosticArray, 'track/sensitivity',
                                              output_qos(values['sensitivity_qos_depth']))
        self._band_msg = Vector3Stamped()
        self._band_msg.header.frame_id = OUTPUT_FRAME
        self.create_timer(values['process_period_s'], self._on_timer,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._diagnostics = DiagnosticsPublisher(self, values['hardware_id'])
        self._diagnostics.add('imu input', self._report_input)
        self._diagnostics.add('uncertainty', self._report_uncertainty)

    # ------------------------------------------------------------------ data path
    def _on_odom(self, msg: Odometry) -> None:
        """Keep the newest odometry speed."""
        sample = odom_speed(msg)
        if sample is None:
            self._counts['odom_malformed'] += 1
        elif self._odom is None or sample[0] >= self._odom[0]:
            self._odom = sample

    def _on_timer(self) -> None:
        """Take every message waiting in the reader history and process them."""
        msgs = []
        handle = self._imu_sub.handle
        with handle:
            while len(msgs) < MAX_BATCH:
                taken = handle.take_message(Imu, False)
                if taken is None:
                    break
                msgs.append(taken[0])
        if msgs:
            self.process(msgs)

    def process(self, msgs: Sequence[Imu]) -> Band | None:
        """Convert, push through the stream, publish band and windows; returns the band."""
        self._counts['received'] += len(msgs)
        batch = imu_batch(msgs)
        self._counts['malformed'] += int(batch.malformed.sum())
        good = ~batch.malformed
        if not good.any():
            return None
        cfg: InversionConfig = self.config.inversion
        self._use_reported_noise(batch.accel_var[good, 'xyz'.index(cfg.accel_axis[-1])])
        stamps, frames = batch.stamps_ns[good], batch.frame_ids[good]
        reject = self._values['wrong_frame_policy'] == 'reject'
        try:
            update = self.stream.push(stamps, vertical(batch.accel[good], cfg.accel_axis),
                                      self._speed_for(int(stamps[-1])),
                                      frames if reject else None)
        except Exception as exc:  # the node must survive anything the core trips on
            self._counts['internal_error'] += 1
            self.get_logger().error(f'uncertainty stream failed, filters reset: {exc!r}',
                                    throttle_duration_sec=1.0)
            self._rebuild()
            return None
        self._publish(update.band)
        for record in update.windows:
            self._gsa_pub.publish(sensitivity_message(record, self._values['hardware_id']))
            last = record.compute_s * 1e3
            self._window_ms = (last, max(self._window_ms[1], last))
        self._counts['windows'] += len(update.windows)
        return update.band

    def _use_reported_noise(self, reported: np.ndarray) -> None:
        """kalman: the first IMU-reported variance replaces noise_std_mps2 before any sample,
        as in irregularity_node."""
        reported = reported[np.isfinite(reported)]
        if self.config.inversion.method == 'kalman' and self._noise_variance is None and \
                reported.size and self.stream.counters.get('accepted', 0) == 0:
            self._noise_variance = float(reported[0])
            self._rebuild()

    def _rebuild(self) -> None:
        self._retired.update(self.stream.counters)
        self.stream = UncertaintyStream(self.config, self.vehicle, self.dists,
                                        self._noise_variance)

    def _speed_for(self, stamp_ns: int) -> float:
        """Newest odometry speed if fresh (m/s), else the speed_mps parameter."""
        odom = self._odom
        fresh = odom is not None and \
            stamp_ns - odom[0] <= self._values['odom_timeout_s'] * NS_PER_S
        self._speed = odom[1] if fresh else float(self._values['speed_mps'])
        return self._speed

    def _publish(self, band: Band) -> None:
        """One Vector3Stamped per band sample, stamped with its IMU stamp."""
        sec, nsec = np.divmod(band.stamps_ns, NS_PER_S)
        msg, stamp, vec = self._band_msg, self._band_msg.header.stamp, self._band_msg.vector
        for s, ns, lo, mid, hi in zip(sec.tolist(), nsec.tolist(), band.lower_m.tolist(),
                                      band.mean_m.tolist(), band.upper_m.tolist(), strict=True):
            stamp.sec, stamp.nanosec, vec.x, vec.y, vec.z = s, ns, lo, mid, hi
            self._band_pub.publish(msg)
        self._counts['published'] += len(band)

    def destroy_node(self) -> None:
        """Destroy the helper reader node too."""
        self._reader.destroy_node()
        super().destroy_node()

    # ------------------------------------------------------------------ diagnostics
    def counters(self) -> dict[str, int]:
        """Cumulative counts by reason over the node's life."""
        return dict(self._retired + Counter(self.stream.counters) + self._counts)

    def _report_input(self, elapsed_s: float) -> Report:
        totals = self.counters()
        delta = self._deltas['imu'](totals)
        reasons = (*REASONS, 'malformed')
        values: dict[str, object] = {'topic': self._imu_sub.topic_name,
                                     'rate_hz': delta.get('received', 0) / elapsed_s}
        for key in ('received', 'accepted', 'gap', 'reset', 'bridged', 'odom_malformed'):
            values[key] = totals.get(key, 0)
        values['rejected'] = sum(totals.get(r, 0) for r in reasons)
        values.update({f'rejected_{r}': totals.get(r, 0) for r in reasons})
        recent = {r: delta[r] for r in (*reasons, 'gap') if delta.get(r, 0)}
        if delta.get('received', 0) == 0:
            return Report(ERROR, 'no IMU input', values)
        if recent:
            return Report(WARN, 'bad input in the last period: '
                          + ', '.join(f'{k} {v}' for k, v in recent.items()), values)
        return Report(OK, 'receiving', values)

    def _report_uncertainty(self, elapsed_s: float) -> Report:
        now = (time.monotonic(), time.process_time())
        cpu = (now[1] - self._cpu[1]) / max(now[0] - self._cpu[0], 1e-9)
        self._cpu = now
        totals, design = self.counters(), self.stream.design
        delta = self._deltas['uncertainty'](totals)
        values: dict[str, object] = {
            'rule': self.config.rule, 'order': self.config.order, 'fit': design.fit,
            'parameters': ' '.join(design.names), 'rule_points': design.points,
            'band_delay_samples': self.stream.delay_samples,
            'published': totals.get('published', 0), 'windows': totals.get('windows', 0),
            'window_compute_ms': self._window_ms[0], 'window_compute_max_ms': self._window_ms[1],
            'cpu_fraction_of_one_core': cpu, 'speed_mps': self._speed,
            'internal_errors': totals.get('internal_error', 0)}
        if delta.get('internal_error', 0):
            return Report(ERROR, 'the stream failed and was reset', values)
        if delta.get('received', 0) == 0:
            return Report(STALE, 'no input: nothing to analyse', values)
        return Report(OK, f'{design.points} points, cpu {cpu:.1%} of one core', values)


def main(args: list[str] | None = None) -> int:
    """Run the node until SIGINT/SIGTERM; exit code 0, or 2 with one line for bad parameters."""
    rclpy.init(args=args)
    node = None
    try:
        node = UncertaintyNode()
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
