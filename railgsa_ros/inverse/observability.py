"""Sensor noise propagated into the band: the speed below which the band is not observable.

White accelerometer noise of variance sigma_a^2 at the sample rate fs has the one-sided density
S_n = 2 sigma_a^2 / fs ((m/s^2)^2/Hz). The exact inverse 1/G followed by the band FIR (response
|BP|^2, see ``band.py``) turns it into an irregularity noise of standard deviation

    sigma_u(v) = sqrt( int_0^{fs/2} S_n |BP_v(f)|^4 / |G(j 2 pi f)|^2 df )   (m),

with BP_v the band at speed v (its edges are v / lambda). G has a double zero at f = 0, so
sigma_u grows as v^-1.5 as the band slides down to low frequencies: below the speed where
sigma_u reaches ``noise_limit_m`` the band is not observable (INVALID), below the speed where it
reaches half the limit it is DEGRADED. The integral runs on a fixed logarithmic frequency grid
(G is evaluated once), trapezoidal in log f.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from railgsa_ros.inverse.band import band_edges_hz, bandpass_power
from railgsa_ros.vehicle import frequency_response

F_MIN_HZ = 1e-5  # lowest frequency of the integration grid
GRID_POINTS = 6000  # log-spaced frequencies, fs/2 down to F_MIN_HZ
SPEED_GRID = np.geomspace(0.01, 400.0, 256)  # m/s, where sigma_u is tabulated
#: below this speed (m/s) the vehicle stands: nothing to reconstruct, whatever the band
STANDSTILL_MPS = 0.1


def band_noise_std(theta: np.ndarray, band: str, order: int, rate_hz: float,
                   variance: float, speeds_mps: np.ndarray) -> np.ndarray:
    """sigma_u (m) at each speed (S,) m/s for accelerometer noise ``variance`` (m/s^2)^2 at
    ``rate_hz``, vehicle theta (5,) and the EN 13848 ``band`` of Butterworth order ``order``."""
    f = np.geomspace(F_MIN_HZ, rate_hz / 2, GRID_POINTS)
    inv_g2 = 1.0 / np.abs(frequency_response(np.asarray(theta, float), 2j * np.pi * f)) ** 2
    density = 2.0 * variance / rate_hz
    speeds = np.atleast_1d(np.asarray(speeds_mps, dtype=float))
    out = np.empty(speeds.shape)
    for i, v in enumerate(speeds):  # (F,) per speed: 256 x 6000 floats at most
        lo, hi = band_edges_hz(band, max(v, 1e-9))
        integrand = bandpass_power(f, lo, hi, order) ** 2 * inv_g2 * f  # d f = f d ln f
        out[i] = np.sqrt(density * np.trapezoid(integrand, np.log(f)))
    return out


@lru_cache(maxsize=16)
def _table(theta: tuple[float, ...], band: str, order: int, rate_hz: float,
           variance: float) -> np.ndarray:
    """sigma_u on SPEED_GRID, read-only. Cached: the nominal and the bank's input policies of
    one run (``railgsa review``, ``invert --bands``, the demo) build the same table, 0.1 s each
    on one core."""
    table = band_noise_std(np.array(theta), band, order, rate_hz, variance, SPEED_GRID)
    table.flags.writeable = False
    return table


class NoiseFloor:
    """sigma_u(v) tabulated for one sensor, vehicle and band; ``speed_for(limit)`` inverts it.

    ``band`` 'none' (paper mode) has no wavelength band: sigma_u is not defined, the noise
    check is off and only standstill (< STANDSTILL_MPS) is unobservable.
    """

    def __init__(self, theta: np.ndarray, band: str, order: int, rate_hz: float,
                 variance: float) -> None:
        self.band = band
        self._sigma = None if band == 'none' else _table(
            tuple(np.asarray(theta, float).tolist()), band, order, float(rate_hz),
            float(variance))

    def sigma_m(self, speeds_mps: np.ndarray) -> np.ndarray:
        """sigma_u (m) at |speed| (interpolated log-log on the table; 0 without a band)."""
        v = np.abs(np.asarray(speeds_mps, dtype=float))
        if self._sigma is None:
            return np.zeros(v.shape)
        x = np.log(np.clip(v, SPEED_GRID[0], SPEED_GRID[-1]))
        return np.exp(np.interp(x, np.log(SPEED_GRID), np.log(self._sigma)))

    def speed_for(self, limit_m: float) -> float:
        """Lowest speed (m/s) where sigma_u <= limit_m (sigma_u falls with speed); at least
        STANDSTILL_MPS."""
        if self._sigma is None:
            return STANDSTILL_MPS
        log_s = np.log(self._sigma)[::-1]  # increasing as the speed falls
        log_v = np.log(SPEED_GRID)[::-1]
        v = float(np.exp(np.interp(np.log(limit_m), log_s, log_v)))
        return max(v, STANDSTILL_MPS)
