"""Model-generic regularised band design: the LMMSE (Wiener) inverse of a vehicle model folded
into the band FIR, and the part of the band it cannot observe.

A vehicle model (``railgsa_ros.models``) maps the profile u under its reference wheelset to C
channels, y_c = H_c(f; v) u + n_c with H_c(f; v) = sum_w H_cw(f) exp(-2j pi f d_w / v): every
track point excites the car body once per wheelset, d_w / v seconds after the reference one.
Where the wheelsets' contributions cancel (twice the wheelbase for every car-body signal, the
bogie spacing's odd fractions for a car-centre IMU's bounce) H vanishes and no inverse exists.
The design regularises with the track prior and the sensor noise (LMMSE, per frequency):

    W(f; v) = S_u H^H (H S_u H^H + S_n)^-1 = S_u / (1 + q) H^H S_n^-1,   q = S_u H^H S_n^-1 H

(1 x C; the second form is the matrix inversion lemma for one input and diagonal S_n) with
S_u(f; v) = 2 pi S(2 pi f / v) / v the German spectrum of amplitude ``track_spectrum_av`` in
time at speed v (one-sided, m^2/Hz) and S_n = 2 sigma_c^2 / fs the white noise of channel c at
the sample rate (its unit^2/Hz). The pipeline folds |BP|^2 W into the band FIR, one FIR per
channel, summed. Its error density is the posterior S_u / (1 + q): over the band

    var_post(v) = int |BP|^4 S_u / (1 + q) df,   var_prior(v) = int |BP|^4 S_u df   (m^2),

(|BP|^2 is the zero-phase band's amplitude response) and var_post / var_prior is the fraction
of the band's truth variance the data could not observe: 1 where H = 0 (the posterior is the
prior there), small where the signal dominates the noise. Both are per design speed: the
delays d_w / v move the nulls in frequency but not in wavelength.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import fft

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.band import band_edges_hz, bandpass_power, impulse_response
from railgsa_ros.models import VehicleModel, delayed_sum
from railgsa_ros.track import GERMAN_OMEGA_C, GERMAN_OMEGA_R

#: the posterior integral's log-frequency grid: this many points per decade (the nulls are
#: notches of relative width ~ 1 / sqrt(SNR): 0.1 % spacing resolves them), from this factor
#: below the lowest band edge to this factor above the highest (|BP|^4 of order 2 is 1e-23 there)
POINTS_PER_DECADE = 1000
EDGE_FACTOR = 300.0
SPEED_POINTS = 16  # design speeds (log-spaced, min_design_speed_mps .. max_speed_mps) tabulated
#: the coach's band FIR spans +-this distance at min_design_speed_mps (+-24 s at 10 m/s: the
#: fixed delay), Tukey-tapered over its outer half. Near a null the LMMSE inverse is a notch of
#: width ~ 1 / sqrt(SNR) whose impulse response rings for tens of seconds: cut to +-8 s at
#: 20 m/s the D1 error is 1.7x the LMMSE limit above a bogie and 2.4x at the car centre (more
#: nulls), at +-24 s 1.0x and 1.2x (docs/inversion.md, "Coach")
SPAN_M = 240.0
#: a coach's outputs are DEGRADED where the speed across their band window changes by more
#: than this (the pipeline's window_speed_tolerance is held to it): the FIR maps lags to
#: distance at one speed, and the coach's long, ringing FIR (the wheelsets' delays, the nulls'
#: notches) turns the warp into error: 25 -> 35 m/s in 60 s (+-9 s window: 5 %) reads 0.12 mm
#: VALID against 0.04 mm at constant speed (docs/inversion.md, "Coach")
WINDOW_SPEED_TOLERANCE = 0.02
KEEP_GRIDS = 4  # frequency grids whose wheelset responses a design keeps
GRID_SPANS = 8  # the design grid holds this many FIR half-lengths (the notch's ringing)


def track_psd_hz(f_hz: np.ndarray, speed_mps: float, av: float) -> np.ndarray:
    """One-sided German spectrum of amplitude ``av`` (m rad) in time at speed_mps (m/s), m^2/Hz:
    S_u(f) = 2 pi S(2 pi f / v) / v."""
    omega = 2 * np.pi * np.abs(np.asarray(f_hz, dtype=float)) / speed_mps  # rad/m
    oc2 = GERMAN_OMEGA_C ** 2
    return 2 * np.pi * av * oc2 / ((omega ** 2 + GERMAN_OMEGA_R ** 2) * (omega ** 2 + oc2)
                                   ) / speed_mps


def noise_psd_hz(variances: Sequence[float], rate_hz: float) -> np.ndarray:
    """One-sided density (C,) of white noise of these variances (unit^2) at rate_hz: per Hz."""
    return 2.0 * np.asarray(variances, dtype=float) / rate_hz


def information(h: np.ndarray, s_u: np.ndarray, s_n: np.ndarray) -> np.ndarray:
    """q = S_u H^H S_n^-1 H (..., F): the signal-to-noise ratio of the channels together; h
    (..., C, F) per metre of profile, s_u (F,) m^2/Hz, s_n (C,) unit^2/Hz."""
    return s_u * np.sum((h.real ** 2 + h.imag ** 2) / s_n[:, None], axis=-2)


def wiener(h: np.ndarray, s_u: np.ndarray, s_n: np.ndarray) -> np.ndarray:
    """W = S_u / (1 + q) H^H S_n^-1 (..., C, F): the LMMSE estimate of u per unit of channel."""
    gain = s_u / (1.0 + information(h, s_u, s_n))
    return gain[..., None, :] * h.conj() / s_n[:, None]


def half_width(min_speed_mps: float, rate_hz: float) -> int:
    """Half-length (samples at rate_hz) of the coach's band FIR: SPAN_M at min_speed_mps."""
    return int(np.ceil(SPAN_M / min_speed_mps * rate_hz))


def tapered(response: np.ndarray, half: int) -> np.ndarray:
    """A zero-phase response (..., F) on a design grid whose impulse response is cut to lags
    +-half, Tukey-tapered over the outer half: what its FIR of 2 half + 1 taps does exactly."""
    h = impulse_response(response)
    lag = np.abs(fft.fftfreq(h.shape[-1], 1.0 / h.shape[-1]))  # |lag| of each index
    x = np.clip(2.0 * lag / half - 1.0, 0.0, 1.0)  # 0 up to half / 2, 1 at half
    return fft.rfft(h * np.where(lag <= half, 0.5 + 0.5 * np.cos(np.pi * x), 0.0), axis=-1)


class WienerDesign:
    """The LMMSE inverse of ``model`` for parameter sets theta (P, n), from the data channels
    ``channels`` (names of ``model.channels``) with noise variances ``variances`` (C,) (unit^2
    at rate_hz), under the German prior of amplitude ``av`` (m rad). The wheelsets' responses
    on a grid do not depend on the speed: they are kept for the KEEP_GRIDS grids used last
    (the band design's, the gap filler's covariance and error grids, the posterior's)."""

    def __init__(self, model: VehicleModel, theta: np.ndarray, channels: Sequence[str],
                 variances: Sequence[float], av: float, rate_hz: float) -> None:
        self.model = model
        self.theta = np.atleast_2d(np.asarray(theta, dtype=float))
        self.rows = [model.channels.index(c) for c in channels]
        self.s_n = noise_psd_hz(variances, rate_hz)
        self.av = float(av)
        self.rate_hz = float(rate_hz)
        self._kept: dict[tuple[int, float, float], np.ndarray] = {}  # grid -> H (P, C, W, F)

    def wheel_responses(self, f_hz: np.ndarray) -> np.ndarray:
        """H_cw (P, C, W, F) of the data channels at f_hz (Hz, evenly or log-spaced: a grid is
        known by its size and ends), kept for the grid."""
        key = (f_hz.size, float(f_hz[0]), float(f_hz[-1]))
        if key not in self._kept:
            if len(self._kept) >= KEEP_GRIDS:
                del self._kept[next(iter(self._kept))]  # the oldest
            self._kept[key] = self.model.frequency_response(self.theta, 2j * np.pi * f_hz
                                                            )[:, self.rows]
        return self._kept[key]

    def track_response(self, f_hz: np.ndarray, speed_mps: float) -> np.ndarray:
        """H_c(f; v) (P, C, F): the channels per metre of profile at the reference wheelset."""
        return delayed_sum(self.wheel_responses(f_hz), self.model.wheel_offsets_m, f_hz,
                           speed_mps)

    def accel_response(self, f_hz: np.ndarray, speed_mps: float) -> np.ndarray:
        """H (F,) of the primary accelerometer, first parameter set ((m/s^2)/m): the gap
        filler's model of the acceleration."""
        return self.track_response(f_hz, speed_mps)[0, 0]

    def response(self, f_hz: np.ndarray, speed_mps: float) -> np.ndarray:
        """W (P, C, F) at speed_mps (m/s) on a grid f_hz (Hz)."""
        return wiener(self.track_response(f_hz, speed_mps),
                      track_psd_hz(f_hz, speed_mps, self.av), self.s_n)

    def band_variances(self, band: str, order: int, speeds_mps: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
        """(var_post (P, S), var_prior (S,)) m^2 of the band ``band`` (Butterworth prototype
        order ``order``) at speeds (S,) m/s: trapezoidal in log f on one grid for all speeds."""
        speeds = np.atleast_1d(np.asarray(speeds_mps, dtype=float))
        lo = band_edges_hz(band, float(speeds.min()))[0] / EDGE_FACTOR
        hi = min(band_edges_hz(band, float(speeds.max()))[1] * EDGE_FACTOR, self.rate_hz / 2)
        f = np.logspace(np.log10(lo), np.log10(hi),
                        int(POINTS_PER_DECADE * np.log10(hi / lo)) + 1)
        post = np.empty((self.theta.shape[0], speeds.size))
        prior = np.empty(speeds.size)
        for i, v in enumerate(speeds):
            weight = bandpass_power(f, *band_edges_hz(band, v), order) ** 2 * f  # df = f d ln f
            s_u = track_psd_hz(f, v, self.av)
            q = information(self.track_response(f, v), s_u, self.s_n)
            post[:, i] = np.trapezoid(weight * s_u / (1.0 + q), np.log(f), axis=-1)
            prior[i] = np.trapezoid(weight * s_u, np.log(f))
        return post, prior


class Observability:
    """What the coach's band output can and cannot know, tabulated over the design speeds
    (log-spaced from vmin to vmax; read at |v| held to them as the design is, interpolated
    log-log): ``std_m(v)``, the error standard deviation (m) of the FIR the pipeline runs
    (the LMMSE inverse tapered to +-``half`` samples of the design ``grid`` (Hz), band
    ``power`` (F,) = |BP|^2 at each speed times the multirate roll-off: a function of speed),
    ``limit_std_m(v)`` that of the LMMSE limit, ``fraction(v)`` the limit's var_post /
    var_prior: the part of the band's truth variance the data do not observe."""

    def __init__(self, design: WienerDesign, band: str, order: int, vmin: float, vmax: float,
                 grid: np.ndarray, half: int, rolloff: np.ndarray | float) -> None:
        self.speeds = np.geomspace(vmin, vmax, SPEED_POINTS if vmax > vmin else 1)
        self.achieved_var = np.empty(self.speeds.size)
        for i, v in enumerate(self.speeds):
            power = bandpass_power(grid, *band_edges_hz(band, v), order) * rolloff
            h = design.track_response(grid, v)[0]  # (C, F)
            s_u = track_psd_hz(grid, v, design.av)
            fir = tapered(power * wiener(h, s_u, design.s_n), half)
            density = np.abs(power - np.sum(fir * h, axis=0)) ** 2 * s_u + np.sum(
                np.abs(fir) ** 2 * design.s_n[:, None], axis=0)
            self.achieved_var[i] = np.sum(density) * grid[1]
        post, prior = design.band_variances(band, order, self.speeds)
        self.post_var, self.prior_var = post[0], prior

    def _at(self, table: np.ndarray, speeds_mps: np.ndarray | float) -> np.ndarray:
        v = np.clip(np.abs(np.asarray(speeds_mps, dtype=float)), self.speeds[0], self.speeds[-1])
        if self.speeds.size == 1:
            return np.full(v.shape, table[0])
        return np.exp(np.interp(np.log(v), np.log(self.speeds), np.log(table)))

    def std_m(self, speeds_mps: np.ndarray | float) -> np.ndarray:
        """Error standard deviation (m) of the pipeline's band output at these speeds (m/s)."""
        return np.sqrt(self._at(self.achieved_var, speeds_mps))

    def limit_std_m(self, speeds_mps: np.ndarray | float) -> np.ndarray:
        """Posterior standard deviation (m) of the LMMSE limit at these speeds (m/s)."""
        return np.sqrt(self._at(self.post_var, speeds_mps))

    def fraction(self, speeds_mps: np.ndarray | float) -> np.ndarray:
        """Unobserved fraction var_post / var_prior of the band's truth variance."""
        return self._at(self.post_var / self.prior_var, speeds_mps)


def model_theta(model: VehicleModel, values: Any) -> np.ndarray:
    """theta (..., n) for ``model`` from an array (its nominal for None); ConfigError for
    anything else (another length, the quarter car's VehicleParams)."""
    try:
        theta = np.asarray(model.theta if values is None else values, dtype=float)
    except (TypeError, ValueError):
        theta = np.zeros(0)
    n = len(model.param_names)
    if theta.shape[-1:] != (n,):
        raise ConfigError(f'vehicle: the {model.kind} takes theta (..., {n}) ordered as '
                          f'{", ".join(model.param_names)}, got shape {theta.shape}')
    return theta


def channel_variances(model: VehicleModel, channels: Sequence[str], accel_var: float,
                      gyro_var: float) -> list[float]:
    """Noise variances of the data channels: ``accel_var`` ((m/s^2)^2) for accelerometers,
    ``gyro_var`` ((rad/s)^2) for the pitch rate; ConfigError for a channel the model lacks or
    data without the primary accelerometer first."""
    unknown = [c for c in channels if c not in model.channels]
    if unknown or not channels or channels[0] != model.channels[0]:
        raise ConfigError(f'channels: expected {model.channels[0]} first, then any of '
                          f'{", ".join(model.channels[1:])}; got {", ".join(channels)}')
    return [gyro_var if c == 'pitch_rate' else accel_var for c in channels]
