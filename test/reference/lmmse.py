"""The physical limit: the best linear estimate of the D1 profile from car-body IMU channels.

Prior: the German track spectrum (one-sided, m^2/(rad/m), Omega in rad/m)

    S(Omega) = A_v Omega_c^2 / ((Omega^2 + Omega_r^2)(Omega^2 + Omega_c^2)),

Omega_c = 0.8246, Omega_r = 0.0206 rad/m, A_v = 4.032e-7 m rad (low disturbance). Target: the
profile under the reference wheelset through the EN 13848 D1 band (3-25 m), the zero-phase
Butterworth band-pass of prototype order 2 on distance, |BP|^2 = 1 / (1 + x^4),
x = (k^2 - k_lo k_hi) / (k (k_hi - k_lo)), k in 1/m (-6 dB at the band edges): the band the
project's score applies to the truth. Channels: vertical accelerometers at positions x_p on the
car body and optionally the pitch-rate gyro, each with white noise of a one-sided density ND
(per sqrt(Hz); a sample at rate fs holds variance ND^2 fs / 2).

At a constant speed v the channels are a linear time-invariant function of the profile under
the reference wheelset (each wheelset delayed by its offset / v). Per frequency, with two-sided
PSDs S_u (profile) and S_n = diag(ND_j^2 / 2), the Wiener gain of the band target is

    W = |BP|^2 S_u H^H (H S_u H^H + S_n)^-1 = |BP|^2 (H^H S_n^-1) / (1 / S_u + H^H S_n^-1 H)

(the second form by the matrix inversion lemma; it stays finite where S_u or H vanish), and the
posterior error PSD is E = |BP|^4 / (1 / S_u + H^H S_n^-1 H), variance 2 int_0^fs/2 E df
(``posterior_rmse``). That is the limit of an infinitely long record: no estimator that sees
less can do better. Content above the Nyquist frequency and aliasing are ignored (the D1 band
is far below it at the rates used).

Finite record: ``lmmse_estimate`` is the exact conditional mean given one record of T samples,
z_hat = C_zy C_yy^-1 y, with the covariances from the same spectra (the process taken periodic
over ``period_factor`` x T samples, which its covariances do not reach). It is the optimum at
every point of the record for the D1 RMSE against the band-limited truth, edges included; the
score leaves 100 m out at each end only because the truth's band-pass needs them. Truncating
the Wiener smoother at the record's ends is no substitute: near a null of H (twice the
wheelbase; for a car-centre IMU the odd fractions of twice the bogie spacing) W behaves like
1/H up to where the signal meets the noise, its impulse response rings for kilometres, and a
truncated one still had 3.5x the limit's error 800 m inside a 2 km car-centre record. At the
car centre without the gyro the nulls are resolved only by a long record, so the finite
record's error exceeds the infinite-record limit well inside the record (about 0.15 against
0.115 mm over 800 m at 20 m/s); above a bogie or with the gyro the two nearly agree.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import fft
from scipy.integrate import trapezoid
from scipy.sparse.linalg import LinearOperator, cg

from .coach_ode import Params, profile_response

GERMAN_LOW_AV = 4.032e-7  # m rad
OMEGA_C, OMEGA_R = 0.8246, 0.0206  # rad/m
D1_M = (3.0, 25.0)  # EN 13848 D1 wavelengths, m
G = 9.80665  # m/s^2: ND in ug/sqrt(Hz) * 1e-6 * G


def german_psd(omega: np.ndarray, a_v: float = GERMAN_LOW_AV) -> np.ndarray:
    """One-sided German track PSD (m^2/(rad/m)) at omega (rad/m)."""
    w2 = np.asarray(omega, float) ** 2
    return a_v * OMEGA_C ** 2 / ((w2 + OMEGA_R ** 2) * (w2 + OMEGA_C ** 2))


def band_power(k: np.ndarray, band: tuple[float, float] = D1_M, order: int = 2) -> np.ndarray:
    """|BP|^2 of the zero-phase Butterworth band-pass at wavenumbers k (1/m; or frequencies
    in Hz for the band v / lambda), band = (lambda_min, lambda_max) m."""
    lo, hi = 1.0 / band[1], 1.0 / band[0]
    k = np.abs(np.asarray(k, float))
    with np.errstate(divide='ignore'):
        x = np.where(k > 0, (k ** 2 - lo * hi) / (k * (hi - lo)), np.inf)
    return 1.0 / (1.0 + x ** (2 * order))


def synthesize_profile(n: int, dx: float, rng: np.random.Generator,
                       a_v: float = GERMAN_LOW_AV) -> np.ndarray:
    """A periodic Gaussian draw (m) of the German spectrum on n points dx m apart: independent
    normal cosine and sine amplitudes of variance S(Omega_k) dOmega per FFT bin."""
    omega = 2 * np.pi * fft.rfftfreq(n, dx)
    std = np.sqrt(german_psd(omega, a_v) * omega[1])
    c = n * (rng.standard_normal(omega.size) - 1j * rng.standard_normal(omega.size)) * std / 2
    c[0] = 0.0
    if n % 2 == 0:
        c[-1] = 0.0  # a real Nyquist bin would hold only the cosine's half of the variance
    return fft.irfft(c, n)


@dataclass(frozen=True)
class Channel:
    """A sensor channel: an accelerometer at x_p (m forward of the car-body centre, m/s^2) or,
    for x_p None, the pitch-rate gyro (rad/s); noise_density: one-sided white noise density
    (m/s^2/sqrt(Hz) or rad/s/sqrt(Hz))."""

    x_p: float | None
    noise_density: float


def synthetic_record(p: Params, channels: Sequence[Channel], speed: float, rate_hz: float,
                     n: int, rng: np.random.Generator, a_v: float = GERMAN_LOW_AV,
                     reference: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A periodic record of n samples drawn from the model: the German profile under wheelset
    ``reference`` (n,) m at constant speed, and the channels (channels, n) as the exact
    periodic steady state of the frequency responses plus their white noise."""
    u = synthesize_profile(n, speed / rate_hz, rng, a_v)
    f = fft.rfftfreq(n, 1.0 / rate_hz)
    h = np.zeros((f.size, len(channels)), complex)
    h[1:] = profile_response(p, 2 * np.pi * f[1:], [c.x_p for c in channels], speed,
                             reference)
    y = fft.irfft(h.T * fft.rfft(u), n, axis=1)
    density = np.array([[c.noise_density] for c in channels])
    return u, y + rng.standard_normal(y.shape) * density * np.sqrt(rate_hz / 2)


def _spectra(p: Params, channels: Sequence[Channel], speed: float, f_hz: np.ndarray,
             a_v: float, band: tuple[float, float], reference: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """At frequencies f_hz (> 0): the profile's two-sided PSD S_u (m^2/Hz), the band's |BP|^2,
    the channels' responses H (n, channels) and their two-sided noise PSDs (channels,)."""
    f = np.asarray(f_hz, float)
    s_u = np.pi * german_psd(2 * np.pi * f / speed, a_v) / speed
    bp = band_power(f, (band[0] / speed, band[1] / speed))  # the band in periods, s
    h = profile_response(p, 2 * np.pi * f, [ch.x_p for ch in channels], speed, reference)
    return s_u, bp, h, np.array([ch.noise_density ** 2 / 2 for ch in channels])


def error_spectrum(p: Params, channels: Sequence[Channel], speed: float, f_hz: np.ndarray,
                   a_v: float = GERMAN_LOW_AV, band: tuple[float, float] = D1_M,
                   reference: int = 0) -> np.ndarray:
    """Infinite-record posterior error PSD E (two-sided, m^2/Hz) of the band target at f_hz
    (Hz, > 0): |BP|^4 / (1 / S_u + H^H S_n^-1 H)."""
    s_u, bp, h, noise = _spectra(p, channels, speed, f_hz, a_v, band, reference)
    return bp ** 2 / (1.0 / s_u + np.sum(np.abs(h) ** 2 / noise, axis=1))


def wiener_gains(p: Params, channels: Sequence[Channel], speed: float, f_hz: np.ndarray,
                 a_v: float = GERMAN_LOW_AV, band: tuple[float, float] = D1_M,
                 reference: int = 0) -> np.ndarray:
    """Infinite-record Wiener gains W (n, channels) of the band target at f_hz (Hz, > 0):
    |BP|^2 H^H S_n^-1 / (1 / S_u + H^H S_n^-1 H) (= |BP|^2 S_u H^H (H S_u H^H + S_n)^-1)."""
    s_u, bp, h, noise = _spectra(p, channels, speed, f_hz, a_v, band, reference)
    info = 1.0 / s_u + np.sum(np.abs(h) ** 2 / noise, axis=1)
    return (bp / info)[:, None] * np.conj(h) / noise


def posterior_rmse(p: Params, channels: Sequence[Channel], speed: float, rate_hz: float,
                   a_v: float = GERMAN_LOW_AV, band: tuple[float, float] = D1_M,
                   reference: int = 0, points: int = 200_000) -> float:
    """Infinite-record posterior RMSE (m) of the band target: sqrt(2 int E df) over
    0 < f < min(fs / 2, 30 v / lambda_min) on ``points`` equal steps (|BP|^4 < 1e-11 beyond)."""
    f = np.linspace(0.0, min(rate_hz / 2, 30 * speed / band[0]), points)[1:]
    e = error_spectrum(p, channels, speed, f, a_v, band, reference)
    return float(np.sqrt(2 * trapezoid(e, f)))


def lmmse_estimate(p: Params, channels: Sequence[Channel], speed: float, y: np.ndarray,
                   rate_hz: float, a_v: float = GERMAN_LOW_AV,
                   band: tuple[float, float] = D1_M, reference: int = 0,
                   period_factor: int = 4, rtol: float = 1e-9) -> tuple[np.ndarray, int]:
    """Finite-record LMMSE estimate (m) of the band target under wheelset ``reference`` at
    every sample of the record y (channels, T) (dynamic parts: m/s^2 without g, rad/s), taken
    at rate_hz and constant speed (m/s), and the conjugate-gradient iterations it took.

    z_hat = C_zy C_yy^-1 y with the record's covariances from the spectra. The process is
    taken periodic with period period_factor x T (its covariances decay within that), so both
    products are FFT products on that grid; C_yy a = y is solved by conjugate gradients,
    preconditioned by the per-frequency inverse of the channels' spectral matrix.
    """
    y = np.atleast_2d(np.asarray(y, float))
    c, t = y.shape
    n = fft.next_fast_len(period_factor * t, real=True)
    f = fft.rfftfreq(n, 1.0 / rate_hz)
    s_u, bp, h, noise = _spectra(p, channels, speed, f[1:], a_v, band, reference)
    s_yy = np.concatenate([np.diag(noise)[None],  # f = 0: noise only
                           s_u[:, None, None] * h[:, :, None] * np.conj(h[:, None, :])
                           + np.diag(noise)])
    s_zy = np.concatenate([np.zeros((1, c)),  # cross-spectrum of the target and each channel
                           (bp * s_u)[:, None] * np.conj(h)])
    s_inv = np.linalg.inv(s_yy)

    def apply(spectrum: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Periodic convolution of the zero-padded channels a (c, T) with a spectral matrix
        (per frequency, rows: outputs) at the sample rate; first T samples of each output."""
        a_f = fft.rfft(a.reshape(c, t), n, axis=1).T  # (nf, c)
        return fft.irfft(np.einsum('fij,fj->fi', spectrum, a_f).T, n, axis=1)[:, :t]

    op = LinearOperator((c * t, c * t), matvec=lambda a: apply(s_yy * rate_hz, a).ravel(),
                        dtype=float)
    pre = LinearOperator((c * t, c * t), matvec=lambda a: apply(s_inv / rate_hz, a).ravel(),
                         dtype=float)
    count = [0]
    a, info = cg(op, y.ravel(), rtol=rtol, maxiter=10 * c * t, M=pre,
                 callback=lambda _x: count.__setitem__(0, count[0] + 1))
    if info != 0:
        raise RuntimeError(f'conjugate gradients did not converge ({info})')
    return apply(s_zy[:, None, :] * rate_hz, a)[0], count[0]
