"""The nodes' streaming core run offline over a bag (``railgsa_ros.offline``), reduced to what
a review shows while it streams: nothing of the run is kept per sample.

Per chunk of emitted samples the review updates bounded summaries:

- the run on a 0.25 m chainage grid (``grid.GridBuilder``: reconstruction, band, speed; 84 bytes
  per metre of run) for the figures, the 200 m sections and the truth comparison;
- the exceedances (``exceedances.ExceedanceTracker``: only the samples beyond a limit of the run
  still open are looked at);
- the mean speed per section, the largest |u|, the widest band (of the samples whose band is
  computed, ``review.band``), the sample count per speed
  class, the first and last output;
- the input health (``health.HealthAccumulator``: stamp statistics, messages per second);
- the sample of largest |PCE mean| with its bank outputs (the histogram), and the window
  records (deferred windows: a few numbers each).

Only the samples the input policy did not mark INVALID enter the summaries (their u is NaN):
the grid has no valid cell there; the counts by quality are in ``counters``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace

import numpy as np

from railgsa_ros import samples
from railgsa_ros.bag import ImuStream
from railgsa_ros.errors import InputError
from railgsa_ros.input.findings import Finding
from railgsa_ros.input.options import InputOptions
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.location import Location, Reference
from railgsa_ros.models import VehicleModel
from railgsa_ros.offline import (
    Driver,
    Source,
    Step,
    chunks,
    locate,
    nominal_rate_hz,
    peek,
    steps,
)
from railgsa_ros.review.band import KeptBand
from railgsa_ros.review.exceedances import Exceedance, ExceedanceTracker
from railgsa_ros.review.health import HealthAccumulator, InputHealth
from railgsa_ros.standards.en13848 import Limits
from railgsa_ros.standards.sampling import DX_M, Grid, GridBuilder
from railgsa_ros.standards.sections import SECTION_M, SectionSpeeds
from railgsa_ros.uncertainty import Sensitivity, UncertaintyConfig
from railgsa_ros.uncertainty.surrogate import Design
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import VehicleParams

MAX_JUMP_M = 100e3  # chainage step between two emitted samples that cannot be a real run
# IMU samples per piece (16 s at 1 kHz): the bank's temporaries scale with it and glibc's heap
# keeps the holes they leave (measured, full review of 2 h at 1 kHz: 340 MB peak with pieces of
# 65,536, growing 40 MB/h beyond the grid; 279 MB and about 10 MB/h with 16,384, for 7 % more CPU)
REVIEW_CHUNK = 16384


@dataclass(frozen=True)
class Worst:
    """The sample of largest |PCE mean|: stamp (ns), chainage (m), PCE mean (m) and the bank
    outputs (P,) m there."""

    stamp_ns: int
    chainage_m: float
    mean_m: float
    bank_u_m: np.ndarray


@dataclass(frozen=True)
class Extreme:
    """One sample: stamp (ns), chainage (m) and a value (m)."""

    stamp_ns: int
    chainage_m: float
    value_m: float


@dataclass(frozen=True)
class ReviewRun:
    """What a review keeps of a run: the chainage grid, the exceedances, the section speeds,
    the largest |u| and widest band, samples per speed range (the ranges of the limits' table,
    then beyond it or without a line speed), the limits placed on the run's km-posts, the first
    and last output (stamp ns, chainage m), the emitted count,
    the input health, the window records, the worst sample and design of the band (None
    without), the pipeline's counters and band delay, the imu stamps' source, the location and
    the input policy's findings at the end (the mounting tilt among them).
    """

    grid: Grid
    exceedances: list[Exceedance]
    section_speeds: SectionSpeeds
    peak: Extreme
    widest: Extreme | None
    class_counts: np.ndarray
    limits: Limits
    first: tuple[int, float]
    last: tuple[int, float]
    emitted: int
    health: InputHealth
    windows: list[Sensitivity]
    worst: Worst | None
    design: Design | None
    counters: dict[str, int]
    delay_samples: int
    location: Location
    findings: list[Finding]

    def __len__(self) -> int:
        return self.emitted

    @property
    def length_m(self) -> float:
        """Chainage from the first to the last output (m)."""
        return self.last[1] - self.first[1]


class _Summaries:
    """The bounded summaries of the module docstring, updated step by step."""

    def __init__(self, source: Source, limits: Limits, section_m: float,
                 design: Design | None, quantiles: tuple[float, float]) -> None:
        self.source = source
        self.limits = limits
        self.grid = GridBuilder(DX_M)
        self.band = KeptBand(design, quantiles, limits, DX_M) if design is not None else None
        self.tracker = ExceedanceTracker(limits, design=design)
        self.exceedances: list[Exceedance] = []
        self.speeds = SectionSpeeds(section_m)
        self.classes = np.zeros(limits.table.upper_kmh.size + 1, np.int64)
        self.peak: Extreme | None = None
        self.widest: Extreme | None = None
        self.worst: Worst | None = None
        self.first: tuple[int, float] | None = None
        self.last: tuple[int, float] = (0, 0.0)
        self.emitted = 0
        self.valid = 0  # emitted samples that are not INVALID

    def take(self, step: Step) -> None:
        c = step.chainage_m
        previous = np.concatenate([[self.last[1]], c]) if self.first is not None else c
        jump = np.abs(np.diff(previous))
        if jump.size and np.nanmax(jump) > MAX_JUMP_M:
            k = int(np.nanargmax(jump)) + (c.size - jump.size)
            raise InputError(f'{self.source.bag}: the chainage jumps by {jump.max() / 1e3:.0f} km '
                             f'at the IMU stamp {int(step.stamps_ns[min(k, c.size - 1)])} ns '
                             '(stamps far from their neighbours: zero or corrupt header stamps?)')
        if self.first is None:
            self.first = (int(step.stamps_ns[0]), float(c[0]))
        self.last = (int(step.stamps_ns[-1]), float(c[-1]))
        self.emitted += len(step)
        keep = step.quality != Quality.INVALID
        if not keep.all():  # the summaries take the samples that are not INVALID
            step = samples.take(replace(step, chainage_m=c), keep)
            if not len(step):
                return
            c = step.chainage_m
        self.valid += len(step)
        band, bank = step.band, step.bank_u_m
        lower = upper = None
        if band is not None and bank is not None and step.sensor_std_m is not None \
                and self.band is not None:
            lower, upper = self.band.take(c, step.u_m, step.speed_mps, band.mean_m, bank,
                                          step.sensor_std_m)
        self.grid.push(c, step.u_m, step.speed_mps, lower, upper)
        self.exceedances += self.tracker.push(c, step.u_m, step.speed_mps, step.stamps_ns,
                                              lower, upper, step.bank_u_m,
                                              step.sensor_std_m)
        self.speeds.push(c, step.speed_mps)
        ranges = self.limits.table.index(self.limits.speed_kmh(c, step.speed_mps))
        self.classes += np.bincount(ranges % self.classes.size, minlength=self.classes.size)
        self.peak = _larger(self.peak, step.stamps_ns, c, step.u_m, np.abs(step.u_m))
        if lower is not None and upper is not None and band is not None and bank is not None:
            width = upper - lower
            self.widest = _larger(self.widest, step.stamps_ns, c, width, width)
            k = int(np.argmax(np.abs(band.mean_m)))
            if self.worst is None or abs(band.mean_m[k]) > abs(self.worst.mean_m):
                self.worst = Worst(int(step.stamps_ns[k]), float(c[k]), float(band.mean_m[k]),
                                   bank[:, k].copy())


def _larger(best: Extreme | None, stamps: np.ndarray, chainage: np.ndarray,
            values: np.ndarray, key: np.ndarray) -> Extreme:
    """The sample of largest key (the earlier on ties) against the best so far."""
    k = int(np.nanargmax(key)) if np.any(np.isfinite(key)) else 0
    if best is not None and not key[k] > abs(best.value_m):
        return best
    return Extreme(int(stamps[k]), float(chainage[k]), float(values[k]))


def run_stream(source: Source, config: UncertaintyConfig, vehicle: VehicleParams | VehicleModel,
               dists: Mapping[str, Distribution] | None, limits: Limits,
               reference: Reference | None = None, rate_from_bag: bool = True,
               section_m: float = SECTION_M, chunk: int | None = REVIEW_CHUNK,
               progress: Callable[[int], None] | None = None, *,
               speed_mps: float | None = None,
               options: InputOptions | None = None) -> tuple[ReviewRun, UncertaintyConfig]:
    """Stream the bag through the driver (nominal pipeline, and the bank unless ``dists`` is
    None) and summarise it; returns the run and the configuration in effect (the IMU rate from
    the first chunk when ``rate_from_bag``). With GNSS in the bag, a first pass over the
    odometry and the fixes locates the run (``location.gnss_pass``). ``progress(IMU samples
    read)`` after each chunk. ``speed_mps``: a fixed speed instead of odometry (required
    without odometry: InputError otherwise); ``options``: the input policy's options."""
    first, pieces = peek(chunks(source, chunk))
    location = locate(source, int(first.stamps_ns[0]) if first.stamps_ns.size else 0,
                      reference or Reference())
    limits = replace(limits, km_of=location.reference.km)  # line speeds are given per km-post
    inv = config.inversion
    if rate_from_bag:
        config = config.with_(inversion=inv.with_(rate_hz=nominal_rate_hz(first, source)))
        inv = config.inversion
    options = options if options is not None else InputOptions()
    if speed_mps is not None:
        config = config.with_(inversion=inv.with_(speed_mps=float(speed_mps)))
        inv = config.inversion
        options = replace(options, use_odom=False)
    elif source.odom_topic not in source.topics():
        raise InputError(f'{source.bag}: no odometry on {source.odom_topic}: the speed is '
                         'unknown')
    # the bank's band without quantiles: the summaries compute those they keep (review.band)
    driver = Driver(config, vehicle, dists, options, location.scale.value, quantiles=False)
    health = HealthAccumulator(inv.gap_factor)
    summaries = _Summaries(source, limits, section_m,
                           driver.bank.design if driver.bank is not None else None,
                           (config.lower_quantile, config.upper_quantile))

    def watched(pieces: Iterator[ImuStream]) -> Iterator[ImuStream]:
        for piece in pieces:
            health.push(piece.stamps_ns, piece.log_time_ns, piece.odom_stamps_ns,
                        piece.speed_mps)
            yield piece

    for step in steps(driver, watched(pieces), progress):
        summaries.take(step)
    if summaries.first is None:
        raise InputError(f'{source.bag}: no usable IMU sample (rejected: '
                         f'{_rejections(driver.counters)})')
    if summaries.valid == 0:
        status = driver.nominal.status
        why = status.message if status.level else 'the run is shorter than the band window'
        raise InputError(f'{source.bag}: every one of the {summaries.emitted} outputs is '
                         f'INVALID: {why}')
    grid = summaries.grid.grid()
    if not grid.valid.any():
        raise InputError(f'{source.bag}: the chainage never advances by {DX_M:g} m without a gap '
                         '(standstill, negative odometry speed or no odometry)')
    exceedances = summaries.exceedances + summaries.tracker.close()
    assert summaries.peak is not None  # a valid grid cell needs a valid sample
    windows = driver.windows()
    return ReviewRun(grid, exceedances, summaries.speeds, summaries.peak, summaries.widest,
                     summaries.classes, limits, summaries.first, summaries.last, summaries.emitted,
                     health.health(driver.counters, first.stamp_source), windows,
                     summaries.worst, driver.bank.design if driver.bank else None,
                     driver.counters, driver.delay_samples, location,
                     driver.nominal.findings), config


def _rejections(counters: dict[str, int]) -> str:
    """'nan 3, saturated 10' for the nonzero counters."""
    return ', '.join(f'{k} {v}' for k, v in sorted(counters.items()) if v) or 'none'
