"""One simulated run: track profile + quarter vehicle + MEMS IMU -> stamped data with truth.

The vehicle runs over the profile at a given speed (constant or a speed profile in time). The
forward model runs at an internal rate that is a multiple q >= 2 of the IMU output rate, at least
MIN_SIM_RATE_HZ (resolves the 57 Hz wheel-hop mode) and at least POINTS_PER_WAVELENGTH samples over
the shortest wavelength or defect at the top speed. Output sample k is the simulation sample k q,
so accel, speed, chainage and truth all refer to the same true sample time t = k / rate_hz.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.integrate import cumulative_trapezoid

from railgsa_ros.errors import ConfigError
from railgsa_ros.imu import FRAME_ID, ImuSpec, accel_covariance, imu_spec, measure
from railgsa_ros.simulate import simulate
from railgsa_ros.speed_profile import SpeedProfile
from railgsa_ros.track import DEFAULT_WAVELENGTHS, apply_defects, make_profile, parse_defects
from railgsa_ros.vehicle import VehicleParams, load_vehicle

MIN_SIM_RATE_HZ = 2000.0
DEFAULT_START_NS = 1_700_000_000 * 10**9  # 2023-11-14: realistic, non-zero (nodes refuse 0)
POINTS_PER_WAVELENGTH = 20


@dataclass(frozen=True)
class Run:
    """A simulated run at the delivered IMU samples (dropped samples removed), all shape (T,).

    stamps_ns: int64 sensor stamps (clock drift and jitter included); accel: (T, 3) specific
    force in ``frame_id`` (m/s^2, +g on z); t_true_s: true sample times (s); speed_mps and
    chainage_m (m) at the true time; truth_u_m: irregularity under the wheel at the true time (m).
    """

    stamps_ns: np.ndarray
    accel: np.ndarray
    t_true_s: np.ndarray
    speed_mps: np.ndarray
    chainage_m: np.ndarray
    truth_u_m: np.ndarray
    rate_hz: float
    sim_rate_hz: float
    accel_covariance: float  # per-axis variance for the REP 145 diagonal, (m/s^2)^2
    n_dropped: int
    sensor: ImuSpec
    vehicle: VehicleParams | np.ndarray
    profile: str
    defects: str | None
    seed: int | None
    frame_id: str = FRAME_ID


Speed = float | np.ndarray | SpeedProfile


def check_speed(speed_mps: Speed) -> np.ndarray:
    """Validated speed (m/s): a 0-d array, or a 1-d profile of at least two samples (a
    SpeedProfile is valid by construction: returned as its maximum)."""
    if isinstance(speed_mps, SpeedProfile):
        return np.asarray(speed_mps.max_speed_mps)
    speed = np.asarray(speed_mps, dtype=float)
    if speed.ndim > 1 or (speed.ndim == 1 and speed.size < 2):
        raise ConfigError('speed: expected a number or at least two samples (m/s)')
    if not np.all(np.isfinite(speed)) or np.any(speed < 0) or speed.max() <= 0:
        raise ConfigError(f'speed: must be finite, >= 0 and not all zero (m/s), got {speed_mps!r}')
    return speed


def speed_at(t_s: np.ndarray, speed_mps: Speed, duration_s: float) -> np.ndarray:
    """Speed (m/s) at times t_s: a constant, samples spread evenly over [0, duration_s], or a
    SpeedProfile (its last speed held after its end)."""
    if isinstance(speed_mps, SpeedProfile):
        return speed_mps(t_s)
    speed = check_speed(speed_mps)
    if speed.ndim == 0:
        return np.full_like(t_s, float(speed))
    return np.interp(t_s, np.linspace(0.0, duration_s, speed.size), speed)


def simulation_rate(rate_hz: float, v_max: float, shortest_m: float,
                    points: int = POINTS_PER_WAVELENGTH) -> tuple[float, int]:
    """(simulation rate Hz, q): q * rate_hz >= MIN_SIM_RATE_HZ and points * v_max / shortest_m."""
    needed = max(MIN_SIM_RATE_HZ, points * v_max / shortest_m)
    q = max(2, int(np.ceil(needed / rate_hz - 1e-9)))
    return q * rate_hz, q


def _vehicle(vehicle: VehicleParams | np.ndarray | str | Path | None
             ) -> VehicleParams | np.ndarray:
    if vehicle is None:
        return VehicleParams()
    if isinstance(vehicle, (str, Path)):
        return load_vehicle(vehicle)
    return vehicle


def run_scenario(profile_spec: str, speed_mps: Speed, duration_s: float,
                 rate_hz: float | None, sensor: str | ImuSpec, seed: int | None = 0,
                 defects: str | list | None = None,
                 vehicle: VehicleParams | np.ndarray | str | Path | None = None, *,
                 wavelength_range: tuple[float, float] = DEFAULT_WAVELENGTHS,
                 start_ns: int = DEFAULT_START_NS) -> Run:
    """Simulate one run; see the module docstring.

    profile_spec: german-low|german-high|fra-N|paper|file:CSV (track.make_profile); speed_mps: a
    constant, samples spread evenly over the duration or a ``speed_profile.SpeedProfile``
    (m/s); duration_s (s); rate_hz: IMU output rate (None:
    the preset's); sensor: preset name or ImuSpec; seed drives profile and sensor (independent
    streams); defects: spec string or list (track.parse_defects); vehicle: VehicleParams, theta
    (5,), a vehicle YAML path or None (Table 1); start_ns: stamp of the first sample (ns;
    default DEFAULT_START_NS: a zero stamp is malformed for the nodes).
    """
    spec = imu_spec(sensor) if isinstance(sensor, str) else sensor
    if rate_hz is not None:
        spec = replace(spec, output_rate_hz=rate_hz)
    rate = spec.output_rate_hz
    n_out = round(duration_s * rate) if np.isfinite(duration_s) else 0
    if n_out < 2:
        raise ConfigError(f'duration: {duration_s!r} s gives fewer than two samples at '
                          f'{rate:g} Hz')
    defect_list = parse_defects(defects) if not isinstance(defects, list) else defects
    shortest = min([wavelength_range[0]] + [d.shortest_wavelength for d in defect_list])
    fs_sim, q = simulation_rate(rate, float(check_speed(speed_mps).max()), shortest)

    t = np.arange(n_out * q) / fs_sim
    v = speed_at(t, speed_mps, duration_s)
    travel = cumulative_trapezoid(v, t, initial=0.0)
    # profile grid no coarser than the distance per simulation step: the forward model (first-
    # order hold) then sees the grid profile itself, with no extra interpolation kinks
    dx = float(np.max(v)) / fs_sim
    profile_seed, imu_seed = (int(child.generate_state(1)[0])
                              for child in np.random.SeedSequence(seed).spawn(2))
    x, u = make_profile(profile_spec, travel[-1] + dx, dx, profile_seed, wavelength_range)
    chainage = x[0] + travel
    u_sim = apply_defects(chainage, np.interp(chainage, x, u), defect_list)

    theta = _vehicle(vehicle)
    a_s, _ = simulate(u_sim, 1.0 / fs_sim, theta)
    imu = measure(t, a_s, spec, imu_seed)
    keep = imu.valid
    pick = np.arange(n_out)[keep] * q
    return Run(stamps_ns=imu.stamps_ns[keep] + np.int64(start_ns), accel=imu.accel[keep],
               t_true_s=imu.t_true_s[keep], speed_mps=v[pick], chainage_m=chainage[pick],
               truth_u_m=u_sim[pick], rate_hz=rate, sim_rate_hz=fs_sim,
               accel_covariance=accel_covariance(spec), n_dropped=int(np.sum(~keep)),
               sensor=spec, vehicle=theta, profile=profile_spec,
               defects=defects if isinstance(defects, str) else None, seed=seed)
