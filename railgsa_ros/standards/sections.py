"""EN 13848-5 standard deviation of the band-filtered irregularity per fixed section of track
(200 m).

The signal is resampled to distance (cells of ``dx`` m, EN 13848 samples at <= 0.5 m); a cell
counts when the samples around it lie less than ``max_step_m`` apart, so a gap in the data is
not bridged. Section k covers [k L, (k + 1) L) of chainage; its SD is taken over the valid cells
(mean removed) when they cover at least ``min_coverage`` of it, else NaN. Such short sections at
either end of the run are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SECTION_M = 200.0
DX_M = 0.25
BLOCK = 1 << 20  # cells per bincount


@dataclass(frozen=True)
class Sections:
    """Sections of ``length_m`` (m): start chainage (S,), SD (S,) m (NaN when short of data),
    covered fraction (S,), mean speed (S,) m/s (NaN without data)."""

    length_m: float
    start_m: np.ndarray
    sd_m: np.ndarray
    coverage: np.ndarray
    speed_mps: np.ndarray

    def __len__(self) -> int:
        return int(self.start_m.size)


def resample(chainage_m: np.ndarray, u_m: np.ndarray, dx: float = DX_M,
             max_step_m: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x (N,), u (N,), valid (N,)) on cells of dx m centred at (i + 1/2) dx from chainage 0;
    cells next to an INVALID (NaN) sample are not valid."""
    c = np.asarray(chainage_m, dtype=float)
    first, last = int(np.floor(c[0] / dx)), int(np.ceil(c[-1] / dx))
    x = (np.arange(first, last) + 0.5) * dx
    right = np.clip(np.searchsorted(c, x), 1, c.size - 1)
    valid = (x >= c[0]) & (x <= c[-1]) & (c[right] - c[right - 1] < max_step_m)
    u = np.interp(x, c, u_m)
    return x, u, valid & np.isfinite(u)


def section_sd(chainage_m: np.ndarray, u_m: np.ndarray, speed_mps: np.ndarray | None = None,
               length_m: float = SECTION_M, dx: float = DX_M, min_coverage: float = 0.5,
               max_step_m: float = 1.0) -> Sections:
    """SD per section of a signal u (K,) m at increasing chainage (K,) m (speeds (K,) m/s)."""
    c = np.asarray(chainage_m, dtype=float)
    if c.size < 2:
        return Sections(length_m, *(np.zeros(0) for _ in range(4)))
    speeds = None
    if speed_mps is not None:
        speeds = SectionSpeeds(length_m)
        speeds.push(c, speed_mps)
    return grid_sections(*resample(c, u_m, dx, max_step_m), speeds, length_m, dx, min_coverage)


class SectionSpeeds:
    """Mean |speed| (m/s) per section of the samples' chainage, accumulated chunk by chunk."""

    def __init__(self, length_m: float = SECTION_M) -> None:
        self.length_m = float(length_m)
        self._sums: dict[int, list[float]] = {}  # section index -> [sum |v|, count]

    def push(self, chainage_m: np.ndarray, speed_mps: np.ndarray) -> None:
        """Samples (K,)."""
        c = np.asarray(chainage_m, dtype=float)
        ok = np.isfinite(c)
        if not ok.any():
            return
        which, inverse = np.unique(np.floor(c[ok] / self.length_m).astype(np.int64),
                                   return_inverse=True)
        sums = np.bincount(inverse, np.abs(np.asarray(speed_mps, float)[ok]), which.size)
        counts = np.bincount(inverse, minlength=which.size)
        for k, total, n in zip(which.tolist(), sums.tolist(), counts.tolist(), strict=True):
            acc = self._sums.setdefault(k, [0.0, 0])
            acc[0] += total
            acc[1] += n

    def means(self, first: int, count: int) -> np.ndarray:
        """Mean speed of sections first .. first + count - 1 (samples outside the range count
        for the end sections; NaN without samples)."""
        sums, counts = np.zeros(count), np.zeros(count)
        for k, (total, n) in self._sums.items():
            i = min(max(k - first, 0), count - 1)
            sums[i] += total
            counts[i] += n
        with np.errstate(invalid='ignore', divide='ignore'):
            return sums / counts


def grid_sections(x: np.ndarray, u: np.ndarray, valid: np.ndarray,
                  speeds: SectionSpeeds | None = None, length_m: float = SECTION_M,
                  dx: float = DX_M, min_coverage: float = 0.5) -> Sections:
    """SD per section of a signal on cells of dx m (centres x (N,), values u (N,), valid (N,));
    the section speeds from ``speeds`` (NaN without)."""
    if x.size == 0:
        return Sections(length_m, *(np.zeros(0) for _ in range(4)))
    first = int(np.floor(x[0] / length_m))
    n_sec = int(np.floor(x[-1] / length_m)) - first + 1
    n, s1, s2 = np.zeros(n_sec), np.zeros(n_sec), np.zeros(n_sec)
    for lo in range(0, x.size, BLOCK):  # in blocks: a few MB at a time, whatever the run
        ok = valid[lo:lo + BLOCK]
        which = np.floor(x[lo:lo + BLOCK][ok] / length_m).astype(np.int64) - first
        values = u[lo:lo + BLOCK][ok]
        n += np.bincount(which, minlength=n_sec)
        s1 += np.bincount(which, values, minlength=n_sec)
        s2 += np.bincount(which, values ** 2, minlength=n_sec)
    coverage = n * dx / length_m
    with np.errstate(invalid='ignore', divide='ignore'):
        mean = s1 / n
        sd = np.sqrt(np.maximum(s2 / n - mean ** 2, 0.0))
    speed = np.full(n_sec, np.nan) if speeds is None else speeds.means(first, n_sec)
    short = coverage < min_coverage
    sd[short] = np.nan
    kept = np.flatnonzero(~short)
    keep = slice(kept[0], kept[-1] + 1) if kept.size else slice(0, 0)
    return Sections(length_m, (first + np.arange(n_sec))[keep] * length_m, sd[keep],
                    coverage[keep], speed[keep])
