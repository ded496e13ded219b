"""Input health of a run: sample rates, stamp jitter, gaps and the samples the pipeline rejected.

Stamp steps are taken in bag order. The nominal period is the median positive step; a step above
``gap_factor`` nominal periods is a gap (as in the pipeline's sanitiser), steps <= 0 are
out-of-order or duplicate stamps. Jitter is the spread of the remaining steps about the nominal
period. Rejections and resets are the pipeline's own counters.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from railgsa_ros.input.sanitize import REASONS


@dataclass(frozen=True)
class StampStats:
    """Stamp statistics of one topic: message count, span (s), nominal rate (Hz, from the median
    step), mean rate (Hz), jitter std and largest |step - period| without gaps (s), gaps (count,
    longest step s, time lost s) and steps <= 0 (count)."""

    count: int
    span_s: float
    rate_hz: float
    mean_rate_hz: float
    jitter_std_s: float
    jitter_max_s: float
    gaps: int
    longest_gap_s: float
    lost_s: float
    backwards: int


def stamp_stats(stamps_ns: np.ndarray, gap_factor: float = 3.0) -> StampStats:
    """Statistics of a stamp sequence (ns) in arrival order."""
    acc = StampAccumulator(gap_factor)
    acc.push(stamps_ns)
    return acc.stats()


JITTER_BINS = 80
MAX_GAP_MARKS = 10_000  # gap positions kept for the figure (the count is exact)


class StampAccumulator:
    """Stamp statistics of a topic that streams in chunks (``stamp_stats`` of all of it at
    once). The nominal period is the median positive step of the first chunk with one (65 s
    at 1 kHz: the period the pipeline uses too). For the health figure it also counts the
    messages per second of log time (sparse: memory by the seconds the recording has messages
    in, whatever the stamps), keeps the log times of the first MAX_GAP_MARKS gaps and a
    histogram of the jitter in JITTER_BINS bins from -1 to gap_factor - 1 periods."""

    def __init__(self, gap_factor: float = 3.0) -> None:
        self.gap_factor = float(gap_factor)
        self.count = 0
        self.period_s = np.nan
        self._last: int | None = None
        self._lo, self._hi = np.iinfo(np.int64).max, np.iinfo(np.int64).min
        self._sums = np.zeros(3)  # regular steps: count, sum and sum of squares of the jitter
        self._jitter_max = np.nan
        self._gaps, self._longest, self._lost, self._backwards = 0, 0.0, 0.0, 0
        self._pending = np.zeros(0)  # steps before the period is known
        self._first_log: int | None = None
        self._seconds: dict[int, int] = {}  # second of log time -> messages (sparse)
        self.per_second_origin_s = 0  # first second of ``per_second``
        self.gap_log_s: list[float] = []
        self.jitter_counts = np.zeros(JITTER_BINS, np.int64)

    def push(self, stamps_ns: np.ndarray, log_time_ns: np.ndarray | None = None) -> None:
        """Stamps (K,) ns in arrival order, with their log times (K,) ns for the figure."""
        t = np.asarray(stamps_ns, dtype=np.int64)
        if t.size == 0:
            return
        self.count += t.size
        self._lo, self._hi = min(self._lo, int(t.min())), max(self._hi, int(t.max()))
        prev = t if self._last is None else np.concatenate([[self._last], t])
        self._last = int(t[-1])
        step = np.diff(prev) * 1e-9
        logs = None
        if log_time_ns is not None:
            logs = np.asarray(log_time_ns, dtype=np.int64)
            self._per_second(logs)
            logs = logs[-step.size:] if step.size else logs[:0]
        if np.isnan(self.period_s):
            forward = step[step > 0]
            if forward.size == 0:
                self._pending = np.concatenate([self._pending, step])
                return
            self.period_s = float(np.median(forward))
            step = np.concatenate([self._pending, step])
            if logs is not None and self._pending.size:
                logs = np.concatenate([np.full(self._pending.size, logs[0]), logs])
            self._pending = np.zeros(0)
        self._steps(step, logs)

    def _per_second(self, logs: np.ndarray) -> None:
        if self._first_log is None:
            self._first_log = int(logs[0])
        seconds, counts = np.unique((logs - self._first_log) // 1_000_000_000,
                                    return_counts=True)
        for sec, n in zip(seconds.tolist(), counts.tolist(), strict=True):
            self._seconds[sec] = self._seconds.get(sec, 0) + n

    @property
    def per_second(self) -> np.ndarray:
        """Messages per second of log time over the recording: the longest stretch of seconds
        without an hour missing (a log time far from the others, a clock set wrong, would
        otherwise stretch the figure over years)."""
        if not self._seconds:
            return np.zeros(0, np.int64)
        keys = np.array(sorted(self._seconds))
        cuts = np.flatnonzero(np.diff(keys) > 3600) + 1
        parts = np.split(keys, cuts)
        best = max(parts, key=lambda p: sum(self._seconds[k] for k in p.tolist()))
        self.per_second_origin_s = int(best[0])
        out = np.zeros(int(best[-1] - best[0]) + 1, np.int64)
        out[best - best[0]] = [self._seconds[k] for k in best.tolist()]
        return out

    def _steps(self, step: np.ndarray, logs: np.ndarray | None) -> None:
        period = self.period_s
        gap = step > self.gap_factor * period
        regular = step[(step > 0) & ~gap] - period
        self._sums += (regular.size, regular.sum(), np.sum(regular ** 2))
        if regular.size:
            self._jitter_max = np.fmax(self._jitter_max, float(np.max(np.abs(regular))))
        self.jitter_counts += np.histogram(regular, JITTER_BINS, self.jitter_range_s)[0]
        if gap.any():
            self._gaps += int(gap.sum())
            self._longest = max(self._longest, float(step[gap].max()))
            self._lost += float(np.sum(step[gap] - period))
            if logs is not None and self._first_log is not None:
                room = MAX_GAP_MARKS - len(self.gap_log_s)
                self.gap_log_s += ((logs[gap][:room] - self._first_log) * 1e-9).tolist()
        self._backwards += int(np.sum(step <= 0))

    @property
    def jitter_range_s(self) -> tuple[float, float]:
        """Range (s) of the jitter histogram."""
        return -self.period_s, (self.gap_factor - 1) * self.period_s

    def stats(self) -> StampStats:
        """The statistics of everything pushed."""
        if self.count < 2:
            return StampStats(self.count, 0.0, *(np.nan,) * 4, 0, 0.0, 0.0, 0)
        if np.isnan(self.period_s):  # no forward step at all
            return StampStats(self.count, 0.0, *(np.nan,) * 4, 0, 0.0, 0.0,
                              int(self._pending.size))
        n, total, squares = self._sums
        std = float(np.sqrt(max(squares / n - (total / n) ** 2, 0.0))) if n else np.nan
        span = (self._hi - self._lo) * 1e-9
        return StampStats(self.count, span, 1.0 / self.period_s,
                          (self.count - 1) / span if span else np.nan, std,
                          float(self._jitter_max), self._gaps, self._longest, self._lost,
                          self._backwards)


@dataclass(frozen=True)
class InputHealth:
    """IMU and odometry stamp statistics, speed range (m/s), stamp source, the gap threshold
    (nominal periods), the pipeline counters (rejected by reason, gaps, resets, emitted) and the
    IMU accumulator with the figure's series (messages per second, gaps, jitter histogram)."""

    imu: StampStats
    odom: StampStats | None
    speed_min_mps: float
    speed_max_mps: float
    stamp_source: str
    gap_factor: float
    imu_trace: StampAccumulator  # per-second counts, gap log times, jitter histogram
    counters: dict[str, int] = field(default_factory=dict)

    @property
    def rejected(self) -> dict[str, int]:
        """Rejected samples by reason (every reason, zeros included)."""
        return {reason: int(self.counters.get(reason, 0)) for reason in REASONS}

    @property
    def rejected_total(self) -> int:
        """All rejected samples."""
        return sum(self.rejected.values())


class HealthAccumulator:
    """Input health of a run that streams in chunks: the IMU and odometry stamps and the speed
    range of the odometry."""

    def __init__(self, gap_factor: float = 3.0) -> None:
        self.gap_factor = float(gap_factor)
        self.imu = StampAccumulator(gap_factor)
        self.odom = StampAccumulator(gap_factor)
        self.speed_range = [np.inf, -np.inf]

    def push(self, imu_stamps_ns: np.ndarray, imu_log_ns: np.ndarray | None,
             odom_stamps_ns: np.ndarray, speed_mps: np.ndarray) -> None:
        """One chunk of IMU stamps (with log times) and of odometry."""
        self.imu.push(imu_stamps_ns, imu_log_ns)
        self.odom.push(odom_stamps_ns)
        speed = np.asarray(speed_mps, dtype=float)
        finite = speed[np.isfinite(speed)]
        if finite.size:
            self.speed_range = [min(self.speed_range[0], float(finite.min())),
                                max(self.speed_range[1], float(finite.max()))]

    def health(self, counters: dict[str, int], stamp_source: str = 'header') -> InputHealth:
        """The health of everything pushed, with the pipeline's counters."""
        lo, hi = self.speed_range if np.isfinite(self.speed_range[0]) else (np.nan, np.nan)
        return InputHealth(self.imu.stats(), self.odom.stats() if self.odom.count else None,
                           lo, hi, stamp_source, self.gap_factor, self.imu, dict(counters))

