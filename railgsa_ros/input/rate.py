"""The IMU rate from stamp steps, robust to jitter and to lost samples (no ROS).

Host-stamped drivers jitter: each stamp is off its sample's true time by an independent error
of std sigma (0.1-0.3 ms at 1 kHz). A step is the difference of two such errors, so a rule
applied per step is twice as noisy and its errors walk: the median step of 512 scatters by
~0.08 sigma / T (1.6 % at 0.2 ms, beyond a 2 % tolerance now and then), and rounding each step
to a whole count of periods shifts every later count when one step rounds the wrong way.

So above SMOOTH the periods are counted per stamp against one time base for the whole block:
the period T and phase that the stamps line up on best (the peak of sum exp(2 pi i t / T) over
T, one FFT of the stamps binned by period: lost samples are absent terms and do not move it,
a rate change does), then a least-squares line t = a + T m through the slot counts m,
recounting every stamp against it. A count goes wrong only where a stamp's own error exceeds
half a period, and only that stamp's: the periods spanned are the slots of the first and last
stamp, so the lost count is wrong by the rounding of two stamp errors at most (a sequential
time base, a phase-locked loop, was pulled off by each lost sample at 0.22 ms and went on
counting wrong: 23 of 73 lost samples counted, or another rate). The rate is 1 / T of the
line (0.03 % at 0.25 ms over 512 steps); counts beyond the steps are samples lost without a
gap (a step of two periods: the record would close up around them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a stamp further than this (periods) from its slot sits between two counts (jitter)
BETWEEN = 0.25
MAD_STD = 1.4826  #: std of a normal distribution per median absolute deviation
SMOOTH = 0.125  #: stamp jitter (periods) below which rounding each step counts safely
#: stamp jitter (periods) beyond which stamps reorder often enough to matter (a step <= 0 once
#: in 5000 steps at 0.2, 1 in 430 at 0.25, 1 in 110 at 0.3): the sanitiser rejects them as
#: out_of_order, which loses samples (measured, ADXL355 model at 30 m/s: D1 RMSE 0.0037 mm at
#: 0 and 0.1 ms, 0.0039 at 0.2 ms, 0.020 at 0.3 ms with 295 rejections in 30 s), and from
#: about 0.35 no period locks; the stamp errors themselves are harmless (0.2 ms at 30 m/s:
#: 6 mm of chainage)
JITTER_TOLERANCE = 0.25
LOCKED = 4.0  #: |sum of phases| / sqrt(N) a period must reach to count against it
SEARCH = 0.06  #: relative range of the periods searched around the median step
REFITS = 3  #: recounts of a locked block against the line fitted to its counts


@dataclass(frozen=True)
class CountedSteps:
    """rate_hz measured; lost: periods counted beyond the steps (samples missing between
    stamps closer than a gap); between: stamps more than BETWEEN periods off their slot;
    jitter_s: robust std of the stamp errors, s; heavy: jitter_s beyond JITTER_TOLERANCE
    periods (stamps reorder; when no period locks either, rate_hz is the steps over their
    time and lost 0)."""

    rate_hz: float
    lost: int
    between: int
    jitter_s: float = 0.0
    heavy: bool = False
    noise: float | None = None  #: 3 sigma of ``lost`` (periods) when fitted to a line

    @property
    def lost_significant(self) -> bool:
        """Whether ``lost`` exceeds its counting noise by more than one: the fitted blocks'
        ``noise``; rounded ones, the rounding noise of the ``between`` stamps (each may count
        one period wrong either way: 3 sigma of sqrt(between) x 0.3)."""
        noise = 0.9 * np.sqrt(self.between) if self.noise is None else self.noise
        return self.lost > 1 + noise


def count_steps(steps_ns: np.ndarray, period_ns: float, gap_factor: float) -> CountedSteps:
    """The rate from stamp steps (ns) with ``period_ns`` the nominal period: steps beyond
    ``gap_factor`` of it (gaps) are left out, their two stamps joined. The periods are counted
    against the median step (the true period within a few % while fewer than half the steps
    span a lost sample), so a stream at another rate is measured at its own rate.

    The jitter is the robust std of the steps shorter than two median steps over sqrt(2) (a
    step is the difference of two stamp errors). Below SMOOTH periods of it each positive step
    is rounded: a wrong count needs a 2.8 sigma step (1 in 200). Above it the stamps are
    counted against the period they line up on (:func:`_lock`), stamps out of order too (they
    telescope), and a line fitted to the counts recounts every stamp (:func:`_refit`). Beyond
    JITTER_TOLERANCE the block is ``heavy`` (counted still while a period locks); when none
    does (from about 0.35 periods) the rate is the steps over their time and ``lost`` 0 (a
    lost sample cannot be told from jitter there)."""
    steps = np.asarray(steps_ns, dtype=float)
    s = steps[(steps > 0) & (steps <= gap_factor * period_ns)]
    if s.size == 0:
        return CountedSteps(1e9 / float(np.median(steps[steps > 0])), 0, 0)
    period = float(np.median(s))
    jitter = float(_jitter(s[s < 2 * period]))
    if jitter <= SMOOTH * period:
        rate, counted, off = _rounded(s, np.asarray(period))
        return CountedSteps(float(rate), int(counted) - s.size, int(off), jitter * 1e-9)
    near = steps[(steps != 0) & (np.abs(steps) <= gap_factor * period_ns)]
    t = np.concatenate([[0.0], np.cumsum(near)])
    counts = _lock(t, period)
    if counts is None:  # no period lines the stamps up: the steps over their time
        return CountedSteps(1e9 * near.size / float(near.sum()), 0, near.size, jitter * 1e-9,
                            heavy=True)
    periods, fitted, between = _refit(t, counts)
    return CountedSteps(1e9 / fitted, periods - near.size, between, jitter * 1e-9,
                        jitter > JITTER_TOLERANCE * period, _fit_noise(jitter / fitted, near.size))


def count_blocks(blocks_ns: np.ndarray, period_ns: float, gap_factor: float
                 ) -> list[CountedSteps]:
    """:func:`count_steps` of each row of ``blocks_ns`` (B, S) stamp steps (ns), the same
    results. Rows of the usual case (every step positive, within the gap and shorter than two
    median steps, jitter below SMOOTH: a steady stream) are counted together, the others one by
    one: the per-row medians are one partition of the block (a policy counts 7,000 blocks per
    hour at 1 kHz; about 20 instead of 65 us a block in pieces of 32 blocks, one core)."""
    steps = np.asarray(blocks_ns, dtype=float).reshape(-1, np.shape(blocks_ns)[-1])
    out: list[CountedSteps | None] = [None] * steps.shape[0]
    plain = np.all((steps > 0) & (steps <= gap_factor * period_ns), axis=1)
    s, plain_rows = steps[plain], np.flatnonzero(plain)
    if s.size:  # the smooth branch of count_steps, where short is s itself
        period = np.median(s, axis=1)
        jitter = _jitter(s)
        smooth = np.all(s < 2 * period[:, None], axis=1) & (jitter <= SMOOTH * period)
        rate, counted, between = _rounded(s, period)
        for k in np.flatnonzero(smooth):
            out[plain_rows[k]] = CountedSteps(float(rate[k]), int(counted[k]) - s.shape[1],
                                              int(between[k]), float(jitter[k]) * 1e-9)
    return [c if c is not None else count_steps(row, period_ns, gap_factor)
            for c, row in zip(out, steps, strict=True)]


def _jitter(short: np.ndarray) -> np.ndarray:
    """Robust std of the stamp errors (ns) from steps (..., S) shorter than two periods: a step
    is the difference of two errors, hence the sqrt(2)."""
    median = np.median(short, axis=-1, keepdims=True)
    return MAD_STD / np.sqrt(2.0) * np.median(np.abs(short - median), axis=-1)


def _rounded(s: np.ndarray, period: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each step (..., S) rounded to whole periods (...): the rate (Hz), the periods counted
    and the steps more than BETWEEN periods off a whole count."""
    ratio = s / period[..., None]
    n = np.rint(ratio)
    counted = n.sum(axis=-1)
    between = np.count_nonzero(np.abs(ratio - n) > BETWEEN, axis=-1)
    return 1e9 * counted / s.sum(axis=-1), counted, between


def _lock(t: np.ndarray, period: float) -> np.ndarray | None:
    """The slot count of each stamp t (ns, from the block's first) against the period T that
    the stamps line up on best: the largest |sum exp(2 pi i t / T)| over T = period / (1 - d),
    |d| <= SEARCH. Lost samples leave the sum as it is (they are absent terms); jitter of
    sigma periods scales it by exp(-2 pi^2 sigma^2) (0.29 of N at 0.25, 0.09 at 0.35). With
    x = t / period the sum is sum exp(2 pi i x) exp(-2 pi i d x); x in the second factor
    rounded to whole periods n (a phase error of at most pi SEARCH) makes it the FFT over n
    of the first factor binned by n, at steps of d below a quarter of a peak width. None when
    the largest is below LOCKED sqrt(N) (a Rayleigh test: random phases exceed it once in e^16
    periods tried)."""
    x = (t - t.min()) / period
    n = np.rint(x).astype(np.intp)
    size = 1 << int(4 * (n.max() + 1) - 1).bit_length()
    w = 2 * np.pi * x
    c = np.bincount(n, np.cos(w), size) + 1j * np.bincount(n, np.sin(w), size)
    spectrum = np.fft.fft(c)
    d = np.fft.fftfreq(size)
    spectrum[np.abs(d) > SEARCH] = 0.0
    best = int(np.argmax(np.abs(spectrum)))
    if abs(spectrum[best]) < LOCKED * np.sqrt(t.size):
        return None
    slots = x * (1.0 - d[best])  # t / T
    return np.rint(slots - np.angle(spectrum[best]) / (2 * np.pi))


def _refit(t: np.ndarray, m: np.ndarray) -> tuple[int, float, int]:
    """Recount the stamps against one line: the slot of each stamp is its count from the
    first, a least-squares line t = a + T m through them gives the period T, and every stamp
    is rounded to that line (REFITS times). A wrong count (a stamp beyond half a period off)
    is that stamp's error alone, not a shift of every later one: the periods spanned are the
    line's slots of the first and last stamp. Returns (periods spanned, period ns, stamps more
    than BETWEEN periods off the line)."""
    for _ in range(REFITS):
        mc = m - m.mean()
        period = float(np.dot(mc, t - t.mean()) / np.dot(mc, mc))
        a = t.mean() - period * m.mean()
        m = np.rint((t - a) / period)
    r = (t - a) / period - m
    return int(m[-1] - m[0]), period, int(np.count_nonzero(np.abs(r) > BETWEEN))


def _fit_noise(jitter: float, size: int) -> float:
    """3 sigma of the periods spanned by a fitted block (periods): the first and last stamp's
    own errors (jitter periods each) and the line's period error over the span."""
    return 3.0 * jitter * np.sqrt(2.0 + 12.0 / size)
