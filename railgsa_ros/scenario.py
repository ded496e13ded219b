"""One simulated run: track profile + vehicle + MEMS IMU -> stamped data with truth.

The vehicle runs over the profile at a given speed (constant or a speed profile in time). The
forward model runs at an internal rate that is a multiple q >= 2 of the IMU output rate, at least
MIN_SIM_RATE_HZ (resolves the 57 Hz wheel-hop mode) and at least POINTS_PER_WAVELENGTH samples over
the shortest wavelength or defect at the top speed. Output sample k is the simulation sample k q,
so accel, speed, chainage and truth all refer to the same true sample time t = k / rate_hz.
The vehicle starts at rest in equilibrium on the track under its first position (no start-up
transient from a step onto the irregularity there).

The vehicle is any ``models.VehicleModel`` (a vehicle file chooses it): each wheelset sees the
profile at its own chainage, chainage(t) - d_w (``wheel_offsets_m``: fixed offsets in distance,
so variable speed included), and the run's chainage and truth are the reference wheelset's.
A coach's pitch rate reaches the IMU's gyro (angular_velocity.y) when the sensor has one.

``RunStream`` produces the run in chunks of bounded size (profile, vehicle and sensor keep their
state across chunks: the chunks of a run are equal to its one-shot arrays); ``run_scenario``
gathers one stream into a single ``Run``. The profile is a function of chainage along the line
(``track.line_profile``): the same seed gives the same track whatever the start or the speed.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, fields, replace
from functools import partial
import math
from pathlib import Path
from typing import Any

import numpy as np

from railgsa_ros.errors import ConfigError
from railgsa_ros.imu import (
    FRAME_ID,
    ImuSamples,
    ImuSpec,
    MemsStream,
    accel_covariance,
    gyro_chain,
    gyro_covariance,
    imu_spec,
)
from railgsa_ros.models import VehicleModel, as_model, load_model
from railgsa_ros.simulate import WheelsetBank
from railgsa_ros.speed_profile import SpeedProfile
from railgsa_ros.track import DEFAULT_WAVELENGTHS, apply_defects, line_profile, parse_defects
from railgsa_ros.vehicle import VehicleParams

MIN_SIM_RATE_HZ = 2000.0
DEFAULT_START_NS = 1_700_000_000 * 10**9  # 2023-11-14: realistic, non-zero (nodes refuse 0)
POINTS_PER_WAVELENGTH = 20
DEFAULT_CHUNK_S = 60.0  # RunStream chunk: about 60 s of simulation (bounded memory)


@dataclass(frozen=True)
class Run:
    """A simulated run at the delivered IMU samples (dropped samples removed), all shape (T,).

    stamps_ns: int64 sensor stamps (clock drift and jitter included); accel: (T, 3) specific
    force in ``frame_id`` (m/s^2, +g on z); t_true_s: true sample times (s); speed_mps and
    chainage_m (m) at the true time; truth_u_m: irregularity under the wheel at the true time
    (m) (chainage and truth: the reference wheelset's). gyro: (T, 3) angular velocity in rad/s
    (REP 103; y = a coach's pitch rate) with its per-axis variance gyro_covariance ((rad/s)^2),
    or None when the sensor has no gyro or the vehicle no pitch. imu_names: the further IMUs of
    a coach file; imu_accel and imu_gyro (T, K, 3): their specific force and angular velocity
    at the primary's stamps (None without further IMUs, or without a gyro). track: u(x) (m) of
    the simulated track (defects included) at any chainage array x (m), also under the dropped
    samples (None in runs built by hand).
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
    vehicle: VehicleParams | np.ndarray | VehicleModel  # a quarter car's parameters or a model
    profile: str
    defects: str | None
    seed: int | None
    frame_id: str = FRAME_ID
    odom_scale: float = 1.0  # odometry speed = (1 + wheel-diameter error) * true speed
    gyro: np.ndarray | None = None
    gyro_covariance: float = -1.0
    imu_names: tuple[str, ...] = ()
    imu_accel: np.ndarray | None = None
    imu_gyro: np.ndarray | None = None
    track: Callable[[np.ndarray], np.ndarray] | None = field(default=None, compare=False,
                                                              repr=False)

    @classmethod
    def concat(cls, chunks: list[Run]) -> Run:
        """One run from consecutive chunks of a stream (arrays joined, dropouts summed)."""
        arrays: dict[str, Any] = {f.name: np.concatenate([getattr(c, f.name) for c in chunks])
                  for f in fields(cls) if isinstance(getattr(chunks[0], f.name), np.ndarray)
                  and f.name != 'vehicle'}
        return replace(chunks[0], n_dropped=sum(c.n_dropped for c in chunks), **arrays)


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


Vehicle = VehicleParams | np.ndarray | VehicleModel | str | Path | None


def _vehicle(vehicle: Vehicle) -> VehicleParams | np.ndarray | VehicleModel:
    """What a run records as its vehicle: a quarter car's parameters (Table 1 for None), else
    the model (a vehicle file's model)."""
    if vehicle is None:
        return VehicleParams()
    if isinstance(vehicle, (str, Path)):
        model: Any = load_model(vehicle)
        return model.params if model.kind == 'quarter_car' else model
    return vehicle


class RunStream:
    """One simulated run as an iterator of ``Run`` chunks of about ``chunk_s`` seconds.

    Arguments as ``run_scenario``. Chunk boundaries fall on multiples of the vehicle bank's
    block and of q, so every chunk equals the same slice of the one-shot run bit for bit.
    Memory is bounded by the chunk, whatever the duration.
    """

    def __init__(self, profile_spec: str, speed_mps: Speed, duration_s: float,
                 rate_hz: float | None, sensor: str | ImuSpec, seed: int | None = 0,
                 defects: str | list | None = None, vehicle: Vehicle = None, *,
                 wavelength_range: tuple[float, float] = DEFAULT_WAVELENGTHS,
                 start_ns: int = DEFAULT_START_NS, start_m: float | None = None,
                 line_seed: int | None = None, odom_scale: float = 1.0,
                 chunk_s: float = DEFAULT_CHUNK_S) -> None:
        spec = imu_spec(sensor) if isinstance(sensor, str) else sensor
        if rate_hz is not None:
            spec = replace(spec, output_rate_hz=rate_hz)
        self.spec = spec
        rate = spec.output_rate_hz
        self.n_out = round(duration_s * rate) if np.isfinite(duration_s) else 0
        if self.n_out < 2:
            raise ConfigError(f'duration: {duration_s!r} s gives fewer than two samples at '
                              f'{rate:g} Hz')
        if not (math.isfinite(odom_scale) and 0.9 < odom_scale < 1.1):
            raise ConfigError(f'odometry scale: {odom_scale!r} is not within 10 % of 1')
        self.defects = parse_defects(defects) if not isinstance(defects, list) else defects
        shortest = min([wavelength_range[0]] + [d.shortest_wavelength for d in self.defects])
        self.max_speed_mps = float(check_speed(speed_mps).max())
        self.fs_sim, self.q = simulation_rate(rate, self.max_speed_mps, shortest)
        self.speed, self.duration_s = speed_mps, float(duration_s)
        self.theta = _vehicle(vehicle)
        self.model = as_model(self.theta)
        # the track, then accelerometer and gyro of each IMU: one independent seed each (the
        # first two as before gyros and further IMUs existed)
        n_imus = 1 + sum(c.startswith('accel_z:') for c in self.model.channels)
        profile_seed, *self.imu_seeds = (int(child.generate_state(1)[0]) for child in
                                         np.random.SeedSequence(seed).spawn(1 + 2 * n_imus))
        self.line, origin = line_profile(profile_spec,
                                         profile_seed if line_seed is None else line_seed,
                                         wavelength_range)
        self.offsets_m = np.asarray(self.model.wheel_offsets_m, dtype=float)
        # by default every wheelset starts on the profile: the reference one the vehicle's
        # length behind the reference point ahead of the origin
        behind = max(0.0, float(self.offsets_m.max()))
        self.start_m = origin + behind if start_m is None else float(start_m)
        if not math.isfinite(self.start_m):
            raise ConfigError(f'start chainage: must be finite, got {start_m!r} m')
        self.bank = WheelsetBank(self.model, 1.0 / self.fs_sim)
        self.imus = CarBodyImus(spec, self.fs_sim, self.model.channels, self.imu_seeds)
        step = math.lcm(self.bank.block, self.q)
        self.chunk = step * max(1, int(min(chunk_s * self.fs_sim, 2.0 ** 62)) // step)
        self.template = Run(
            stamps_ns=np.zeros(0, np.int64), accel=np.zeros((0, 3)), t_true_s=np.zeros(0),
            speed_mps=np.zeros(0), chainage_m=np.zeros(0), truth_u_m=np.zeros(0),
            rate_hz=rate, sim_rate_hz=self.fs_sim, accel_covariance=accel_covariance(spec),
            n_dropped=0, sensor=spec, vehicle=self.theta, profile=profile_spec,
            defects=defects if isinstance(defects, str) else None, seed=seed,
            odom_scale=float(odom_scale), track=partial(_track, self.line, self.defects),
            gyro_covariance=gyro_covariance(spec) if self.imus.rate_row is not None else -1.0,
            imu_names=self.imus.names)
        self.start_ns = np.int64(start_ns)

    def __iter__(self) -> Iterator[Run]:
        """The chunks, from the start (each iteration is the whole run again)."""
        if self.imus.started:  # iterated before: start the sensors again
            self.imus = CarBodyImus(self.spec, self.fs_sim, self.model.channels, self.imu_seeds)
        reference = int(np.argmin(np.abs(self.offsets_m)))  # offset 0: the output chainage
        n_sim = self.n_out * self.q
        dt = 1.0 / self.fs_sim
        travel, v_last = np.zeros(1), None
        pending = [np.zeros(0)] * 3  # speed, chainage, truth of outputs not yet measured
        for lo in range(0, n_sim, self.chunk):
            hi = min(lo + self.chunk, n_sim)
            index = np.arange(lo, hi)
            v = speed_at(index * dt, self.speed, self.duration_s)
            # trapezoidal chainage, summed in one sequence across chunks (np.cumsum is serial)
            steps = 0.5 * (v[1:] + v[:-1]) * dt if v_last is None else \
                0.5 * (np.concatenate([[v_last], v[:-1]]) + v) * dt
            travel = np.cumsum(np.concatenate([travel[-1:], steps]))
            travel = travel if v_last is None else travel[1:]
            v_last = v[-1]
            chainage = self.start_m + travel
            wheels = np.stack([_track(self.line, self.defects, chainage - d)
                               for d in self.offsets_m])  # (W, n): each wheelset's profile
            u = wheels[reference]
            if lo == 0:  # the vehicle starts at rest on the track where it stands: no step
                self.bank.settle(wheels[:, 0])
            imu, *values = self.imus.process(self.bank.process(wheels)[0], final=hi == n_sim)
            out = index % self.q == 0
            pending = [np.concatenate([p, x[out]]) for p, x in
                       zip(pending, (v, chainage, u), strict=True)]
            n = imu.stamps_ns.size
            (speed, chain, truth), pending = [p[:n] for p in pending], [p[n:] for p in pending]
            keep = imu.valid
            yield replace(self.template, stamps_ns=imu.stamps_ns[keep] + self.start_ns,
                          accel=imu.accel[keep], t_true_s=imu.t_true_s[keep],
                          speed_mps=speed[keep], chainage_m=chain[keep],
                          truth_u_m=truth[keep], n_dropped=int(np.sum(~keep)),
                          gyro=_kept(values[0], keep), imu_accel=_kept(values[1], keep),
                          imu_gyro=_kept(values[2], keep))


class CarBodyImus:
    """The IMUs on the car body, run over a model's channels in chunks.

    Per IMU (the primary, then one per ``accel_z:<name>`` channel) an accelerometer
    ``MemsStream`` and, when the sensor has a gyro and the vehicle pitches, a gyro stream on the
    pitch rate (``gyro_chain``); ``seeds``: accelerometer and gyro seed of each IMU in turn.
    The further IMUs share the primary's stamps and dropouts (one logger): their values only.
    """

    def __init__(self, spec: ImuSpec, fs_sim: float, channels: tuple[str, ...],
                 seeds: list[int]) -> None:
        self.rows = [0] + [i for i, c in enumerate(channels) if c.startswith('accel_z:')]
        self.names = tuple(channels[i].split(':', 1)[1] for i in self.rows[1:])
        self.rate_row = channels.index('pitch_rate') \
            if spec.gyro and 'pitch_rate' in channels else None
        self.accel = [MemsStream(spec, fs_sim, s) for s in seeds[0:2 * len(self.rows):2]]
        self.gyro = [] if self.rate_row is None else \
            [MemsStream(gyro_chain(spec), fs_sim, s) for s in seeds[1:2 * len(self.rows):2]]

    @property
    def started(self) -> bool:
        """Whether any input went in (a stream cannot restart)."""
        return self.accel[0].n_in > 0

    def process(self, channels: np.ndarray, final: bool
                ) -> tuple[ImuSamples, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """The primary IMU's samples for the next chunk of channels (C, n) and the other
        ``Run`` arrays at its outputs: gyro (T, 3), imu_accel (T, K, 3) and imu_gyro
        (T, K, 3) of the K further IMUs (None when absent)."""
        primary = self.accel[0].process(channels[0], final=final)
        extra = [m.process(channels[r], final=final).accel
                 for m, r in zip(self.accel[1:], self.rows[1:], strict=True)]
        gyros = []
        if self.rate_row is not None:
            rate = channels[self.rate_row]
            zero = np.zeros_like(rate)
            omega = np.column_stack([zero, rate, zero])
            gyros = [g.process(omega, final=final).accel for g in self.gyro]
        return (primary, gyros[0] if gyros else None,
                np.stack(extra, axis=1) if extra else None,
                np.stack(gyros[1:], axis=1) if extra and gyros else None)


def _kept(values: np.ndarray | None, keep: np.ndarray) -> np.ndarray | None:
    """The delivered rows of an optional array."""
    return None if values is None else values[keep]


def _track(line: Callable[[np.ndarray], np.ndarray], defects: list, x: np.ndarray
           ) -> np.ndarray:
    """u(x) (m) of a line with its defects at chainages x (m)."""
    return apply_defects(x, line(x), defects)


def run_scenario(profile_spec: str, speed_mps: Speed, duration_s: float,
                 rate_hz: float | None, sensor: str | ImuSpec, seed: int | None = 0,
                 defects: str | list | None = None, vehicle: Vehicle = None, *,
                 wavelength_range: tuple[float, float] = DEFAULT_WAVELENGTHS,
                 start_ns: int = DEFAULT_START_NS, start_m: float | None = None,
                 line_seed: int | None = None, odom_scale: float = 1.0) -> Run:
    """Simulate one run in one piece (``RunStream`` with one chunk); see the module docstring.

    profile_spec: german-low|german-high|fra-N|paper|file:CSV (track.line_profile); speed_mps:
    a constant, samples spread evenly over the duration or a ``speed_profile.SpeedProfile``
    (m/s); duration_s (s); rate_hz: IMU output rate (None: the preset's); sensor: preset name
    or ImuSpec; seed drives profile and sensor (independent streams); defects: spec string or list
    (track.parse_defects); vehicle: VehicleParams, theta (5,), a ``models.VehicleModel``, a vehicle
    YAML path (quarter car or coach) or None (Table 1); start_ns: stamp of the first sample (ns;
    default DEFAULT_START_NS: a zero stamp is malformed for the nodes); start_m: the reference
    wheelset's chainage at the start (m; default the profile's origin, 0 or a CSV's first chainage,
    plus the distance of the last wheelset behind the reference: every wheelset on the profile);
    line_seed: the track's seed (default: drawn from seed), so that runs with other seeds pass over
    the same line; odom_scale: odometry speed / true speed (1 + wheel-diameter error).
    """
    stream = RunStream(profile_spec, speed_mps, duration_s, rate_hz, sensor, seed, defects,
                       vehicle, wavelength_range=wavelength_range, start_ns=start_ns,
                       start_m=start_m, line_seed=line_seed, odom_scale=odom_scale,
                       chunk_s=math.inf)
    return Run.concat(list(stream))
