"""Forward ("classical") simulation of the quarter vehicle, vectorised over parameter sets.

Exact discretisation with a first-order hold: the irregularity is taken as linear between its
samples, so the result is exact for piecewise-linear profiles and matches ``scipy.signal.lsim``.
Zero initial state (vehicle at rest on the undisturbed track) unless ``x0`` is given.
"""

from __future__ import annotations

import numpy as np

from railgsa_ros.lti import StateSpaceBank, discretize_foh
from railgsa_ros.vehicle import VehicleParams, as_theta, feedthrough, state_space


def vehicle_bank(params: VehicleParams | np.ndarray, dt: float,
                 x0: np.ndarray | None = None) -> StateSpaceBank:
    """A streaming bank of quarter vehicles (one per parameter set) with outputs (a_s, a_us).

    ``params``: VehicleParams or theta of shape (5,) or (P, 5); dt: sample period in s.
    """
    theta = np.atleast_2d(as_theta(params))
    a, b, c_s, c_us = state_space(theta)
    c = np.concatenate([c_s, c_us], axis=-2)
    d = np.concatenate(feedthrough(theta), axis=-2)
    return StateSpaceBank(discretize_foh(a, b, c, d, dt), x0=x0)


def simulate(u: np.ndarray, dt: float, params: VehicleParams | np.ndarray,
             x0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Car-body and wheel accelerations (m/s^2) for an irregularity ``u`` (m) sampled every dt s.

    Returns (a_s, a_us), each of shape (T,) for one parameter set or (P, T) for theta (P, 5).
    """
    theta = as_theta(params)
    out = vehicle_bank(theta, dt, x0).process(np.asarray(u, dtype=float))
    a_s, a_us = out[:, 0], out[:, 1]
    if theta.ndim == 1:
        return a_s[0], a_us[0]
    return a_s, a_us
