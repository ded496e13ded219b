"""A regularised vehicle's inverse scenario for :func:`analyze`: theta (N, n) -> its D1 estimate.

The coach's counterpart of ``scenarios.py``'s ``inverse``: a record of the data channels is
simulated once with the NOMINAL vehicle (German profile of amplitude ``av``, white sensor noise,
constant speed, per frequency: Y_c = H_c(f; v) U + N_c), and each parameter set inverts it
with its own LMMSE design (``inverse.design.WienerDesign``) and the zero-phase band |BP|^2, over
the whole record by FFT. The output is the estimate (m) at ``times`` (s): the samples of a
window give windowed indices (``window_indices``: the variance-weighted aggregate), which say
which parameters drive the D1 output's doubt there. Parameter sets run in chunks of CHUNK.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import fft

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.band import band_edges_hz, bandpass_power
from railgsa_ros.inverse.design import WienerDesign, track_psd_hz
from railgsa_ros.models import VehicleModel
from railgsa_ros.uq.distributions import Distribution

EDGE_S = 25.0  # the band's and the design's reach (s): times this far from the record's ends
CHUNK = 64  # parameter sets per design: 64 x 2 x 4 x 20 modes on 2500 frequencies, ~ 0.1 GB


@dataclass(frozen=True)
class WienerScenario:
    """A callable model: uncertain values (N, n) in ``names`` order -> (N, m) (m = times)."""

    model: VehicleModel
    names: tuple[str, ...]
    dists: tuple[Distribution, ...]
    channels: tuple[str, ...]
    variances: tuple[float, ...]
    speed_mps: float
    rate_hz: float
    av: float
    band: str
    order: int
    times: np.ndarray
    data: np.ndarray = field(repr=False)  # rfft of the data channels (C, F)
    unit: str = 'm'

    def theta(self, x: np.ndarray) -> np.ndarray:
        """Full parameter sets (N, n_model): nominal values with the uncertain columns set."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        theta = np.tile(self.model.theta, (x.shape[0], 1))
        theta[:, [self.model.param_names.index(n) for n in self.names]] = x
        return theta

    def __call__(self, x: np.ndarray) -> np.ndarray:
        theta = self.theta(x)
        size = 2 * (self.data.shape[-1] - 1)
        f = fft.rfftfreq(size, 1.0 / self.rate_hz)
        bp = bandpass_power(f, *band_edges_hz(self.band, self.speed_mps), self.order)
        k = np.atleast_1d(np.rint(self.times * self.rate_hz).astype(int))
        out = np.empty((theta.shape[0], k.size))
        for start in range(0, theta.shape[0], CHUNK):
            design = WienerDesign(self.model, theta[start:start + CHUNK], self.channels,
                                  self.variances, self.av, self.rate_hz)
            w = design.response(f[1:], self.speed_mps)  # (P, C, F - 1): no DC (H = 0 there)
            spec = np.zeros((w.shape[0], f.size), complex)
            spec[:, 1:] = bp[1:] * np.sum(w * self.data[None, :, 1:], axis=1)
            out[start:start + CHUNK] = fft.irfft(spec, size, axis=-1)[:, k]
        return out[:, 0] if self.times.ndim == 0 else out


def make_wiener_scenario(model: VehicleModel, dists: Mapping[str, Distribution],
                         times: float | Sequence[float], speed_mps: float = 20.0,
                         duration_s: float = 100.0, rate_hz: float = 50.0,
                         accel_std_mps2: float = 0.0017, channels: Sequence[str] = ('accel_z',),
                         gyro_std_rads: float = 5.5e-3, av: float = 4.032e-7,
                         band: str = 'd1', order: int = 2, seed: int = 0) -> WienerScenario:
    """Simulate the nominal record (module docstring) and build the scenario; ``times`` (s)
    must keep a band window inside the record (the FFT wraps around at its ends)."""
    if not dists:
        raise ConfigError('uncertainty: no uncertain parameter')
    bad = [n for n in dists if n not in model.param_names]
    if bad:
        raise ConfigError(f'uncertainty: the {model.kind} has no parameter {bad[0]}')
    if not (np.isfinite(speed_mps) and speed_mps > 0):
        raise ConfigError(f'speed: must be positive, got {speed_mps!r}')
    t = np.asarray(times, dtype=float)
    edge = EDGE_S
    if np.any(t < edge) or np.any(t > duration_s - edge):
        raise ConfigError(f'time: expected times within [{edge:g}, {duration_s - edge:g}] s of '
                          f'the {duration_s:g} s record')
    size = fft.next_fast_len(int(duration_s * rate_hz), real=True)
    f = fft.rfftfreq(size, 1.0 / rate_hz)
    rng = np.random.default_rng(seed)
    # the profile under the reference wheelset in time: circular Gaussian with S_u(f; v)
    s_u = np.zeros(f.size)
    s_u[1:] = track_psd_hz(f[1:], speed_mps, av)
    amp = np.sqrt(s_u * rate_hz * size / 4.0)  # one-sided density -> rfft coefficient std
    u_f = amp * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))
    h = np.zeros((len(channels), f.size), complex)
    rows = [model.channels.index(c) for c in channels]
    h[:, 1:] = model.track_response(model.theta, f[1:], speed_mps)[rows]
    noise_std = np.array([gyro_std_rads if c == 'pitch_rate' else accel_std_mps2
                          for c in channels])
    noise = fft.rfft(noise_std[:, None] * rng.standard_normal((len(channels), size)), axis=-1)
    return WienerScenario(model, tuple(dists), tuple(dists.values()), tuple(channels),
                          tuple((noise_std ** 2).tolist()), float(speed_mps), float(rate_hz),
                          float(av), band, order, t, h * u_f + noise)


def window_indices(variances: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Indices (n,) of a window of outputs: sum_k V_k S_ik / sum_k V_k from the outputs'
    variances (m,) and indices (m, n) (Sobol' indices of the window's outputs together)."""
    return (variances[:, None] * indices).sum(axis=0) / variances.sum()
