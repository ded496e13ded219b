"""EN 13848 wavelength bands as zero-phase FIR filters in time, designed for the current speed.

A band [lambda_min, lambda_max] (m) at speed v (m/s) is the frequency band [v / lambda_max,
v / lambda_min] (Hz). The band-pass is the analogue Butterworth band-pass BP of order n (the
low-pass prototype order; 2n poles) run forward and backward, i.e. the real, zero-phase response
|BP(j w)|^2 = 1 / (1 + ((w^2 - w0^2) / (w B))^(2n)), w0^2 = w_lo w_hi, B = w_hi - w_lo:
-6 dB at the band edges, 40 n dB per decade on each side. The FIR taps sample a response on a
dense FFT grid, are centred (delay D samples) and cut to 2 D + 1 taps where the impulse response
has decayed below a tolerance; ``truncation_error`` measures what the cut costs.

A band is named (``band_limits``): the EN 13848 bands d1, d2, d3, ``wide`` (WIDE_M: for users
who filter themselves; what limits it is in docs/inversion.md) or custom limits 'LMIN:LMAX' (m).
"""

from __future__ import annotations

import numpy as np
from scipy import fft

from railgsa_ros.errors import ConfigError
from railgsa_ros.standards.en13848 import BANDS_M

#: 'wide': the shortest wave is ~4 samples of the 0.25 m chainage grid and well inside the
#: IMU bandwidth (ADXL355 ODR/4 = 250 Hz holds 1 m up to 250 m/s), the longest is D3's edge
WIDE_M = (1.0, 200.0)
_DESIGN_PERIODS = 32  # default span of a design grid, periods of the lowest band frequency


def band_limits(band: str) -> tuple[float, float]:
    """Wavelength limits (lambda_min, lambda_max) m of a band name: d1, d2, d3, wide or
    'LMIN:LMAX' (0 < LMIN < LMAX, m); ConfigError otherwise."""
    if band in BANDS_M:
        return BANDS_M[band]
    if band == 'wide':
        return WIDE_M
    try:
        lmin, lmax = (float(x) for x in str(band).split(':'))
    except ValueError:
        raise ConfigError(f'band: expected {", ".join(BANDS_M)}, wide, none or LMIN:LMAX in m '
                          f'(e.g. 2:70), got {band!r}') from None
    if not (0.0 < lmin < lmax < 1e5):
        raise ConfigError(f'band: {band!r}: expected 0 < LMIN < LMAX < 1e5 m')
    return lmin, lmax


def band_edges_hz(band: str, speed_mps: float) -> tuple[float, float]:
    """Frequency band (Hz) of wavelength band ``band`` (``band_limits``) at speed_mps (m/s)."""
    lmin, lmax = band_limits(band)
    return speed_mps / lmax, speed_mps / lmin


def bandpass_power(f_hz: np.ndarray, f_lo: float, f_hi: float, order: int) -> np.ndarray:
    """|BP(j 2 pi f)|^2 of the analogue Butterworth band-pass of prototype order ``order``."""
    f = np.abs(np.asarray(f_hz, dtype=float))
    with np.errstate(divide='ignore'):
        x = np.where(f > 0, (f ** 2 - f_lo * f_hi) / (f * (f_hi - f_lo)), np.inf)
    return 1.0 / (1.0 + x ** (2 * order))


def design_grid(rate_hz: float, f_lo: float, periods: float = _DESIGN_PERIODS) -> np.ndarray:
    """Frequencies (Hz) of a real-FFT grid spanning ``periods`` periods of f_lo (Hz) in time."""
    n = 1 << int(np.ceil(np.log2(periods * rate_hz / f_lo)))
    return fft.rfftfreq(n, 1.0 / rate_hz)


def impulse_response(response: np.ndarray) -> np.ndarray:
    """Zero-phase (circular, index 0 = lag 0) impulse response of a response on a design grid."""
    n = 2 * (response.shape[-1] - 1)
    return fft.irfft(response, n=n, axis=-1)


def half_length(response: np.ndarray, tol: float) -> int:
    """Smallest D such that taps beyond lag +-D hold < tol of the impulse response's L1 norm."""
    h = np.abs(np.atleast_2d(impulse_response(response)))
    half = h.shape[-1] // 2
    mass = h[:, :half + 1].copy()  # |h| by |lag|, both sides together
    mass[:, 1:half] += h[:, :half:-1]
    tail = np.cumsum(mass[:, ::-1], axis=-1)[:, ::-1] / mass.sum(-1, keepdims=True)
    beyond = np.append(tail[:, 1:], np.zeros((tail.shape[0], 1)), axis=-1)  # mass at lags > D
    return int(max(np.argmax(row < tol) for row in beyond))


def fir_taps(response: np.ndarray, d: int) -> np.ndarray:
    """Causal taps (..., 2 d + 1) of delay d: tap j is the impulse response at lag j - d."""
    return np.roll(impulse_response(response), d, axis=-1)[..., :2 * d + 1]


def truncation_error(taps: np.ndarray, response: np.ndarray) -> float:
    """Largest |H_fir - H| on the design grid, relative to the largest |H| (worst row)."""
    n = 2 * (response.shape[-1] - 1)
    d = (taps.shape[-1] - 1) // 2
    circ = np.zeros((*taps.shape[:-1], n))
    circ[..., :2 * d + 1] = taps
    circ = np.roll(circ, -d, axis=-1)
    return float(np.max(np.abs(fft.rfft(circ, axis=-1) - response))
                 / np.max(np.abs(response)))
