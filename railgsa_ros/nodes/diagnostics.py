"""A small stand-in for diagnostic_updater (not packaged for pip): periodic /diagnostics.

Each node registers tasks; every period (steady clock, so it keeps reporting when a simulated
clock stops) the publisher calls them and sends one DiagnosticArray with a status per task named
``"<node>: <task>"`` and the node's hardware_id (:class:`HardwareId`: the ``hardware_id``
parameter, else the IMU's frame_id). A task that raises becomes an ERROR status: the reporter
never takes the node down.

Levels as diagnostic_msgs users expect: STALE while there is nothing to judge yet (no input has
arrived), OK, WARN when degraded, ERROR for faults. Values are strings at full precision
(``repr`` of floats: ``float(value)`` gives the number back).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from railgsa_ros.location import Reference
from railgsa_ros.nodes.qos import DIAGNOSTICS_QOS

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)
LEVELS = (OK, WARN, ERROR)  #: by the core's finding levels 0, 1, 2
LEVEL_NAMES = ('OK', 'WARN', 'ERROR')
QUALITIES = ('valid', 'degraded', 'invalid')  #: output counters by quality code 0, 1, 2


@dataclass
class Report:
    """One task's verdict: level (DiagnosticStatus.OK..STALE, bytes), message and values."""

    level: bytes
    message: str
    values: Mapping[str, object] = field(default_factory=dict)


def format_value(value: object) -> str:
    """Diagnostic values are strings: floats at full precision (repr: the shortest string that
    reads back as the same float), the rest with str()."""
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


class HardwareId:
    """The ``hardware_id`` of a node's statuses: the parameter when set, else the frame_id of
    the newest IMU message ('' before the first)."""

    def __init__(self, parameter: str) -> None:
        self.parameter = parameter
        self.frame_id = ''

    def see(self, frame_ids: Sequence[str]) -> None:
        """Note the frame_ids of an IMU batch (the newest one counts)."""
        if len(frame_ids):
            self.frame_id = str(frame_ids[-1])

    def __str__(self) -> str:
        return self.parameter or self.frame_id


def make_status(name: str, hardware_id: object, report: Report) -> DiagnosticStatus:
    """Build a DiagnosticStatus from a Report."""
    return DiagnosticStatus(level=report.level, name=name, message=report.message,
                            hardware_id=str(hardware_id),
                            values=[KeyValue(key=str(k), value=format_value(v))
                                    for k, v in report.values.items()])


class Deltas:
    """Per-period increments of cumulative counters (reason -> count)."""

    def __init__(self) -> None:
        self._previous: dict[str, int] = {}

    def __call__(self, totals: Mapping[str, int]) -> dict[str, int]:
        """Return totals minus the totals of the previous call, for every reason in totals."""
        delta = {k: int(v) - self._previous.get(k, 0) for k, v in totals.items()}
        self._previous = dict(totals)
        return delta


class LatencyWindow:
    """Latencies (s) collected during one diagnostics period; bounded memory."""

    def __init__(self, maxlen: int = 100_000) -> None:
        self._values: deque[float] = deque(maxlen=maxlen)

    def add(self, seconds: float) -> None:
        """Record one latency in seconds."""
        self._values.append(seconds)

    def take(self) -> dict[str, float]:
        """p50, p99 and max in ms of the period (NaN when empty), then start a new period."""
        if not self._values:
            return {'latency_p50_ms': float('nan'), 'latency_p99_ms': float('nan'),
                    'latency_max_ms': float('nan')}
        ms = np.fromiter(self._values, float) * 1e3
        self._values.clear()
        p50, p99 = np.percentile(ms, [50, 99])
        return {'latency_p50_ms': float(p50), 'latency_p99_ms': float(p99),
                'latency_max_ms': float(ms.max())}


class DiagnosticsPublisher:
    """Publishes the node's tasks on /diagnostics every ``period_s`` seconds of steady time.

    A task is ``fn(elapsed_s) -> Report`` where elapsed_s is the steady time since the previous
    report (for rates).
    """

    def __init__(self, node: Node, hardware_id: object, period_s: float = 1.0) -> None:
        """``hardware_id``: a string or a :class:`HardwareId` (read at every report)."""
        self._node = node
        self._name = node.get_fully_qualified_name().lstrip('/')
        self.hardware_id = hardware_id
        self._tasks: list[tuple[str, Callable[[float], Report]]] = []
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
        self._last = time.monotonic()
        self._timer = node.create_timer(period_s, self.publish,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def add(self, task: str, fn: Callable[[float], Report]) -> None:
        """Register a task; its status is named ``"<node>: <task>"`` (the node's fully
        qualified name without the leading slash: ``train1/irregularity_node: imu input`` in
        namespace /train1, so that two trains in one domain are told apart)."""
        self._tasks.append((task, fn))

    def publish(self) -> DiagnosticArray:
        """Run every task now and publish (and return) the array."""
        now = time.monotonic()
        elapsed, self._last = max(now - self._last, 1e-9), now
        statuses = []
        for task, fn in self._tasks:
            try:
                report = fn(elapsed)
            except Exception as exc:  # a diagnostic task must not kill the node
                report = Report(ERROR, f'diagnostic task failed: {exc!r}')
            statuses.append(make_status(f'{self._name}: {task}', self.hardware_id, report))
        msg = DiagnosticArray(status=statuses)
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(msg)
        return msg

    def destroy(self) -> None:
        """Release the timer and the publisher."""
        self._node.destroy_timer(self._timer)
        self._node.destroy_publisher(self._pub)


def quality_values(totals: Mapping[str, int], delta: Mapping[str, int]) -> dict[str, int]:
    """Outputs by quality (the core's counters valid, degraded, invalid): totals and in the
    period."""
    values = {q: totals.get(q, 0) for q in QUALITIES}
    values.update({f'{q}_last_period': delta.get(q, 0) for q in QUALITIES})
    return values


def checks_report(policy: Any) -> Report:
    """The 'input checks' task: the input policy's worst finding as level and message, every
    finding's one-line message as a value (key = the check); STALE before any check (no
    input yet)."""
    if not policy.findings:
        return Report(STALE, 'nothing checked yet: no input')
    status = policy.status
    values = {f.key: f'{LEVEL_NAMES[f.level]}: {f.message}' for f in policy.findings}
    return Report(LEVELS[status.level], status.message, values)


def location_report(values: Mapping[str, Any], stamp_ns: int, chainage_m: float) -> Report:
    """The 'location' task: the location parameters (``location.Reference``) and the km-post of
    the newest output (its IMU stamp and chainage); STALE before the first (-1, NaN)."""
    reference = Reference.from_mapping(values)
    shown = {**reference.values(chainage_m), 'stamp_ns': stamp_ns}
    if stamp_ns < 0:
        return Report(STALE, 'no output yet', shown)
    return Report(OK, f'line {reference.line} track {reference.track}, km {shown["km"]:.3f}',
                  shown)
