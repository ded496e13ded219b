"""Kalman filter with the unknown input in the state (paper Appendix A.3) and an RTS smoother.

The irregularity is modelled as the output of a shaping filter driven by unit white noise w:
u'' + (a + b) u' + a b u = g w, a = v Omega_r, b = v Omega_c (rad/s), g^2 = pi A_v Omega_c^2 v^3.
Its one-sided spectrum g^2 / (pi (w^2 + a^2)(w^2 + b^2)) in m^2/(rad/s) is the German spectrum
S(Omega) = A_v Omega_c^2 / ((Omega^2 + Omega_r^2)(Omega^2 + Omega_c^2)) mapped to time with
w = v Omega and S_t(w) = S(w / v) / v: its exact 2nd-order factorisation, poles scaled by speed.
The augmented state [v_s, v_us, x_s, x_us, u, u', b] adds the accelerometer bias b as a random
walk ((m/s^2)/sqrt(s)), so that a constant offset is not read as a parabola in u (the double zero
of G at s = 0 makes both look alike). It is discretised exactly (Van Loan), the measurement is
the sprung acceleration plus b with noise variance R, and the steady-state gain (DARE)
makes the filter LTI, so it runs as a ``StateSpaceBank`` over parameter sets.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from railgsa_ros.errors import ConfigError
from railgsa_ros.lti import DiscreteSystem, StateSpaceBank
from railgsa_ros.vehicle import state_space

OMEGA_R = 0.0206  # rad/m, German spectrum [rail_domain.md section 2]
OMEGA_C = 0.8246  # rad/m
N_STATE = 7
U_INDEX = 4


def shaping_coefficients(speed_mps: float, av: float) -> tuple[float, float, float]:
    """(a, b, g): shaping-filter poles -a, -b (rad/s) and gain g for speed (m/s), A_v (m rad)."""
    v = max(float(speed_mps), 1e-3)
    return v * OMEGA_R, v * OMEGA_C, float(np.sqrt(np.pi * av * OMEGA_C ** 2 * v ** 3))


def augmented_model(theta: np.ndarray, speed_mps: float, av: float, bias_walk: float,
                    dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete (Phi (P,7,7), Q (P,7,7), C (P,1,7)) of vehicle, shaping filter and bias."""
    a_v, b_v, c_s, _ = state_space(np.atleast_2d(theta))
    p = a_v.shape[0]
    a, b, g = shaping_coefficients(speed_mps, av)
    f = np.zeros((p, N_STATE, N_STATE))
    f[:, :4, :4] = a_v
    f[:, :4, U_INDEX] = b_v[..., 0]
    f[:, 4, 5] = 1.0
    f[:, 5, 4], f[:, 5, 5] = -a * b, -(a + b)
    gw = np.zeros((N_STATE, 2))
    gw[5, 0], gw[6, 1] = g, bias_walk
    # Van Loan: expm([[-F, G G^T], [0, F^T]] dt) = [[., Phi^-1 Q], [0, Phi^T]]
    m = np.zeros((p, 2 * N_STATE, 2 * N_STATE))
    m[:, :N_STATE, :N_STATE] = -f * dt
    m[:, :N_STATE, N_STATE:] = gw @ gw.T * dt
    m[:, N_STATE:, N_STATE:] = np.swapaxes(f, 1, 2) * dt
    e = expm(m)
    phi = np.swapaxes(e[:, N_STATE:, N_STATE:], 1, 2)
    q = phi @ e[:, :N_STATE, N_STATE:]
    q = 0.5 * (q + np.swapaxes(q, 1, 2))
    c = np.zeros((p, 1, N_STATE))
    c[:, :, :4] = c_s
    c[:, :, 6] = 1.0
    return phi, q, c


class KalmanDesign:
    """Steady-state filter and smoother gains for one speed; arrays over P parameter sets."""

    def __init__(self, theta: np.ndarray, speed_mps: float, av: float, bias_walk: float,
                 noise_var: float, dt: float) -> None:
        self.speed, self.dt = float(speed_mps), dt
        phi, q, c = augmented_model(theta, speed_mps, av, bias_walk, dt)
        r = np.array([[noise_var]])
        try:
            prior = np.stack([solve_discrete_are(ph.T, cc.T, qq, r)
                              for ph, cc, qq in zip(phi, c, q, strict=True)])
        except (np.linalg.LinAlgError, ValueError) as exc:  # an extreme vehicle: one line
            reason = (str(exc).splitlines() or [type(exc).__name__])[0]
            raise ConfigError(f'method kalman: no steady-state filter for this vehicle at '
                              f'{speed_mps:g} m/s ({reason}); use method spectral') from None
        s = c @ prior @ np.swapaxes(c, 1, 2) + r  # (P,1,1)
        gain = prior @ np.swapaxes(c, 1, 2) / s  # (P,6,1)
        eye = np.eye(N_STATE)
        self.phi, self.c, self.gain = phi, c, gain[..., 0]
        self.update = eye - gain @ c  # I - K C
        post = self.update @ prior
        # smoother gain J = P_f Phi^T P_p^-1 (P symmetric)
        self.smoother = np.swapaxes(np.linalg.solve(prior, phi @ post), 1, 2)

    def filter_system(self, outputs: str = 'u') -> DiscreteSystem:
        """LTI filter y -> u_hat ('u') or y -> x_hat_k|k ('state'); its state is x_k|k-1."""
        ad = self.phi @ self.update
        bd = (self.phi @ self.gain[..., None])[..., 0]
        cd, dd = self.update, self.gain
        if outputs == 'u':
            cd, dd = cd[:, U_INDEX:U_INDEX + 1], dd[:, U_INDEX:U_INDEX + 1]
        return DiscreteSystem(ad, bd, cd, dd, self.dt)

    @property
    def spectral_radius(self) -> float:
        """Largest |eigenvalue| of the filter's state matrix over the bank (< 1: stable)."""
        return float(np.max(np.abs(np.linalg.eigvals(self.phi @ self.update))))


class KalmanInverse:
    """Streaming steady-state KF for a bank: ``process(a_s (T,)) -> u_hat (P, T)``.

    ``set_speed`` redesigns the gains when the speed moved by more than ``tolerance`` (relative)
    and keeps the state estimate; ``smooth`` is the offline RTS smoother for a whole record.
    """

    def __init__(self, theta: np.ndarray, av: float, bias_walk: float, noise_var: float,
                 dt: float, speed_mps: float, tolerance: float, min_speed_mps: float,
                 max_speed_mps: float) -> None:
        self.theta = np.atleast_2d(theta)
        self.av, self.bias_walk, self.noise_var, self.dt = av, bias_walk, noise_var, dt
        self.tolerance = tolerance
        self.min_speed, self.max_speed = min_speed_mps, max_speed_mps
        self.design = self._design(speed_mps)
        self._bank = StateSpaceBank(self.design.filter_system())

    def _held(self, speed: float) -> float:
        """Design speed (m/s): |speed| held in [min_speed, max_speed], as the band stage does."""
        return min(max(abs(speed), self.min_speed), self.max_speed)

    def _design(self, speed: float) -> KalmanDesign:
        return KalmanDesign(self.theta, self._held(speed), self.av, self.bias_walk,
                            self.noise_var, self.dt)

    def set_speed(self, speed_mps: float) -> bool:
        """Redesign for a new speed (m/s) when needed; True when the gains changed."""
        v = self._held(speed_mps)
        if abs(v - self.design.speed) <= self.tolerance * self.design.speed:
            return False
        self.design = self._design(v)
        self._bank = StateSpaceBank(self.design.filter_system(), x0=self._bank.state)
        return True

    def reset(self) -> None:
        """Zero state estimate."""
        self._bank.reset()

    def process(self, a_s: np.ndarray) -> np.ndarray:
        """Filtered irregularity estimate (m), shape (P, T), for sprung accelerations (m/s^2)."""
        return self._bank.process(a_s)[:, 0]

    def smooth(self, a_s: np.ndarray) -> np.ndarray:
        """RTS smoother over a whole record from the zero state: u_hat_k|N (m), shape (P, T).

        Backward pass x_k|N = (I - J Phi) x_k|k + J x_k+1|N, run in reversed time as a bank of
        P x 7 single-input systems (one per state component of x_k|k), summed.
        """
        d = self.design
        fwd = StateSpaceBank(d.filter_system('state')).process(a_s)  # (P, 7, T) x_k|k
        p, n, t_len = fwd.shape
        if t_len == 0:
            return np.zeros((p, 0))
        j = d.smoother
        m = np.eye(n) - j @ d.phi
        ad = np.repeat(j, n, axis=0)  # system (p, i) at row p * n + i
        bd = np.swapaxes(m, 1, 2).reshape(p * n, n)  # column i of M
        cd = np.repeat(j[:, U_INDEX:U_INDEX + 1], n, axis=0)
        dd = m[:, U_INDEX, :].reshape(p * n, 1)
        x0 = np.zeros((p, n, n))
        x0[:, 0] = (d.phi @ fwd[:, :, -1:])[..., 0]
        back = StateSpaceBank(DiscreteSystem(ad, bd, cd, dd, self.dt), x0=x0.reshape(p * n, n))
        rev = back.process(fwd[:, :, ::-1].reshape(p * n, t_len))[:, 0]
        return rev.reshape(p, n, t_len).sum(1)[:, ::-1]
