"""Vehicle models as data: one interface for the paper's quarter car and a multibody coach.

A vehicle file chooses its model with ``model:`` (``coach``; without it, or with
``quarter_car``, the file is the quarter car of ``config/vehicle.yaml``). ``load_model`` reads
either; both answer ``VehicleModel`` (docs/vehicles.md):

- ``theta`` (n,) are the physical parameters that may be uncertain, in ``param_names`` order
  (SI units, ``units``, ``docs``, inclusive ``bounds``); every function takes ``theta`` of shape
  (..., n): parameter samples are an array axis. Geometry is known and is not in theta.
- ``channels``: the outputs, first ``accel_z`` (vertical specific-force change of the primary
  IMU, m/s^2), then for the coach ``pitch_rate`` (rad/s, REP 103 angular_velocity.y) and
  ``accel_z:<name>`` per further IMU.
- ``wheel_offsets_m`` (W,): distance (m) of each wheelset behind the output reference point;
  wheelset w meets a track point d_w / v seconds after the reference does.
- ``frequency_response(theta, s)`` (..., C, W, F): channel per metre of profile under wheelset
  w alone; ``track_response(theta, f_hz, v)`` (..., C, F): the sum over the wheelsets with their
  delays, per metre of profile at the reference point.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np

from railgsa_ros.errors import ConfigError


class ModeInfo(NamedTuple):
    """One vibration mode: natural frequency (Hz), damping ratio (-) and what moves."""

    f_hz: float
    zeta: float
    description: str


class VehicleModel(Protocol):
    """What the inversion, band, sensitivities and calibration need of a vehicle."""

    kind: str
    param_names: tuple[str, ...]
    theta: np.ndarray
    units: dict[str, str]
    docs: dict[str, str]
    bounds: dict[str, tuple[float, float]]
    channels: tuple[str, ...]
    wheel_offsets_m: np.ndarray

    def frequency_response(self, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(..., C, W, F) complex at complex frequencies s (F,) rad/s, theta (..., n)."""
        ...

    def track_response(self, theta: np.ndarray, f_hz: np.ndarray,
                       speed_mps: float) -> np.ndarray:
        """(..., C, F): the wheelsets' responses summed with their delays d_w / v."""
        ...

    def state_space(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray]:
        """(A, B, C, D), shapes (..., N, N), (..., N, W), (..., C, N), (..., C, W)."""
        ...

    def modes(self, theta: np.ndarray | None = None) -> list[ModeInfo]:
        """The vibration modes of one parameter set (default: the nominal), by frequency."""
        ...


def delayed_sum(h: np.ndarray, offsets_m: np.ndarray, f_hz: np.ndarray,
                speed_mps: float) -> np.ndarray:
    """sum_w h[..., c, w, f] exp(-2j pi f d_w / v): (..., C, W, F) -> (..., C, F).

    One wheelset at offset 0 returns h[..., 0, :] itself (no multiplication: bit for bit).
    """
    if not (np.isfinite(speed_mps) and speed_mps > 0):
        raise ConfigError(f'speed: must be a positive finite number (m/s), got {speed_mps!r}')
    offsets_m = np.asarray(offsets_m, dtype=float)
    if offsets_m.shape == (1,) and offsets_m[0] == 0:
        return h[..., 0, :]
    phase = np.exp(-2j * np.pi * np.asarray(f_hz, dtype=float)[None, :]
                   * offsets_m[:, None] / speed_mps)  # (W, F)
    return np.einsum('...cwf,wf->...cf', h, phase)


def load_model(path_or_doc: str | Path | Mapping[str, Any]) -> VehicleModel:
    """The model a vehicle file (or its parsed YAML document) describes; ConfigError naming the
    file and field otherwise. ``model: coach`` selects the coach; no ``model:`` key (or
    ``model: quarter_car``) is the quarter car."""
    from railgsa_ros.config import load_yaml

    if isinstance(path_or_doc, Mapping):
        doc: Any = path_or_doc
        source = 'vehicle file'
    else:
        doc = load_yaml(path_or_doc)
        source = str(path_or_doc)
    if not isinstance(doc, Mapping):
        raise ConfigError(f'{source}: expected a mapping with a "vehicle:" section')
    kind = doc.get('model', 'quarter_car')
    try:
        if kind == 'coach':
            from railgsa_ros.models.coach import CoachModel

            return CoachModel.from_doc(doc)
        if kind == 'quarter_car':
            from railgsa_ros.models.quarter_car import QuarterCarModel

            return QuarterCarModel.from_doc(doc)
    except ConfigError as exc:
        raise ConfigError(f'{source}: {exc}') from None
    raise ConfigError(f'{source}: model: expected coach or quarter_car, got {kind!r}')


def as_model(vehicle: Any) -> VehicleModel:
    """A model from what the entry points accept: a model, a vehicle file path, VehicleParams
    or a quarter-car theta (5,) (the paper's Table 1 for None)."""
    if isinstance(vehicle, (str, Path)):
        return load_model(vehicle)
    if hasattr(vehicle, 'kind'):
        return vehicle
    from railgsa_ros.models.quarter_car import QuarterCarModel
    from railgsa_ros.vehicle import VehicleParams, as_theta

    if vehicle is None or isinstance(vehicle, VehicleParams):
        return QuarterCarModel(vehicle)
    return QuarterCarModel(VehicleParams(*as_theta(vehicle).tolist()))
