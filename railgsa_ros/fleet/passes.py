"""One pass (one bag) inverted with the project's offline pipeline: the unit of work of a worker.

``analyse_pass`` is the only place the fleet calls the inversion: the project's offline driver
(``railgsa_ros.offline``: the bag in pieces of about 65,536 IMU samples through the nominal
streaming core, in constant memory; no surrogate band: the fleet measures the pass-to-pass
scatter from repeated passes instead), each piece's output gridded as it comes
(``standards.sampling.GridBuilder``: 0.25 m cells of odometry chainage; cells across data gaps, and
cells outside the speeds the input policy trusts (``trusted_speeds``), are invalid). It
returns the band-filtered profile with the stamp and speed of each cell and what the database
needs about the pass: plain numpy arrays, about 4 values per metre of track, so Dask ships
them back cheaply.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
import time

import numpy as np

from railgsa_ros.bag import ImuStream
from railgsa_ros.bag.reader import GnssFixes, iter_imu
from railgsa_ros.errors import InputError, RailGsaError
from railgsa_ros.fleet.defects import DETECT_FRACTION
from railgsa_ros.fleet.gnss import GNSS_TOPIC
from railgsa_ros.inverse.observability import NoiseFloor
from railgsa_ros.inverse.policy import PolicyOptions
from railgsa_ros.offline import (
    Driver,
    Source,
    nominal_rate_hz,
    peek,
    steps,
)
from railgsa_ros.standards.en13848 import LimitTable
from railgsa_ros.standards.line_speed import LineSpeed
from railgsa_ros.standards.sampling import GridBuilder
from railgsa_ros.uncertainty import UncertaintyConfig
from railgsa_ros.vehicle import VehicleParams

DX_M = 0.25  # common chainage grid step, m (EN 13848 samples at <= 0.5 m, 0.25 m typical)


@dataclass(frozen=True)
class PassOptions:
    """How every pass of a batch is inverted and where it lies: inversion configuration, nominal
    vehicle, location (line, track, direction of the km-posts along the run 'increasing' or
    'decreasing', km-post of the odometry origin), vehicle id, topics (IMU, odometry, GNSS),
    grid step (m), whether the IMU rate comes from the bag (else ``config.inversion.rate_hz``)
    and the share of the alert limit from which the line's defects are detected, the limit
    table and the line's permitted speed that class them."""

    config: UncertaintyConfig = field(default_factory=UncertaintyConfig)
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    line: str = 'line'
    track: str = '1'
    direction: str = 'increasing'
    km_origin: float = 0.0
    vehicle_id: str = ''
    imu_topic: str = '/imu/data'
    odom_topic: str = '/odom'
    gnss_topic: str = GNSS_TOPIC
    dx_m: float = DX_M
    rate_from_bag: bool = True
    detect_fraction: float = DETECT_FRACTION
    limits: LimitTable | None = None  # the manager's table; None: the standard's (lower end)
    line_speed: LineSpeed | None = None  # None: class by the measuring speed (fastest pass)


@dataclass(frozen=True)
class PassResult:
    """A pass on its odometry grid: cell centres s (N,) m from the first sample, band-filtered
    irregularity u (N,) m, valid (N,) (False across data gaps), stamp (N,) ns and speed (N,) m/s
    at each cell; the run's first/last stamp (ns), IMU samples, rate (Hz), rejected-sample
    counters, the CPU seconds the worker spent and the GNSS fixes (empty without GNSS)."""

    bag: str
    options: PassOptions
    s_m: np.ndarray
    u_m: np.ndarray
    valid: np.ndarray
    stamps_ns: np.ndarray
    speed_mps: np.ndarray
    start_ns: int
    end_ns: int
    samples: int
    rate_hz: float
    counters: dict[str, int]
    cpu_s: float
    fixes: GnssFixes

    @property
    def duration_s(self) -> float:
        """Span of the IMU stamps (s)."""
        return (self.end_ns - self.start_ns) * 1e-9


@dataclass(frozen=True)
class PassFailure:
    """A bag that cannot be used (bad input, a RailGsaError): its one-line message."""

    bag: str
    message: str


def analyse_or_fail(bag: str | Path, options: PassOptions) -> PassResult | PassFailure:
    """``analyse_pass``, with bad input returned as a PassFailure: Dask then retries only what
    may pass on another try (a lost worker, an unexpected exception), not a bad bag."""
    try:
        return analyse_pass(bag, options)
    except RailGsaError as exc:
        return PassFailure(str(bag), str(exc).strip().splitlines()[0])


def trusted_speeds(config: UncertaintyConfig, vehicle: VehicleParams,
                   variance: float | None) -> tuple[float, float]:
    """Speed range (m/s) whose cells the fleet keeps: where the input policy does not call the
    output DEGRADED (sensor noise through the band below half ``noise_limit_m``, at least
    ``min_design_speed_mps``, at most ``max_speed_mps``; ``observability.NoiseFloor``, the
    policy's own object)."""
    inv = config.inversion
    floor = NoiseFloor(vehicle.as_array(), inv.band, inv.band_order, inv.rate_hz,
                       inv.noise_std_mps2 ** 2 if variance is None else variance)
    return max(floor.speed_for(inv.noise_limit_m / 2), inv.min_design_speed_mps), \
        inv.max_speed_mps


def analyse_pass(bag: str | Path, options: PassOptions) -> PassResult:
    """Invert one bag and grid it (see the module docstring); InputError naming the bag when it
    cannot be read or gives no usable output."""
    cpu = time.process_time()
    source = Source(Path(bag), options.imu_topic, options.odom_topic, options.gnss_topic)
    topics = source.topics()
    gnss_topic = options.gnss_topic if options.gnss_topic in topics else None
    try:  # one read of the bag: IMU, odometry and the GNSS fixes of the same span
        first, pieces = peek(iter_imu(source.bag, options.imu_topic, options.odom_topic,
                                      gnss_topic))
    except StopIteration:
        raise InputError(f'{bag}: {options.imu_topic} has no message') from None
    cfg = options.config
    if options.rate_from_bag:
        cfg = cfg.with_(inversion=cfg.inversion.with_(rate_hz=nominal_rate_hz(first, source)))
    inv = cfg.inversion
    if options.odom_topic not in topics:
        raise InputError(f'{bag}: no odometry on {options.odom_topic}: the speed is unknown')
    driver = Driver(cfg, options.vehicle, None, PolicyOptions())
    t0 = int(first.stamps_ns[0]) if first.stamps_ns.size else 0
    profile, clock = GridBuilder(options.dx_m), GridBuilder(options.dx_m)
    seen = {'samples': 0, 'last': t0}
    fixes: list[GnssFixes] = []

    def counted(pieces: Iterator[ImuStream]) -> Iterator[ImuStream]:
        for piece in pieces:
            seen['samples'] += piece.stamps_ns.size
            if piece.stamps_ns.size:
                seen['last'] = max(seen['last'], int(piece.stamps_ns.max()))
            if piece.gnss is not None:
                fixes.append(piece.gnss)
            yield piece

    for step in steps(driver, counted(pieces)):
        profile.push(step.chainage_m, step.u_m, step.speed_mps)
        seconds = (step.stamps_ns - t0) * 1e-9  # NaN where INVALID, as u: the same cells
        clock.push(step.chainage_m, np.where(np.isnan(step.u_m), np.nan, seconds),
                   step.speed_mps)
    grid, times = profile.grid(), clock.grid()
    if grid.valid.sum() < 10:
        raise InputError(f'{bag}: the pass covers {grid.valid.sum() * options.dx_m:.1f} m of '
                         'usable chainage, too short to align')
    # the input policy's noise decision (median of the reported variances, else the config's)
    slowest, fastest = trusted_speeds(cfg, options.vehicle, driver.nominal.noise_variance)
    with np.errstate(invalid='ignore'):
        valid = grid.valid & (grid.speed_mps >= slowest) & (grid.speed_mps <= fastest)
    timed = np.isfinite(times.u_m)  # every cell reached has a time; gaps are interpolated
    stamps = t0 + np.round(np.interp(grid.x_m, grid.x_m[timed], times.u_m[timed]) * 1e9
                           ).astype(np.int64)
    return PassResult(str(bag), options, grid.x_m, np.where(valid, grid.u_m, 0.0), valid,
                      stamps, np.nan_to_num(grid.speed_mps), t0, seen['last'],
                      seen['samples'], float(inv.rate_hz), dict(driver.counters),
                      time.process_time() - cpu, GnssFixes.concat(fixes))

