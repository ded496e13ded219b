"""10-DOF vertical multibody coach: time-domain ODE (solve_ivp) and frequency responses.

Bodies and coordinates (SI; deviations from static equilibrium, so gravity drops out; z up;
pitch theta about +y of REP 103, x forward, so positive theta puts the nose down and a point at
x (m forward of a body's centre) moves z - x theta):

    q = [z_c, theta_c, z_b1, theta_b1, z_b2, theta_b2, z_w1, z_w2, z_w3, z_w4]

car body (M_c, J_c); bogie 1 (leading) at x = +l_c and bogie 2 at -l_c (M_b, J_b); wheelsets
leading first at x = l_c + l_t, l_c - l_t, -l_c + l_t, -l_c - l_t (M_w). Per bogie side a
secondary spring k_s and damper c_s between the car body above the bogie centre and the bogie
(2 sides: 2 k_s, 2 c_s); per axle box a primary k_p, c_p between the bogie above the wheelset and
the wheelset (2 boxes: 2 k_p, 2 c_p); per wheelset a linear contact spring k_H to the rail
profile u under it (contact loss is not modelled).

Two code paths on purpose: ``simulate`` integrates forces written body by body (Newton-Euler),
``matrices`` assembles M, C, K, B from the elements' connectivity vectors, and
``frequency_response`` solves (K + i w C - w^2 M) X = B; the tests hold one against the other.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

Params = dict[str, float]
Profile = Callable[[np.ndarray], np.ndarray]

# Manchester benchmark passenger coach (S. Iwnicki, "Manchester benchmarks for rail vehicle
# simulation", Vehicle System Dynamics 30(3-4):295-313, 1998, doi 10.1080/00423119808969454),
# vertical values as reproduced in DanielCanteroNTNU/TTB-2D TrainProp_Manchester_BenchMark.m:
# per axle box and per bogie side. The benchmark's contact is Hertzian; k_H is its linearisation
# k = 3 P0^(1/3) / (2 G) per wheel (Zhai's form, G = 4.57e-8 R^-0.149 m/N^(2/3) with the wheel
# radius R = 0.46 m and the static wheel load P0 = 54.6 kN of this coach: 1.1e9 N/m), two wheels.
MANCHESTER_COACH: Params = {
    'M_c': 32000.0,   # car body mass, kg
    'J_c': 1.97e6,    # car body pitch inertia, kg m^2
    'M_b': 2615.0,    # bogie frame mass, kg
    'J_b': 1476.0,    # bogie frame pitch inertia, kg m^2
    'M_w': 1813.0,    # wheelset mass, kg
    'k_p': 1.2e6,     # primary vertical stiffness per axle box, N/m
    'c_p': 4.0e3,     # primary vertical damping per axle box, N s/m
    'k_s': 4.3e5,     # secondary vertical stiffness per bogie side, N/m
    'c_s': 2.0e4,     # secondary vertical damping per bogie side, N s/m
    'k_H': 2.2e9,     # linearised contact stiffness per wheelset, N/m
    'l_c': 9.5,       # bogie semi-spacing, m
    'l_t': 1.28,      # wheelbase semi-length, m
}

DOF = ('z_c', 'theta_c', 'z_b1', 'theta_b1', 'z_b2', 'theta_b2',
       'z_w1', 'z_w2', 'z_w3', 'z_w4')


def bogie_positions(p: Params) -> np.ndarray:
    """x (m, forward of the car-body centre) of the bogie centres, leading first (2,)."""
    return np.array([p['l_c'], -p['l_c']])


def wheelset_positions(p: Params) -> np.ndarray:
    """x (m, forward of the car-body centre) of the wheelsets, leading first (4,)."""
    return np.repeat(bogie_positions(p), 2) + np.tile([p['l_t'], -p['l_t']], 2)


def wheelset_offsets(p: Params, reference: int = 0) -> np.ndarray:
    """Distance (m) of each wheelset behind wheelset ``reference``: its chainage is the
    reference's chainage minus this (4,)."""
    x = wheelset_positions(p)
    return x[reference] - x


# ----------------------------------------------------------------- time domain (Newton-Euler)
def newton_euler(p: Params) -> Callable[..., list]:
    """accelerations(q, dq, u_w): generalised accelerations (10 items) from the forces on each
    body, for coordinates q, rates dq and the rail profile u_w (m) under the four wheelsets;
    items are floats (one state: lists are the integrator's fast path) or equal-shape arrays."""
    ks, cs, kp, cp, kh = (2 * p['k_s'], 2 * p['c_s'], 2 * p['k_p'], 2 * p['c_p'], p['k_H'])
    bogie_x, wheel_x = (p['l_c'], -p['l_c']), (p['l_t'], -p['l_t'])
    m_c, j_c, m_b, j_b, m_w = p['M_c'], p['J_c'], p['M_b'], p['J_b'], p['M_w']

    def accelerations(q: Sequence, dq: Sequence, u_w: Sequence | np.ndarray) -> list:
        zc, thc, vzc, vthc = q[0], q[1], dq[0], dq[1]
        car_f = car_m = 0.0  # vertical force on the car body, generalised force on theta_c
        bogies, wheels = [], []
        for j, xb in enumerate(bogie_x):
            zb, thb, vzb, vthb = q[2 + 2 * j], q[3 + 2 * j], dq[2 + 2 * j], dq[3 + 2 * j]
            # secondary: compression of both sides = car-body point above the bogie - bogie
            f_s = ks * (zc - xb * thc - zb) + cs * (vzc - xb * vthc - vzb)
            car_f = car_f - f_s
            car_m = car_m + xb * f_s  # force -f_s at x = xb does work (-f_s)(-xb) per theta
            bog_f, bog_m = f_s, 0.0
            for k, xw in enumerate(wheel_x):
                i = 6 + 2 * j + k
                f_p = kp * (zb - xw * thb - q[i]) + cp * (vzb - xw * vthb - dq[i])
                bog_f = bog_f - f_p
                bog_m = bog_m + xw * f_p
                wheels.append((f_p + kh * (u_w[i - 6] - q[i])) / m_w)
            bogies += [bog_f / m_b, bog_m / j_b]
        return [car_f / m_c, car_m / j_c, *bogies, *wheels]

    return accelerations


@dataclass(frozen=True)
class CoachRun:
    """Sampled solution: t (T,) s, chainage (T,) m of the reference wheelset, speed (T,) m/s,
    q, dq, ddq (10, T) coordinates, rates, accelerations; u_w (4, T) the profile under the
    wheelsets."""

    t: np.ndarray
    chainage: np.ndarray
    speed: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    u_w: np.ndarray

    def accel(self, x_p: float) -> np.ndarray:
        """Vertical acceleration (m/s^2, up) of the car-body point x_p m forward of its centre."""
        return self.ddq[0] - x_p * self.ddq[1]

    def pitch_rate(self) -> np.ndarray:
        """d theta_c / dt (rad/s): the angular velocity about +y (REP 103)."""
        return self.dq[1]


def simulate(p: Params, profile: Profile, speed: float | Callable[[float], float],
             t_eval: np.ndarray, *, start_m: float = 0.0, reference: int = 0,
             rtol: float = 1e-8, atol: float = 1e-13, y0: np.ndarray | None = None
             ) -> CoachRun:
    """Integrate the coach over t_eval (s, increasing, from t_eval[0]) with DOP853.

    profile(x): rail profile (m) at chainages x (m, array), smooth enough for the tolerance;
    speed: m/s, a constant or v(t); start_m: chainage of wheelset ``reference`` at t_eval[0]
    (every wheelset's chainage is that minus its ``wheelset_offsets``); y0: initial [q, dq] (20,)
    (None: at rest in static equilibrium). atol (m, m/s, rad, rad/s alike) must be small
    against the responses: the defaults suit profiles of 0.1 mm and more, where halving both
    changes the car-body outputs by < 1e-6 of their peak (test_reference_coach).
    """
    v = speed if callable(speed) else (lambda _t, c=float(speed): c)
    offsets = wheelset_offsets(p, reference)
    accelerations = newton_euler(p)

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        s = y.tolist()
        u_w = profile(s[20] - offsets).tolist()
        return np.array([*s[10:20], *accelerations(s[:10], s[10:20], u_w), v(t)])

    start = np.concatenate([np.zeros(20) if y0 is None else y0, [start_m]])
    sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), start, method='DOP853', t_eval=t_eval,
                    rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f'solve_ivp: {sol.message}')
    y = sol.y
    u_w = profile(y[20][None, :] - offsets[:, None])
    return CoachRun(sol.t, y[20], np.array([v(t) for t in sol.t]), y[:10], y[10:20],
                    np.array(accelerations(y[:10], y[10:20], u_w)), u_w)


# ----------------------------------------------------------------- frequency domain (matrices)
def matrices(p: Params) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """M, C, K (10, 10) and the input matrix B (10, 4): M q'' + C q' + K q = B u_w.

    Every spring/damper pair is a connectivity vector a (its extension = a . q) with
    K += k a a^T, C += c a a^T; the contact springs tie each wheelset to its rail input.
    """
    M = np.diag([p['M_c'], p['J_c'], p['M_b'], p['J_b'], p['M_b'], p['J_b'], *[p['M_w']] * 4])
    K = np.zeros((10, 10))
    C = np.zeros((10, 10))
    for j, xb in enumerate(bogie_positions(p)):
        a = np.zeros(10)
        a[[0, 1, 2 + 2 * j]] = [1.0, -xb, -1.0]
        K += 2 * p['k_s'] * np.outer(a, a)
        C += 2 * p['c_s'] * np.outer(a, a)
        for k, xw in enumerate((p['l_t'], -p['l_t'])):
            a = np.zeros(10)
            a[[2 + 2 * j, 3 + 2 * j, 6 + 2 * j + k]] = [1.0, -xw, -1.0]
            K += 2 * p['k_p'] * np.outer(a, a)
            C += 2 * p['c_p'] * np.outer(a, a)
    B = np.zeros((10, 4))
    B[6:, :] = p['k_H'] * np.eye(4)
    K[6:, 6:] += p['k_H'] * np.eye(4)
    return M, C, K, B


def displacement_response(p: Params, omega: np.ndarray) -> np.ndarray:
    """X (n, 10, 4): coordinates per unit rail input under each wheelset at omega (rad/s)."""
    M, C, K, B = matrices(p)
    w = np.asarray(omega, float)
    out = np.empty((w.size, 10, 4), complex)
    for lo in range(0, w.size, 8192):  # bounded memory
        wc = w[lo:lo + 8192, None, None]
        out[lo:lo + 8192] = np.linalg.solve(K + 1j * wc * C - wc ** 2 * M, B[None])
    return out


def frequency_response(p: Params, omega: np.ndarray, outputs: Sequence[float | None]
                       ) -> np.ndarray:
    """G (n, outputs, 4): response per unit rail input under each wheelset at omega (rad/s)
    of each output: the vertical acceleration (m/s^2 per m) of the car-body point x_p, or the
    pitch rate (rad/s per m) for None."""
    w = np.asarray(omega, float)[:, None]
    X = displacement_response(p, omega)
    return np.stack([1j * w * X[:, 1] if x_p is None else -(w ** 2) * (X[:, 0] - x_p * X[:, 1])
                     for x_p in outputs], axis=1)


def profile_response(p: Params, omega: np.ndarray, outputs: Sequence[float | None],
                     speed: float, reference: int = 0) -> np.ndarray:
    """H (n, outputs): response to the profile under wheelset ``reference`` at constant speed
    (m/s): the four wheelsets' responses (``frequency_response``), each delayed by its
    offset / speed."""
    delays = wheelset_offsets(p, reference) / speed
    G = frequency_response(p, omega, outputs)
    return np.sum(G * np.exp(-1j * np.asarray(omega, float)[:, None, None] * delays), axis=2)
