"""The input stage: every decision about IMU and odometry input, the same live and offline.

``irregularity_node``, ``uncertainty_node``, ``railgsa invert [--bands]`` and ``railgsa review``
feed an :class:`InputStage` and publish what it returns (docs/inversion.md, "Input policy").
It runs, in this order:

- REP 145 input: accel (T, 3) in the sensor frame, the vertical axis picked by ``accel_axis``;
  covariance[0] = -1 (or NaN) marks the acceleration absent (the sample is rejected as ``nan``),
  an all-zero covariance is unknown; zero or negative stamps are malformed;
- a coach (``model``): the pitch rate, angular_velocity.y (REP 103), is a data channel when the
  first IMU message carries a gyro (angular_velocity_covariance[0] not -1 or NaN), decided once
  for the stage; its rows ride as a fourth accel column through the re-order buffer and the
  held queue, so they stay with their samples; the gyro variance is the median of the first
  messages' angular_velocity_covariance[4], else ``gyro_noise_std_rads``^2;
- the re-order buffer (``input.reorder``) and the time resets (a new stream);
- the arrival checks (``input.monitors``: gravity, rate and jitter, frame, mounting), the noise
  decision (``input.noise``) and the vertical projection (``input.mounting``);
- the held queue (``input.held``): each sample waits for its speed (``input.odometry``);
- the release: speed grades, the rest check, the distance across stretches without a speed,
  then the pipeline (``inverse.pipeline``: sanitiser, filters); quality per sample
  (:class:`~railgsa_ros.inverse.quality.Quality`) is carried through the band delay line, and
  INVALID outputs have u = NaN;
- findings (``input.findings``): ``findings`` and ``status`` say what to do in one line;
- rebuild on a parameter change (old filters flushed, chainage continued), reset, flush.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import Any, TypeGuard

import numpy as np

from railgsa_ros.errors import ConfigError
from railgsa_ros.input.findings import Finding, Findings
from railgsa_ros.input.held import NO_STAMP, Held
from railgsa_ros.input.monitors import (
    AccelerationMonitor,
    FrameMonitor,
    GravityMonitor,
    MountingMonitor,
    RateMonitor,
    RejectMonitor,
    RestMonitor,
)
from railgsa_ros.input.mounting import Mounting
from railgsa_ros.input.noise import NOISE_SAMPLES, Noise
from railgsa_ros.input.odometry import Odometry
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.reorder import Reorder
from railgsa_ros.input.sanitize import SMALL, Clean, InputSanitizer, text_array
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.design import model_theta
from railgsa_ros.inverse.observability import STANDSTILL_MPS
from railgsa_ros.inverse.pipeline import InversionPipeline, Output
from railgsa_ros.inverse.quality import Quality, quality_counts
from railgsa_ros.models import VehicleModel
from railgsa_ros.vehicle import VehicleParams, as_theta

_INVALID = int(Quality.INVALID)


class InputStage:
    """Odometry and IMU samples in, reconstructed samples with their quality out.

    ``config``: InversionConfig; ``vehicle``: the nominal vehicle (VehicleParams or theta (5,)):
    it sets the noise floor, so every stage with the same config and vehicle makes the same
    decisions; ``bank``: theta (P, 5) for a bank pipeline (uncertainty: outputs u (P, K)), else
    the nominal vehicle is inverted; ``options``: InputOptions; ``noise_variance``: a fixed
    accelerometer variance ((m/s^2)^2) instead of the rule from the data; ``model``: a
    ``railgsa_ros.models`` vehicle (a coach inverts with its design, ``vehicle`` then its
    theta (n,), default its nominal; None or a quarter car: the quarter car of ``vehicle``);
    a model given as ``vehicle`` is that model at its nominal theta.
    """

    def __init__(self, config: InversionConfig | None = None,
                 vehicle: VehicleParams | np.ndarray | VehicleModel | None = None, *,
                 bank: np.ndarray | None = None, options: InputOptions | None = None,
                 noise_variance: float | None = None,
                 model: VehicleModel | None = None) -> None:
        self.config = config if config is not None else InversionConfig()
        if _is_model(vehicle):
            model, vehicle = vehicle, None
        #: the coach model (None: the quarter car)
        self.model = None if model is None or model.kind == 'quarter_car' else model
        self.gyro: bool | None = None  #: a coach's pitch-rate channel (None: not decided)
        self.theta = self._as_theta(vehicle if vehicle is not None else
                                    VehicleParams() if model is None else model.theta)
        if self.theta.ndim != 1:
            raise ConfigError('vehicle: the policy takes the nominal vehicle (5,); pass a '
                              'parameter bank as bank=')
        self.bank = None if bank is None else np.atleast_2d(self._as_theta(bank))
        self.options = options if options is not None else InputOptions()
        self.noise = Noise(noise_variance)  #: the noise decision, its floor and speed limits
        self.pipeline: InversionPipeline | None = None
        self._sanitizer: InputSanitizer | None = None  # built with the pipeline
        self._bank_theta: np.ndarray | None = None  # a bank pipeline fed alongside, (P, 5)
        self._bank: InversionPipeline | None = None
        self._bank_out: list[Output] = []
        self._counts: Counter[str] = Counter()
        self._retired: Counter[str] = Counter()
        self._findings = Findings()
        self._held = Held()
        self._odom = Odometry(self.config, self.options, self._counts, self._findings)
        self._gravity = GravityMonitor(self.config, self._counts, self._findings)
        self._rate = RateMonitor(self.config, self._counts, self._findings)
        self._rest = RestMonitor(self.config, self._counts, self._findings)
        self._frame = FrameMonitor(self.config, self.options, self._counts, self._findings)
        self._rejected = RejectMonitor(self.config, self._counts, self._findings,
                                       lambda: self.counters)
        self._acceleration = AccelerationMonitor(self.config, self._counts, self._findings)
        self._start_chainage = 0.0
        self.mounting = Mounting(self.config)  #: gravity estimate and vertical projection
        self._mounting = MountingMonitor(self.mounting, self._findings)
        self._reorder = Reorder(*self.options.reorder_limits(self.config.rate_hz))
        self.options.check_speed(self.config)
        if noise_variance is not None and self.model is None:  # a coach waits for its gyro
            self._build()

    # ------------------------------------------------------------------ public interface
    @property
    def delay_samples(self) -> int:
        """Band delay of the pipeline (samples; 0 before it is built)."""
        return self.pipeline.delay_samples if self.pipeline is not None else 0

    @property
    def held(self) -> int:
        """IMU samples waiting for their stamp order, speed decision or the noise decision."""
        return len(self._held) + self._reorder.held

    @property
    def reordering(self) -> int:
        """IMU samples in the re-order buffer (waiting for their stamp order)."""
        return self._reorder.held

    @property
    def chainage_m(self) -> float:
        """Chainage of the newest sample pushed into the filters (m)."""
        return self.pipeline.chainage_m if self.pipeline is not None else self._start_chainage

    @property
    def noise_variance(self) -> float | None:
        """The accelerometer noise variance, (m/s^2)^2, once decided."""
        return self.noise.variance

    @property
    def noise_source(self) -> str:
        """Where the noise variance came from ('' before it is decided)."""
        return self.noise.source

    @property
    def channels(self) -> tuple[str, ...]:
        """The data channels the pipeline inverts (model channel names, accel first)."""
        return ('accel_z', 'pitch_rate') if self.gyro else ('accel_z',)

    @property
    def counters(self) -> dict[str, int]:
        """Counts by reason: the sanitiser's and the pipeline's (over every rebuild), plus
        reordered and late (IMU samples re-ordered within reorder_window_s, and beyond it),
        odom_received, odom_nan, odom_implausible, odom_out_of_order, odom_time_reset,
        speed_unknown, reverse, gravity_invalid, rate_invalid, lost (samples missing between
        stamps closer than a gap), wrong_frame_accepted and the
        emitted outputs by quality: valid, degraded, invalid."""
        mounting = Counter({'mounting_degraded': self.mounting.degraded})
        return dict(self._retired + self._live() + self._counts + mounting
                    + self._reorder.counters)

    @property
    def findings(self) -> list[Finding]:
        """The current verdict of each check made so far."""
        return self._findings.all

    @property
    def status(self) -> Finding:
        """The worst finding (ERROR > WARN > OK), or OK 'ok' before any."""
        return self._findings.status

    def odometry(self, stamps_ns: np.ndarray, speed_mps: np.ndarray) -> Output:
        """Odometry samples (stamps (M,) int64 ns, speeds (M,) m/s, in stamp order as they
        came); returns the outputs of IMU samples whose speed became known."""
        self._odom.add(stamps_ns, speed_mps)
        return self._release(final=False)

    def imu(self, stamps_ns: np.ndarray, accel: np.ndarray,
            frame_ids: np.ndarray | None = None,
            covariance: np.ndarray | None = None,
            angular_velocity: np.ndarray | None = None,
            gyro_covariance: np.ndarray | None = None) -> Output:
        """IMU samples: stamps (T,) int64 ns, accel (T, 3) m/s^2 in the sensor frame (REP 145,
        +g up at rest), frame_ids (T,) str (None: the expected one), covariance (T, 9) REP 145
        linear_acceleration_covariance (None: unknown); a coach also takes angular_velocity
        (T, 3) rad/s and gyro_covariance (T, 9) angular_velocity_covariance (None: unknown).
        Returns the outputs now final."""
        stamps = np.atleast_1d(np.asarray(stamps_ns, dtype=np.int64))
        accel = np.array(accel, dtype=float, ndmin=2)
        if accel.shape != (stamps.size, 3):
            raise ConfigError(f'accel: expected shape ({stamps.size}, 3), got {accel.shape}')
        if self.model is not None:
            accel = self._with_rate(accel, angular_velocity, gyro_covariance)
        frames = np.full(stamps.size, self.config.frame_id) \
            if frame_ids is None else text_array(frame_ids)
        cov = None if covariance is None else \
            np.asarray(covariance, dtype=float).reshape(stamps.size, 9)
        if stamps.size and (min(stamps.tolist()) if stamps.size <= SMALL else stamps.min()) <= 0:
            # a zero or negative stamp is malformed, as a node's intake finds it before the
            # core; bag readers pass it on (a stamp 0 among real ones was a 54-year time jump)
            keep = stamps > 0
            self._counts['malformed'] += int(np.count_nonzero(~keep))
            stamps, accel, frames = stamps[keep], accel[keep], frames[keep]
            cov = None if cov is None else cov[keep]
        before = self._reorder.counters.total()
        released = self._reorder.push(stamps, accel, frames, cov)
        if self._reorder.counters.total() != before:
            self._findings.set('order', *self._reorder.verdict())
        return self._intake(*released)

    def flush(self) -> Output:
        """End of the input (offline end, node idle timeout, deactivate, shutdown): decide every
        held sample and emit everything pending; the next sample starts afresh."""
        drained = self._intake(*self._reorder.drain())
        out = Output.concat([drained, self._release(final=True)], self._channels)
        if self.pipeline is None:
            return out
        return Output.concat([out, self._restart()], self._channels)

    def reset(self, reason: str = 'request') -> Output:
        """Restart the filters (pending outputs emitted, the tail INVALID); held samples go to
        the restarted filters."""
        if self.pipeline is None:
            return self._empty()
        return self._restart(reason)

    def rebuild(self, config: InversionConfig | None = None,
                vehicle: VehicleParams | np.ndarray | VehicleModel | None = None, *,
                bank: np.ndarray | None = None,
                options: InputOptions | None = None) -> Output:
        """A parameter change: flush the old filters (their outputs are returned), build new
        ones that continue the chainage; held samples and the noise decision are kept. A
        change the filters do not see (input options alone; speed_mps while the speed comes
        from odometry) is applied to the running ones (``reconfigure`` counted): a rebuild
        costs the band delay of INVALID outputs, 5 s of track. A model as ``vehicle`` (a node's
        vehicle_file) is inverted at its nominal theta; another model kind rebuilds."""
        changed = False  # a coach (its geometry may differ) or a change of model kind
        if _is_model(vehicle):
            coach = None if vehicle.kind == 'quarter_car' else vehicle
            changed = coach is not None or self.model is not None
            self.model = coach
        seen = config if config is not None else self.config  # what the filters see of it
        if self.options.use_odom and (options is None or options.use_odom):
            seen = replace(seen, speed_mps=self.config.speed_mps)  # unused with odometry
        keep = self.pipeline is not None and not changed and bank is None and \
            seen == self.config and (
            vehicle is None or np.array_equal(self._as_theta(vehicle), self.theta))
        out = self._empty()
        if self.pipeline is not None and not keep:
            out = self._restart()
            self._retired.update(self._live())
            self._start_chainage = self.pipeline.chainage_m
            self.pipeline = self._bank = None
        self.config = config if config is not None else self.config
        self.theta = self._as_theta(vehicle) if vehicle is not None else self.theta
        self.bank = np.atleast_2d(self._as_theta(bank)) if bank is not None else self.bank
        self.options = options if options is not None else self.options
        for monitor in (self._odom, self._gravity, self._rate, self._rest, self._frame,
                        self._rejected, self._acceleration):
            monitor.config = self.config
        self._odom.options = self._frame.options = self.options
        self._reorder.configure(*self.options.reorder_limits(self.config.rate_hz))
        if keep and self._sanitizer is not None:  # the running filters take the new options
            self._sanitizer.set_limits(self.options.stuck_s, self.options.backward_reset_s)
            self._counts['reconfigure'] += 1
            return out
        self._counts['rebuild'] += 1
        self.mounting.configure(self.config)
        self.options.check_speed(self.config)
        if self.noise_variance is not None:
            self._build()
        return out

    def start(self) -> InversionPipeline:
        """Decide the noise now (from the variances reported so far, else noise_std_mps2) and
        build the filters if that has not happened yet; returns the pipeline."""
        if self.pipeline is None:
            self._decide_noise()
        assert self.pipeline is not None  # deciding the noise builds it
        return self.pipeline

    def feed_bank(self, theta: np.ndarray) -> None:
        """Hand the accepted batches to a bank pipeline over theta (P, 5) as well (the
        uncertainty band of the same stream, offline): the same decisions, outputs u (P, K)
        (NaN where INVALID) collected for ``bank_outputs``."""
        self._bank_theta = np.atleast_2d(self._as_theta(theta))
        if self.pipeline is not None:
            self._build_bank()

    def bank_outputs(self) -> Output:
        """The bank pipeline's outputs since the last call (``feed_bank``)."""
        theta = self._bank_theta
        out = Output.concat(self._bank_out, None if theta is None else theta.shape[0])
        self._bank_out = []
        return out

    def finish(self, out: Output) -> Output:
        """Count pipeline outputs by quality, the 'acceleration' finding, and set u = NaN
        where INVALID."""
        if not len(out) or out.quality is None:
            return out
        counts = quality_counts(out.quality)
        self._counts.update(counts)
        if self.pipeline is not None:
            self._acceleration.check(self.pipeline.speed_changed,
                                     self._retired['speed_change'])
        return _invalid_nan(out) if counts['invalid'] else out

    # ------------------------------------------------------------------ building
    def _as_theta(self, vehicle: VehicleParams | np.ndarray | VehicleModel) -> np.ndarray:
        """theta of the stage's model: the coach's (n,), else the quarter car's (5,) (a
        model's: its nominal)."""
        values: Any = vehicle.theta if _is_model(vehicle) else vehicle
        return as_theta(values) if self.model is None else model_theta(self.model, values)

    def _with_rate(self, accel: np.ndarray, gyro: np.ndarray | None,
                   cov: np.ndarray | None) -> np.ndarray:
        """A coach's accel rows (T, 3), with the pitch rate (rad/s, NaN where REP 145 marks
        the gyro absent) as a fourth column when the stage uses the gyro; the first call
        decides that and notes the reported gyro variances."""
        n = accel.shape[0]
        if gyro is not None:
            gyro = np.asarray(gyro, dtype=float).reshape(n, 3)
        cov = None if cov is None else np.asarray(cov, dtype=float).reshape(n, 9)
        absent = np.zeros(n, bool) if cov is None else (np.isnan(cov[:, 0]) | (cov[:, 0] == -1))
        if self.gyro is None and n:
            self.gyro = gyro is not None and not absent[0]
        if not self.gyro:
            return accel
        rate = np.full(n, np.nan) if gyro is None else np.where(absent, np.nan, gyro[:, 1])
        if cov is not None:
            self.noise.note_gyro(cov, absent, self._held.received)
        return np.column_stack([accel, rate])

    @property
    def _channels(self) -> int | None:
        return None if self.bank is None else self.bank.shape[0]

    def _empty(self) -> Output:
        return Output.concat([], self._channels)

    def _live(self) -> Counter[str]:
        """The counts of the running sanitiser and pipeline (none before they are built)."""
        if self.pipeline is None or self._sanitizer is None:
            return Counter()
        return self._sanitizer.counters + Counter(self.pipeline.counters)

    def _restart(self, reason: str | None = None) -> Output:
        """Flush the pipeline (``reason``: count it as a reset) and restart the sanitiser."""
        assert self.pipeline is not None and self._sanitizer is not None
        out = self.pipeline.flush() if reason is None else self.pipeline.reset(reason)
        if self._bank is not None:
            self._bank_out.append(_invalid_nan(self._bank.flush() if reason is None
                                               else self._bank.reset(reason)))
        self._sanitizer.reset()
        return self.finish(out)

    def _feed(self, clean: Clean, quality: np.ndarray, rates: np.ndarray | None) -> Output:
        """A sanitised batch into the pipeline (and the bank pipeline); ``rates``: the raw
        batch's pitch rates (T,) rad/s when the stage uses the gyro."""
        assert self.pipeline is not None
        count = None if rates is None else rates.size
        out = self.pipeline.feed(clean, quality, rates, count)
        if self._bank is not None:
            self._bank_out.append(_invalid_nan(self._bank.feed(clean, quality, rates, count)))
        return out

    def _pipeline(self, theta: np.ndarray, variance: float) -> InversionPipeline:
        """A pipeline over theta (the nominal or a bank) for the stage's model and channels,
        graded as the nominal one."""
        if self.model is None:
            return InversionPipeline(self.config, theta, variance,
                                     start_chainage_m=self._start_chainage, nominal=self.theta)
        config = self.config if self.noise.gyro_variance is None else self.config.with_(
            gyro_noise_std_rads=float(np.sqrt(self.noise.gyro_variance)))
        return InversionPipeline(config, theta, variance, start_chainage_m=self._start_chainage,
                                 nominal=self.theta, model=self.model, channels=self.channels)

    def _build_bank(self) -> None:
        """The bank pipeline of ``feed_bank``, graded as the nominal one."""
        if self._bank_theta is not None:
            assert self.noise_variance is not None  # built with the nominal pipeline
            self._bank = self._pipeline(self._bank_theta, self.noise_variance)

    def _build(self) -> None:
        """The sanitiser, the pipeline and the noise floor for the decided noise variance."""
        cfg, opt, variance = self.config, self.options, self.noise_variance
        assert variance is not None  # called once the noise is decided
        self._sanitizer = InputSanitizer.for_config(cfg, opt.stuck_s, opt.backward_reset_s)
        if self.model is not None:
            self.gyro = bool(self.gyro)  # filters built before any IMU message: no gyro
        self.pipeline = self._pipeline(self.bank if self.bank is not None else self.theta,
                                       variance)
        self._build_bank()
        self._acceleration.seen = 0  # the new pipeline's speed_change count seen so far
        self.noise.design(cfg, self.theta, self._findings, self.pipeline.observability)

    def _decide_noise(self) -> None:
        self.noise.decide(self.config)
        self._build()

    # ------------------------------------------------------------------ arrival
    def _intake(self, stamps: np.ndarray, accel: np.ndarray, frames: np.ndarray,
                cov: np.ndarray | None) -> Output:
        """IMU samples released by the re-order buffer (stamp order): the arrival checks, then
        held for their speed decision; returns the outputs now final."""
        if stamps.size == 0:
            return self._release(final=False)
        parts = []
        back = round(self.options.backward_reset_s * 1e9)
        while (cut := self._held.new_stream_at(stamps, back)) is not None:  # time went back
            # (a loop: two interleaved clocks jump at every other sample)
            if cut:
                parts.append(self._arrive(stamps[:cut], accel[:cut], frames[:cut],
                                          None if cov is None else cov[:cut]))
            parts.append(self._release(final=True))  # the old stream's held samples first
            self._held.newest_imu = NO_STAMP  # the new stream's samples wait for its odometry
            self._odom.new_stream(stamps[cut])
            stamps, accel, frames = stamps[cut:], accel[cut:], frames[cut:]
            cov = None if cov is None else cov[cut:]
        out = self._arrive(stamps, accel, frames, cov)
        return Output.concat([*parts, out], self._channels) if parts else out

    def _arrive(self, stamps: np.ndarray, accel: np.ndarray, frames: np.ndarray,
                cov: np.ndarray | None) -> Output:
        """``_intake`` of samples of one stream (no time reset among them); a coach's pitch
        rate rides in a fourth accel column to the held queue."""
        small = stamps.size <= SMALL
        held = self._held
        full, accel = accel, accel[:, :3]  # full: with the rate column, if any
        if cov is not None:
            if small and held.received >= NOISE_SAMPLES:  # the mask only where needed
                for i, c in enumerate(cov[:, 0].tolist()):
                    if c != c or c == -1.0:
                        accel[i] = np.nan
            else:
                absent = np.isnan(cov[:, 0]) | (cov[:, 0] == -1.0)
                accel[absent] = np.nan
                self.noise.note(self.config, cov, absent, held.received)
        self._frame.check(frames)
        # the gravity mean takes the rows within the saturation limit (the sanitiser rejects
        # the others: one 1e30 sample made the mean miss gravity for a minute)
        lim = self.mounting.limit
        if small:
            data = accel.tolist()
            rows = [all(-np.inf < x < np.inf for x in row) for row in data]
            usable = [all(-lim < x < lim for x in row) for row in data]
            flags = np.maximum(self._gravity.flags_small(data, usable),
                               self._rate.flags_small(stamps, rows))
            vert, mount = self.mounting.vertical_small(data, rows)
            newest = max((t for t, ok in zip(stamps.tolist(), rows, strict=True) if ok),
                         default=None)
        else:
            finite = np.isfinite(accel).all(axis=1)
            usable = finite if float(np.max(np.abs(accel), initial=0.0)) < lim else \
                finite & (np.abs(accel) < lim).all(axis=1)  # NaN fails: the finite mask
            flags = np.maximum(self._gravity.flags(accel, usable),
                               self._rate.flags(stamps, finite))
            vert, mount = self.mounting.vertical(accel, finite)
            newest = int(stamps[finite].max()) if finite.any() else None
        arrival = held.received + np.arange(stamps.size)
        held.received += stamps.size
        if newest is not None:
            held.newest_imu = max(held.newest_imu, newest)
        self._mounting.report()
        held.extend(stamps, full, vert, frames, np.maximum(flags, mount), arrival)
        return self._release(final=False)

    # ------------------------------------------------------------------ release
    def _ready(self) -> int:
        """Number of held samples (a prefix) whose speed decision is final."""
        if not self.options.use_odom or not len(self._held):
            return len(self._held)
        timeout = np.int64(round(self.options.odom_timeout_s * 1e9))
        return self._held.ready(self._odom.newest, timeout)

    def _release(self, final: bool) -> Output:
        """Push the held samples whose decisions are final into the filters."""
        if self.pipeline is None:
            if not final and self._held.received < NOISE_SAMPLES:
                return self._empty()
            if not self._held.received:
                return self._empty()
            self._decide_noise()
        pipeline = self.start()
        count = len(self._held) if final else self._ready()
        if count == 0:
            return self._empty()
        stamps, full, vert, frames, flags = self._held.pop(count)
        accel, rates = full[:, :3], (full[:, 3] if full.shape[1] > 3 else None)
        speed, known = self._odom.speeds(stamps)
        if count <= SMALL:
            v, k = speed.tolist(), known.tolist()
            self._odom.report(k.count(False), sum(x < 0 for x in v), k[-1])
            if any(ok and abs(x) < STANDSTILL_MPS for x, ok in zip(v, k, strict=True)):
                self._rest.check(accel, speed, known)
        else:
            self._odom.report(known.size - int(np.count_nonzero(known)),
                              int(np.count_nonzero(speed < 0)), bool(known[-1]))
            self._rest.check(accel, speed, known)
        quality = np.maximum(flags, self.noise.speed_quality(self.config, speed, known))
        checked = self._frame.checked(frames)
        sanitizer = self._sanitizer
        assert sanitizer is not None  # built with the pipeline
        before = sanitizer.counters['accepted']
        missed = self._odom.missed_distance(stamps, speed, known)
        if not missed:  # the usual case: one batch
            clean = sanitizer.process(stamps, vert, speed, checked)
            out = self._feed(clean, clean.carry(quality), rates)
        else:  # the chainage moves on where the speed is known again
            parts, lo = [], 0
            for at, metres in (*missed, (count, 0.0)):
                clean = sanitizer.process(stamps[lo:at], vert[lo:at], speed[lo:at],
                                          None if checked is None else checked[lo:at])
                parts.append(self._feed(clean, clean.carry(quality[lo:at]),
                                        None if rates is None else rates[lo:at]))
                for each in (pipeline, self._bank):
                    if each is not None:
                        each.add_distance(metres)
                lo = at
            out = Output.concat(parts, self._channels)
        self._rejected.check(count, sanitizer.counters['accepted'] - before)
        return self.finish(out)


def _is_model(vehicle: object) -> TypeGuard[VehicleModel]:
    """Whether ``vehicle`` is a ``railgsa_ros.models`` model (not parameters)."""
    return hasattr(vehicle, 'kind')


def _invalid_nan(out: Output) -> Output:
    """``out`` with u = NaN where INVALID."""
    if not len(out) or out.quality is None or not (invalid := out.quality == _INVALID).any():
        return out
    u = np.array(out.u_m, dtype=float)
    u[..., invalid] = np.nan
    return Output(out.stamps_ns, out.chainage_m, u, out.quality, out.speed_mps, out.gap_std_m)
