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

Input: the same :class:`~railgsa_ros.nodes.stream_node.StreamNode` data path as
irregularity_node (serialized messages read by a thread that no executor wakes, decoded
vectorised), handing over at most one batch every ``process_period_s``: the bank's cost per call
is high, so batches of 50 samples keep it low. All parameters are read-only: to change them,
deactivate, clean up, set, configure and activate again, or restart. A managed lifecycle node
like irregularity_node (:mod:`railgsa_ros.nodes.lifecycle`), flushing like it on
``idle_flush_s`` without input, on deactivate and on shutdown, and publishing the band through an
:class:`~railgsa_ros.nodes.pacing.OutputPacer`. See docs/uncertainty_node.md.
"""

from __future__ import annotations

import railgsa_ros.nodes.early_signals  # noqa: F401  (first: exit 0 on a signal from here on)

# isort: split

from collections.abc import Mapping
from dataclasses import fields, replace
import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
import numpy as np

from railgsa_ros.bag.messages import VECTOR3_STAMPED
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.stage import InputStage
from railgsa_ros.nodes.diagnostics import ERROR, OK, STALE, Report, make_status, quality_values
from railgsa_ros.nodes.imu_conversion import NS_PER_S, ImuBatch
from railgsa_ros.nodes.lifecycle import run
from railgsa_ros.nodes.params import accept_integers, declare
from railgsa_ros.nodes.qos import output_qos
from railgsa_ros.nodes.specs import (
    INVERSION_SPECS,
    NODE_SPECS,
    UNCERTAINTY_SPECS,
    VEHICLE_SPECS,
    vehicle_values,
)
from railgsa_ros.nodes.stream_node import OUTPUT_FRAME, StreamNode
from railgsa_ros.uncertainty import Band, Sensitivity, UncertaintyConfig, UncertaintyStream, Update
from railgsa_ros.uncertainty.parameters import load_uncertainty, table3, with_discrepancy
from railgsa_ros.vehicle import VehicleParams

NODE_NAME = 'uncertainty_node'

#: irregularity_node's inversion, vehicle and input parameters (same names and defaults), then
#: the uncertainty parameters; all read-only.
SPECS = tuple(replace(s, read_only=True) for s in
              (*INVERSION_SPECS, *VEHICLE_SPECS, *NODE_SPECS, *UNCERTAINTY_SPECS))
#: uncertainty_node's own parameters that UncertaintyConfig holds
_OWN_SPECS = tuple(s for s in UNCERTAINTY_SPECS
                   if s.name in {f.name for f in fields(UncertaintyConfig)})


def sensitivity_message(record: Sensitivity, hardware_id: object) -> DiagnosticArray:
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


class UncertaintyNode(StreamNode):
    """The managed node; with autostart (default), ConfigError from the constructor when the
    parameters are invalid."""

    NODE_NAME, SPECS = NODE_NAME, SPECS
    PERIOD_PARAM = 'process_period_s'

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.stream: UncertaintyStream | None = None
        self._window_ms = (float('nan'), 0.0)  # last, max compute time per window
        self._cpu = (time.monotonic(), time.process_time())
        self.add_pre_set_parameters_callback(accept_integers(SPECS))
        self.autostart()

    # ------------------------------------------------------------------ lifecycle
    def configure(self) -> None:
        """Read and validate the parameters, build the stream and the publishers."""
        values = declare(self, SPECS)
        inversion = {s.name: values[s.name] for s in INVERSION_SPECS}
        self.config = UncertaintyConfig.from_mapping(
            {**inversion, **{s.name: values[s.name] for s in _OWN_SPECS}})
        self.vehicle = VehicleParams(**vehicle_values(values))
        self.dists = load_uncertainty(values['uncertainty_file']) if \
            values['uncertainty_file'] else table3(self.vehicle)
        self.config = with_discrepancy(self.config, values['uncertainty_file'])
        self._values = values
        self.stream = self._new_stream()
        self.create_output(Vector3Stamped, 'track/irregularity_band', VECTOR3_STAMPED)
        self._pubs.append(self.create_lifecycle_publisher(
            DiagnosticArray, 'track/sensitivity', output_qos(values['sensitivity_qos_depth'])))

    def activate(self) -> None:
        """The intake and the diagnostics reporter."""
        super().activate()
        self.add_task('uncertainty', self._report_uncertainty)

    def release_core(self) -> None:
        """Drop the stream (its counters are kept)."""
        if self.stream is not None:
            self._retired.update(self.stream.counters)
            self.stream = None

    # ------------------------------------------------------------------ data path
    @property
    def input_policy(self) -> InputStage | None:
        return None if self.stream is None else self.stream.policy

    def core_counters(self) -> Mapping[str, int]:
        return self.stream.counters

    def core_imu(self, batch: ImuBatch | None) -> Update | None:
        if batch is None:
            return None
        return self._guarded(lambda: self.stream.imu(batch.stamps_ns, batch.accel,
                                                     batch.frame_ids, batch.covariance))

    def core_odometry(self, stamps_ns: np.ndarray, speeds_mps: np.ndarray) -> Update | None:
        return self._guarded(lambda: self.stream.odometry(stamps_ns, speeds_mps))

    def core_flush(self) -> Update | None:
        return self._guarded(self.stream.flush)

    def _guarded(self, step: Any) -> Update | None:
        """``step()`` of the core through ``guarded``: on an exception the stream is rebuilt."""
        return self.guarded(step, 'uncertainty stream', self._rebuild)

    def emit(self, update: Update | None, live: int) -> Band | None:
        """The band (one Vector3Stamped per sample, stamped with its IMU stamp, through the
        pacer; ``live``: input samples of the batch) and the closed windows; returns the band
        (None when nothing was accepted)."""
        if update is None:
            return None
        band = update.band
        if len(band):  # x lower, y mean, z upper: NaN where INVALID, widened where DEGRADED
            self._pacer.put(band.stamps_ns, (band.lower_m, band.mean_m, band.upper_m), live)
        for record in update.windows:
            self._pubs[1].publish(sensitivity_message(record, self._hardware))
            last = record.compute_s * 1e3
            self._window_ms = (last, max(self._window_ms[1], last))
        self._counts['windows'] += len(update.windows)
        return band

    def _new_stream(self) -> UncertaintyStream:
        """A stream (its input policy with the bank) for the configuration."""
        return UncertaintyStream(self.config, self.vehicle, self.dists,
                                 options=InputOptions.from_mapping(self._values))

    def _rebuild(self) -> None:
        """After a failure: the stream's filters rebuilt, continuing the chainage (the pending
        outputs are dropped); a new stream if even that fails."""
        try:
            self.stream.policy.rebuild()
        except Exception:  # the node must survive the core
            self._retired.update(self.stream.counters)
            self.stream = self._new_stream()

    # ------------------------------------------------------------------ diagnostics
    def describe(self) -> str:
        """The start-up line: method, band, the rule design and topics."""
        inv, design = self.config.inversion, self.stream.design
        inputs = ['imu/data', 'odom'] if self._values['use_odom'] else ['imu/data']
        outputs = ['track/irregularity_band', 'track/sensitivity', '/diagnostics']
        return (f'{inv.method}, band {inv.band}, {design.points} rule points '
                f'({self.config.rule}, order {self.config.order}, {design.fit}) over '
                f'{", ".join(design.names)}: {self.topic_line(inputs, outputs)}')

    def _report_uncertainty(self, elapsed_s: float) -> Report:
        now = (time.monotonic(), time.process_time())
        cpu = (now[1] - self._cpu[1]) / max(now[0] - self._cpu[0], 1e-9)
        self._cpu = now
        totals, design = self.counters(), self.stream.design
        delta = self._deltas['uncertainty'](totals)
        values: dict[str, object] = {
            'rule': self.config.rule, 'order': self.config.order, 'fit': design.fit,
            'parameters': ' '.join(design.names), 'rule_points': design.points,
            'band_delay_samples': self.stream.policy.delay_samples,  # 0 before the first 64
            **self.output_values(totals), 'windows': totals.get('windows', 0),
            'idle_flushes': totals.get('flush_idle', 0),
            'window_compute_ms': self._window_ms[0], 'window_compute_max_ms': self._window_ms[1],
            'cpu_fraction_of_one_core': cpu, **quality_values(totals, delta),
            'internal_errors': totals.get('internal_error', 0),
            'first_stamp_ns': self._first_stamp_ns, **self.lifecycle_values()}
        if delta.get('internal_error', 0):
            return Report(ERROR, 'the stream failed and was reset', values)
        if delta.get('received', 0) == 0:
            return Report(STALE, 'no input: nothing to analyse', values)
        return Report(OK, f'{design.points} points, cpu {cpu:.1%} of one core', values)


def main(args: list[str] | None = None) -> int:
    """Run the node until SIGINT/SIGTERM; exit code 0, or 2 with one line for bad parameters."""
    return run(UncertaintyNode, args)


if __name__ == '__main__':
    sys.exit(main())
