"""Quarter-vehicle model of Schenkendorf & Groos (Eq. 1-4, Table 1), vectorised over parameters.

State x = [v_s, v_us, x_s, x_us] (m/s, m/s, m, m); input u = vertical track irregularity under the
wheel (m, +z up); outputs are the sprung (car-body) and unsprung accelerations (m/s^2).

Every function takes ``theta``, an array of shape (..., 5) ordered as ``PARAM_NAMES``, so that many
parameter sets are evaluated at once; a :class:`VehicleParams` converts to it with ``as_array``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
import math
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from railgsa_ros.config import key_list, load_yaml
from railgsa_ros.errors import ConfigError

PARAM_NAMES = ('m_s', 'm_us', 'k_s', 'k_us', 'c')
PARAM_UNITS = {'m_s': 'kg', 'm_us': 'kg', 'k_s': 'N/m', 'k_us': 'N/m', 'c': 'N*s/m'}
#: What each parameter is (node parameter descriptions, docs).
PARAM_DOCS = {'m_s': 'sprung (car-body) mass', 'm_us': 'unsprung (wheelset) mass',
              'k_s': 'suspension stiffness', 'k_us': 'wheel-rail contact stiffness',
              'c': 'suspension damping'}
#: Physical range of each parameter of one quarter of a rail vehicle (inclusive; Table 1 lies
#: well inside): the same bounds in every entry point (vehicle files, node parameters, ``gsa``).
#: Values outside (1e300 kg) are typing errors, and they overflow the filters to NaN.
PARAM_BOUNDS = {'m_s': (100.0, 1e5), 'm_us': (10.0, 1e4), 'k_s': (1e4, 1e8),
                'k_us': (1e6, 1e10), 'c': (1e2, 1e7)}


def _coerce_number(value: Any) -> Any:
    """Accept numeric strings such as '2.13e6', which YAML 1.1 leaves as strings."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def check_parameter(name: str, value: Any, unit: str, bounds: tuple[float, float]) -> float:
    """``value`` as a float: a positive finite number (numeric strings accepted) inside the
    inclusive ``bounds``; else ConfigError naming ``name`` (e.g. 'vehicle.k_s') and ``unit``."""
    value = _coerce_number(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f'{name}: expected a number in {unit}, got {value!r}')
    try:
        number = float(value)
    except OverflowError:  # an int beyond the float range
        number = math.inf
    if not math.isfinite(number) or number <= 0:
        raise ConfigError(f'{name}: must be a positive finite number in {unit}, got {number!r}')
    low, high = bounds
    if not low <= number <= high:
        raise ConfigError(f'{name}: {number:g} {unit} is outside the physical range '
                          f'[{low:g}, {high:g}] {unit}')
    return number


def check_fields(data: Any, names: tuple[str, ...], source: str) -> None:
    """ConfigError naming ``source`` unless ``data`` is a mapping with exactly ``names``."""
    if not isinstance(data, Mapping):
        raise ConfigError(f'{source}: expected a mapping of {", ".join(names)}')
    unknown = set(data) - set(names)
    if unknown:
        raise ConfigError(f'{source}: unknown field(s) {key_list(unknown)}; '
                          f'expected {", ".join(names)}')
    missing = [n for n in names if n not in data]
    if missing:
        raise ConfigError(f'{source}: missing field(s) {", ".join(missing)}')


class ParamSet:
    """Base of the frozen parameter dataclasses (SI units): every field is checked against
    ``UNITS`` and ``BOUNDS`` (``check_parameter``: ConfigError naming 'vehicle.<field>')."""

    NAMES: ClassVar[tuple[str, ...]]
    UNITS: ClassVar[dict[str, str]]
    BOUNDS: ClassVar[dict[str, tuple[float, float]]]

    def __post_init__(self) -> None:
        for f in fields(self):  # type: ignore[arg-type]
            object.__setattr__(self, f.name, check_parameter(
                f'vehicle.{f.name}', getattr(self, f.name), self.UNITS[f.name],
                self.BOUNDS[f.name]))

    def as_array(self) -> np.ndarray:
        """Return the parameters as a float array of shape (n,), ordered as NAMES."""
        return np.array([getattr(self, n) for n in self.NAMES])

    def as_dict(self) -> dict[str, float]:
        """Return the parameters as a plain dict."""
        return asdict(self)  # type: ignore[call-overload]


@dataclass(frozen=True)
class VehicleParams(ParamSet):
    """Quarter-vehicle parameters (SI units); defaults are the paper's Table 1. Each must lie
    in ``PARAM_BOUNDS`` (ConfigError naming the field otherwise)."""

    NAMES: ClassVar[tuple[str, ...]] = PARAM_NAMES
    UNITS: ClassVar[dict[str, str]] = PARAM_UNITS
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = PARAM_BOUNDS

    m_s: float = 9875.0
    m_us: float = 1100.0
    k_s: float = 2.13e6
    k_us: float = 1.42e8
    c: float = 1.2e5

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = 'vehicle') -> VehicleParams:
        """Build from a mapping with every field present; unknown or missing keys are errors."""
        check_fields(data, PARAM_NAMES, source)
        return cls(**{n: data[n] for n in PARAM_NAMES})


def load_vehicle(path: str | Path) -> VehicleParams:
    """Load ``vehicle:`` parameters from a YAML file such as ``config/vehicle.yaml``."""
    doc = load_yaml(path)
    try:
        return vehicle_from_doc(doc)
    except ConfigError as exc:
        raise ConfigError(f'{path}: {exc}') from None


def vehicle_from_doc(doc: Any) -> VehicleParams:
    """The quarter car of a parsed vehicle file: its ``vehicle:`` section. A file of another
    model (``model: coach``) is refused by name (ConfigError without the file name)."""
    if isinstance(doc, dict) and doc.get('model', 'quarter_car') != 'quarter_car':
        raise ConfigError(f'model: {doc["model"]!r}: this entry point takes a quarter car '
                          '(vehicle: m_s, m_us, k_s, k_us, c; docs/vehicles.md)')
    section = doc.get('vehicle') if isinstance(doc, dict) else None
    if section is None:
        raise ConfigError('missing top-level "vehicle:" section')
    return VehicleParams.from_mapping(section)


def as_theta(params: VehicleParams | np.ndarray | Mapping[str, float]) -> np.ndarray:
    """Coerce parameters to a float array of shape (..., 5)."""
    if isinstance(params, VehicleParams):
        return params.as_array()
    if isinstance(params, Mapping):
        return VehicleParams.from_mapping(params).as_array()
    theta = np.asarray(params, dtype=float)
    if theta.shape[-1:] != (5,):
        raise ValueError(f'theta must have shape (..., 5) ordered as {PARAM_NAMES}, '
                         f'got {theta.shape}')
    return theta


def state_space(params: VehicleParams | np.ndarray) -> tuple[np.ndarray, ...]:
    """Return (A, B, C_s, C_us) of Eq. 2: shapes (..., 4, 4), (..., 4, 1), (..., 1, 4) twice.

    C_s maps the state to the sprung acceleration (no feedthrough), C_us to the unsprung one,
    whose feedthrough k_us / m_us comes from ``feedthrough``.
    """
    m_s, m_us, k_s, k_us, c = np.moveaxis(as_theta(params), -1, 0)
    zero, one = np.zeros_like(m_s), np.ones_like(m_s)
    row_s = [-c / m_s, c / m_s, -k_s / m_s, k_s / m_s]
    row_us = [c / m_us, -c / m_us, k_s / m_us, -(k_s + k_us) / m_us]
    a = np.stack([np.stack(row_s, -1), np.stack(row_us, -1),
                  np.stack([one, zero, zero, zero], -1),
                  np.stack([zero, one, zero, zero], -1)], -2)
    b = np.stack([zero, k_us / m_us, zero, zero], -1)[..., None]
    return a, b, a[..., 0:1, :], a[..., 1:2, :]


def feedthrough(params: VehicleParams | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(D_s, D_us), shapes (..., 1, 1): 0 for the sprung output, k_us / m_us (1/s^2) for the
    unsprung one (the wheel acceleration responds directly to the irregularity)."""
    theta = as_theta(params)
    d_us = (theta[..., 3] / theta[..., 1])[..., None, None]
    return np.zeros_like(d_us), d_us


def tf_polynomials(params: VehicleParams | np.ndarray) -> tuple[np.ndarray, ...]:
    """Coefficients, highest power first, of G_s = num_s/den and G_us = num_us/den (Eq. 3).

    Derived by hand from Eq. 1 (exact, no ill-conditioned ss2tf):
    den    = m_s m_us s^4 + c (m_s + m_us) s^3 + (k_s (m_s + m_us) + k_us m_s) s^2
             + c k_us s + k_s k_us
    num_s  = k_us (c s + k_s) s^2
    num_us = k_us (m_s s^2 + c s + k_s) s^2
    All three are divided by m_s m_us so that den is monic. Shapes (..., 5).
    """
    m_s, m_us, k_s, k_us, c = np.moveaxis(as_theta(params), -1, 0)
    zero = np.zeros_like(m_s)
    den = np.stack([m_s * m_us, c * (m_s + m_us), k_s * (m_s + m_us) + k_us * m_s,
                    c * k_us, k_s * k_us], -1)
    num_s = np.stack([zero, k_us * c, k_us * k_s, zero, zero], -1)
    num_us = np.stack([k_us * m_s, k_us * c, k_us * k_s, zero, zero], -1)
    scale = (m_s * m_us)[..., None]
    return num_s / scale, num_us / scale, den / scale


def frequency_response(params: VehicleParams | np.ndarray, s: np.ndarray,
                       output: str = 'sprung') -> np.ndarray:
    """G(s) for complex ``s`` (rad/s), shape theta.shape[:-1] + s.shape; output sprung|unsprung."""
    num_s, num_us, den = tf_polynomials(params)
    num = {'sprung': num_s, 'unsprung': num_us}[output]
    s = np.asarray(s)
    expand = (Ellipsis,) + (None,) * s.ndim
    top, bottom = num[..., 0][expand], den[..., 0][expand]
    for i in range(1, num.shape[-1]):  # Horner: complex powers cost 10x more
        top = top * s + num[..., i][expand]
        bottom = bottom * s + den[..., i][expand]
    return top / bottom


def poles(params: VehicleParams | np.ndarray) -> np.ndarray:
    """Open-loop poles (rad/s) = eigenvalues of A, shape (..., 4)."""
    return np.linalg.eigvals(state_space(params)[0])


def zeros_sprung(params: VehicleParams | np.ndarray) -> np.ndarray:
    """Zeros (rad/s) of G_s: a double zero at 0 and -k_s/c; shape (..., 3)."""
    theta = as_theta(params)
    k_s, c = theta[..., 2], theta[..., 4]
    zero = np.zeros_like(k_s)
    return np.stack([zero, zero, -k_s / c], -1)


@dataclass(frozen=True)
class Mode:
    """One vibration mode: natural frequency (Hz), damping ratio and the pole (rad/s)."""

    natural_frequency_hz: float
    damping_ratio: float
    pole: complex


def modes(params: VehicleParams) -> list[Mode]:
    """The two modes (bounce of the car body, wheel hop), sorted by natural frequency."""
    p = poles(params)
    upper = p[p.imag > 0]
    out = [Mode(float(abs(z) / (2 * np.pi)), float(-z.real / abs(z)), complex(z)) for z in upper]
    return sorted(out, key=lambda m: m.natural_frequency_hz)
