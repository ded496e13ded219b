"""Put a pass on its line's chainage: x = offset + scale * s (s: odometry chainage of the pass).

The reference is the line's profile on the common grid (its first pass, later the fused
profile). Alignment by cross-correlation of the band-filtered profiles, in two steps:

1. coarse: one long stretch of the pass (``COARSE_M``) against the whole reference, or within a
   GNSS prior's search range, by normalised cross-correlation over every lag (``masked_ncc``).
   With a GNSS prior the stretch is the one the prior puts on the reference; without, the
   pass's start and up to ``COARSE_TRIES`` - 1 later stretches are tried (a pass may begin off
   the reference);
2. tracking: the pass in windows of ``WINDOW_M``, each resampled with the current estimate and
   searched within +-``FINE_M`` of where the fit so far puts it; the peak lag is refined to a
   fraction of a cell by a parabola through the three best lags. A straight line fitted through
   the window positions (numpy.polynomial, least squares) gives offset and scale with their
   covariance from the residual scatter; the tracking runs twice (the second time with the
   fitted scale, so no window is smeared by an odometry scale error).

Windows whose correlation stays below ``MIN_NCC`` are left out; with fewer than ``MIN_WINDOWS``
the pass is reported as not aligned rather than placed by a guess.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import correlate

COARSE_M = 400.0
COARSE_TRIES = 4  # coarse stretches tried without a prior placing the pass
WINDOW_M = 100.0
FINE_M = 4.0
MIN_NCC = 0.6
MIN_WINDOWS = 3
MIN_OVERLAP = 0.8  # share of a window that must overlap valid reference cells


@dataclass(frozen=True)
class Alignment:
    """x = offset_m + scale * s (m). Covariance (2, 2) of (offset, scale); method 'origin' (the
    line's first pass: its frame defines the line), 'xcorr', 'gnss' or 'gnss+xcorr'; median
    window correlation and the number of windows used (0 without cross-correlation)."""

    offset_m: float
    scale: float
    cov: np.ndarray
    method: str
    correlation: float = float('nan')
    windows: int = 0

    def position(self, s_m: np.ndarray | float) -> np.ndarray:
        """Line chainage (m) of odometry chainages s (m)."""
        return self.offset_m + self.scale * np.asarray(s_m, dtype=float)

    def position_sd(self, s_m: np.ndarray | float) -> np.ndarray:
        """Standard deviation (m) of ``position(s)`` from the alignment covariance."""
        s = np.asarray(s_m, dtype=float)
        c = self.cov
        return np.sqrt(np.maximum(c[0, 0] + 2 * s * c[0, 1] + s * s * c[1, 1], 0.0))

    @property
    def offset_sd_m(self) -> float:
        """SD of the offset (m)."""
        return float(np.sqrt(self.cov[0, 0]))

    @property
    def scale_sd(self) -> float:
        """SD of the scale (m/m)."""
        return float(np.sqrt(self.cov[1, 1]))


def origin(offset_m: float, direction: str) -> Alignment:
    """The frame of a line's first pass: offset at the km-post, scale +1 (km-posts
    'increasing' along the run) or -1 ('decreasing'), no uncertainty."""
    return Alignment(offset_m, -1.0 if direction == 'decreasing' else 1.0, np.zeros((2, 2)),
                     'origin')


def on_line_grid(s_m: np.ndarray, columns: tuple[np.ndarray, ...], valid: np.ndarray,
                 alignment: Alignment, dx: float
                 ) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """A pass resampled on the line's grid: cells (M,) int64 (centre at cell * dx m), each
    column (odometry grid (N,)) linearly interpolated there (M,), and valid (M,) (both odometry
    cells around a grid cell valid)."""
    x = alignment.position(s_m)
    order = np.argsort(x, kind='stable')
    x, ok = x[order], np.asarray(valid)[order]
    cells = np.arange(int(np.ceil(x[0] / dx)), int(np.floor(x[-1] / dx)) + 1, dtype=np.int64)
    xc = cells * dx
    right = np.clip(np.searchsorted(x, xc), 1, x.size - 1)
    return (cells, [np.interp(xc, x, np.asarray(col, dtype=float)[order]) for col in columns],
            ok[right] & ok[right - 1])


def masked_ncc(ref: np.ndarray, ref_ok: np.ndarray, win: np.ndarray, win_ok: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Normalised cross-correlation (L,) of ``win`` (n,) at every lag inside ``ref`` (n + L - 1,),
    invalid cells of either left out (Padfield's masked form), and the overlap counts (L,)."""
    r, w = np.where(ref_ok, ref, 0.0), np.where(win_ok, win, 0.0)
    mr, mw = ref_ok.astype(float), win_ok.astype(float)
    num = correlate(r, w, 'valid')
    energy_r = correlate(r * r, mw, 'valid')
    energy_w = correlate(mr, w * w, 'valid')
    overlap = correlate(mr, mw, 'valid')
    with np.errstate(invalid='ignore', divide='ignore'):
        ncc = num / np.sqrt(energy_r * energy_w)
    return np.where(np.isfinite(ncc), ncc, -1.0), overlap


def _peak(ncc: np.ndarray) -> float:
    """Index of the maximum refined by a parabola through it and its neighbours."""
    k = int(np.argmax(ncc))
    if 0 < k < ncc.size - 1:
        a, b, c = ncc[k - 1], ncc[k], ncc[k + 1]
        denom = a - 2 * b + c
        if denom < 0:
            return k + 0.5 * (a - c) / denom
    return float(k)


@dataclass(frozen=True)
class Reference:
    """A line's profile on the common grid: first cell, values (N,) m, valid (N,), step (m)."""

    first_cell: int
    u_m: np.ndarray
    valid: np.ndarray
    dx: float

    def segment(self, x_lo: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n cells from the cell at x_lo (m); cells outside the reference are invalid."""
        idx = round(x_lo / self.dx) - self.first_cell + np.arange(n)
        inside = (idx >= 0) & (idx < self.u_m.size)
        safe = np.clip(idx, 0, max(self.u_m.size - 1, 0))
        return np.where(inside, self.u_m[safe], 0.0), inside & self.valid[safe]


def _match(ref: Reference, s: np.ndarray, u: np.ndarray, ok: np.ndarray, offset: float,
           scale: float, search_m: float) -> tuple[float, float] | None:
    """Shift (m) that best moves the stretch (s, u, ok), placed by (offset, scale), onto the
    reference within +-search_m, and its correlation; None without enough overlap."""
    dx = ref.dx
    ends = offset + scale * np.array([s[0], s[-1]])
    first = int(np.floor(ends.min() / dx))
    grid_x = (first + np.arange(int(np.ceil(ends.max() / dx)) - first + 1)) * dx
    s_at = (grid_x - offset) / scale
    step = (s[-1] - s[0]) / max(s.size - 1, 1)
    near = np.clip(np.rint((s_at - s[0]) / step).astype(int), 0, s.size - 1)
    win_ok = (s_at >= s[0]) & (s_at <= s[-1]) & ok[near]
    win = np.interp(s_at, s, u)
    lags = int(np.ceil(search_m / dx))
    seg, seg_ok = ref.segment(grid_x[0] - lags * dx, grid_x.size + 2 * lags)
    ncc, overlap = masked_ncc(seg, seg_ok, win, win_ok)
    ncc = np.where(overlap >= MIN_OVERLAP * max(win_ok.sum(), 1), ncc, -1.0)
    if ncc.max() <= -1.0:
        return None
    return (_peak(ncc) - lags) * dx, float(np.max(ncc))


def _coarse_starts(ref: Reference, s_m: np.ndarray, n0: int, prior: Alignment,
                   placed: bool) -> list[int]:
    """First cells of the stretches to try for the coarse match: with a placing prior (GNSS),
    the one that overlaps the reference most where the prior puts it; otherwise the start of
    the pass and up to COARSE_TRIES - 1 later stretches (a pass may begin off the reference)."""
    last = s_m.size - n0
    if placed:
        lo, hi = ref.first_cell * ref.dx, (ref.first_cell + ref.u_m.size) * ref.dx
        x = np.sort(prior.position(s_m[[0, n0 - 1]]))
        starts = np.linspace(0, last, max(min(last // max(n0 // 4, 1), 64), 1) + 1).astype(int)
        shifted = prior.scale * (s_m[starts] - s_m[0])
        overlap = np.minimum(x[1] + shifted, hi) - np.maximum(x[0] + shifted, lo)
        return [int(starts[np.argmax(overlap)])]
    return sorted({int(j) for j in np.linspace(0, last, COARSE_TRIES)})


def _fit(s_c: np.ndarray, x_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares line x = a + b s: coefficients (a, b) and their covariance (2, 2) from the
    residual scatter (numpy.polynomial; at least three points)."""
    coef, (resid, *_) = np.polynomial.polynomial.polyfit(s_c, x_c, 1, full=True)
    design = np.column_stack([np.ones_like(s_c), s_c])
    dof = max(s_c.size - 2, 1)
    sigma2 = float(resid[0]) / dof if np.size(resid) else 0.0
    return coef, sigma2 * np.linalg.inv(design.T @ design)


def xcorr_align(ref: Reference, s_m: np.ndarray, u_m: np.ndarray, valid: np.ndarray,
                prior: Alignment, search_m: float | None = None) -> Alignment | None:
    """Refine ``prior`` (offset, scale) by cross-correlation against ``ref`` (module docstring);
    ``search_m``: coarse search range around the prior (None: the whole reference). None when
    the pass does not match the reference."""
    dx = ref.dx
    step = float(np.median(np.diff(s_m)))
    offset, scale = prior.offset_m, prior.scale
    n0 = min(s_m.size, int(COARSE_M / step))
    coarse = None
    for j in _coarse_starts(ref, s_m, n0, prior, search_m is not None):
        sl = slice(j, j + n0)
        if search_m is None:  # the whole reference: centre the stretch on it, search its length
            span = (ref.u_m.size + n0) * dx
            low = min(scale * s_m[j], scale * s_m[j + n0 - 1])
            hit = _match(ref, s_m[sl], u_m[sl], valid[sl],
                         ref.first_cell * dx - n0 * dx + span / 2 - low, scale, span / 2)
            if hit is not None:
                hit = (hit[0] + ref.first_cell * dx - n0 * dx + span / 2 - low - offset, hit[1])
        else:
            hit = _match(ref, s_m[sl], u_m[sl], valid[sl], offset, scale, search_m)
        if hit is not None and hit[1] >= MIN_NCC:
            coarse = hit
            break
    if coarse is None:
        return None
    offset += coarse[0]
    n_win = max(int(WINDOW_M / step), 8)
    starts = np.arange(0, s_m.size - n_win + 1, n_win)
    for _ in range(2):
        s_c: list[float] = []
        x_c: list[float] = []
        r_c: list[float] = []
        for j in starts.tolist():
            sl = slice(j, j + n_win)
            if valid[sl].mean() < MIN_OVERLAP:
                continue
            if len(s_c) >= 2:  # predict from the windows so far
                coef, _cov = _fit(np.array(s_c), np.array(x_c))
                off_j, scale_j = coef[0], coef[1]
            else:
                off_j, scale_j = offset, scale
            hit = _match(ref, s_m[sl], u_m[sl], valid[sl], off_j, scale_j, FINE_M)
            if hit is None or hit[1] < MIN_NCC:
                continue
            centre = s_m[j + n_win // 2]
            s_c.append(centre)
            x_c.append(off_j + scale_j * centre + hit[0])
            r_c.append(hit[1])
        if len(s_c) < MIN_WINDOWS:
            return None
        coef, cov = _fit(np.array(s_c), np.array(x_c))
        offset, scale = float(coef[0]), float(coef[1])
    method = 'xcorr' if prior.method in ('origin', 'xcorr') else prior.method + '+xcorr'
    return Alignment(offset, scale, cov, method, float(np.median(r_c)), len(s_c))
