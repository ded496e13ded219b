"""Inverse simulation by high-gain feedback (paper Section 4, Eq. 5-7) and its stability analysis.

The closed loop u = K (y_meas - y_model) around the quarter vehicle gives the inverse system
(A - B K C, B K, -K C, K) from the sprung acceleration y (m/s^2) to the irregularity u (m);
it tends to 1/G as K -> infinity.
Its poles are the roots of den(s) + K num_s(s). With the monic
polynomials of ``vehicle.tf_polynomials`` (den = s^4 + d3 s^3 + d2 s^2 + d1 s + d0,
num_s = n3 s^3 + n2 s^2) the model has d1 = n3 and d0 = n2, so the closed loop is
s^4 + (d3 + K n3) s^3 + (d2 + K n2) s^2 + n3 s + n2. Its Hurwitz determinants, expanded so that the
K^2 terms cancel by hand, are
  H2 = (d3 + K n3)(d2 + K n2) - n3
  H3 = n3 (d3 d2 - n3) - n2 d3^2 + K n3 (n3 d2 - d3 n2),
and n3 d2 - d3 n2 = c k_us^2 m_s / (m_s m_us)^2 > 0: every K > 0 is stable for physical
parameters. The slow pair sits at +-j sqrt(n2 / a2), a2 = d2 + K n2 (about +-j / sqrt(K)), with
real part -(n3 d2 - d3 n2) / (2 a2^2) (~ -1e-10 / s at K = 1000): marginally damped. The fast pole
near -K n3 (-1.6e9 rad/s at K = 1000) maps to z ~ 0 under the exact FOH discretisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from railgsa_ros.errors import ConfigError
from railgsa_ros.lti import StateSpaceBank, discretize_foh
from railgsa_ros.vehicle import state_space, tf_polynomials


def check_gain(gain: float) -> float:
    """Return the gain as a float; ConfigError unless it is a positive finite number."""
    try:
        k = float(gain)
    except (TypeError, ValueError):
        raise ConfigError(f'gain: expected a positive number, got {gain!r}') from None
    if not np.isfinite(k) or k <= 0:
        raise ConfigError(f'gain: must be positive and finite (K^c > 0), got {gain!r}')
    return k


@dataclass(frozen=True)
class Stability:
    """Closed-loop stability of the feedback inverse for each parameter set (arrays of shape (P,)).

    ``hurwitz`` (P, 3): a3, H2, H3 (all > 0 <=> stable); ``slow_real`` (1/s) and ``slow_hz`` (Hz):
    real part and frequency of the slow pole pair; ``margin`` = min over P of -slow_real (1/s), the
    decay rate of the least-damped mode; ``eigenvalues`` (P, 4) rad/s, from eig, for the report
    only (eig cannot resolve a real part of 1e-10 next to a pole at 1e9).
    """

    gain: float
    hurwitz: np.ndarray
    slow_real: np.ndarray
    slow_hz: np.ndarray
    eigenvalues: np.ndarray

    @property
    def stable(self) -> bool:
        """True when every parameter set passes the Routh-Hurwitz test."""
        return bool(np.all(self.hurwitz > 0))

    @property
    def margin(self) -> float:
        """Decay rate (1/s) of the least-damped closed-loop mode over the bank."""
        return float(np.min(-self.slow_real))


def inverse_matrices(theta: np.ndarray, gain: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 7: (A - B K C, B K, -K C, K) for theta (P, 5): (P,4,4), (P,4,1), (P,1,4), (P,1,1)."""
    a, b, c_s, _ = state_space(theta)
    k = check_gain(gain)
    d = np.full((*a.shape[:-2], 1, 1), k)
    return a - k * b @ c_s, k * b, -k * c_s, d


def stability(theta: np.ndarray, gain: float) -> Stability:
    """Routh-Hurwitz verdict (cancellation-free), slow-pair damping, eigenvalues; theta (P, 5)."""
    k = check_gain(gain)
    theta = np.atleast_2d(theta)
    num, _, den = tf_polynomials(theta)
    d3, d2 = den[:, 1], den[:, 2]
    n3, n2 = num[:, 1], num[:, 2]
    a3, a2 = d3 + k * n3, d2 + k * n2
    h2 = a3 * a2 - n3
    cross = n3 * d2 - d3 * n2
    h3 = n3 * (d3 * d2 - n3) - n2 * d3 ** 2 + k * n3 * cross
    eig = np.linalg.eigvals(inverse_matrices(theta, k)[0])
    return Stability(k, np.stack([a3, h2, h3], -1), -cross / (2 * a2 ** 2),
                     np.sqrt(n2 / a2) / (2 * np.pi), eig)


def require_stable(theta: np.ndarray, gain: float) -> Stability:
    """Stability report; ConfigError when any parameter set gives a pole with Re >= 0."""
    report = stability(theta, gain)
    if not report.stable:
        bad = int(np.argmin(report.hurwitz.min(-1)))
        raise ConfigError(f'gain: K^c = {report.gain:g} makes the feedback inverse unstable '
                          f'(Routh-Hurwitz fails for parameter set {bad})')
    return report


class FeedbackInverse:
    """Streaming Eq. 7 for a bank: ``process(a_s (T,)) -> u (P, T)``; exact FOH, period dt (s)."""

    def __init__(self, theta: np.ndarray, gain: float, dt: float) -> None:
        theta = np.atleast_2d(theta)
        self.stability = require_stable(theta, gain)
        self._bank = StateSpaceBank(discretize_foh(*inverse_matrices(theta, gain), dt))

    def reset(self) -> None:
        """Return to the zero state (vehicle at rest on level track)."""
        self._bank.reset()

    def process(self, a_s: np.ndarray) -> np.ndarray:
        """Irregularity u (m), shape (P, T), for a chunk of sprung accelerations (m/s^2)."""
        return self._bank.process(a_s)[:, 0]


UNSUPPORTED = {
    'analytical': 'analytical inversion (paper A.1) needs u = D^-1 (y - C x), but the sprung '
                  'acceleration has D = 0, so D^-1 does not exist; use feedback, spectral or '
                  'kalman',
    'flatness': 'flatness inversion (paper A.2) needs a flat output of relative degree 4 (the '
                'number of states); the sprung acceleration has relative degree 1, so it is not '
                'flat; use feedback, spectral or kalman',
}
