"""The offline driver: a bag's IMU stream through the nodes' streaming cores, in bounded chunks.

``railgsa invert``, ``invert --bands`` and ``railgsa review`` all run through :class:`Driver`:
pieces of the bag (``bag.iter_imu``, about 65,536 IMU samples each) go to one ``InputStage``
(irregularity_node's core: every input decision once), each piece's odometry first, then its
IMU samples; it hands the accepted batches to the nominal pipeline and, with uncertain
parameters, to the bank pipeline of an ``UncertaintyStream`` (uncertainty_node's core, sharing
the stage, windows deferred). The band lags the nominal output by the bank's longer filter
delay; the driver holds the nominal samples until their band arrives and hands both out
together as :class:`Step` objects. Memory: one piece, the delay lines and the odometry of the
pending samples, whatever the length of the run.

Speed: the stage's (the newest odometry sample at or before each stamp within
odom_timeout_s, else unknown: INVALID outputs), the odometry times its scale (1 unless GNSS
corrected it, ``railgsa_ros.location``); a fixed speed only when the options say so
(``use_odom`` false with ``speed_mps``).

Vehicle: a quarter car (VehicleParams) or a coach (``railgsa_ros.models.vehicle_of``): the
stage inverts the coach from the bag's accelerometer and, when its IMU has a gyro, the pitch
rate (angular_velocity.y). The uncertainty band does not take a coach yet (``COACH_BAND``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from functools import cached_property
from itertools import chain
from pathlib import Path

import numpy as np

from railgsa_ros.bag import ImuStream, open_bag
from railgsa_ros.bag.reader import iter_imu
from railgsa_ros.errors import ConfigError, InputError
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.rate import count_steps
from railgsa_ros.input.stage import InputStage
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import Output
from railgsa_ros.location import Location, Reference, gnss_pass
from railgsa_ros.models import VehicleModel
from railgsa_ros.samples import split
from railgsa_ros.uncertainty import (
    Band,
    Sensitivity,
    UncertaintyConfig,
    UncertaintyStream,
    Update,
)
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import VehicleParams

#: why a coach gets no uncertainty band (the nominal output only)
COACH_BAND = ('the uncertainty band does not take a coach yet (issue 21): the nominal '
              'reconstruction only')


@dataclass(frozen=True)
class Source:
    """Where the run is: bag path and topics (``gnss_topic`` used when the bag has it)."""

    bag: Path
    imu_topic: str = '/imu/data'
    odom_topic: str = '/odom'
    gnss_topic: str = '/gnss/fix'

    def topics(self) -> set[str]:
        """Topics present in the bag (InputError naming it when unreadable)."""
        return set(self._counts)

    def count(self, topic: str) -> int:
        """Messages of a topic as the bag's index says (0 when unknown)."""
        return self._counts.get(topic, 0)

    @cached_property
    def _counts(self) -> dict[str, int]:
        """Messages per topic from the bag's index, read once: each opening parses the
        metadata (ruamel.yaml, 16 ms on one core) and a review asked three times."""
        counts: dict[str, int] = {}
        with open_bag(self.bag) as reader:
            for c in reader.connections:
                counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
        return counts


def peek(pieces: Iterable[ImuStream]) -> tuple[ImuStream, Iterator[ImuStream]]:
    """The first piece and an iterator over all of them (the first included)."""
    it = iter(pieces)
    first = next(it)
    return first, chain([first], it)


def nominal_rate_hz(piece: ImuStream, source: Source) -> float:
    """IMU rate (Hz) of a piece (the first one: 65 s at 1 kHz): the periods counted from the
    median step's over their time (``input.rate``: robust to jitter and lost samples), in
    stamp order (the policy re-orders the stamps; arrival order would add negative and double
    steps); InputError when it has no two distinct stamps."""
    steps = np.diff(np.sort(piece.stamps_ns))
    steps = steps[steps > 0]
    if steps.size == 0:
        raise InputError(f'{source.bag}: {source.imu_topic} needs at least two distinct stamps')
    return count_steps(steps, float(np.median(steps)), InversionConfig().gap_factor).rate_hz


@dataclass(frozen=True)
class Step:
    """Emitted samples (K,): IMU stamps (ns), chainage (m), nominal reconstruction u (m, NaN
    where INVALID), speed (m/s), quality (Quality codes); with uncertain parameters the band of
    the same stamps, the bank outputs (P, K) m and the band's sensor std (K,) m."""

    stamps_ns: np.ndarray
    chainage_m: np.ndarray
    u_m: np.ndarray
    speed_mps: np.ndarray
    quality: np.ndarray
    band: Band | None = None
    bank_u_m: np.ndarray | None = None
    sensor_std_m: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.stamps_ns.size)

    @classmethod
    def of(cls, nominal: Output, band: Band | None = None, bank_u_m: np.ndarray | None = None,
           sensor_std_m: np.ndarray | None = None) -> Step:
        """The Step of nominal outputs (with their band, bank outputs and sensor std)."""
        return cls(nominal.stamps_ns, nominal.chainage_m, nominal.u_m,
                   _given(nominal.speed_mps), _given(nominal.quality), band, bank_u_m,
                   sensor_std_m)


def _given(values: np.ndarray | None) -> np.ndarray:
    """A column the policy always fills (None only in outputs built by hand)."""
    if values is None:
        raise AssertionError('a policy output without speed or quality')
    return values


class Driver:
    """Chunks of a bag in, Steps out: one input stage per stream (``nominal``), which hands
    the accepted batches to the nominal pipeline and, with ``dists``, to the uncertainty
    stream's bank pipeline (windows deferred to ``windows()``): one set of decisions, so the
    band's samples are the nominal ones, later by the difference of the filter delays.
    ``options``: the stage's input options; ``speed_scale``: factor on the odometry speeds
    (GNSS-corrected wheel diameter); ``quantiles`` False: bands of the mean only
    (``UncertaintyStream``)."""

    def __init__(self, config: UncertaintyConfig, vehicle: VehicleParams | VehicleModel,
                 dists: Mapping[str, Distribution] | None, options: InputOptions,
                 speed_scale: float = 1.0, quantiles: bool = True) -> None:
        self.config = config
        self.options = options
        self.nominal = InputStage(config.inversion, vehicle, options=options)
        self.bank: UncertaintyStream | None = None
        if dists is not None:
            if not isinstance(vehicle, VehicleParams):
                raise ConfigError(COACH_BAND)
            self.bank = UncertaintyStream(config, vehicle, dists, options=options, defer=True,
                                          quantiles=quantiles, stage=self.nominal)
        self.speed_scale = float(speed_scale)
        self._pending = Output.concat([])  # nominal samples awaiting a band

    @property
    def counters(self) -> dict[str, int]:
        """The nominal policy's counters (rejections by reason, gaps, resets, quality, ...)."""
        return self.nominal.counters

    @property
    def delay_samples(self) -> int:
        """Band delay of the nominal pipeline (samples)."""
        return self.nominal.delay_samples

    def push(self, piece: ImuStream) -> Step:
        """One piece of the bag: the samples that came out (maybe none)."""
        outs: list[Output] = []
        updates: list[Update] = []
        if self.options.use_odom and piece.odom_stamps_ns.size:
            outs.append(self.nominal.odometry(piece.odom_stamps_ns,
                                              piece.speed_mps * self.speed_scale))
            updates += self._band(last=False)
        if piece.stamps_ns.size:
            outs.append(self.nominal.imu(piece.stamps_ns, piece.accel, piece.frame_ids,
                                         piece.covariance, piece.angular_velocity,
                                         piece.gyro_covariance))
            updates += self._band(last=False)
        return self._join(outs, updates)

    def flush(self) -> Step:
        """End of the run: every pending sample."""
        return self._join([self.nominal.flush()], self._band(last=True))

    def _band(self, last: bool) -> list[Update]:
        """The band of the bank outputs the stage made in its latest call (``last``: the
        stream's end, the open window closed); none without a bank."""
        if self.bank is None:
            return []
        bank = self.nominal.bank_outputs()
        return [self.bank.close(bank) if last else self.bank.update(bank)]

    def windows(self) -> list[Sensitivity]:
        """The sensitivity records of the closed windows (after ``flush``: all of them)."""
        return self.bank.analyze_deferred() if self.bank is not None else []

    def _join(self, outs: list[Output], updates: list[Update]) -> Step:
        """The pending nominal samples that have their band (all of them without a bank)."""
        self._pending = Output.concat([self._pending, *outs])
        if self.bank is None:
            ready, self._pending = self._pending, Output.concat([])
            return Step.of(ready)
        band = Band.concat([u.band for u in updates])
        if len(band) > len(self._pending):  # the join below needs the longer bank delay
            raise AssertionError('band samples ahead of the irregularity samples')
        ready, self._pending = split(self._pending, len(band))  # the same samples, later
        if not len(band):
            return Step.of(ready)
        bank_u = np.concatenate([u.bank_u_m for u in updates], axis=1)
        sensor = np.concatenate([u.sensor_std_m for u in updates])
        return Step.of(ready, band, bank_u, sensor)


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
