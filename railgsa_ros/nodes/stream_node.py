"""The data path irregularity_node and uncertainty_node share: raw intake, core, paced output.

:class:`StreamNode` is the managed node both derive from. It owns the IMU and odometry intake
(raw subscriptions read by a thread, :class:`~railgsa_ros.nodes.imu_input.ImuIntake`), the
per-sample output topic with its :class:`~railgsa_ros.nodes.pacing.OutputPacer`, the idle
flush, the node lock and the counters. A subclass supplies its core (``input_policy``,
``core_counters``, ``core_imu``, ``core_odometry``, ``core_flush``, ``release_core``), turns
core results into outputs (``emit``) and adds its diagnostics task.

Threads: the reader thread runs ``process`` and ``on_idle``; the executor runs the pacing and
diagnostics timers, parameter callbacks and lifecycle transitions. Everything that touches the
core, the pacer or the counters holds ``lock``. Deactivate stops the reader first, then
processes what waits in the reader history, flushes the core and publishes (paced) before the
subscriptions go.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Callable, Mapping, Sequence
import threading
import time
from typing import Any

import numpy as np

from railgsa_ros.bag.cdr import StampedLayout
from railgsa_ros.input.stage import InputStage
from railgsa_ros.nodes.diagnostics import (
    Deltas,
    DiagnosticsPublisher,
    HardwareId,
    Report,
    checks_report,
    location_report,
)
from railgsa_ros.nodes.imu_conversion import ImuBatch
from railgsa_ros.nodes.imu_input import ImuIntake
from railgsa_ros.nodes.lifecycle import ManagedNode
from railgsa_ros.nodes.pacing import OutputPacer
from railgsa_ros.nodes.qos import output_qos

OUTPUT_FRAME = 'track'  #: header.frame_id of every per-sample output


class StreamNode(ManagedNode):
    """Raw IMU intake, the core's steps under one lock, and one paced per-sample output."""

    #: parameter holding the shortest time between two batches, s (None: batch as they come)
    PERIOD_PARAM: str | None = None

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.lock = threading.RLock()
        self._values: dict[str, Any] | None = None
        self._retired: Counter[str] = Counter()  # counters of replaced cores
        self._counts: Counter[str] = Counter()   # internal_error, published, windows, flush_*
        self._deltas: defaultdict[str, Deltas] = defaultdict(Deltas)
        self._first_stamp_ns = -1  # first IMU stamp processed since the process started
        self._intake: ImuIntake | None = None
        self._diagnostics: DiagnosticsPublisher | None = None
        self._hardware = HardwareId('')  # the parameter, else the IMU frame_id
        self._pubs: list[Any] = []
        self._pacer: OutputPacer | None = None
        self._last_input = time.monotonic()  # steady time of the last IMU batch, s
        self._unflushed = False  # samples given to the core since the last flush
        self._newest = (-1, float('nan'))  # IMU stamp (ns) and chainage (m) of the newest output

    # ------------------------------------------------------------------ for subclasses
    @property
    def input_policy(self) -> InputStage | None:
        """The core's input policy (None when not configured)."""
        raise NotImplementedError

    def core_counters(self) -> Mapping[str, int]:
        """The live core's counters."""
        raise NotImplementedError

    def core_imu(self, batch: ImuBatch | None) -> Any:
        """Give well-formed IMU samples (or none) to the core; its result for ``emit``."""
        raise NotImplementedError

    def core_odometry(self, stamps_ns: np.ndarray, speeds_mps: np.ndarray) -> Any:
        """Give odometry samples to the core; its result for ``emit``."""
        raise NotImplementedError

    def core_flush(self) -> Any:
        """Flush the core (a stream ended); its result for ``emit``."""
        raise NotImplementedError

    def release_core(self) -> None:
        """Drop the core, keeping its counters in ``_retired``."""
        raise NotImplementedError

    def emit(self, result: Any, live: int) -> Any:
        """Publish a core result (``live``: input samples it consumed, OutputPacer.put);
        returns what ``process`` returns."""
        raise NotImplementedError

    # ------------------------------------------------------------------ lifecycle pieces
    def create_output(self, msg_cls: type, topic: str, layout: StampedLayout) -> None:
        """The per-sample output: a lifecycle publisher (RELIABLE, KEEP_ALL: a message is kept
        until every reader acknowledged it) and its pacer (slices of ``output_qos_depth`` / 8)."""
        self._hardware.parameter = self._values['hardware_id']
        depth = self._values['output_qos_depth']
        self._pubs.append(self.create_lifecycle_publisher(msg_cls, topic,
                                                          output_qos(depth, keep_all=True)))
        self._pacer = OutputPacer(self, self._pubs[-1], layout, OUTPUT_FRAME, depth,
                                  self._values['flush_rate_hz'], self.lock)

    def activate(self) -> None:
        """The intake (its reader thread) and the diagnostics reporter."""
        values = self._values
        period = values[self.PERIOD_PARAM] if self.PERIOD_PARAM else 0.0
        self._intake = ImuIntake(self, values, self.process, self.on_idle, period)
        self._diagnostics = DiagnosticsPublisher(self, self._hardware)
        self.add_task('imu input', self._report_input)
        self.add_task('input checks', lambda _: checks_report(self.input_policy))
        self.add_task('location', lambda _: location_report(self._values, *self._newest))

    def add_task(self, name: str, report: Callable[[float], Report]) -> None:
        """A diagnostics task run under the node lock."""
        def locked(elapsed_s: float) -> Report:
            with self.lock:
                return report(elapsed_s)
        self._diagnostics.add(name, locked)

    def deactivate(self) -> None:
        """Stop the reader, process the input waiting in it (one history at most), flush the
        core, publish and await the acknowledgement of every output; then drop the
        subscriptions and the reporter."""
        if self._intake is not None:
            self._intake.stop()
            with self.lock:
                imu, odom = self._intake.take(self._intake.depth)
                if imu or odom:
                    self.process(imu, odom)
                self.flush('flush_deactivate')
            self._pacer.finish()
            self._counts.update(self._intake.counts)
            self._intake.destroy()
            self._intake = None
        if self._diagnostics is not None:
            self._diagnostics.destroy()
            self._diagnostics = None

    def release(self) -> None:
        """Drop the core (its counters are kept), the pacer and the publishers."""
        with self.lock:
            self.release_core()
            if self._pacer is not None:
                self._counts.update(self._paced())
                self._pacer.destroy()
                self._pacer = None
        for pub in self._pubs:
            self.destroy_lifecycle_publisher(pub)
        self._pubs = []

    def destroy_node(self) -> None:
        """Stop the reader thread before the node goes (no flush: use ``finish`` for that)."""
        if self._intake is not None:
            self._intake.destroy()
            self._intake = None
        super().destroy_node()

    # ------------------------------------------------------------------ data path
    def process(self, imu: Sequence[bytes], odom: Sequence[bytes] = ()) -> Any:
        """Serialized odometry, then serialized IMU messages through the core; publish the
        outputs. Returns ``emit``'s result of the IMU step (None when not active)."""
        with self.lock:
            if self._intake is None or self.input_policy is None:
                return None
            if len(odom):
                stamps, speeds = self._intake.odometry(odom)
                if stamps.size:
                    self._step(lambda: self.core_odometry(stamps, speeds))
            if len(imu):
                self._last_input = time.monotonic()
            batch = self._intake.convert(imu)
            if batch is None:
                return self._step(lambda: self.core_imu(None))
            if self._first_stamp_ns < 0:
                self._first_stamp_ns = int(batch.stamps_ns[0])
            self._hardware.see(batch.frame_ids)
            self._unflushed = True
            return self._step(lambda: self.core_imu(batch), len(batch))

    def on_idle(self) -> None:
        """No IMU message for idle_flush_s (steady clock): the stream ended, flush."""
        with self.lock:
            if time.monotonic() - self._last_input >= self._values['idle_flush_s']:
                self.flush('flush_idle')

    def flush(self, reason: str) -> Any:
        """Flush the core if it got samples since the last flush; count ``reason``."""
        if self.input_policy is None or not self._unflushed:
            return None
        self._unflushed = False
        self._counts[reason] += 1
        return self._noted(self.emit(self.core_flush(), 0))

    def _step(self, step: Callable[[], Any], added: int = 0) -> Any:
        """Run a core step and emit its result; ``added`` input samples go in with it (each
        one that leaves the policy's hold adds a live output; the rest are paced)."""
        held = self.input_policy.held + added
        result = step()
        return self._noted(self.emit(result, max(0, held - self.input_policy.held)))

    def _noted(self, out: Any) -> Any:
        """``out`` (emit's Output or Band: stamps_ns, chainage_m), its newest sample kept for
        the 'location' task."""
        if out is not None and len(out):
            self._newest = (int(out.stamps_ns[-1]), float(out.chainage_m[-1]))
        return out

    # ------------------------------------------------------------------ diagnostics
    def counters(self) -> dict[str, int]:
        """Cumulative counts by reason over the node's life (all cores)."""
        with self.lock:
            live = [] if self.input_policy is None else [Counter(self.core_counters())]
            intake = [] if self._intake is None else [self._intake.counts]
            return dict(sum((*live, *intake, self._counts, self._paced()), self._retired.copy()))

    def _paced(self) -> Counter[str]:
        """The live pacer's counts: published (taken by the writer), output_blocked (publishes
        that found it full of unacknowledged messages), output_dropped."""
        if self._pacer is None:
            return Counter()
        return Counter(published=self._pacer.published, output_blocked=self._pacer.blocked,
                       output_dropped=self._pacer.dropped)

    def output_values(self, totals: Mapping[str, int]) -> dict[str, int]:
        """The output's diagnostics values: published, output_blocked, output_dropped (over the
        node's life) and the pacer's queue now and at most."""
        return {'published': totals.get('published', 0),
                'output_blocked': totals.get('output_blocked', 0),
                'output_dropped': totals.get('output_dropped', 0),
                'output_queue': self._pacer.pending, 'output_queue_max': self._pacer.max_pending}

    def _report_input(self, elapsed_s: float) -> Report:
        totals = self.counters()
        return self._intake.report(totals, self._deltas['imu'](totals), elapsed_s,
                                   self.input_policy.config.frame_id)
