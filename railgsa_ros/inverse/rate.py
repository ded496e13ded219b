"""The IMU rate from stamp steps, robust to jitter and to lost samples (no ROS).

Host-stamped drivers jitter: each stamp is off its sample's true time by an independent error
of std sigma (0.1-0.3 ms at 1 kHz). A step is the difference of two such errors, so a rule
applied per step is twice as noisy and its errors walk: the median step of 512 scatters by
~0.08 sigma / T (1.6 % at 0.2 ms, beyond a 2 % tolerance now and then), and rounding each step
to a whole count of periods shifts every later count when one step rounds the wrong way.

So the periods are counted per stamp against a time base: a second-order phase-locked loop
(phase gain ALPHA, period gain BETA, critically damped) predicts the next sample's slot from
the stamps so far; a stamp counts the whole periods since the previous slot, and its residual
(stamp - slot) is its jitter. A count goes wrong only where a stamp's own error exceeds half
a period (not the difference of two), and it does not shift the later ones. The rate is the
periods counted over their time (the stamps telescope: the jitter of the first and last stamp
alone, 0.06 % at 0.2 ms over 512 steps); counts beyond the steps are samples lost without a
gap (a step of two periods: the record would close up around them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a stamp further than this (periods) from its slot sits between two counts (jitter)
BETWEEN = 0.25
ALPHA = 1.0 / 8.0  #: phase gain of the time base (it settles in ~2 / ALPHA stamps)
BETA = ALPHA ** 2 / 4.0  #: period gain: a critically damped second-order loop
MAD_STD = 1.4826  #: std of a normal distribution per median absolute deviation
SMOOTH = 0.125  #: stamp jitter (periods) below which rounding each step counts safely
#: stamp jitter (periods) beyond which stamps reorder often enough to matter (a step <= 0 once
#: in 5000 steps at 0.2, 1 in 430 at 0.25, 1 in 110 at 0.3): the sanitiser rejects them as
#: out_of_order, which loses samples (measured, ADXL355 model at 30 m/s: D1 RMSE 0.0037 mm at
#: 0 and 0.1 ms, 0.0039 at 0.2 ms, 0.020 at 0.3 ms with 295 rejections in 30 s), and the loop
#: cannot count; the stamp errors themselves are harmless (0.2 ms at 30 m/s: 6 mm of chainage)
JITTER_TOLERANCE = 0.25


@dataclass(frozen=True)
class CountedSteps:
    """rate_hz measured; lost: periods counted beyond the steps (samples missing between
    stamps closer than a gap); between: stamps more than BETWEEN periods off their slot;
    jitter_s: robust std of the stamp errors, s (0 at another rate); heavy: jitter_s beyond
    JITTER_TOLERANCE periods (rate_hz is then the steps over their time, lost 0)."""

    rate_hz: float
    lost: int
    between: int
    jitter_s: float = 0.0
    heavy: bool = False

    @property
    def lost_significant(self) -> bool:
        """Whether ``lost`` exceeds the rounding noise of the ``between`` stamps (each may
        count one period wrong either way: 3 sigma of sqrt(between) x 0.3) by more than one."""
        return self.lost > 1 + 0.9 * np.sqrt(self.between)


def count_steps(steps_ns: np.ndarray, period_ns: float, gap_factor: float) -> CountedSteps:
    """The rate from stamp steps (ns) with ``period_ns`` a guess within a third of a period;
    when most steps span several periods (another rate), the median step's. Steps beyond
    ``gap_factor`` periods (gaps) are left out, their two stamps joined.

    The jitter is the robust std of the steps shorter than two periods over sqrt(2) (a step
    is the difference of two stamp errors). Below SMOOTH periods of it each positive step is
    rounded: a wrong count needs a 2.8 sigma step (1 in 200). Up to JITTER_TOLERANCE the loop
    counts, following the stamps out of order too (they telescope). Beyond it no count is
    safe (``heavy``): the rate is the steps over their time and ``lost`` 0 (a lost sample
    cannot be told from jitter there)."""
    steps = np.asarray(steps_ns, dtype=float)
    s = steps[(steps > 0) & (steps <= gap_factor * period_ns)]
    n = np.rint(s / period_ns)
    if s.size == 0 or np.median(n) != 1:
        return CountedSteps(1e9 / float(np.median(steps[steps > 0])), 0, 0)
    short = s[s < 2 * period_ns]
    jitter = MAD_STD / np.sqrt(2.0) * float(np.median(np.abs(short - np.median(short))))
    if jitter <= SMOOTH * period_ns:
        counted = int(n.sum())
        between = int(np.count_nonzero(np.abs(s / period_ns - n) > BETWEEN))
        return CountedSteps(1e9 * counted / float(s.sum()), counted - s.size, between,
                            jitter * 1e-9)
    near = steps[(steps != 0) & (np.abs(steps) <= gap_factor * period_ns)]
    total = float(near.sum())
    if jitter > JITTER_TOLERANCE * period_ns:
        return CountedSteps(1e9 * near.size / total, 0, near.size, jitter * 1e-9, heavy=True)
    counted, between = _track(near.tolist(), float(s.sum() / n.sum()))
    return CountedSteps(1e9 * counted / total, counted - near.size, between, jitter * 1e-9)


def _track(steps: list[float], period: float) -> tuple[int, int]:
    """Count the periods of each step (ns) against the loop's time base: (periods counted,
    stamps more than BETWEEN periods off their slot)."""
    t = slot = 0.0  # stamp and slot of the previous sample, from the block's first stamp
    counted = between = 0
    edge = BETWEEN * period
    for step in steps:
        t += step
        k = max(round((t - slot) / period), 0)  # periods since the previous slot
        slot += k * period
        r = t - slot
        slot += ALPHA * r
        period += BETA * r
        counted += k
        between += r > edge or r < -edge
    return counted, between
