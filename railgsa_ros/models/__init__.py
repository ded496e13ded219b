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
from typing import TYPE_CHECKING, Any

from railgsa_ros.errors import ConfigError
from railgsa_ros.models.base import ModeInfo, VehicleModel, delayed_sum

if TYPE_CHECKING:
    from railgsa_ros.models.coach import CoachModel
    from railgsa_ros.vehicle import VehicleParams

__all__ = ['ModeInfo', 'VehicleModel', 'as_model', 'delayed_sum', 'load_model', 'vehicle_of']


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


def vehicle_of(path: str | Path | None) -> VehicleParams | CoachModel:
    """What the entry points invert for a vehicle file: VehicleParams for a quarter car (the
    paper's Table 1 without a file), the model for a coach; ConfigError naming the file
    otherwise."""
    from railgsa_ros.models.coach import CoachModel
    from railgsa_ros.vehicle import VehicleParams, load_vehicle

    if path is None:
        return VehicleParams()
    model = load_model(path)
    return model if isinstance(model, CoachModel) else load_vehicle(path)
