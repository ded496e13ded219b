"""Forward ("classical") simulation of vehicles, vectorised over parameter sets.

Exact discretisation with a first-order hold: the irregularity is taken as linear between its
samples, so the result is exact for piecewise-linear profiles and matches ``scipy.signal.lsim``.
Zero initial state (vehicle at rest on the undisturbed track) unless ``x0`` is given.
``vehicle_bank``/``simulate``: the quarter car with both its outputs; ``WheelsetBank``/
``simulate_model``: any ``models.VehicleModel``, one profile per wheelset, its ``channels``.
"""

from __future__ import annotations

import numpy as np

from railgsa_ros.lti import StateSpaceBank, discretize_foh
from railgsa_ros.models import VehicleModel
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


class WheelsetBank:
    """A streaming bank of vehicles (one per parameter set) driven by one profile per wheelset.

    One single-input ``StateSpaceBank`` per wheelset on the model's state space (exact FOH
    discretisation each), outputs summed: superposition of the wheelsets' inputs, exact for a
    linear vehicle. ``process(u)`` takes u (W, T) in m, returns the channels (P, C, T).
    """

    def __init__(self, model: VehicleModel, dt: float, theta: np.ndarray | None = None) -> None:
        theta = np.atleast_2d(model.theta if theta is None else theta)
        a, b, c, d = model.state_space(theta)
        self.banks = [StateSpaceBank(discretize_foh(a, b[..., w:w + 1], c, d[..., w:w + 1], dt))
                      for w in range(b.shape[-1])]
        self.block = self.banks[0].block

    def settle(self, u0: np.ndarray) -> None:
        """Equilibrium under the constant profile u0 (W,) m under each wheelset."""
        for bank, u in zip(self.banks, np.asarray(u0, dtype=float), strict=True):
            bank.settle(float(u))

    def process(self, u: np.ndarray) -> np.ndarray:
        """Advance over u (W, T) (m); returns the channels (P, C, T)."""
        u = np.asarray(u, dtype=float)
        out = self.banks[0].process(u[0])
        for bank, row in zip(self.banks[1:], u[1:], strict=True):
            out = out + bank.process(row)
        return out


def simulate_model(u: np.ndarray, dt: float, model: VehicleModel,
                   theta: np.ndarray | None = None) -> np.ndarray:
    """The model's channels (C, T), or (P, C, T) for theta (P, n), for the profiles u (W, T)
    (m) under its wheelsets sampled every dt s, from rest on the undisturbed track."""
    out = WheelsetBank(model, dt, theta).process(np.atleast_2d(u))
    return out[0] if theta is None or np.ndim(theta) == 1 else out
