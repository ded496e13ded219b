"""One pass (one bag) inverted with the project's offline pipeline: the unit of work of a worker.

``analyse_pass`` is the only place the fleet calls the inversion: it reads the bag, runs the
nominal streaming core (``review.stream.run_stream``, no surrogate band: the fleet measures the
pass-to-pass scatter from repeated passes instead) and returns the band-filtered profile on a
regular grid of odometry chainage, with what the database needs about the pass. The result is
plain numpy arrays, small (about 4 values per metre of track), so Dask ships it back cheaply.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import time

import numpy as np

from railgsa_ros.bag import read_imu
from railgsa_ros.errors import InputError, RailGsaError
from railgsa_ros.fleet.gnss import GNSS_TOPIC, Fixes, read_fixes
from railgsa_ros.review.health import stamp_stats
from railgsa_ros.review.sections import resample
from railgsa_ros.review.stream import run_stream
from railgsa_ros.uncertainty import UncertaintyConfig
from railgsa_ros.vehicle import VehicleParams

DX_M = 0.25  # common chainage grid step, m (EN 13848 samples at <= 0.5 m, 0.25 m typical)


@dataclass(frozen=True)
class PassOptions:
    """How every pass of a batch is inverted and where it lies: inversion configuration, nominal
    vehicle, location (line, track, direction 'up' (chainage grows with odometry) or 'down',
    km-post of the odometry origin), vehicle id, topics (IMU, odometry, GNSS), grid step (m)
    and whether the IMU rate comes from the bag (else ``config.inversion.rate_hz``)."""

    config: UncertaintyConfig = field(default_factory=UncertaintyConfig)
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    line: str = 'line'
    track: str = '1'
    direction: str = 'up'
    km_origin: float = 0.0
    vehicle_id: str = ''
    imu_topic: str = '/imu/data'
    odom_topic: str = '/odom'
    gnss_topic: str = GNSS_TOPIC
    dx_m: float = DX_M
    rate_from_bag: bool = True


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
    fixes: Fixes

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


def analyse_pass(bag: str | Path, options: PassOptions) -> PassResult:
    """Invert one bag and grid it (see the module docstring); InputError naming the bag when it
    cannot be read or gives no usable output."""
    cpu = time.process_time()
    stream = read_imu(bag, options.imu_topic, options.odom_topic)
    cfg = options.config
    stats = stamp_stats(stream.stamps_ns, cfg.inversion.gap_factor)
    if not np.isfinite(stats.rate_hz):
        raise InputError(f'{bag}: {options.imu_topic} needs at least two distinct stamps')
    if options.rate_from_bag:
        cfg = cfg.with_(inversion=cfg.inversion.with_(rate_hz=stats.rate_hz))
    run = run_stream(stream, cfg, options.vehicle, None)
    if run.chainage_m[-1] - run.chainage_m[0] < 10 * options.dx_m:
        raise InputError(f'{bag}: the pass covers {run.chainage_m[-1] - run.chainage_m[0]:.1f} m,'
                         ' too short to align')
    s, u, valid = resample(run.chainage_m, run.u_m, options.dx_m)
    stamps = np.interp(s, run.chainage_m, run.stamps_ns.astype(float)).astype(np.int64)
    speed = np.interp(s, run.chainage_m, run.speed_mps)
    fixes = read_fixes(bag, options.gnss_topic)
    return PassResult(str(bag), options, s, u, valid, stamps, speed, int(stream.stamps_ns[0]),
                      int(stream.stamps_ns[-1]), int(stream.stamps_ns.size), float(stats.rate_hz),
                      dict(run.counters), time.process_time() - cpu, fixes)
