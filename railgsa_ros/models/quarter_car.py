"""The paper's quarter car (``railgsa_ros.vehicle``) behind the ``VehicleModel`` interface.

A thin wrapper: one wheelset at offset 0, one channel (``accel_z``, the sprung acceleration);
every number comes from ``vehicle.py`` unchanged, so ``track_response`` equals
``vehicle.frequency_response`` bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from railgsa_ros import vehicle
from railgsa_ros.models.base import ModeInfo, delayed_sum
from railgsa_ros.vehicle import (
    PARAM_BOUNDS,
    PARAM_DOCS,
    PARAM_NAMES,
    PARAM_UNITS,
    VehicleParams,
    vehicle_from_doc,
)

MODE_NAMES = ('car-body bounce', 'wheel hop')


class QuarterCarModel:
    """The quarter car of Schenkendorf & Groos (Eq. 1-4) as a ``VehicleModel``."""

    kind = 'quarter_car'
    param_names: tuple[str, ...] = PARAM_NAMES
    units = PARAM_UNITS
    docs = PARAM_DOCS
    bounds = PARAM_BOUNDS
    channels: tuple[str, ...] = ('accel_z',)

    def __init__(self, params: VehicleParams | None = None) -> None:
        self.params = VehicleParams() if params is None else params
        self.theta = self.params.as_array()
        self.wheel_offsets_m = np.zeros(1)

    @classmethod
    def from_doc(cls, doc: Mapping[str, Any]) -> QuarterCarModel:
        """From a parsed vehicle file: its ``vehicle:`` section (``vehicle.vehicle_from_doc``)."""
        return cls(vehicle_from_doc(doc))

    def frequency_response(self, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(..., 1, 1, F): sprung acceleration per metre of irregularity ((m/s^2)/m)."""
        return vehicle.frequency_response(theta, np.asarray(s))[..., None, None, :]

    def track_response(self, theta: np.ndarray, f_hz: np.ndarray,
                       speed_mps: float) -> np.ndarray:
        """(..., 1, F): the sprung response itself (one wheelset, no delay)."""
        s = 2j * np.pi * np.asarray(f_hz, dtype=float)
        return delayed_sum(self.frequency_response(theta, s), self.wheel_offsets_m, f_hz,
                           speed_mps)

    def state_space(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray]:
        """(A, B, C, D) of Eq. 2 with the sprung acceleration as the output (D = 0)."""
        a, b, c_s, _ = vehicle.state_space(theta)
        return a, b, c_s, vehicle.feedthrough(theta)[0]

    def modes(self, theta: np.ndarray | None = None) -> list[ModeInfo]:
        """Car-body bounce and wheel hop (an overdamped mode has no pair of poles: omitted)."""
        params = self.params if theta is None else VehicleParams(*np.asarray(theta).tolist())
        return [ModeInfo(m.natural_frequency_hz, m.damping_ratio, name)
                for name, m in zip(MODE_NAMES, vehicle.modes(params), strict=False)]
