"""Vertical multibody coach: 10 degrees of freedom, vectorised over the parameters.

Coordinates q (m, rad), z up, pitch positive nose (+x) down (REP 103 rotation about +y):
``[z_c, th_c, z_b1, th_b1, z_b2, th_b2, z_w1, z_w2, z_w3, z_w4]``: car body bounce and pitch,
the leading (1) and trailing (2) bogie frame's bounce and pitch, the four wheelsets' bounce
(leading first). A point at x (m, forward of a body's centre) moves z - x th.

Geometry (known, not in theta): bogie centres at x = +-L/2 on the car body (L = bogie spacing),
wheelsets at +-a/2 about their bogie centre (a = wheelbase), IMUs at x_p on the car body.
Elements, each a spring and a damper in parallel between two points:
- secondary: per bogie side between the car body at the bogie centre and the bogie frame
  (2 sides per bogie: 2 k_s, 2 c_s per bogie);
- primary: per axle box between the bogie frame above the wheelset and the wheelset (2 axle
  boxes per wheelset: 2 k_p, 2 c_p per wheelset);
- contact: the linearised Hertz spring per wheel between the wheelset and the rail
  (2 wheels: 2 k_h per wheelset), whose other end follows the profile u_w under wheelset w.
Equations: M q'' + C q' + K q = K_u u with K = sum k_e g_e g_e^T (g_e: the element's
extension per unit q; virtual work gives the pitch moments) and K_u = 2 k_h per wheelset.
State x = [q, q'] (20); outputs: the car-body acceleration at each IMU, z_c'' - x_p th_c''
(m/s^2), and the pitch rate th_c' (rad/s).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
import re
from typing import Any, ClassVar

import numpy as np

from railgsa_ros.config import key_list
from railgsa_ros.errors import ConfigError
from railgsa_ros.models.base import ModeInfo, delayed_sum
from railgsa_ros.vehicle import ParamSet, check_fields, check_parameter

PARAM_NAMES = ('m_c', 'J_c', 'm_b', 'J_b', 'm_w', 'k_p', 'c_p', 'k_s', 'c_s', 'k_h')
PARAM_UNITS = {'m_c': 'kg', 'J_c': 'kg*m^2', 'm_b': 'kg', 'J_b': 'kg*m^2', 'm_w': 'kg',
               'k_p': 'N/m', 'c_p': 'N*s/m', 'k_s': 'N/m', 'c_s': 'N*s/m', 'k_h': 'N/m'}
PARAM_DOCS = {'m_c': 'car-body mass', 'J_c': 'car-body pitch inertia about its centre',
              'm_b': 'bogie-frame mass (each bogie)', 'J_b': 'bogie-frame pitch inertia (each)',
              'm_w': 'wheelset mass (each)', 'k_p': 'primary stiffness per axle box',
              'c_p': 'primary damping per axle box', 'k_s': 'secondary stiffness per bogie side',
              'c_s': 'secondary damping per bogie side',
              'k_h': 'linearised wheel-rail contact stiffness per wheel'}
#: Physical range of each parameter (inclusive): a passenger or freight car, generous; values
#: outside are typing or unit errors (tonnes for kg, kN/m for N/m).
PARAM_BOUNDS = {'m_c': (5e3, 1.5e5), 'J_c': (1e5, 1e8), 'm_b': (300.0, 2e4),
                'J_b': (100.0, 1e5), 'm_w': (300.0, 5e3), 'k_p': (1e4, 1e8),
                'c_p': (10.0, 1e6), 'k_s': (1e4, 1e8), 'c_s': (10.0, 1e6),
                'k_h': (1e7, 1e11)}
GEOMETRY_BOUNDS = {'bogie_spacing_m': (4.0, 40.0), 'wheelbase_m': (1.0, 5.0)}
IMU_REACH = 0.75  # an IMU lies within this fraction of the bogie spacing from the centre
N_DOF = 10
ZC, TC = 0, 1
ZB, TB, ZW = (2, 4), (3, 5), (6, 7, 8, 9)
BOGIE_OF = (0, 0, 1, 1)  # the bogie of each wheelset
MASS_INDEX = (0, 1, 2, 3, 2, 3, 4, 4, 4, 4)  # theta index of each coordinate's mass/inertia
MODE_GROUPS = {'car-body bounce': (ZC,), 'car-body pitch': (TC,), 'bogie bounce': ZB,
               'bogie pitch': TB, 'wheelset hop': ZW}
SOLVE_BATCH = 50_000  # complex 10x10 systems solved at once (about 80 MB)
MODAL_COND = 1e8  # above this eigenvector condition number, solve instead of the modal sum


@dataclass(frozen=True)
class CoachParams(ParamSet):
    """Coach parameters (SI units): the Manchester benchmark passenger coach (Iwnicki 1998,
    vehicle 1; docs/vehicles.md) with a contact stiffness of 1e9 N/m per wheel. Each must lie
    in ``PARAM_BOUNDS`` (ConfigError naming the field otherwise)."""

    NAMES: ClassVar[tuple[str, ...]] = PARAM_NAMES
    UNITS: ClassVar[dict[str, str]] = PARAM_UNITS
    BOUNDS: ClassVar[dict[str, tuple[float, float]]] = PARAM_BOUNDS

    m_c: float = 32000.0
    J_c: float = 1.97e6
    m_b: float = 2615.0
    J_b: float = 1476.0
    m_w: float = 1813.0
    k_p: float = 1.2e6
    c_p: float = 4.0e3
    k_s: float = 4.3e5
    c_s: float = 2.0e4
    k_h: float = 1.0e9


@dataclass(frozen=True)
class ImuPosition:
    """An IMU on the car-body floor: a name (letters, digits, _) and x (m, forward of the car-body
    centre, + towards the leading bogie)."""

    name: str
    x_m: float


@dataclass(frozen=True)
class CoachGeometry:
    """Known geometry: bogie spacing L (m, between bogie centres = 2 x semi-spacing), wheelbase
    a (m, between a bogie's wheelsets), the IMUs (the first is the primary one) and the output
    reference wheelset (1 = leading ... 4 = trailing)."""

    bogie_spacing_m: float = 19.0
    wheelbase_m: float = 2.56
    imus: tuple[ImuPosition, ...] = (ImuPosition('primary', 9.5),)
    reference_wheelset: int = 1

    def __post_init__(self) -> None:
        for name, bounds in GEOMETRY_BOUNDS.items():
            object.__setattr__(self, name, check_parameter(f'geometry.{name}',
                                                           getattr(self, name), 'm', bounds))
        if self.wheelbase_m >= self.bogie_spacing_m:
            raise ConfigError(f'geometry.wheelbase_m: {self.wheelbase_m:g} m must be shorter '
                              f'than bogie_spacing_m {self.bogie_spacing_m:g} m')
        if not self.imus:
            raise ConfigError('imus: expected at least one IMU position')
        reach = IMU_REACH * self.bogie_spacing_m
        names = [imu.name for imu in self.imus]
        for i, imu in enumerate(self.imus):
            if not isinstance(imu.name, str) or not re.fullmatch(r'[A-Za-z0-9_]+', imu.name):
                raise ConfigError(f'imus[{i}].name: expected letters, digits or _, '
                                  f'got {imu.name!r}')
            if imu.name in names[:i]:
                raise ConfigError(f'imus[{i}].name: {imu.name!r} is given twice')
            x = imu.x_m
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not abs(x) <= reach:
                raise ConfigError(f'imus[{i}].x_m: expected a number within +-{reach:g} m of '
                                  f'the car-body centre (m, forward +), got {x!r}')
        ref = self.reference_wheelset
        if isinstance(ref, bool) or ref not in (1, 2, 3, 4):
            raise ConfigError(f'reference_wheelset: expected 1, 2, 3 or 4, got {ref!r}')

    @property
    def wheel_x_m(self) -> np.ndarray:
        """x (m) of the wheelsets on the car body, leading first."""
        half_l, half_a = self.bogie_spacing_m / 2, self.wheelbase_m / 2
        return np.array([half_l + half_a, half_l - half_a, -half_l + half_a, -half_l - half_a])

    @property
    def bogie_x_m(self) -> np.ndarray:
        """x (m) of the bogie centres, leading first."""
        return np.array([1.0, -1.0]) * self.bogie_spacing_m / 2


def _unit(index: int) -> np.ndarray:
    e = np.zeros(N_DOF)
    e[index] = 1.0
    return e


def element_matrices(geometry: CoachGeometry) -> dict[str, np.ndarray]:
    """Geometric matrices: 'secondary', 'primary', 'contact' = sum of g g^T over the
    elements of that kind (10, 10), 'input' (10, 4): the contact's profile input per unit
    stiffness. K = 2 (k_s S_sec + k_p S_prim + k_h S_cont), K_u = 2 k_h E."""
    sec = np.zeros((N_DOF, N_DOF))
    for i, x_b in enumerate(geometry.bogie_x_m):  # bogie frame minus car body at x_b
        g = _unit(ZB[i]) - _unit(ZC) + x_b * _unit(TC)
        sec += np.outer(g, g)
    prim = np.zeros((N_DOF, N_DOF))
    for w, x_w in enumerate(geometry.wheel_x_m):  # wheelset minus bogie frame above it
        i = BOGIE_OF[w]
        g = _unit(ZW[w]) - _unit(ZB[i]) + (x_w - geometry.bogie_x_m[i]) * _unit(TB[i])
        prim += np.outer(g, g)
    contact = np.zeros((N_DOF, N_DOF))
    inputs = np.zeros((N_DOF, 4))
    for w in range(4):
        contact[ZW[w], ZW[w]] = inputs[ZW[w], w] = 1.0
    return {'secondary': sec, 'primary': prim, 'contact': contact, 'input': inputs}


class CoachModel:
    """The 10-DOF coach as a ``VehicleModel``: nominal ``params`` and known ``geometry``."""

    kind = 'coach'
    param_names: tuple[str, ...] = PARAM_NAMES
    units = PARAM_UNITS
    docs = PARAM_DOCS
    bounds = PARAM_BOUNDS

    def __init__(self, params: CoachParams | None = None,
                 geometry: CoachGeometry | None = None) -> None:
        self.params = CoachParams() if params is None else params
        self.geometry = CoachGeometry() if geometry is None else geometry
        self.theta = self.params.as_array()
        imus = self.geometry.imus
        self.channels: tuple[str, ...] = ('accel_z', 'pitch_rate',
                                          *(f'accel_z:{m.name}' for m in imus[1:]))
        x_w = self.geometry.wheel_x_m
        self.wheel_offsets_m = x_w[self.geometry.reference_wheelset - 1] - x_w
        self._elements = element_matrices(self.geometry)
        x_p = np.array([imu.x_m for imu in imus])
        self._accel_rows = _unit(ZC)[None, :] - x_p[:, None] * _unit(TC)[None, :]  # (I, 10)
        # each channel as a displacement (the IMU point, the pitch angle) times s^power
        self._output_rows = np.concatenate([self._accel_rows[:1], _unit(TC)[None, :],
                                            self._accel_rows[1:]])
        self._powers = np.array([2, 1] + [2] * (len(imus) - 1))

    def as_dict(self) -> dict[str, float]:
        """The nominal parameters by name (SI units), as VehicleParams.as_dict."""
        return self.params.as_dict()

    @classmethod
    def from_doc(cls, doc: Mapping[str, Any]) -> CoachModel:
        """From a parsed coach file (config/vehicles/coach.yaml): ``model: coach``,
        ``vehicle:`` (every PARAM_NAMES field), ``geometry:`` (bogie_spacing_m, wheelbase_m),
        ``imus:`` (a list of {name, x_m}, the primary first) and ``reference_wheelset``."""
        known = {'model', 'vehicle', 'geometry', 'imus', 'reference_wheelset'}
        unknown = set(doc) - known
        if unknown:
            raise ConfigError(f'unknown top-level key(s) {key_list(unknown)}; expected '
                              f'{", ".join(sorted(known))}')
        for key in ('vehicle', 'geometry', 'imus'):
            if doc.get(key) is None:
                raise ConfigError(f'missing top-level "{key}:" section')
        check_fields(doc['vehicle'], PARAM_NAMES, 'vehicle')
        params = CoachParams(**{n: doc['vehicle'][n] for n in PARAM_NAMES})
        check_fields(doc['geometry'], tuple(GEOMETRY_BOUNDS), 'geometry')
        imus = doc['imus']
        if not isinstance(imus, list):
            raise ConfigError('imus: expected a list of {name: ..., x_m: ...}')
        positions = []
        for i, imu in enumerate(imus):
            check_fields(imu, ('name', 'x_m'), f'imus[{i}]')
            positions.append(ImuPosition(imu['name'], imu['x_m']))
        geometry = CoachGeometry(**doc['geometry'], imus=tuple(positions),
                                 reference_wheelset=doc.get('reference_wheelset', 1))
        return cls(params, geometry)

    def matrices(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                    np.ndarray]:
        """(mass diagonal (..., 10), C (..., 10, 10), K (..., 10, 10), K_u (..., 10, 4)) of
        M q'' + C q' + K q = K_u u for theta (..., 10)."""
        theta = _theta(theta)
        el = self._elements

        def scaled(element: str, param: str) -> np.ndarray:
            """2 x the parameter (two axle boxes, sides or wheels) x the element's matrix."""
            return 2.0 * theta[..., PARAM_NAMES.index(param), None, None] * el[element]

        k = scaled('secondary', 'k_s') + scaled('primary', 'k_p') + scaled('contact', 'k_h')
        c = scaled('secondary', 'c_s') + scaled('primary', 'c_p')
        return theta[..., MASS_INDEX], c, k, scaled('input', 'k_h')

    def state_space(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray]:
        """(A (..., 20, 20), B (..., 20, 4), C (..., n_channels, 20), D (..., n_channels, 4)):
        state [q, q'], inputs the four wheelsets' profiles (m), outputs ``channels``."""
        mass, c, k, k_u = self.matrices(theta)
        minv = 1.0 / mass[..., :, None]
        lead = mass.shape[:-1]
        a = np.zeros((*lead, 2 * N_DOF, 2 * N_DOF))
        a[..., :N_DOF, N_DOF:] = np.eye(N_DOF)
        a[..., N_DOF:, :N_DOF] = -minv * k
        a[..., N_DOF:, N_DOF:] = -minv * c
        b = np.zeros((*lead, 2 * N_DOF, 4))
        b[..., N_DOF:, :] = minv * k_u
        accel_c = self._accel_rows @ a[..., N_DOF:, :]  # (..., I, 20)
        accel_d = self._accel_rows @ b[..., N_DOF:, :]  # (..., I, 4): zero (no car-body input)
        rate_c = np.zeros((*lead, 1, 2 * N_DOF))
        rate_c[..., 0, N_DOF + TC] = 1.0
        c_out = np.concatenate([accel_c[..., :1, :], rate_c, accel_c[..., 1:, :]], axis=-2)
        d_out = np.concatenate([accel_d[..., :1, :], np.zeros((*lead, 1, 4)),
                                accel_d[..., 1:, :]], axis=-2)
        return a, b, c_out, d_out

    def frequency_response(self, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        """(..., C, 4, F): each channel per metre of profile under one wheelset at complex
        frequencies s (F,) rad/s: (m/s^2)/m for accelerations, (rad/s)/m for the pitch rate.

        Modal sum: with A = V diag(lambda) V^-1, an output row r gives
        sum_k (r V)_k (V^-1 B)_k / (s - lambda_k): one 20 x 20 eigen-decomposition per
        parameter set instead of a solve per frequency. Below the lowest natural frequency the
        rows are the outputs' displacements (the IMU point, the pitch angle) times s^2 or s,
        which tend to their static values (the state space's acceleration rows cancel to zero
        there); above it the state space's C and D (whose displacement form would cancel). A
        parameter set whose eigenvectors are ill-conditioned (cond > MODAL_COND: nearly
        defective) is solved directly, (s^2 M + s C + K) Q = K_u per frequency."""
        theta = _theta(theta)
        s = np.asarray(s, dtype=complex).reshape(-1)
        a, b, c, d = self.state_space(theta)
        lam, vec = np.linalg.eig(a)
        load = np.swapaxes(np.linalg.solve(vec, b.astype(complex)), -1, -2)  # (..., 4, 20)
        poles = 1.0 / (s - lam[..., :, None])  # (..., 20, F)

        def modal(rows: np.ndarray) -> np.ndarray:
            residues = (rows @ vec)[..., :, None, :] * load[..., None, :, :]  # (.., C, 4, 20)
            return np.einsum('...cwk,...kf->...cwf', residues, poles)

        rows = np.concatenate([self._output_rows, np.zeros_like(self._output_rows)], axis=-1)
        low = modal(rows) * s ** self._powers[:, None, None]
        high = modal(c) + d[..., None]
        below = np.abs(s) < np.abs(lam).min(axis=-1)[..., None, None, None]
        out = np.where(below, low, high)
        defective = np.linalg.cond(vec) > MODAL_COND
        if np.any(defective):
            out[defective] = self._solved(theta[defective], s)
        return out

    def _solved(self, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        """``frequency_response`` by a linear solve per frequency, in batches of SOLVE_BATCH."""
        mass, c, k, k_u = self.matrices(theta)
        lead = mass.shape[:-1]
        out = np.empty((*lead, len(self.channels), 4, s.size), dtype=complex)
        step = max(1, SOLVE_BATCH // max(1, math.prod(lead)))
        for lo in range(0, s.size, step):
            sf = s[lo:lo + step]
            dyn = (sf[:, None, None] ** 2 * np.eye(N_DOF)) * mass[..., None, None, :] \
                + sf[:, None, None] * c[..., None, :, :] + k[..., None, :, :]  # (.., Fc, 10, 10)
            q = np.linalg.solve(dyn, np.broadcast_to(k_u[..., None, :, :], (*dyn.shape[:-1], 4)))
            out[..., lo:lo + step] = np.einsum('cj,...fjw->...cwf', self._output_rows, q) \
                * sf ** self._powers[:, None, None]
        return out

    def track_response(self, theta: np.ndarray, f_hz: np.ndarray,
                       speed_mps: float) -> np.ndarray:
        """(..., C, F): the channels per metre of profile at the reference wheelset, the four
        wheelsets summed with their delays d_w / v (``wheel_offsets_m``)."""
        f_hz = np.asarray(f_hz, dtype=float).reshape(-1)
        return delayed_sum(self.frequency_response(theta, 2j * np.pi * f_hz),
                           self.wheel_offsets_m, f_hz, speed_mps)

    def null_wavelengths(self, channel: str, shortest_m: float = 1.0) -> np.ndarray:
        """Wavelengths (m, >= shortest_m, descending) at which ``channel``'s track response is
        zero whatever the parameters and the speed, in closed form (front and rear bogies are
        alike): a bogie's two wheelsets cancel at 2a/(2n+1) for every car-body signal; a
        car-centre IMU sees bounce only (2L/(2n+1)); the pitch rate sees pitch only (L/n)."""
        a, span = self.geometry.wheelbase_m, self.geometry.bogie_spacing_m
        odd = 2.0 * np.arange(1, int(2 * span / shortest_m) + 2) - 1.0  # 1, 3, 5, ...
        found = [2 * a / odd]
        if channel == 'pitch_rate':
            found.append(span / np.arange(1, int(span / shortest_m) + 1))
        elif self._imu_x(channel) == 0.0:
            found.append(2 * span / odd)
        waves = np.concatenate(found)
        return np.unique(waves[waves >= shortest_m])[::-1]

    def _imu_x(self, channel: str) -> float:
        """x (m) of the IMU of an ``accel_z`` channel (ValueError for another channel)."""
        if channel not in self.channels or channel == 'pitch_rate':
            raise ValueError(f'not an acceleration channel of this coach: {channel!r}')
        index = 0 if channel == 'accel_z' else 1 + self.channels[2:].index(channel)
        return float(self.geometry.imus[index].x_m)

    def modes(self, theta: np.ndarray | None = None) -> list[ModeInfo]:
        """The modes of one parameter set (default the nominal), by frequency: each pair of
        complex poles, named for the bodies that hold most of its kinetic energy (an
        overdamped mode's real poles are listed each with zeta = 1)."""
        theta = self.theta if theta is None else _theta(theta)
        if theta.ndim != 1:
            raise ValueError(f'modes: one parameter set (10,), got {theta.shape}')
        a = self.state_space(theta)[0]
        poles, vectors = np.linalg.eig(a)
        mass = theta[list(MASS_INDEX)]
        out = []
        for pole, vec in zip(poles, vectors.T, strict=True):
            if pole.imag < 0:
                continue
            energy = mass * np.abs(vec[:N_DOF]) ** 2
            name = _mode_name(energy, vec[:N_DOF])
            if pole.imag == 0:
                out.append(ModeInfo(abs(pole) / (2 * np.pi), 1.0, f'{name} (overdamped)'))
            else:
                out.append(ModeInfo(abs(pole) / (2 * np.pi), -pole.real / abs(pole), name))
        return sorted(out, key=lambda m: m.f_hz)


def _theta(theta: np.ndarray) -> np.ndarray:
    theta = np.asarray(theta, dtype=float)
    if theta.shape[-1:] != (len(PARAM_NAMES),):
        raise ValueError(f'theta must have shape (..., {len(PARAM_NAMES)}) ordered as '
                         f'{PARAM_NAMES}, got {theta.shape}')
    return theta


def _mode_name(energy: np.ndarray, shape: np.ndarray) -> str:
    """The group of coordinates with most of the energy; for two bogies, which one or both
    (in phase or antiphase); for the wheelsets, those above a fifth of the group's energy."""
    group, index = max(MODE_GROUPS.items(), key=lambda kv: energy[list(kv[1])].sum())
    part = energy[list(index)] / energy[list(index)].sum()
    if len(index) == 2:
        if part.max() > 0.9:
            return f'{group}, {("leading", "trailing")[int(np.argmax(part))]}'
        phase = (shape[index[0]] * np.conj(shape[index[1]])).real
        return f'{group}, {"in phase" if phase > 0 else "antiphase"}'
    if len(index) == 4:
        major = ', '.join(str(w + 1) for w in np.flatnonzero(part > 0.2))
        return f'{group}, wheelset {major}'
    return group
