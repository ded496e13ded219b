"""The offline driver: a bag's IMU stream through the nodes' streaming cores, in bounded chunks.

``railgsa invert``, ``invert --bands`` and ``railgsa review`` all run through :class:`Driver`:
pieces of the bag (``bag.iter_imu``, about 65,536 IMU samples each) go to the nominal
``InversionPipeline`` (irregularity_node's core) and, with uncertain parameters, to an
``UncertaintyStream`` (uncertainty_node's core, windows deferred). The band lags the nominal
output by the bank's longer filter delay; the driver holds the nominal samples until their band
arrives and hands both out together as :class:`Step` objects. Memory: one piece, the delay lines
and the odometry of the pending samples, whatever the length of the run.

Speed: the newest odometry sample at or before each stamp, times the odometry scale (1 unless
GNSS corrected it, ``railgsa_ros.location``); the configured speed when the bag has no odometry
topic or ``speed_override`` is set.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from itertools import chain
from pathlib import Path

import numpy as np

from railgsa_ros.bag import ImuStream, open_bag
from railgsa_ros.bag.reader import iter_imu
from railgsa_ros.errors import InputError
from railgsa_ros.inverse.pipeline import InversionPipeline, Output, vertical
from railgsa_ros.location import Location, Reference, gnss_pass
from railgsa_ros.uncertainty import Band, Sensitivity, UncertaintyConfig, UncertaintyStream
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import VehicleParams


@dataclass(frozen=True)
class Source:
    """Where the run is: bag path and topics (``gnss_topic`` used when the bag has it)."""

    bag: Path
    imu_topic: str = '/imu/data'
    odom_topic: str = '/odom'
    gnss_topic: str = '/gnss/fix'

    def topics(self) -> set[str]:
        """Topics present in the bag (InputError naming it when unreadable)."""
        with open_bag(self.bag) as reader:
            return {c.topic for c in reader.connections}

    def count(self, topic: str) -> int:
        """Messages of a topic as the bag's index says (0 when unknown)."""
        with open_bag(self.bag) as reader:
            return sum(c.msgcount for c in reader.connections if c.topic == topic)


def peek(pieces: Iterable[ImuStream]) -> tuple[ImuStream, Iterator[ImuStream]]:
    """The first piece and an iterator over all of them (the first included)."""
    it = iter(pieces)
    first = next(it)
    return first, chain([first], it)


def nominal_rate_hz(piece: ImuStream, source: Source) -> float:
    """IMU rate (Hz) from the median positive stamp step of a piece (the first one: 65 s at
    1 kHz); InputError when it has no two distinct stamps."""
    steps = np.diff(piece.stamps_ns)
    steps = steps[steps > 0]
    if steps.size == 0:
        raise InputError(f'{source.bag}: {source.imu_topic} needs at least two distinct stamps')
    return 1e9 / float(np.median(steps))


def noise_variance(piece: ImuStream, axis: str, default_std_mps2: float) -> float | None:
    """Median recorded accelerometer variance ((m/s^2)^2) on the vertical axis of a piece, None
    where none is recorded."""
    var = piece.accel_variance(default_std_mps2 ** 2)[:, 'xyz'.index(axis[-1])]
    known = var[np.isfinite(var)]
    return float(np.median(known)) if known.size else None


class HeldSpeed:
    """Speed (m/s) at stamps: the newest odometry sample at or before each (the first one before
    the odometry starts), times ``scale``; ``default_mps`` when there is no odometry. Keeps only
    the odometry the samples still in the delay lines need (``forget``)."""

    def __init__(self, default_mps: float, use_odometry: bool, scale: float = 1.0) -> None:
        self.default_mps = float(default_mps)
        self.use_odometry = use_odometry
        self.scale = float(scale)
        self._stamps = np.zeros(0, np.int64)
        self._speeds = np.zeros(0)

    def add(self, stamps_ns: np.ndarray, speeds_mps: np.ndarray) -> None:
        """Odometry samples in bag order."""
        if not self.use_odometry or np.size(stamps_ns) == 0:
            return
        stamps = np.concatenate([self._stamps, stamps_ns])
        order = np.argsort(stamps, kind='stable')
        self._stamps = stamps[order]
        self._speeds = np.concatenate([self._speeds, speeds_mps])[order]

    def at(self, stamps_ns: np.ndarray) -> np.ndarray:
        """Speeds (m/s) at stamps (ns)."""
        if not self.use_odometry or self._stamps.size == 0:
            return np.full(np.shape(stamps_ns), self.default_mps)
        idx = np.searchsorted(self._stamps, stamps_ns, side='right') - 1
        return self._speeds[np.clip(idx, 0, None)] * self.scale

    def forget(self, before_ns: int) -> None:
        """Drop the odometry no stamp at or after ``before_ns`` needs."""
        keep = max(int(np.searchsorted(self._stamps, before_ns, side='right')) - 1, 0)
        self._stamps, self._speeds = self._stamps[keep:], self._speeds[keep:]


@dataclass(frozen=True)
class Step:
    """Emitted samples (K,): IMU stamps (ns), chainage (m), nominal reconstruction u (m), speed
    (m/s); with uncertain parameters the band of the same stamps, the bank outputs (P, K) m and
    the band's sensor std (K,) m."""

    stamps_ns: np.ndarray
    chainage_m: np.ndarray
    u_m: np.ndarray
    speed_mps: np.ndarray
    band: Band | None = None
    bank_u_m: np.ndarray | None = None
    sensor_std_m: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.stamps_ns.size)


class Driver:
    """Chunks of a bag in, Steps out: the nominal pipeline and, with ``dists``, the uncertainty
    stream (windows deferred to ``windows()``), fed the same samples; their outputs joined on the
    stamps (the band comes later by the difference of the filter delays)."""

    def __init__(self, config: UncertaintyConfig, vehicle: VehicleParams,
                 dists: Mapping[str, Distribution] | None, noise_variance: float | None,
                 speed: HeldSpeed) -> None:
        self.config = config
        self.nominal = InversionPipeline(config.inversion, vehicle, noise_variance)
        self.bank = (UncertaintyStream(config, vehicle, dists, noise_variance, defer=True)
                     if dists is not None else None)
        self.speed = speed
        self._pending: list[tuple[Output, np.ndarray]] = []  # nominal samples awaiting a band

    @property
    def counters(self) -> dict[str, int]:
        """The nominal pipeline's counters (rejections by reason, gaps, resets, emitted)."""
        return self.nominal.counters

    @property
    def delay_samples(self) -> int:
        """Band delay of the nominal pipeline (samples)."""
        return self.nominal.delay_samples

    def push(self, piece: ImuStream) -> Step:
        """One piece of the bag: the samples that came out (maybe none)."""
        self.speed.add(piece.odom_stamps_ns, piece.speed_mps)
        if piece.stamps_ns.size == 0:
            return self._join(None, None)
        speed = self.speed.at(piece.stamps_ns)
        args = (piece.stamps_ns, vertical(piece.accel, self.config.inversion.accel_axis), speed,
                piece.frame_ids)
        out = self.nominal.push(*args)
        update = self.bank.push(*args) if self.bank is not None else None
        return self._join(out, update)

    def flush(self) -> Step:
        """End of the run: every pending sample."""
        return self._join(self.nominal.flush(),
                          self.bank.flush() if self.bank is not None else None)

    def windows(self) -> list[Sensitivity]:
        """The sensitivity records of the closed windows (after ``flush``: all of them)."""
        return self.bank.analyze_deferred() if self.bank is not None else []

    def _join(self, out: Output | None, update) -> Step:
        if out is not None and len(out):
            self._pending.append((out, self.speed.at(out.stamps_ns)))
            self.speed.forget(int(out.stamps_ns[-1]))  # later outputs come after it
        waiting = sum(len(o) for o, _ in self._pending)
        ready = waiting if self.bank is None else (0 if update is None else len(update.band))
        if ready > waiting:
            raise AssertionError('band samples without irregularity samples')
        nominal = _take(self._pending, ready)
        if self.bank is None or ready == 0:
            return Step(*nominal)
        if not np.array_equal(update.band.stamps_ns, nominal[0]):
            raise AssertionError('band and irregularity stamps differ')
        return Step(*nominal, update.band, update.bank_u_m, update.sensor_std_m)


def _take(pending: list[tuple[Output, np.ndarray]], count: int) -> tuple[np.ndarray, ...]:
    """The first ``count`` pending samples (stamps, chainage, u, speed), removed from
    ``pending``."""
    parts: list[tuple[np.ndarray, ...]] = []
    while count > 0:
        out, speed = pending[0]
        n = min(count, len(out))
        parts.append((out.stamps_ns[:n], out.chainage_m[:n], out.u_m[:n], speed[:n]))
        if n == len(out):
            pending.pop(0)
        else:
            pending[0] = (Output(out.stamps_ns[n:], out.chainage_m[n:], out.u_m[n:]), speed[n:])
        count -= n
    if not parts:
        return (np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0))
    return tuple(np.concatenate(cols) for cols in zip(*parts, strict=True))


def steps(driver: Driver, pieces: Iterable[ImuStream],
        progress: Callable[[int], None] | None = None) -> Iterator[Step]:
    """Every piece through ``driver``, then its flush: the non-empty Steps in order;
    ``progress(IMU samples read)`` after each piece."""
    done = 0
    for piece in pieces:
        step = driver.push(piece)
        done += piece.stamps_ns.size
        if progress is not None:
            progress(done)
        if len(step):
            yield step
    step = driver.flush()
    if len(step):
        yield step


def chunks(source: Source, chunk: int | None = None) -> Iterator[ImuStream]:
    """``iter_imu`` over the source (no GNSS: the location pass reads it)."""
    kwargs = {} if chunk is None else {'chunk': chunk}
    return iter_imu(source.bag, source.imu_topic, source.odom_topic, None, **kwargs)


def locate(source: Source, start_ns: int, reference: Reference) -> Location:
    """The run's location: with the GNSS topic in the bag, the GNSS pass (odometry scale and
    positions, ``location.gnss_pass``), else the reference alone."""
    if source.gnss_topic and source.gnss_topic in source.topics():
        return gnss_pass(source.bag, source.odom_topic, source.gnss_topic, start_ns, reference)
    return Location(reference)
