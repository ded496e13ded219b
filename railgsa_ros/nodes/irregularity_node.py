"""irregularity_node: live vertical track irregularity from car-body acceleration.

Subscribes ``imu/data`` (sensor_msgs/Imu) and optionally ``odom`` (nav_msgs/Odometry, speed =
twist.twist.linear.x); publishes ``track/irregularity`` (geometry_msgs/PointStamped, stamp = the
IMU sample's stamp, frame ``track``, x = chainage m, z = irregularity m, +z up) and
``/diagnostics``. A thin adapter over :class:`railgsa_ros.input.stage.InputStage` (every
input decision: axis, frame policy, speed with its timeout, noise, quality; the same object as
``railgsa invert``): ``point.y`` = the sample's quality code (0 VALID, 1 DEGRADED, 2 INVALID),
``point.z`` = NaN when INVALID. With ``publish_grid`` also ``track/irregularity_grid``: the
profile on chainage multiples of ``grid_step_m`` band-passed on distance
(:class:`railgsa_ros.inverse.grid.GridStream`, what ``railgsa invert --grid`` computes; x =
chainage, y = quality, z = u, stamp = the IMU sample nearest in chainage). See docs/nodes.md
for topics, parameters, QoS and diagnostics.

Nothing is held back: ``idle_flush_s`` without input, deactivate and shutdown flush the samples
pending in the band filter; every output goes through an
:class:`~railgsa_ros.nodes.pacing.OutputPacer` (no burst beyond the writer history).

Processing (:class:`~railgsa_ros.nodes.stream_node.StreamNode`): a reader thread takes every
serialized IMU message waiting in the reader history as it arrives, decodes them vectorised and
gives them to the policy at once; outputs are encoded per slice and published serialized. At
light load each sample is processed as it arrives (lowest latency); under load the batches grow
and the cost per sample falls. benchmarks/bench_node_latency.py measures it against a relay.

A managed lifecycle node (:mod:`railgsa_ros.nodes.lifecycle`): configure declares and checks the
parameters and builds the policy, activate subscribes, deactivate flushes and unsubscribes,
cleanup drops the policy; ``autostart`` (default true) goes to active at start-up.
"""

from __future__ import annotations

import railgsa_ros.nodes.early_signals  # noqa: F401  (first: exit 0 on a signal from here on)

# isort: split

from collections.abc import Mapping
from dataclasses import fields
import sys
import time
from typing import Any

from geometry_msgs.msg import PointStamped
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter

from railgsa_ros.bag.messages import POINT_STAMPED
from railgsa_ros.errors import ConfigError
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.grid import GridOutput, GridStream
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.models import vehicle_of
from railgsa_ros.models.coach import CoachModel
from railgsa_ros.nodes.diagnostics import ERROR, OK, STALE, LatencyWindow, Report, quality_values
from railgsa_ros.nodes.imu_conversion import ImuBatch
from railgsa_ros.nodes.lifecycle import run
from railgsa_ros.nodes.pacing import OutputPacer
from railgsa_ros.nodes.params import accept_integers, declare, merged
from railgsa_ros.nodes.qos import output_qos
from railgsa_ros.nodes.specs import (
    INVERSION_SPECS,
    IRREGULARITY_PERIOD,
    IRREGULARITY_SPECS,
    NODE_SPECS,
    VEHICLE_SPECS,
    inversion_config,
    vehicle_values,
)
from railgsa_ros.nodes.stream_node import OUTPUT_FRAME, StreamNode
from railgsa_ros.vehicle import PARAM_NAMES, VehicleParams

NODE_NAME = 'irregularity_node'
#: process_period_s, publish_grid, grid_step_m: specs.IRREGULARITY_SPECS
SPECS = (*INVERSION_SPECS, *VEHICLE_SPECS, *NODE_SPECS, *IRREGULARITY_SPECS)
#: parameters whose change rebuilds the policy (old filters flushed, chainage continued)
MODEL_PARAMS = frozenset((*(s.name for s in INVERSION_SPECS + VEHICLE_SPECS),
                          *(f.name for f in fields(InputOptions))))
Model = tuple[InversionConfig, VehicleParams | CoachModel, InputOptions]


def model_inputs(values: Mapping[str, Any]) -> Model:
    """Inversion config, vehicle and input options of parameter ``values`` (ConfigError with
    the reason if invalid); the vehicle is the coach of a coach ``vehicle_file`` (it takes
    angular_velocity.y from the Imu messages as its pitch rate), else m_s..c."""
    coach = coach_file(values)
    return (inversion_config(values),
            coach if coach is not None else VehicleParams(**{n: values[n] for n in PARAM_NAMES}),
            InputOptions.from_mapping(values))


def coach_file(values: Mapping[str, Any]) -> CoachModel | None:
    """The coach of ``vehicle_file``, None without one or for a quarter car."""
    if not values['vehicle_file']:
        return None
    vehicle = vehicle_of(values['vehicle_file'])
    return vehicle if isinstance(vehicle, CoachModel) else None


def build_model(values: Mapping[str, Any], noise_variance: float | None = None) -> InputStage:
    """The input policy for parameter ``values``; ConfigError (with the reason) if invalid.

    ``noise_variance``: a fixed accelerometer variance (m/s^2)^2 (the filters are built at
    once, which checks e.g. the feedback stability); None: the policy's rule from the data.
    """
    config, vehicle, options = model_inputs(values)
    return InputStage(config, vehicle, options=options, noise_variance=noise_variance)


def build_grid(values: Mapping[str, Any]) -> GridStream:
    """The grid stream for parameter ``values`` (the model's config, vehicle and options)."""
    config, vehicle, options = model_inputs(values)
    return GridStream(config, vehicle, options, values['grid_step_m'])


class IrregularityNode(StreamNode):
    """The managed node; with autostart (default), ConfigError from the constructor when the
    parameters are invalid."""

    NODE_NAME, SPECS = NODE_NAME, SPECS
    PERIOD_PARAM = IRREGULARITY_PERIOD.name

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.policy: InputStage | None = None
        self._candidate: Model | None = None
        self._next_model: Model | None = None
        self._latency = LatencyWindow()
        self._speed_mps = float('nan')  # speed of the newest output, m/s
        self.grid: GridStream | None = None  # with publish_grid
        self._grid_pacer: OutputPacer | None = None
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
        self.create_output(PointStamped, 'track/irregularity', POINT_STAMPED)
        if values['publish_grid']:
            self.grid = build_grid(values)
            depth = values['output_qos_depth']
            self._pubs.append(self.create_lifecycle_publisher(
                PointStamped, 'track/irregularity_grid', output_qos(depth, keep_all=True)))
            self._grid_pacer = OutputPacer(self, self._pubs[-1], POINT_STAMPED, OUTPUT_FRAME,
                                           depth, values['flush_rate_hz'], self.lock)

    def activate(self) -> None:
        """The intake and the diagnostics reporter."""
        super().activate()
        self.add_task('inversion', self._report_inversion)

    def deactivate(self) -> None:
        """StreamNode.deactivate (its flush also ends the grid), then the grid's outputs are
        published and acknowledged."""
        super().deactivate()
        if self._grid_pacer is not None:
            self._grid_pacer.finish()

    def release_core(self) -> None:
        """Drop the policy (its counters are kept), the grid and the pending parameter
        changes."""
        if self.policy is not None:
            self._retired.update(self.policy.counters)
            self.policy = None
        if self._grid_pacer is not None:
            self._counts['grid_published'] += self._grid_pacer.published
            self._grid_pacer.destroy()
            self._grid_pacer = None
        self.grid = None
        self._values = self._candidate = self._next_model = None

    # ------------------------------------------------------------------ configuration
    def _declare_parameters(self) -> dict[str, Any]:
        """Declare every parameter; vehicle_file overrides m_s..c. ConfigError if invalid."""
        values = declare(self, SPECS)
        if values['vehicle_file'] and coach_file(values) is None:  # a quarter car's m_s..c
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
        with self.lock:
            if self._values is None:
                return
            self._values, _ = merged(self._values, SPECS, params)
            if self._candidate is not None:
                self._next_model, self._candidate = self._candidate, None

    # ------------------------------------------------------------------ data path
    @property
    def input_policy(self) -> InputStage | None:
        return self.policy

    def core_counters(self) -> Mapping[str, int]:
        return self.policy.counters

    def core_imu(self, batch: ImuBatch | None) -> Output | None:
        """A pending parameter change first (old filters flushed), then the samples."""
        outs = [self._switch_model()]
        if batch is not None:
            outs.append(self._guarded(lambda: self.policy.imu(
                batch.stamps_ns, batch.accel, batch.frame_ids, batch.covariance,
                batch.angular_velocity, batch.gyro_covariance)))
            self._grid_step(lambda g: g.imu(batch.stamps_ns, batch.accel, batch.frame_ids,
                                            batch.covariance))
        outs = [o for o in outs if o is not None and len(o)]
        if len(outs) < 2:  # the usual: one result, no concatenation
            return outs[0] if outs else None
        return Output.concat(outs)

    def core_odometry(self, stamps_ns: np.ndarray, speeds_mps: np.ndarray) -> Output | None:
        self._grid_step(lambda g: g.odometry(stamps_ns, speeds_mps))
        return self._guarded(lambda: self.policy.odometry(stamps_ns, speeds_mps))

    def core_flush(self) -> Output | None:
        self._grid_step(GridStream.flush, live=False)
        return self._guarded(self.policy.flush)

    def _grid_step(self, step: Any, live: bool = True) -> None:
        """With publish_grid: ``step(grid)`` and its points on track/irregularity_grid (live:
        at the input's pace, else paced as a flush); on an exception the grid restarts."""
        if self.grid is None:
            return
        out: GridOutput | None = self.guarded(lambda: step(self.grid), 'grid', self._new_grid)
        if out is not None and len(out):
            self._grid_pacer.put(out.stamps_ns, (out.chainage_m, out.quality, out.u_m),
                                 len(out) if live else 0)

    def _new_grid(self) -> None:
        """A fresh grid stream for the current values (after an internal error)."""
        self.grid = build_grid(self._values)

    def process(self, imu: Any, odom: Any = ()) -> Output | None:
        """StreamNode.process, its time recorded for /diagnostics (latency_*)."""
        t_rx = time.monotonic()
        out = super().process(imu, odom)
        self._latency.add(time.monotonic() - t_rx)
        return out

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
        self._grid_step(lambda g: g.rebuild(config, vehicle, options), live=False)
        return self._guarded(lambda: self.policy.rebuild(config, vehicle, options=options))

    def emit(self, out: Output | None, live: int) -> Output | None:
        """One PointStamped per output sample, stamped with its IMU stamp (x chainage, y
        quality code, z u or NaN), through the pacer (``live``: see OutputPacer.put)."""
        if out is None or not len(out):
            return out
        self._speed_mps = float(out.speed_mps[-1])
        self._pacer.put(out.stamps_ns, (out.chainage_m, out.quality, out.u_m), live)
        return out

    # ------------------------------------------------------------------ diagnostics
    def describe(self) -> str:
        """The start-up line: method, band, speed source and topics."""
        values = self._values
        speed = 'odom' if values['use_odom'] else f'speed_mps {values["speed_mps"]!r} m/s'
        inputs = ['imu/data', 'odom'] if values['use_odom'] else ['imu/data']
        return (f'{values["method"]}, band {values["band"]}, speed from {speed}: '
                f'{self.topic_line(inputs, ["track/irregularity", "/diagnostics"])}')

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
            **self.output_values(totals),
            'output_rate_hz': delta.get('published', 0) / elapsed_s,
            **quality_values(totals, delta),
            'rebuilds': totals.get('rebuild', 0), 'reconfigures': totals.get('reconfigure', 0),
            'redesigns': totals.get('redesign', 0),
            'idle_flushes': totals.get('flush_idle', 0),
            'held_for_speed': policy.held - policy.reordering,
            'held_for_order': policy.reordering,
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
