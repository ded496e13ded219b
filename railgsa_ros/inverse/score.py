"""Scoring a reconstruction against the true irregularity on distance, in an EN 13848 band.

Both signals are resampled to a common distance grid and reach the score in the band exactly
once: the truth through the zero-phase band-pass |BP|^2 in wavenumber, a pipeline output as
emitted (it already is the band signal) or, with ``band_rec=True``, through the same band-pass.
The ends, where the filters see the record's edges, are left out. ``reconstruct`` runs the
pipeline over a simulated run and places its output on the true chainage; ``near`` scores the
samples around a point (a dropout).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft

from railgsa_ros.inverse.band import band_limits, bandpass_power
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, Output, vertical
from railgsa_ros.models import VehicleModel
from railgsa_ros.scenario import Run
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
    lmin, lmax = band_limits(band)
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
    lmin, lmax = band_limits(band)
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


def reconstruct(run: Run, config: InversionConfig | None = None,
                keep: np.ndarray | None = None, sensor_delay_s: float = 0.0,
                vehicle: VehicleParams | np.ndarray | None = None, *,
                model: VehicleModel | None = None, pitch_rate: bool = True
                ) -> tuple[np.ndarray, Output]:
    """Pipeline output over the run's samples ``keep`` (bool mask, None: all; odometry = the
    true speed; ``vehicle``: the parameters the inversion assumes, None: nominal; rate_hz: the
    run's) and its chainage on the truth's axis (m). ``model``: the vehicle model the
    inversion assumes (a coach: its LMMSE design; ``vehicle`` then its theta), with the run's
    gyro pitch rate when it has one and ``pitch_rate``.

    ``sensor_delay_s`` plays a sensor whose causal filter delays the signal by that much (the
    simulator's filter is delay-compensated): every sample is stamped that much after the
    acceleration it holds, and the chainage is anchored where the train is at the first stamp,
    as odometry would place it.
    """
    keep = np.ones(run.stamps_ns.size, bool) if keep is None else keep
    config = (config if config is not None else InversionConfig()).with_(rate_hz=run.rate_hz)
    gyro = run.gyro is not None and pitch_rate and model is not None and model.kind == 'coach'
    if gyro:
        config = config.with_(gyro_noise_std_rads=float(np.sqrt(run.gyro_covariance)))
    pipe = InversionPipeline(config, vehicle, noise_variance=run.accel_covariance, model=model,
                             channels=('accel_z', 'pitch_rate') if gyro else ('accel_z',))
    stamps = run.stamps_ns[keep] + np.int64(round(sensor_delay_s * 1e9))
    rates = {'rates': run.gyro[keep, 1]} if gyro and run.gyro is not None else {}
    out = Output.concat([pipe.push(stamps, vertical(run.accel[keep], 'z'), run.speed_mps[keep],
                                   **rates), pipe.flush()])
    t0 = run.t_true_s[keep][0] + sensor_delay_s
    return out.chainage_m + np.interp(t0, run.t_true_s, run.chainage_m), out


def near(chainage_rec: np.ndarray, u_rec: np.ndarray, chainage_true: np.ndarray,
         u_true: np.ndarray, centre_m: float, radius_m: float = 50.0, band: str = 'd1',
         dx: float = 0.25) -> tuple[float, float]:
    """(largest, RMS) error (m) of the output samples within radius_m of centre_m against the
    truth band-passed on distance; only grid points with an output within dx / 2 count (no
    interpolation across a gap)."""
    x = np.arange(chainage_true[0], chainage_true[-1], dx)
    truth = band_distance(np.interp(x, chainage_true, u_true), dx, band)
    j = np.clip(np.searchsorted(chainage_rec, x), 1, chainage_rec.size - 1)
    covered = np.minimum(np.abs(x - chainage_rec[j - 1]), np.abs(chainage_rec[j] - x)) <= dx / 2
    win = covered & (np.abs(x - centre_m) <= radius_m)
    err = np.interp(x[win], chainage_rec, u_rec) - truth[win]
    return float(np.max(np.abs(err))), float(np.sqrt(np.mean(err ** 2)))
