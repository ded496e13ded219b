"""Input health of a run: sample rates, stamp jitter, gaps and the samples the pipeline rejected.

Stamp steps are taken in bag order. The nominal period is the median positive step; a step above
``gap_factor`` nominal periods is a gap (as in the pipeline's sanitiser), steps <= 0 are
out-of-order or duplicate stamps. Jitter is the spread of the remaining steps about the nominal
period. Rejections and resets are the pipeline's own counters.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from railgsa_ros.inverse.sanitize import REASONS


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
    t = np.asarray(stamps_ns, dtype=np.int64)
    if t.size < 2:
        return StampStats(int(t.size), 0.0, *(np.nan,) * 4, 0, 0.0, 0.0, 0)
    step = np.diff(t) * 1e-9
    forward = step[step > 0]
    period = float(np.median(forward)) if forward.size else np.nan
    gap = step > gap_factor * period
    regular = forward[forward <= gap_factor * period] - period
    span = float(t.max() - t.min()) * 1e-9
    return StampStats(int(t.size), span, 1.0 / period, (t.size - 1) / span if span else np.nan,
                      float(np.std(regular)) if regular.size else np.nan,
                      float(np.max(np.abs(regular))) if regular.size else np.nan,
                      int(gap.sum()), float(step[gap].max()) if gap.any() else 0.0,
                      float(np.sum(step[gap] - period)), int(np.sum(step <= 0)))


@dataclass(frozen=True)
class InputHealth:
    """IMU and odometry stamp statistics, speed range (m/s), stamp source, the gap threshold
    (nominal periods) and the pipeline counters (rejected by reason, gaps, resets, emitted)."""

    imu: StampStats
    odom: StampStats | None
    speed_min_mps: float
    speed_max_mps: float
    stamp_source: str
    gap_factor: float
    counters: dict[str, int] = field(default_factory=dict)

    @property
    def rejected(self) -> dict[str, int]:
        """Rejected samples by reason (every reason, zeros included)."""
        return {reason: int(self.counters.get(reason, 0)) for reason in REASONS}

    @property
    def rejected_total(self) -> int:
        """All rejected samples."""
        return sum(self.rejected.values())


def input_health(imu_stamps_ns: np.ndarray, odom_stamps_ns: np.ndarray, speed_mps: np.ndarray,
                 counters: dict[str, int], gap_factor: float = 3.0,
                 stamp_source: str = 'header') -> InputHealth:
    """Health of an IMU stream with its odometry (empty arrays when the bag has none)."""
    odom = stamp_stats(odom_stamps_ns, gap_factor) if np.size(odom_stamps_ns) else None
    speed = np.asarray(speed_mps, dtype=float)
    finite = speed[np.isfinite(speed)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (np.nan, np.nan)
    return InputHealth(stamp_stats(imu_stamps_ns, gap_factor), odom, lo, hi, stamp_source,
                       gap_factor, dict(counters))
