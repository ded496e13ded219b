"""Borgonovo's moment-independent importance delta_i (paper Eq. 9-12) from samples.

delta_i = 1/2 E_{X_i}[ integral |f_Y(y) - f_{Y|X_i}(y)| dy ].

The L1 distance between two sampled densities is estimated as sum_b s_b (p_b - q_b): p, q are
bin probabilities of the two samples on a fine common grid and s = sign(f - g) is taken from a
Gaussian-kernel density estimate (Eq. 16-17) of the *other half* of the samples (cross-fitting).
Why not ``scipy.stats.gaussian_kde`` and the L1 distance of the two KDEs: smoothing can only
shrink an L1 distance, so that estimator is biased low by 0.04-0.09 on Ishigami at the default
(Silverman) bandwidth (gsa_notes section 2). Here the kernel only decides the sign, whose errors
sit next to the crossings where |f - g| is small (a second-order loss), the magnitudes come
unsmoothed from the binned samples, and cross-fitting makes the estimate unbiased given the
signs (an input with no influence gets 0 on average, not a positive noise floor).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage, stats

from railgsa_ros.uq.germ import from_unit, sobol

BINS = 1024  # grid cells across the joint sample range
BANDWIDTH_FACTOR = 0.25  # x Silverman's rule, for the sign of f - g only
TAIL_BANDWIDTHS = 10.0  # zero padding of the smoothing, in kernel bandwidths
CHUNK_ROWS = 128  # (conditional sample, output) rows per pass of l1_distances: 1.2 MB arrays
FOLD = 64  # rows per row of the reduction of _extent
HALVES = (slice(0, None, 2), slice(1, None, 2))  # the cross-fitting halves of a sample's rows


def _silverman(y: np.ndarray) -> np.ndarray:
    """Silverman's rule-of-thumb bandwidth along axis -2 of y (..., N, m): shape (..., m).

    The quartiles are np.percentile's (linear), from one sort along a contiguous axis:
    np.percentile partitions along the strided axis, 3.8 ms against 0.5 ms for (96, 156, 12)
    (measured on one core).
    """
    ys = np.sort(np.moveaxis(y, -2, -1), axis=-1)  # (..., m, N)
    pos = np.array([0.75, 0.25]) * (ys.shape[-1] - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, ys.shape[-1] - 1)
    q75, q25 = np.moveaxis(ys[..., lo] + (ys[..., hi] - ys[..., lo]) * (pos - lo), -1, 0)
    spread = np.minimum(np.std(ys, axis=-1), (q75 - q25) / 1.349)
    return 0.9 * spread * y.shape[-2] ** -0.2


def _probabilities(idx: np.ndarray, bins: int) -> np.ndarray:
    """Bin probabilities of indices idx (..., N, m) per leading group and output (..., m, bins)."""
    lead, (n_rows, m) = idx.shape[:-2], idx.shape[-2:]
    groups = int(np.prod(lead, dtype=int))
    key = (np.arange(groups)[:, None, None] * m + np.arange(m)) * bins + idx.reshape(groups,
                                                                                    n_rows, m)
    counts = np.bincount(key.ravel(), minlength=groups * m * bins)
    return counts.reshape((*lead, m, bins)) / n_rows


def _smooth(diff: np.ndarray, h_bins: np.ndarray) -> np.ndarray:
    """Gaussian smoothing of diff (..., bins) with one bandwidth per row (h_bins (...), in bins).

    scipy.ndimage.gaussian_filter1d takes one sigma per call; the Gaussian's analytic transfer
    function on a zero-padded FFT grid applies a different bandwidth to every row at once.
    Measured: binning + this smoothing of 96 rows of 1562 samples on 1024 points takes 0.05 s,
    scipy.stats.gaussian_kde row by row 15 s (300x, on 2 loaded cores). Each row is padded by
    the first of bins / 8, bins / 4, bins / 2, bins, 2 bins, ... that holds TAIL_BANDWIDTHS of
    its kernel bandwidths: what wraps around the circular grid weighs below
    exp(-TAIL_BANDWIDTHS^2 / 2) of the kernel's peak (below 2 bins, the transfer function's
    cut at the Nyquist frequency leaves a slower tail: 2.5e-6 of the peak wraps at 1 bin).
    Typical rows (h of 1 to 11 bins) take transforms of 1152 instead of 2048 points:
    delta_indices at n_mc 20000 takes 0.065 instead of 0.095 s. The padding depends on the
    row alone, so a row's result does not depend on the rows smoothed with it.
    """
    bins = diff.shape[-1]
    rows, h = diff.reshape(-1, bins), np.ravel(h_bins)
    step = max(bins // 8, 1)
    doublings = np.ceil(np.log2(np.maximum(TAIL_BANDWIDTHS * h / step, 1.0))).astype(np.int64)
    groups = np.unique(doublings)
    if groups.size == 1:  # the usual case, without copies
        return _gaussian_fft(rows, h, step << int(groups[0])).reshape(diff.shape)
    out = np.empty(rows.shape)
    for g in groups:
        pick = doublings == g
        out[pick] = _gaussian_fft(rows[pick], h[pick], step << int(g))
    return out.reshape(diff.shape)


def _gaussian_fft(rows: np.ndarray, h: np.ndarray, pad: int) -> np.ndarray:
    """rows (R, bins) convolved with Gaussians of standard deviation h (R,) bins, by FFT on a
    grid zero-padded by ``pad`` bins (at least, rounded up to a fast transform length)."""
    bins = rows.shape[-1]
    size = sp_fft.next_fast_len(bins + pad, real=True)
    spec = sp_fft.rfft(rows, n=size, axis=-1)
    spec *= np.exp(-2.0 * (np.pi * sp_fft.rfftfreq(size) * h[:, None]) ** 2)
    return sp_fft.irfft(spec, n=size, axis=-1)[:, :bins]


def l1_distances(y_ref: np.ndarray, y_cond: np.ndarray, bins: int | None = None,
                 bandwidth_factor: float | None = None) -> np.ndarray:
    """integral |f_ref - f_cond| for a reference sample y_ref (N, m) and K conditional samples
    y_cond (K, Nc, m): shape (K, m), each value in [0, 2] up to sampling noise.

    Rows 0::2 and 1::2 of each sample are the two cross-fitting halves and must be independent
    of each other (e.g. :func:`paired_sobol` or random rows): the even and odd points of one
    Sobol' sequence are not (measured: L1 = -0.29 for two shifted normals). The conditional
    samples go through in groups of about CHUNK_ROWS (sample, output) rows, so that the
    binned densities and their transforms stay in the cache (each row's result is its own:
    43 instead of 56 ms per delta_indices call at n_mc 20000 and m = 12, measured on one
    core; 512 rows take 72 ms).
    """
    y_ref, y_cond = np.asarray(y_ref, dtype=float), np.asarray(y_cond, dtype=float)
    bins = bins or BINS
    bandwidth_factor = bandwidth_factor or BANDWIDTH_FACTOR
    (ref_lo, ref_hi), (cond_lo, cond_hi) = _extent(y_ref), _extent(y_cond)
    lo, hi = np.minimum(ref_lo, cond_lo), np.maximum(ref_hi, cond_hi)
    width = np.where(hi > lo, (hi - lo) / bins, 1.0)
    grid = (lo, width, bins)
    p = [_probabilities(_bin_index(y_ref[half], grid), bins) for half in HALVES]  # (m, bins)
    step = max(1, CHUNK_ROWS // y_cond.shape[-1])
    dist = np.empty((y_cond.shape[0], y_cond.shape[-1]))
    for k in range(0, y_cond.shape[0], step):
        dist[k:k + step] = _cross_fitted(p, y_cond[k:k + step], grid, bandwidth_factor)
    return np.where(hi > lo, dist, 0.0)


def _extent(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest value (m,) of each column of y (..., m), over every leading axis.

    The rows are reduced FOLD at a time (FOLD m values per row of the reduction): numpy's
    reduction over the rows of a (59904, 12) array runs an inner loop of 12 values per row,
    1.7 ms for its minimum against 0.15 ms folded (one core), the same values.
    """
    rows = y.reshape(-1, y.shape[-1])
    whole = rows.shape[0] // FOLD * FOLD
    out = []
    for reduce in (np.min, np.max):
        parts = [rows[whole:]]
        if whole:
            parts.append(reduce(rows[:whole].reshape(-1, FOLD * rows.shape[1]), axis=0
                                ).reshape(FOLD, -1))
        out.append(reduce(np.concatenate(parts), axis=0))
    return out[0], out[1]


def _bin_index(y: np.ndarray, grid: tuple[np.ndarray, np.ndarray, int]) -> np.ndarray:
    """Bin of every value of y (..., m) on the grid (lower edge (m,), bin width (m,), bins)."""
    lo, width, bins = grid
    return np.clip(((y - lo) / width).astype(np.int64), 0, bins - 1)


def _cross_fitted(p: list[np.ndarray], y_cond: np.ndarray,
                  grid: tuple[np.ndarray, np.ndarray, int], bandwidth_factor: float
                  ) -> np.ndarray:
    """L1 distances (K, m) between the reference halves' bin probabilities p (2 x (m, bins))
    and conditional samples y_cond (K, Nc, m): each half's sign against the other's masses."""
    diffs, widths = [], []
    for p_half, half in zip(p, HALVES, strict=True):
        yc = y_cond[:, half]
        diffs.append(p_half - _probabilities(_bin_index(yc, grid), grid[2]))  # (K, m, bins)
        widths.append(np.maximum(bandwidth_factor * _silverman(yc) / grid[1], 1.0))  # (K, m)
    (d_a, d_b), (h_a, h_b) = diffs, widths
    sign_a, sign_b = np.sign(_smooth(d_a, h_a)), np.sign(_smooth(d_b, h_b))
    return 0.5 * (np.sum(sign_a * d_b, axis=-1) + np.sum(sign_b * d_a, axis=-1))


def paired_sobol(n: int, size: int, seed: int | None, germ: str) -> np.ndarray:
    """Two independently scrambled Sobol' sets in germ space, interleaved by row: (2 size, n).

    Quasi-random samples make the binned densities far less noisy than random ones for the same
    surrogate cost; two independent scrambles keep the cross-fitted halves independent.
    """
    rng = np.random.default_rng(seed)
    a, b = (sobol(n, size, rng, germ) for _ in range(2))
    return np.stack([a, b], axis=1).reshape(2 * size, n)


@dataclass(frozen=True)
class DeltaDesign:
    """Germ points of the double-loop estimate of :func:`delta_indices`: ``ref`` (N, n)
    reference samples, ``cond`` (n, n_outer, n_inner, n) with input i fixed at stratum k in
    ``cond[i, k]``."""

    ref: np.ndarray
    cond: np.ndarray


def delta_design(n: int, n_mc: int = 100_000, n_outer: int = 32, seed: int | None = 0,
                 germ: str = 'hermite') -> DeltaDesign:
    """The germ points :func:`delta_indices` evaluates (the same ones for the same arguments
    unless ``seed`` is None): n_mc reference samples; for each input, n_outer fixed values at
    the midpoints of equal-probability strata of xi_i times n_mc // n_outer inner samples of
    the others (common random numbers across strata)."""
    ref = paired_sobol(n, n_mc // 2, seed, germ)
    inner_seed = None if seed is None else seed + 1
    inner = paired_sobol(n, max(n_mc // (2 * n_outer), 8), inner_seed, germ)
    nodes = from_unit((np.arange(n_outer) + 0.5) / n_outer, germ)
    cond = np.broadcast_to(inner, (n, n_outer, *inner.shape)).copy()
    cond[np.arange(n), :, :, np.arange(n)] = nodes[:, None]
    return DeltaDesign(ref, cond)


def delta_from_outputs(y_ref: np.ndarray, y_cond: np.ndarray) -> np.ndarray:
    """delta (m, n) from outputs at the points of a :class:`DeltaDesign`: y_ref (N, m) at
    ``ref``, y_cond (n, n_outer, n_inner, m) at ``cond``."""
    n, n_outer, n_inner = y_cond.shape[:3]
    dist = l1_distances(y_ref, y_cond.reshape(n * n_outer, n_inner, -1)).reshape(n, n_outer, -1)
    return np.clip(0.5 * dist.mean(axis=1).T, 0.0, 1.0)


def delta_indices(func: Callable[[np.ndarray], np.ndarray], n: int, n_mc: int = 100_000,
                  n_outer: int = 32, seed: int | None = 0, germ: str = 'hermite') -> np.ndarray:
    """delta_i of a function of germ inputs (independent), func: xi (N, n) -> (N, m); (m, n).

    Double loop on a cheap function (a surrogate) at the points of :func:`delta_design`.
    """
    design = delta_design(n, n_mc, n_outer, seed, germ)
    y_ref = np.atleast_2d(func(design.ref).T).T
    y_cond = np.atleast_2d(func(design.cond.reshape(-1, n)).T).T
    return delta_from_outputs(y_ref, y_cond.reshape(*design.cond.shape[:3], -1))


def delta_given_data(x: np.ndarray, y: np.ndarray, bins: int | None = None,
                     smooth: float = 2.0, seed: int | None = 0) -> np.ndarray:
    """delta_i from one sample of inputs x (N, n) and outputs y (N, m), no model: (m, n).

    With u = F_i(x_i), v = F_Y(y) (ranks), f(x, y) = c(u, v) f(x) f(y), so
    delta_i = 1/2 integral |c(u, v) - 1| du dv: the copula density of (X_i, Y) against 1. The
    same cross-fitted estimator on a bins x bins rank grid (default 2 N^(1/3)): sign from one
    random half smoothed by ``smooth`` cells (scipy.ndimage.gaussian_filter), cell
    probabilities from the other. Neighbouring x-classes share the smoothing, which is what
    makes it better than independent classes at brute-force sample sizes; it is still biased
    low for peaky conditional densities (Ishigami, N = 16384: about -0.03).
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float).reshape(len(x), -1)
    n_rows, n, m = x.shape[0], x.shape[1], y.shape[1]
    bins = bins or round(2 * n_rows ** (1 / 3))
    iu = (stats.rankdata(x, axis=0, method='ordinal').astype(np.int64) - 1) * bins // n_rows
    iv = (stats.rankdata(y, axis=0, method='ordinal').astype(np.int64) - 1) * bins // n_rows
    perm = np.random.default_rng(seed).permutation(n_rows)
    pair = np.arange(n)[:, None] * m + np.arange(m)  # (n, m)
    diffs = []
    for half in (perm[0::2], perm[1::2]):
        key = (pair * bins + iu[half][:, :, None]) * bins + iv[half][:, None, :]
        counts = np.bincount(key.ravel(), minlength=n * m * bins * bins)
        diffs.append(counts.reshape(n, m, bins, bins) / len(half) - 1.0 / bins ** 2)
    sign_a, sign_b = (np.sign(ndimage.gaussian_filter(d, sigma=(0, 0, smooth, smooth)))
                      for d in diffs)
    total = 0.5 * (np.sum(sign_a * diffs[1], axis=(-2, -1))
                   + np.sum(sign_b * diffs[0], axis=(-2, -1)))
    return np.clip(0.5 * total.T, 0.0, 1.0)
