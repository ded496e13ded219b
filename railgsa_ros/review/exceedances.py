"""Isolated-defect exceedances of the EN 13848-5 limits along a reconstructed run.

The band-filtered reconstruction has zero mean, so its magnitude |u| is the mean-to-peak value.
With an uncertainty band [lower, upper] each sample has a nearest and a farthest magnitude (the
band's closest point to zero and its farthest one): an exceedance is a stretch of chainage where
the farthest magnitude passes the alert limit, merged over interruptions shorter than
``merge_m`` on the same side of zero. Its level is that of the central estimate; its confidence
says what the band adds:

- ``certain``: the whole band passes the same limit;
- ``likely``: the central estimate passes it, the band reaches below it;
- ``possible``: only the band's far edge passes a limit (level = that limit).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from railgsa_ros.review.limits import LEVELS, Limits

CONFIDENCES = ('certain', 'likely', 'possible')


@dataclass(frozen=True)
class Exceedance:
    """One isolated defect beyond a limit: level (AL/IL/IAL), confidence, chainage start, end
    and peak (m), stamp of the peak (ns), signed central value and band at the peak (m), the
    limit passed (m) and the speed at the peak (km/h)."""

    level: str
    confidence: str
    start_m: float
    end_m: float
    peak_m: float
    peak_stamp_ns: int
    peak_u_m: float
    lower_m: float
    upper_m: float
    limit_m: float
    speed_kmh: float

    @property
    def severity(self) -> int:
        """1 (AL), 2 (IL), 3 (IAL)."""
        return LEVELS.index(self.level) + 1


def magnitudes(u: np.ndarray, lower: np.ndarray | None = None,
               upper: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(nearest, farthest) |value| (K,) over the interval spanned by u, lower and upper (m)."""
    u = np.asarray(u, dtype=float)
    if lower is None or upper is None:
        return np.abs(u), np.abs(u)
    lo = np.minimum(np.minimum(lower, upper), u)
    hi = np.maximum(np.maximum(lower, upper), u)
    near = np.where((lo > 0) | (hi < 0), np.minimum(np.abs(lo), np.abs(hi)), 0.0)
    return near, np.maximum(np.abs(lo), np.abs(hi))


def levels(magnitude: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Highest level passed per sample (K,): 0 none, 1 AL, 2 IL, 3 IAL; NaN limits never pass."""
    with np.errstate(invalid='ignore'):
        passed = magnitude[:, None] > thresholds
    return np.max(np.where(passed, np.arange(1, 4), 0), axis=1, initial=0)


def _runs(mask: np.ndarray, chainage: np.ndarray, sign: np.ndarray,
          merge_m: float) -> tuple[np.ndarray, ...]:
    """Sample indices of the masked samples, and for each run its first position in them: a
    run ends where the sign changes or the next masked sample lies more than merge_m away."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return idx, idx
    split = ((np.diff(idx) > 1) & (np.diff(chainage[idx]) > merge_m)) | \
        (np.diff(sign[idx]) != 0)
    return idx, np.concatenate([[0], np.flatnonzero(split) + 1])


def find_exceedances(chainage_m: np.ndarray, u_m: np.ndarray, speed_mps: np.ndarray,
                     stamps_ns: np.ndarray, limits: Limits, lower_m: np.ndarray | None = None,
                     upper_m: np.ndarray | None = None, merge_m: float = 1.0
                     ) -> list[Exceedance]:
    """Exceedances along a run (all inputs (K,), chainage increasing), in chainage order."""
    u = np.asarray(u_m, dtype=float)
    thresholds = limits.at(speed_mps)
    near, far = magnitudes(u, lower_m, upper_m)
    lvl_c, lvl_near, lvl_far = (levels(m, thresholds) for m in (np.abs(u), near, far))
    idx, starts = _runs(lvl_far > 0, np.asarray(chainage_m), np.sign(u), merge_m)
    if idx.size == 0:
        return []
    run = np.repeat(np.arange(starts.size), np.diff(np.concatenate([starts, [idx.size]])))
    worst_c, worst_near, worst_far = (np.maximum.reduceat(x[idx], starts)
                                      for x in (lvl_c, lvl_near, lvl_far))
    # peak: largest central magnitude in the run; when it passes nothing, the farthest edge
    key = np.where(worst_c[run] > 0, np.abs(u[idx]), far[idx])
    peak = idx[np.lexsort((-key, run))[starts]]
    ends = idx[np.concatenate([starts[1:], [idx.size]]) - 1]
    lo = u if lower_m is None else np.asarray(lower_m, dtype=float)
    hi = u if upper_m is None else np.asarray(upper_m, dtype=float)
    out = []
    for r in range(starts.size):
        level = worst_c[r] if worst_c[r] > 0 else worst_far[r]
        confidence = ('possible' if worst_c[r] == 0 else
                      'certain' if worst_near[r] >= worst_c[r] else 'likely')
        k = peak[r]
        out.append(Exceedance(LEVELS[level - 1], confidence, float(chainage_m[idx[starts[r]]]),
                              float(chainage_m[ends[r]]), float(chainage_m[k]),
                              int(stamps_ns[k]), float(u[k]), float(lo[k]), float(hi[k]),
                              float(thresholds[k, level - 1]), float(abs(speed_mps[k]) * 3.6)))
    return out


def count_by_level(exceedances: list[Exceedance]) -> dict[str, Counter[str]]:
    """Level -> Counter of confidences, every level present (empty counters included)."""
    counts: dict[str, Counter[str]] = {level: Counter() for level in LEVELS}
    for e in exceedances:
        counts[e.level][e.confidence] += 1
    return counts


def describe_counts(exceedances: list[Exceedance]) -> dict[str, str]:
    """Level -> 'n' or 'n (a certain, b likely, c possible)', most severe level first."""
    out = {}
    for level, counts in reversed(count_by_level(exceedances).items()):
        parts = ', '.join(f'{counts[c]} {c}' for c in CONFIDENCES if counts[c])
        total = sum(counts.values())
        out[level] = f'{total} ({parts})' if total else '0'
    return out
