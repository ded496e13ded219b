"""The paper's Section 8 scenarios as models for :func:`analyze`: theta (N, n) -> (N, m).

inverse: the irregularity (m) reconstructed by the feedback inversion (Eq. 7, K^c = 1000, exact
FOH, zero initial state) from noise-free car-body accelerations simulated with the NOMINAL
parameters, the inverse using the uncertain ones; forward: the car-body acceleration (m/s^2)
simulated with the uncertain parameters. Both are read at the sample times ``times`` (s) of the
simulation grid (no interpolation: a time off the grid is an error). Parameter sets are a bank
axis, run in chunks of ``CHUNK`` sets to bound memory.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from railgsa_ros.errors import ConfigError
from railgsa_ros.inverse.feedback import FeedbackInverse
from railgsa_ros.simulate import simulate
from railgsa_ros.track import make_profile
from railgsa_ros.uq.analyze import check_seed
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import PARAM_NAMES, VehicleParams

KINDS = ('inverse', 'forward')
CHUNK = 256  # parameter sets per bank
#: longest scenario, simulation samples: a bank of CHUNK series of this length is 0.5 GB
#: (120 s at the default 2000 Hz; the paper reads t = 7 s)
MAX_SAMPLES = 240_000


def sample_indices(times: float | Sequence[float] | np.ndarray, dt: float) -> np.ndarray:
    """Indices k with k dt = t for every t (s); ConfigError when t is negative or off the grid."""
    t = np.atleast_1d(np.asarray(times, dtype=float))
    k = np.rint(t / dt)
    bad = (t < 0) | ~np.isfinite(t) | (np.abs(k * dt - t) > 1e-9 * np.maximum(1.0, t))
    if np.any(bad):
        raise ConfigError(f'time: {t[bad][0]:g} s is not a sample time (a multiple of '
                          f'{dt:g} s, >= 0)')
    return k.astype(int)


@dataclass(frozen=True)
class Scenario:
    """A callable model: uncertain parameter values (N, n) in ``names`` order -> (N, m), or
    (N,) when ``times`` is a scalar."""

    kind: str
    names: tuple[str, ...]
    dists: tuple[Distribution, ...]
    times: np.ndarray
    dt: float
    vehicle: VehicleParams
    gain: float
    u: np.ndarray = field(repr=False)  # irregularity at the samples, m
    a_meas: np.ndarray = field(repr=False)  # nominal car-body acceleration, m/s^2

    def theta(self, x: np.ndarray) -> np.ndarray:
        """Full parameter sets (N, 5): nominal values with the uncertain columns replaced."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        theta = np.tile(self.vehicle.as_array(), (x.shape[0], 1))
        theta[:, [PARAM_NAMES.index(n) for n in self.names]] = x
        return theta

    def __call__(self, x: np.ndarray) -> np.ndarray:
        theta = self.theta(x)
        idx = sample_indices(self.times, self.dt)
        out = np.empty((theta.shape[0], idx.size))
        for start in range(0, theta.shape[0], CHUNK):  # memory-bound chunks of the bank
            part = theta[start:start + CHUNK]
            if self.kind == 'inverse':
                series = FeedbackInverse(part, self.gain, self.dt).process(self.a_meas)
            else:
                series = simulate(self.u, self.dt, part)[0]
            out[start:start + CHUNK] = series[:, idx]
        return out[:, 0] if self.times.ndim == 0 else out

    @property
    def unit(self) -> str:
        """Unit of the output quantity."""
        return 'm' if self.kind == 'inverse' else 'm/s^2'


def make_scenario(kind: str, times: float | Sequence[float],
                  dists: Mapping[str, Distribution], profile: str = 'paper',
                  speed_mps: float = 10.0, vehicle: VehicleParams | None = None,
                  gain: float = 1000.0, rate_hz: float = 2000.0, seed: int | None = 0) -> Scenario:
    """Build a scenario; the profile (``track.make_profile`` spec) is run at ``speed_mps``."""
    if kind not in KINDS:
        raise ConfigError(f'scenario: unknown {kind!r}; expected inverse or forward')
    if not np.isfinite(speed_mps) or speed_mps <= 0:
        raise ConfigError(f'speed: must be positive, got {speed_mps!r}')
    if not dists:
        raise ConfigError('uncertainty: no uncertain parameter')
    vehicle = vehicle or VehicleParams()
    dt = 1.0 / rate_hz
    at = np.asarray(times, dtype=float)
    last = int(sample_indices(at, dt).max())
    if last > MAX_SAMPLES:
        raise ConfigError(f'time: {float(np.max(at)):g} s is beyond the longest scenario '
                          f'({MAX_SAMPLES * dt:g} s at {rate_hz:g} Hz)')
    check_seed(seed)
    _, u = make_profile(profile, speed_mps * dt * last, speed_mps * dt, seed)
    u = u[:last + 1]
    a_meas = simulate(u, dt, vehicle)[0]
    return Scenario(kind, tuple(dists), tuple(dists.values()), at, dt, vehicle, float(gain),
                    u, a_meas)
