"""irregularity_node: live vertical track irregularity from car-body acceleration.

Subscribes ``imu/data`` (sensor_msgs/Imu) and optionally ``odom`` (nav_msgs/Odometry, speed =
twist.twist.linear.x); publishes ``track/irregularity`` (geometry_msgs/PointStamped, stamp = the
IMU sample's stamp, frame ``track``, x = chainage m, z = irregularity m, +z up) and
``/diagnostics``. A thin adapter over :class:`railgsa_ros.inverse.policy.InputPolicy` (every
input decision: axis, frame policy, speed with its timeout, noise, quality; the same object as
``railgsa invert``): ``point.y`` = the sample's quality code (0 VALID, 1 DEGRADED, 2 INVALID),
``point.z`` = NaN when INVALID. See docs/nodes.md for topics, parameters, QoS and diagnostics.

Nothing is held back: ``idle_flush_s`` without input, deactivate and shutdown flush the samples
pending in the band filter; every output goes through an
:class:`~railgsa_ros.nodes.pacing.OutputPacer` (no burst beyond the writer history).

Processing: the IMU callback gets the message it was called for plus every message already
waiting in the reader history (:class:`~railgsa_ros.nodes.imu_input.ImuIntake`) and gives them
to the policy at once. At light load each sample is processed as it arrives (lowest
latency); under load the batches grow and the cost per sample falls. benchmarks/
bench_node_latency.py measured this against per-message processing (falls behind) and a 100 Hz
timer (+5-10 ms latency).

A managed lifecycle node (:mod:`railgsa_ros.nodes.lifecycle`): configure declares and checks the
parameters and builds the policy, activate subscribes, deactivate flushes and unsubscribes,
cleanup drops the policy; ``autostart`` (default true) goes to active at start-up.
"""

from __future__ import annotations

import railgsa_ros.nodes.early_signals  # noqa: F401  (first: exit 0 on a signal from here on)

# isort: split

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import fields
import sys
import time
from typing import Any

from geometry_msgs.msg import PointStamped
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.inverse.policy import InputPolicy, PolicyOptions
from railgsa_ros.nodes.diagnostics import (
    ERROR,
    OK,
    STALE,
    Deltas,
    DiagnosticsPublisher,
    HardwareId,
    LatencyWindow,
    Report,
    checks_report,
    quality_values,
)
from railgsa_ros.nodes.imu_input import ImuIntake
from railgsa_ros.nodes.lifecycle import ManagedNode, run
from railgsa_ros.nodes.pacing import OutputPacer
from railgsa_ros.nodes.params import accept_integers, declare, merged
from railgsa_ros.nodes.qos import output_qos
from railgsa_ros.nodes.specs import (
    INVERSION_SPECS,
    NODE_SPECS,
    VEHICLE_SPECS,
    inversion_config,
    vehicle_values,
)
from railgsa_ros.vehicle import PARAM_NAMES, VehicleParams

NODE_NAME = 'irregularity_node'
OUTPUT_FRAME = 'track'
SPECS = INVERSION_SPECS + VEHICLE_SPECS + NODE_SPECS
#: parameters whose change rebuilds the policy (old filters flushed, chainage continued)
MODEL_PARAMS = frozenset((*(s.name for s in INVERSION_SPECS + VEHICLE_SPECS),
                          *(f.name for f in fields(PolicyOptions))))
Model = tuple[InversionConfig, VehicleParams, PolicyOptions]


def model_inputs(values: Mapping[str, Any]) -> Model:
    """Inversion config, vehicle and input options of parameter ``values`` (ConfigError with
    the reason if invalid)."""
    return (inversion_config(values), VehicleParams(**{n: values[n] for n in PARAM_NAMES}),
            PolicyOptions.from_mapping(values))


def build_model(values: Mapping[str, Any], noise_variance: float | None = None) -> InputPolicy:
    """The input policy for parameter ``values``; ConfigError (with the reason) if invalid.

    ``noise_variance``: a fixed accelerometer variance (m/s^2)^2 (the filters are built at
    once, which checks e.g. the feedback stability); None: the policy's rule from the data.
    """
    config, vehicle, options = model_inputs(values)
    return InputPolicy(config, vehicle, options=options, noise_variance=noise_variance)


class IrregularityNode(ManagedNode):
    """The managed node; with autostart (default), ConfigError from the constructor when the
    parameters are invalid."""

    NODE_NAME, SPECS = NODE_NAME, SPECS

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._values: dict[str, Any] | None = None
        self.policy: InputPolicy | None = None
        self._candidate: Model | None = None
        self._next_model: Model | None = None
        self._retired: Counter[str] = Counter()  # counters of replaced policies
        self._counts: Counter[str] = Counter()   # internal_error, published, flush_*
        self._latency = LatencyWindow()
        self._deltas = {task: Deltas() for task in ('imu', 'inversion')}
        self._first_stamp_ns = -1  # first IMU stamp processed since the process started
        self._speed_mps = float('nan')  # speed of the newest output, m/s
        self._intake: ImuIntake | None = None
        self._diagnostics: DiagnosticsPublisher | None = None
        self._hardware = HardwareId('')
        self._pub: Any = None
        self._pacer: OutputPacer | None = None
        self._idle_timer: Any = None
        self._last_input = time.monotonic()  # steady time of the last IMU batch, s
        self._unflushed = False  # samples given to the policy since the last flush
        self.add_pre_set_parameters_callback(accept_integers(SPECS))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.autostart()

    # ------------------------------------------------------------------ lifecycle
    def configure(self) -> None:
        """Read and validate the parameters, build the policy and the publisher."""
        values = self._declare_parameters()
        build_model(values, values['noise_std_mps2'] ** 2)  # every check of the core, now
        self.policy = build_model(values)
        self._values = values
        self._hardware.parameter = values['hardware_id']
        self._pub = self.create_lifecycle_publisher(PointStamped, 'track/irregularity',
                                                    output_qos(values['output_qos_depth']))
        msg = PointStamped()
        msg.header.frame_id = OUTPUT_FRAME
        self._pacer = OutputPacer(self, self._pub, msg, 'point', values['output_qos_depth'],
                                  values['flush_rate_hz'])

    def activate(self) -> None:
        """Subscriptions, the idle check and the diagnostics reporter."""
        assert self._values is not None
        self._intake = ImuIntake(self, self._values, self._on_messages, self._on_odometry)
        self._diagnostics = DiagnosticsPublisher(self, self._hardware)
        self._diagnostics.add('imu input', self._report_input)
        self._diagnostics.add('inversion', self._report_inversion)
        self._diagnostics.add('input checks', lambda _: checks_report(self.policy))
        idle = self._values['idle_flush_s']
        self._idle_timer = self.create_timer(min(0.1, idle / 2), self._on_idle_check,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME))

    def deactivate(self) -> None:
        """Process the input waiting in the reader (one history at most), flush the filters,
        publish and await the acknowledgement of every output; then stop taking input and
        reporting."""
        if self._intake is not None:
            if msgs := self._intake.take_waiting():
                self.process(msgs)
            self._flush('flush_deactivate')
            self._pacer.finish()
            self._counts.update(self._intake.counts)
            self._intake.destroy()
            self._intake = None
        if self._diagnostics is not None:
            self._diagnostics.destroy()
            self._diagnostics = None
        if self._idle_timer is not None:
            self.destroy_timer(self._idle_timer)
            self._idle_timer = None

    def release(self) -> None:
        """Drop the policy (its counters are kept) and the publisher."""
        if self.policy is not None:
            self._retired.update(self.policy.counters)
            self.policy = None
        if self._pacer is not None:
            self._counts['published'] += self._pacer.published
            self._pacer.destroy()
            self._pacer = None
        if self._pub is not None:
            self.destroy_lifecycle_publisher(self._pub)
            self._pub = None
        self._values = self._candidate = self._next_model = None

    # ------------------------------------------------------------------ configuration
    def _declare_parameters(self) -> dict[str, Any]:
        """Declare every parameter; vehicle_file overrides m_s..c. ConfigError if invalid."""
        values = declare(self, SPECS)
        if values['vehicle_file']:
            vehicle = vehicle_values(values)
            results = self.set_parameters([Parameter(n, value=vehicle[n]) for n in PARAM_NAMES])
            for name, result in zip(PARAM_NAMES, results, strict=True):
                if not result.successful:
                    raise ConfigError(f'{values["vehicle_file"]}: vehicle.{name}: {result.reason}')
            values.update(vehicle)
        return values

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Reject invalid values or combinations with the core's reason (the filters are built
        once to check them). Unconfigured: only the specs' own checks (configure validates
        the whole set)."""
        if self._values is None:
            reason = next((r for r in (s.check(p.value) for p in params for s in SPECS
                                       if s.name == p.name) if r), None)
            return SetParametersResult(successful=reason is None, reason=reason or '')
        values, reason = merged(self._values, SPECS, params)
        self._candidate = None
        if any(p.name in MODEL_PARAMS for p in params):
            variance = self.policy.noise_variance or values['noise_std_mps2'] ** 2
            try:  # the core's reasons are the more telling ones
                build_model(values, variance)
                candidate = model_inputs(values)
            except ConfigError as exc:
                reason = str(exc)
            else:
                self._candidate = candidate if reason is None else None
        return SetParametersResult(successful=reason is None, reason=reason or '')

    def _apply_parameters(self, params: list[Parameter]) -> None:
        """Accepted: store the values; the policy is rebuilt at the next sample."""
        if self._values is None:
            return
        self._values, _ = merged(self._values, SPECS, params)
        if self._candidate is not None:
            self._next_model, self._candidate = self._candidate, None

    # ------------------------------------------------------------------ data path
    def _on_messages(self, msgs: list[Imu]) -> None:
        t_rx = time.monotonic()
        self.process(msgs)
        self._latency.add(time.monotonic() - t_rx)

    def _on_odometry(self, stamp_ns: int, speed_mps: float) -> None:
        """An odometry sample: IMU samples waiting for their speed may become final."""
        if self.policy is not None:
            held = self.policy.held
            out = self._guarded(lambda: self.policy.odometry([stamp_ns], [speed_mps]))
            self._publish(out, live=self._released(held))

    def _on_idle_check(self) -> None:
        """No IMU message for idle_flush_s: the stream ended, flush what the filters hold
        (first whatever waits in the reader: a stall of this process is no end)."""
        if not self._unflushed or \
                time.monotonic() - self._last_input < self._values['idle_flush_s']:
            return
        msgs = self._intake.take()
        if msgs:
            self._on_messages(msgs)
        else:
            self._flush('flush_idle')

    def _flush(self, reason: str) -> Output | None:
        """Flush the policy (a stream ended): publish its pending outputs, count ``reason``."""
        if self.policy is None or not self._unflushed:
            return None
        self._unflushed = False
        self._counts[reason] += 1
        return self._publish(self._guarded(self.policy.flush))

    def process(self, msgs: Sequence[Imu]) -> Output | None:
        """Convert, give to the policy, publish; returns what was published (None when not
        active)."""
        if self._intake is None or self.policy is None or self._values is None:
            return None
        self._last_input = time.monotonic()
        batch = self._intake.convert(msgs)
        outs = [self._switch_model()]
        held = self.policy.held
        if batch is not None:
            if self._first_stamp_ns < 0:
                self._first_stamp_ns = int(batch.stamps_ns[0])
            self._hardware.see(batch.frame_ids)
            self._unflushed = True
            held += len(batch)
            outs.append(self._guarded(lambda: self.policy.imu(
                batch.stamps_ns, batch.accel, batch.frame_ids, batch.covariance)))
        return self._publish(self._join(outs), live=self._released(held))

    def _released(self, held: int) -> int:
        """Input samples that went into the filters since the policy held ``held``: each adds
        one output at the input's pace; the rest of the outputs (a flush, a reset) are paced
        (OutputPacer.put). Outputs released by odometry are not all live ones."""
        return max(0, held - self.policy.held)

    def _guarded(self, step: Any) -> Output | None:
        """``step()`` of the core through ``guarded``: on an exception the policy is rebuilt."""
        return self.guarded(step, 'inversion', self._rebuild_policy)

    def _rebuild_policy(self) -> None:
        """A fresh policy for the current values; the old one's counters are kept."""
        self._retired.update(self.policy.counters)
        self.policy = build_model(self._values)

    def _switch_model(self) -> Output | None:
        """Apply a pending parameter change: flush the old filters, start the new ones."""
        if self._next_model is None:
            return None
        config, vehicle, options = self._next_model
        self._next_model = None
        return self._guarded(lambda: self.policy.rebuild(config, vehicle, options=options))

    def _join(self, outs: list[Output | None]) -> Output | None:
        outs = [o for o in outs if o is not None and len(o)]
        return Output.concat(outs) if outs else None

    def _publish(self, out: Output | None, live: int = 0) -> Output | None:
        """One PointStamped per output sample, stamped with its IMU stamp (x chainage, y
        quality code, z u or NaN), through the pacer (``live``: see OutputPacer.put)."""
        if out is None or not len(out):
            return out
        self._speed_mps = float(out.speed_mps[-1])
        xyz = np.column_stack([out.chainage_m, out.quality, out.u_m])
        self._pacer.put(out.stamps_ns, xyz, live)
        return out

    # ------------------------------------------------------------------ diagnostics
    def describe(self) -> str:
        """The start-up line: method, band, speed source and topics."""
        values = self._values
        speed = 'odom' if values['use_odom'] else f'speed_mps {values["speed_mps"]!r} m/s'
        inputs = ['imu/data', 'odom'] if values['use_odom'] else ['imu/data']
        return (f'{values["method"]}, band {values["band"]}, speed from {speed}: '
                f'{self.topic_line(inputs, ["track/irregularity", "/diagnostics"])}')

    def counters(self) -> dict[str, int]:
        """Cumulative counts by reason over the node's life (all policies)."""
        live = [] if self.policy is None else [Counter(self.policy.counters)]
        intake = [] if self._intake is None else [self._intake.counts]
        paced = Counter() if self._pacer is None else Counter(published=self._pacer.published)
        return dict(sum((*live, *intake, self._counts, paced), self._retired.copy()))

    def _report_input(self, elapsed_s: float) -> Report:
        totals = self.counters()
        return self._intake.report(totals, self._deltas['imu'](totals), elapsed_s,
                                   self.policy.config.frame_id)

    def _report_inversion(self, elapsed_s: float) -> Report:
        policy, totals = self.policy, self.counters()
        delta = self._deltas['inversion'](totals)
        cfg, pipe = policy.config, policy.pipeline
        values: dict[str, object] = {
            'method': cfg.method, 'band': cfg.band,
            'band_delay_samples': policy.delay_samples,
            'band_delay_s': policy.delay_samples / cfg.rate_hz,
            'stability_margin_per_s': pipe.stability_margin if pipe is not None
            else float('nan'),
            'published': totals.get('published', 0),
            'output_rate_hz': delta.get('published', 0) / elapsed_s,
            **quality_values(totals, delta),
            'rebuilds': totals.get('rebuild', 0), 'redesigns': totals.get('redesign', 0),
            'idle_flushes': totals.get('flush_idle', 0),
            'output_queue': self._pacer.pending, 'output_queue_max': self._pacer.max_pending,
            'held_for_speed': policy.held,
            'internal_errors': totals.get('internal_error', 0),
            'speed_mps': self._speed_mps,
            'speed_source': 'odom' if policy.options.use_odom else 'parameter',
            'noise_std_mps2': np.sqrt(policy.noise_variance) if policy.noise_variance
            is not None else float('nan'),
            'noise_source': policy.noise_source,
            'first_stamp_ns': self._first_stamp_ns, **self.lifecycle_values(),
        }
        values.update(self._latency.take())
        if delta.get('internal_error', 0):
            return Report(ERROR, 'inversion failed and was reset', values)
        if delta.get('received', 0) == 0:
            return Report(STALE, 'no input: nothing to invert', values)
        return Report(OK, f'{cfg.method}, band {cfg.band}', values)


def main(args: list[str] | None = None) -> int:
    """Run the node until SIGINT/SIGTERM; exit code 0, or 2 with one line for bad parameters."""
    return run(IrregularityNode, args)


if __name__ == '__main__':
    sys.exit(main())
