"""Scoring a reconstruction against the true irregularity on distance, in an EN 13848 band.

Both signals are resampled to a common distance grid and reach the score in the band exactly
once: the truth through the zero-phase band-pass |BP|^2 in wavenumber, a pipeline output as
emitted (it already is the band signal) or, with ``band_rec=True``, through the same band-pass.
The ends, where the filters see the record's edges, are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft

from railgsa_ros.inverse.band import BANDS_M, bandpass_power
from railgsa_ros.vehicle import VehicleParams, frequency_response


@dataclass(frozen=True)
class Score:
    """RMSE (m), correlation, peak error (m) at a defect (NaN when none given), samples scored."""

    rmse: float
    correlation: float
    peak_error: float
    n: int


def band_distance(u: np.ndarray, dx: float, band: str = 'd1', order: int = 2) -> np.ndarray:
    """Zero-phase band-pass |BP|^2 of a profile sampled every dx m (wavelength band ``band``)."""
    lmin, lmax = BANDS_M[band]
    n = fft.next_fast_len(2 * u.size, real=True)  # zero padding against wrap-around
    k = fft.rfftfreq(n, dx)  # 1/m
    return fft.irfft(fft.rfft(u, n) * bandpass_power(k, 1 / lmax, 1 / lmin, order), n)[:u.size]


def exact_inverse(stamps_ns: np.ndarray, a_s: np.ndarray, speed_mps: float, band: str = 'd1',
                  order: int = 2, vehicle: VehicleParams | np.ndarray | None = None
                  ) -> np.ndarray:
    """Exact-physics baseline (m) at the stamps: the whole record, linearly resampled to its
    median period (fills dropouts), FFT divided by G(j w) and band-limited at a constant speed."""
    theta = VehicleParams().as_array() if vehicle is None else np.asarray(vehicle)
    t = (np.asarray(stamps_ns) - stamps_ns[0]) * 1e-9
    dt = float(np.median(np.diff(t)))
    grid = np.arange(0.0, t[-1] + dt / 2, dt)
    a_u = np.interp(grid, t, a_s)
    lmin, lmax = BANDS_M[band]
    n = fft.next_fast_len(2 * grid.size, real=True)
    f = fft.rfftfreq(n, dt)
    bp = bandpass_power(f, speed_mps / lmax, speed_mps / lmin, order)
    w = np.zeros(f.size, complex)
    w[1:] = bp[1:] / frequency_response(theta, 2j * np.pi * f[1:])
    u = fft.irfft(fft.rfft(a_u - np.mean(a_u), n) * w, n)[:grid.size]
    return np.interp(t, grid, u)


def score(chainage_rec: np.ndarray, u_rec: np.ndarray, chainage_true: np.ndarray,
          u_true: np.ndarray, band: str = 'd1', dx: float = 0.25, margin_m: float = 100.0,
          defect: tuple[float, float] | None = None, band_rec: bool = False) -> Score:
    """Score u_rec (m) at chainage_rec (m) against u_true at chainage_true in ``band``.

    ``defect`` = (start, length) m: peak error = |extreme of the reconstruction - extreme of the
    band-passed truth| over the defect +- one length. ``margin_m`` is left out at both ends.
    """
    lo = max(chainage_rec[0], chainage_true[0])
    hi = min(chainage_rec[-1], chainage_true[-1])
    x = np.arange(lo, hi, dx)
    truth = band_distance(np.interp(x, chainage_true, u_true), dx, band)
    rec = np.interp(x, chainage_rec, u_rec)
    if band_rec:
        rec = band_distance(rec, dx, band)
    keep = (x >= lo + margin_m) & (x <= hi - margin_m)
    err = rec[keep] - truth[keep]
    peak = float('nan')
    if defect is not None:
        start, length = defect
        win = (x >= start - length) & (x <= start + 2 * length)
        i = np.argmax(np.abs(truth[win]))
        j = np.argmax(np.abs(rec[win]))
        peak = float(abs(rec[win][j] - truth[win][i]))
    return Score(float(np.sqrt(np.mean(err ** 2))),
                 float(np.corrcoef(rec[keep], truth[keep])[0, 1]), peak, int(keep.sum()))
