"""Isolated defects in one pass on the line grid, and the same defect across passes.

A defect is a local peak of |u| (mean-to-peak of the band-filtered profile, as EN 13848-5)
above ``DETECT_FRACTION`` of the alert limit of the speed range there (``standards.en13848``),
at least ``MIN_SEP_M`` from a larger one (scipy.signal.find_peaks); its position and depth are
refined by a parabola through the peak cell and its neighbours. Detections of different passes
are the same defect when they have the same sign and lie within ``TOLERANCE_M`` of it (matched
in time order, each to the nearest defect; a defect's position is the mean of its detections).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import find_peaks

from railgsa_ros.standards.en13848 import Limits

DETECT_FRACTION = 0.5  # of the alert limit: defects are followed well before they reach it
MIN_SEP_M = 5.0
TOLERANCE_M = 2.0


@dataclass(frozen=True)
class Peak:
    """A peak at line chainage x (m): depth |u| (m), signed value (m), cell index in the pass."""

    x_m: float
    depth_m: float
    signed_m: float
    index: int


def _refine(mag: np.ndarray, k: int, dx: float) -> tuple[float, float]:
    """(sub-cell offset (m), peak value) of a parabola through mag[k-1:k+2]."""
    if 0 < k < mag.size - 1:
        a, b, c = mag[k - 1], mag[k], mag[k + 1]
        denom = a - 2 * b + c
        if denom < 0:
            d = 0.5 * (a - c) / denom
            return d * dx, b - 0.25 * (a - c) * d
    return 0.0, float(mag[k])


def detect(cells: np.ndarray, u_m: np.ndarray, valid: np.ndarray, speed_mps: np.ndarray,
           dx: float, limits: Limits, fraction: float = DETECT_FRACTION,
           min_sep_m: float = MIN_SEP_M) -> list[Peak]:
    """Peaks of |u| above ``fraction`` of the alert limit at each cell (line position cell * dx
    m, measured speed m/s)."""
    threshold = fraction * limits.at(np.asarray(cells) * dx, speed_mps)[:, 0]
    mag = np.where(valid & np.isfinite(threshold), np.abs(u_m), 0.0)
    found, _ = find_peaks(mag, height=np.nan_to_num(threshold, nan=np.inf),
                          distance=max(int(min_sep_m / dx), 1))
    out = []
    for k in found:
        shift, depth = _refine(mag, int(k), dx)
        out.append(Peak(float(cells[k] * dx + shift), float(depth), float(u_m[k]), int(k)))
    return out


def measure(cells: np.ndarray, u_m: np.ndarray, valid: np.ndarray, dx: float, x_m: float,
            sign: float, tol_m: float = TOLERANCE_M) -> Peak | None:
    """The largest value of sign * u within +-tol_m of x (the defect as this pass sees it, found
    or not); None when the pass does not cover that stretch with valid cells."""
    lo, hi = np.searchsorted(cells, [round((x_m - tol_m) / dx), round((x_m + tol_m) / dx) + 1])
    if hi - lo < 3 or not valid[lo:hi].all():
        return None
    signed = sign * u_m[lo:hi]
    k = int(np.argmax(signed))
    shift, depth = _refine(signed, k, dx)
    return Peak(float(cells[lo + k] * dx + shift), float(depth), float(u_m[lo + k]), lo + k)


def match(x_m: np.ndarray, sign: np.ndarray, tol_m: float = TOLERANCE_M) -> np.ndarray:
    """Defect index (D,) of each of D detections given in time order (module docstring)."""
    ids = np.empty(len(x_m), dtype=np.int64)
    centres: list[list[float]] = []  # per defect: sum of x, count, sign
    for i, (x, s) in enumerate(zip(x_m, sign, strict=True)):
        best, dist = -1, tol_m
        for j, (sx, n, sj) in enumerate(centres):
            if sj == s and abs(sx / n - x) <= dist:
                best, dist = j, abs(sx / n - x)
        if best < 0:
            centres.append([x, 1, s])
            best = len(centres) - 1
        else:
            centres[best][0] += x
            centres[best][1] += 1
        ids[i] = best
    return ids
