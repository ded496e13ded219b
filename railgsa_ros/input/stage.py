"""The input policy: every decision about IMU and odometry input, the same live and offline.

``irregularity_node``, ``uncertainty_node``, ``railgsa invert [--bands]`` and ``railgsa review``
feed an :class:`InputStage` and publish what it returns. It owns (docs/inversion.md, "Input
policy"):

- REP 145 input: accel (T, 3) in the sensor frame, the vertical axis picked by ``accel_axis``;
  covariance[0] = -1 (or NaN) marks the acceleration absent (the sample is rejected as ``nan``),
  an all-zero covariance is unknown.
- noise: the median of the configured axis' reported variance over the first NOISE_SAMPLES IMU
  samples (absent or unknown ones skipped), else ``noise_std_mps2``^2; it designs the Kalman
  method and the sensor noise floor (``observability.NoiseFloor``).
- speed: the newest odometry sample at or before an IMU stamp if it is not older than
  ``odom_timeout_s``, else UNKNOWN (the output is INVALID). IMU samples wait until that is
  final: until odometry newer than them has arrived, or IMU stamps ``odom_timeout_s`` later,
  or HOLD_SAMPLES later samples, or ``flush``; so the decisions depend on the data, not on how
  it was batched (odometry must arrive in stamp order; older odometry is counted and ignored,
  odometry going back by more than ``backward_reset_s`` restarts it). Non-finite odometry,
  speeds beyond SPEED_LIMIT_MPS and jumps beyond ``_speed_step`` from the last accepted speed
  are counted and ignored (no IMU sample is dropped); a negative
  speed is reverse running: the band uses |v|, the chainage decreases, it is counted and
  reported. ``speed_mps`` is used only with ``use_odom`` false (``--speed`` offline).
- quality per sample (:class:`~railgsa_ros.inverse.quality.Quality`), carried through the band
  delay line; INVALID outputs have u = NaN.
- mounting (``input.mounting.Mounting``, ``mounting``): the gravity direction estimated from
  the 3-axis specific force, the vertical projected on it or on a configured rotation, the
  tilt reported, DEGRADED while the axis in use is off it or unsettled.
- plausibility: gravity on the configured axis and sign, the measured rate against
  ``rate_hz``, the magnitude of the specific force at rest against gravity (scale factor and
  bias), speed known, every sample rejected, the frame policy; ``findings`` and
  ``status`` say what to do in one line.
- rebuild on a parameter change (old filters flushed, chainage continued), reset, flush.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from scipy.signal import lfilter

from railgsa_ros.errors import ConfigError
from railgsa_ros.input.mounting import Mounting
from railgsa_ros.input.rate import JITTER_TOLERANCE, CountedSteps, count_blocks
from railgsa_ros.input.reorder import Reorder
from railgsa_ros.input.sanitize import (
    REASONS,
    SMALL,
    SPEED_LIMIT_MPS,
    frame_mask,
    text_array,
)
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.observability import STANDSTILL_MPS, NoiseFloor
from railgsa_ros.inverse.pipeline import InversionPipeline, Output
from railgsa_ros.inverse.quality import Quality, quality_counts
from railgsa_ros.vehicle import VehicleParams, as_theta

OK, WARN, ERROR = 0, 1, 2  #: finding levels (diagnostic_msgs/DiagnosticStatus levels)
NOISE_SAMPLES = 64  #: IMU samples whose reported variances decide the noise
HOLD_SAMPLES = 1 << 16  #: an IMU sample waits for odometry at most this many later samples
#: an odometry speed changing faster than this (beyond ODOM_NOISE_MPS) is implausible: 2 g,
#: where trains brake at up to about 3 m/s^2 in an emergency (a margin for simulated
#: profiles); a sign flip at 20 m/s is 2000 m/s^2 at 50 Hz, a drop to 0 is 1000 m/s^2
ODOM_ACCEL_MPS2 = 20.0
ODOM_NOISE_MPS = 1.0  #: odometry speed noise allowed on top of ODOM_ACCEL_MPS2, m/s
GRAVITY_TAU_S = 1.0  #: time constant of the per-axis running mean that finds gravity, s
GRAVITY_TOLERANCE = 0.25  #: the vertical axis must read gravity within this fraction
RATE_BLOCK = 512  #: stamp steps per rate measurement (``input.rate``: counted per stamp)
REJECT_RUN_S = 1.0  #: status ERROR after this long (in samples at rate_hz) with none accepted
REST_S = 1.0  #: standstill (in samples at rate_hz) before the scale and bias check at rest
REST_TOLERANCE = 0.01  #: at rest |mean specific force| must be gravity within this fraction
#: default re-order window, s: a recorder's receipt jitter and a driver's bursts are a few ms
REORDER_WINDOW_S = 0.05
REORDER_CAP = 4  #: the re-order buffer holds at most this many windows of samples at rate_hz
AXES = 'xyz'
_VALID, _DEGRADED, _INVALID = int(Quality.VALID), int(Quality.DEGRADED), int(Quality.INVALID)
_NO_STAMP = int(np.iinfo(np.int64).min)  #: the newest IMU stamp before any


def _largest(values: list[float]) -> int:
    """np.argmax(np.abs(values)) of a short list: the first NaN, else the first largest."""
    mags = [abs(v) for v in values]
    return next((k for k, m in enumerate(mags) if m != m), mags.index(max(mags)))


_HINTS = {'wrong_frame': "set frame_id to the driver's frame_id or wrong_frame_policy to "
                         'accept',
          'nan': 'the accelerations are NaN or marked absent (covariance[0] = -1)',
          'saturated': 'check saturation_mps2 and the units of the accelerometer',
          'stuck': 'the sensor repeats one value: it is frozen, or raise stuck_s',
          'out_of_order': 'the stamps do not increase: check the driver clock',
          'duplicate': 'the stamps repeat: check the driver clock'}


@dataclass(frozen=True)
class InputOptions:
    """Input options that are not inversion parameters (the nodes' parameters of these names).

    use_odom: speed from odometry (false: ``speed_mps`` for every sample); odom_timeout_s (s):
    odometry older than this is missing; wrong_frame_policy: 'accept' (default: a driver's own
    frame_id is used, with a WARN finding) or 'reject' (strict: such samples are rejected);
    stuck_s (s, 0 = off) and backward_reset_s (s): see ``InputSanitizer``; reorder_window_s
    (s, 0 = off): IMU samples are re-ordered by header stamp within this window before any
    other decision (``input.reorder``; it adds this much latency).
    """

    use_odom: bool = True
    odom_timeout_s: float = 1.0
    wrong_frame_policy: str = 'accept'
    stuck_s: float = 0.5
    backward_reset_s: float = 1.0
    reorder_window_s: float = REORDER_WINDOW_S

    def __post_init__(self) -> None:
        if self.wrong_frame_policy not in ('accept', 'reject'):
            raise ConfigError(f'wrong_frame_policy: expected accept or reject, got '
                              f'{self.wrong_frame_policy!r}')
        for name in ('odom_timeout_s', 'backward_reset_s'):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f'{name}: expected a positive number of s, got {value!r}')
        if not (np.isfinite(self.stuck_s) and self.stuck_s >= 0):
            raise ConfigError(f'stuck_s: expected >= 0 s, got {self.stuck_s!r}')
        if not (0 <= self.reorder_window_s < self.backward_reset_s):
            raise ConfigError(f'reorder_window_s: expected >= 0 s and below backward_reset_s '
                              f'({self.backward_reset_s:g} s), got {self.reorder_window_s!r}')

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> InputOptions:
        """The options found in ``values`` (e.g. a node's parameters); other keys ignored."""
        return cls(**{f.name: values[f.name] for f in fields(cls) if f.name in values})


@dataclass(frozen=True)
class Finding:
    """One plausibility verdict: key ('gravity', 'rate', 'jitter', 'rest', 'mounting',
    'speed', 'odometry', 'frame', 'rejected', 'acceleration', 'noise'), level (OK/WARN/ERROR)
    and a one-line message saying what to do."""

    key: str
    level: int
    message: str


def _axis_of(config: InversionConfig) -> tuple[int, float]:
    """Column (0..2) and sign (+-1.0) of the configured vertical axis."""
    axis = config.accel_axis
    return AXES.index(axis[-1]), -1.0 if axis.startswith('-') else 1.0


def _gravity_verdict(cfg: InversionConfig, last: list[float], bad: bool) -> Finding:
    """The 'gravity' finding from the newest running mean ``last`` (3 m/s^2) and whether it
    failed the check."""
    col, sign = _axis_of(cfg)
    if not bad:
        return Finding('gravity', OK,
                       f'gravity on {cfg.accel_axis} ({sign * last[col]:.2f} m/s^2)')
    k = _largest(last)
    axis = ('-' if last[k] < 0 else '') + AXES[k]
    if abs(abs(last[k]) - cfg.gravity_mps2) <= GRAVITY_TOLERANCE * cfg.gravity_mps2:
        message = (f'gravity is on {axis} ({last[k]:+.2f} m/s^2 on {AXES[k]}), not on '
                   f'{cfg.accel_axis}: set accel_axis to {axis!r}; outputs are INVALID until then')
    else:
        message = (f'no axis reads gravity {cfg.gravity_mps2:g} m/s^2 (largest: '
                   f'{last[k]:+.2f} on {AXES[k]}): check the units and mounting, or set '
                   'gravity_mps2 to 0 if the driver removes gravity; outputs are INVALID')
    return Finding('gravity', ERROR, message)


def _speed_verdict(options: InputOptions, speed_mps: float, lost: bool, reverse: int,
                   total_reverse: int) -> Finding:
    """The 'speed' finding of a release (``speed_mps``: the fixed speed without odometry;
    ``lost``: its newest sample has no speed; ``reverse``: its samples at negative speed,
    ``total_reverse`` so far)."""
    if not options.use_odom:
        return Finding('speed', OK, f'fixed speed_mps {speed_mps:g} m/s (use_odom false)')
    if lost:
        return Finding('speed', WARN, (
            f'no odometry within odom_timeout_s ({options.odom_timeout_s:g} s) of the IMU '
            'stamps: outputs are INVALID until a speed is known; check the odom topic (offline: '
            '--speed)'))
    if reverse:
        return Finding('speed', WARN, (
            f'reverse running: {total_reverse} samples at negative speed (the chainage '
            'decreases); if the train ran forward, the odometry sign is reversed'))
    return Finding('speed', OK, 'speed from odometry')


def _speed_step(dt_ns: np.ndarray | int) -> np.ndarray | float:
    """Largest odometry speed change (m/s) a train makes in dt_ns: ODOM_ACCEL_MPS2 x dt plus
    ODOM_NOISE_MPS for the odometry's own noise."""
    return ODOM_ACCEL_MPS2 * np.asarray(dt_ns) * 1e-9 + ODOM_NOISE_MPS


def _held_speeds(odom_t: np.ndarray, odom_v: np.ndarray, stamps: np.ndarray, timeout_ns: int
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """(speed m/s, known, first odometry sample used) at the stamps: the newest odometry
    sample at or before each, if at most ``timeout_ns`` older; unknown speeds are 0."""
    if odom_t.size == 0:
        return np.zeros(stamps.size), np.zeros(stamps.size, bool), 0
    idx = np.searchsorted(odom_t, stamps, side='right') - 1
    j = np.maximum(idx, 0)
    known = (idx >= 0) & (stamps - odom_t[j] <= timeout_ns)
    return np.where(known, odom_v[j], 0.0), known, int(j.min())


class _Held:
    """IMU samples waiting for their speed decision, in arrival order."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self.stamps = np.zeros(0, np.int64)
        self.accel = np.zeros((0, 3))
        self.vertical = np.zeros(0)  # upward specific force (mounting projection), m/s^2
        self.frames = np.zeros(0, dtype=str)
        self.flags = np.zeros(0, np.uint8)  # input quality from gravity and rate checks
        self.arrival = np.zeros(0, np.int64)  # index of the sample since the policy started

    def __len__(self) -> int:
        return int(self.stamps.size)

    def extend(self, stamps: np.ndarray, accel: np.ndarray, vertical: np.ndarray,
               frames: np.ndarray, flags: np.ndarray, arrival: np.ndarray) -> None:
        if not len(self):  # the usual live case: nothing waits, no copy
            self.stamps, self.accel, self.frames = stamps, accel, frames
            self.vertical = vertical
            self.flags, self.arrival = flags, arrival
            return
        self.stamps = np.concatenate([self.stamps, stamps])
        self.accel = np.concatenate([self.accel, accel])
        self.vertical = np.concatenate([self.vertical, vertical])
        self.frames = np.concatenate([self.frames, frames])
        self.flags = np.concatenate([self.flags, flags])
        self.arrival = np.concatenate([self.arrival, arrival])

    def pop(self, count: int) -> tuple[np.ndarray, ...]:
        out = (self.stamps[:count], self.accel[:count], self.vertical[:count],
               self.frames[:count], self.flags[:count])
        if count == len(self):
            self.clear()
            return out
        self.stamps, self.accel = self.stamps[count:], self.accel[count:]
        self.vertical = self.vertical[count:]
        self.frames, self.flags = self.frames[count:], self.flags[count:]
        self.arrival = self.arrival[count:]
        return out


class InputStage:
    """Odometry and IMU samples in, reconstructed samples with their quality out.

    ``config``: InversionConfig; ``vehicle``: the nominal vehicle (VehicleParams or theta (5,)):
    it sets the noise floor, so every policy with the same config and vehicle makes the same
    decisions; ``bank``: theta (P, 5) for a bank pipeline (uncertainty: outputs u (P, K)), else
    the nominal vehicle is inverted; ``options``: InputOptions; ``noise_variance``: a fixed
    accelerometer variance ((m/s^2)^2) instead of the rule from the data.
    """

    def __init__(self, config: InversionConfig | None = None,
                 vehicle: VehicleParams | np.ndarray | None = None, *,
                 bank: np.ndarray | None = None, options: InputOptions | None = None,
                 noise_variance: float | None = None) -> None:
        self.config = config if config is not None else InversionConfig()
        self.theta = as_theta(vehicle if vehicle is not None else VehicleParams())
        if self.theta.ndim != 1:
            raise ConfigError('vehicle: the policy takes the nominal vehicle (5,); pass a '
                              'parameter bank as bank=')
        self.bank = None if bank is None else np.atleast_2d(as_theta(bank))
        self.options = options if options is not None else InputOptions()
        self._fixed_variance = noise_variance
        self.noise_variance: float | None = noise_variance  #: (m/s^2)^2 once decided
        self.noise_source = 'given' if noise_variance is not None else ''
        self.pipeline: InversionPipeline | None = None
        self.noise: NoiseFloor | None = None
        self.v_invalid = self.v_degraded = np.nan  #: speed limits of the noise floor, m/s
        self._counts: Counter[str] = Counter()
        self._retired: Counter[str] = Counter()
        self._findings: dict[str, Finding | None] = {}  # None: made from _lazy when read
        self._lazy: dict[str, Callable[[], Finding]] = {}
        self._held = _Held()
        self._known_at: tuple[int, float] | None = None  # stamp, speed: newest known released
        self._gap_span: tuple[int, int] | None = None  # stamps: released without speed since
        self._reported: list[float] = []  # variances of the first NOISE_SAMPLES samples
        self._received = 0  # IMU samples given so far
        self._newest_imu = _NO_STAMP
        self._odom_t = np.zeros(0, np.int64)
        self._odom_v = np.zeros(0)
        self._odom_old: tuple[np.ndarray, np.ndarray] | None = None  # before a time reset
        self._gravity: np.ndarray | None = None  # running mean (3,) m/s^2 of the finite rows
        self._rate_steps = np.zeros(RATE_BLOCK, np.int64)  # stamp steps of the open rate block
        self._rate_fill = 0  # how many of them are filled
        self._rate_prev: int | None = None  # last finite stamp seen
        self._rate_state = _VALID  # quality code after the newest rate block
        self._reject_run = 0  # samples pushed since the last accepted one
        self._start_chainage = 0.0
        self._rest = (np.zeros(3), 0)  # sum (3,) m/s^2 and count of the samples at rest
        self.mounting = Mounting(self.config)  #: gravity estimate and vertical projection
        self._mounting_version = 0  # the decision the 'mounting' finding was made from
        self._reorder = Reorder(*self._reorder_limits())
        self._check_units()
        if noise_variance is not None:
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
    def counters(self) -> dict[str, int]:
        """Counts by reason: the sanitiser's and the pipeline's (over every rebuild), plus
        reordered and late (IMU samples re-ordered within reorder_window_s, and beyond it),
        odom_received, odom_nan, odom_implausible, odom_out_of_order, odom_time_reset,
        speed_unknown, reverse, gravity_invalid, rate_invalid, lost (samples missing between
        stamps closer than a gap), wrong_frame_accepted and the
        emitted outputs by quality: valid, degraded, invalid."""
        live = Counter(self.pipeline.counters) if self.pipeline is not None else Counter()
        mounting = Counter({'mounting_degraded': self.mounting.degraded})
        return dict(self._retired + live + self._counts + mounting + self._reorder.counters)

    @property
    def findings(self) -> list[Finding]:
        """The current verdict of each check made so far."""
        for key, make in self._lazy.items():
            self._findings[key] = make()
        self._lazy.clear()
        return [f for f in self._findings.values() if f is not None]

    @property
    def status(self) -> Finding:
        """The worst finding (ERROR > WARN > OK), or OK 'ok' before any."""
        worst = max(self.findings, key=lambda f: f.level, default=None)
        if worst is None or worst.level == OK:
            return Finding('status', OK, 'ok')
        return worst

    def odometry(self, stamps_ns: np.ndarray, speed_mps: np.ndarray) -> Output:
        """Odometry samples (stamps (M,) int64 ns, speeds (M,) m/s, in stamp order as they
        came); returns the outputs of IMU samples whose speed became known."""
        stamps = np.atleast_1d(np.asarray(stamps_ns, dtype=np.int64))
        speed = np.broadcast_to(np.asarray(speed_mps, dtype=float), stamps.shape)
        self._counts['odom_received'] += stamps.size
        stamped = stamps > 0  # else malformed, as a node's intake finds it
        finite = stamped & np.isfinite(speed)
        plausible = finite & (np.abs(speed) <= SPEED_LIMIT_MPS)
        self._counts['odom_malformed'] += int((~stamped).sum())
        self._counts['odom_nan'] += int((stamped & ~finite).sum())
        self._counts['odom_implausible'] += int((finite & ~plausible).sum())
        t_ok, v_ok = stamps[plausible], speed[plausible]
        t_all = np.concatenate([self._odom_t[-1:], t_ok])
        v_all = np.concatenate([self._odom_v[-1:], v_ok])
        if t_ok.size and np.all(np.diff(t_all) > 0) and np.all(  # in order, no jump
                np.abs(np.diff(v_all)) <= _speed_step(np.diff(t_all))):
            # in order after the newest (as recorded): what the loop below appends, at once
            self._odom_t = np.concatenate([self._odom_t, t_ok])
            self._odom_v = np.concatenate([self._odom_v, v_ok])
        else:
            for t, v in zip(t_ok.tolist(), v_ok.tolist(), strict=True):
                self._add_odometry(t, v)
        self._odometry_finding()
        return self._release(final=False)

    def imu(self, stamps_ns: np.ndarray, accel: np.ndarray,
            frame_ids: np.ndarray | None = None,
            covariance: np.ndarray | None = None) -> Output:
        """IMU samples: stamps (T,) int64 ns, accel (T, 3) m/s^2 in the sensor frame (REP 145,
        +g up at rest), frame_ids (T,) str (None: the expected one), covariance (T, 9) REP 145
        linear_acceleration_covariance (None: unknown). Returns the outputs now final."""
        stamps = np.atleast_1d(np.asarray(stamps_ns, dtype=np.int64))
        accel = np.array(accel, dtype=float, ndmin=2)
        if accel.shape != (stamps.size, 3):
            raise ConfigError(f'accel: expected shape ({stamps.size}, 3), got {accel.shape}')
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
            self._order_finding()
        return self._intake(*released)

    def _intake(self, stamps: np.ndarray, accel: np.ndarray, frames: np.ndarray,
                cov: np.ndarray | None) -> Output:
        """IMU samples released by the re-order buffer (stamp order): the arrival checks, then
        held for their speed decision; returns the outputs now final."""
        if stamps.size == 0:
            return self._release(final=False)
        parts = []
        while (cut := self._new_stream_at(stamps)) is not None:  # time went back (a loop:
            # two interleaved clocks jump at every other sample)
            if cut:
                parts.append(self._arrive(stamps[:cut], accel[:cut], frames[:cut],
                                          None if cov is None else cov[:cut]))
            parts.append(self._release(final=True))  # the old stream's held samples first
            self._newest_imu = _NO_STAMP  # the new stream's samples wait for its odometry
            self._known_at = self._gap_span = self._odom_old = None
            recent = self._odom_t <= stamps[cut] + round(self.options.backward_reset_s * 1e9)
            self._odom_t, self._odom_v = self._odom_t[recent], self._odom_v[recent]  # its own
            stamps, accel, frames = stamps[cut:], accel[cut:], frames[cut:]
            cov = None if cov is None else cov[cut:]
        out = self._arrive(stamps, accel, frames, cov)
        return Output.concat([*parts, out], self._channels) if parts else out

    def _arrive(self, stamps: np.ndarray, accel: np.ndarray, frames: np.ndarray,
                cov: np.ndarray | None) -> Output:
        """``_intake`` of samples of one stream (no time reset among them)."""
        small = stamps.size <= SMALL
        if cov is not None:
            if small and self._received >= NOISE_SAMPLES:  # the mask only where needed
                for i, c in enumerate(cov[:, 0].tolist()):
                    if c != c or c == -1.0:
                        accel[i] = np.nan
            else:
                absent = np.isnan(cov[:, 0]) | (cov[:, 0] == -1.0)
                accel[absent] = np.nan
                self._note_variances(cov, absent)
        self._frame_check(frames)
        # the gravity mean takes the rows within the saturation limit (the sanitiser rejects
        # the others: one 1e30 sample made the mean miss gravity for a minute)
        lim = self.mounting.limit
        if small:
            data = accel.tolist()
            rows = [all(-np.inf < x < np.inf for x in row) for row in data]
            usable = [all(-lim < x < lim for x in row) for row in data]
            flags = np.maximum(self._gravity_flags_small(data, usable),
                               self._rate_flags_small(stamps, rows))
            vert, mount = self.mounting.vertical_small(data, rows)
            newest = max((t for t, ok in zip(stamps.tolist(), rows, strict=True) if ok),
                         default=None)
        else:
            finite = np.isfinite(accel).all(axis=1)
            usable = finite if float(np.max(np.abs(accel), initial=0.0)) < lim else \
                finite & (np.abs(accel) < lim).all(axis=1)  # NaN fails: the finite mask
            flags = np.maximum(self._gravity_flags(accel, usable),
                               self._rate_flags(stamps, finite))
            vert, mount = self.mounting.vertical(accel, finite)
            newest = int(stamps[finite].max()) if finite.any() else None
        arrival = self._received + np.arange(stamps.size)
        self._received += stamps.size
        if newest is not None:
            self._newest_imu = max(self._newest_imu, newest)
        self._mounting_finding()
        self._held.extend(stamps, accel, vert, frames, np.maximum(flags, mount), arrival)
        return self._release(final=False)

    def _new_stream_at(self, stamps: np.ndarray) -> int | None:
        """Index of the first IMU sample stamped more than backward_reset_s before every
        earlier one (a time reset: a new stream, e.g. a bag played again), None without."""
        back = round(self.options.backward_reset_s * 1e9)
        if stamps.size <= SMALL:
            newest = self._newest_imu
            for i, t in enumerate(stamps.tolist()):
                if newest != _NO_STAMP and t < newest - back:
                    return i
                newest = max(newest, t)
            return None
        running = np.maximum.accumulate(stamps)
        before = np.concatenate([[self._newest_imu], np.maximum(running[:-1], self._newest_imu)])
        jumps = np.flatnonzero((before != _NO_STAMP) & (stamps < before - back))
        return int(jumps[0]) if jumps.size else None

    def flush(self) -> Output:
        """End of the input (offline end, node idle timeout, deactivate, shutdown): decide every
        held sample and emit everything pending; the next sample starts afresh."""
        drained = self._intake(*self._reorder.drain())
        out = Output.concat([drained, self._release(final=True)], self._channels)
        if self.pipeline is None:
            return out
        return Output.concat([out, self.finish(self.pipeline.flush())], self._channels)

    def reset(self, reason: str = 'request') -> Output:
        """Restart the filters (pending outputs emitted, the tail INVALID); held samples go to
        the restarted filters."""
        if self.pipeline is None:
            return self._empty()
        return self.finish(self.pipeline.reset(reason))

    def rebuild(self, config: InversionConfig | None = None,
                vehicle: VehicleParams | np.ndarray | None = None, *,
                bank: np.ndarray | None = None,
                options: InputOptions | None = None) -> Output:
        """A parameter change: flush the old filters (their outputs are returned), build new
        ones that continue the chainage; held samples and the noise decision are kept. A
        change the filters do not see (input options alone; speed_mps while the speed comes
        from odometry) is applied to the running ones (``reconfigure`` counted): a rebuild
        costs the band delay of INVALID outputs, 5 s of track."""
        seen = config if config is not None else self.config  # what the filters see of it
        if self.options.use_odom and (options is None or options.use_odom):
            seen = replace(seen, speed_mps=self.config.speed_mps)  # unused with odometry
        keep = self.pipeline is not None and bank is None and seen == self.config and (
            vehicle is None or np.array_equal(as_theta(vehicle), self.theta))
        out = self._empty()
        if self.pipeline is not None and not keep:
            out = self.finish(self.pipeline.flush())
            self._retired.update(self.pipeline.counters)
            self._start_chainage = self.pipeline.chainage_m
            self.pipeline = None
        self.config = config if config is not None else self.config
        self.theta = as_theta(vehicle) if vehicle is not None else self.theta
        self.bank = np.atleast_2d(as_theta(bank)) if bank is not None else self.bank
        self.options = options if options is not None else self.options
        self._reorder.configure(*self._reorder_limits())
        if keep and self.pipeline is not None:  # the running filters take the new options
            self.pipeline.sanitizer.set_limits(self.options.stuck_s,
                                               self.options.backward_reset_s)
            self._counts['reconfigure'] += 1
            return out
        self._counts['rebuild'] += 1
        self.mounting.configure(self.config)
        self._check_units()
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

    def noise_std_m(self, speeds_mps: np.ndarray) -> np.ndarray:
        """Sensor noise propagated into the band, sigma_u (m), at the given speeds (m/s)."""
        if self.noise is None:
            return np.full(np.shape(speeds_mps), np.nan)
        return self.noise.sigma_m(speeds_mps)

    # ------------------------------------------------------------------ building
    @property
    def _channels(self) -> int | None:
        return None if self.bank is None else self.bank.shape[0]

    def _empty(self) -> Output:
        return Output.concat([], self._channels)

    def _reorder_limits(self) -> tuple[float, float, int]:
        """The re-order buffer's window (s), backward jump (s) and cap (samples)."""
        opt = self.options
        cap = max(SMALL, int(np.ceil(REORDER_CAP * opt.reorder_window_s * self.config.rate_hz)))
        return opt.reorder_window_s, opt.backward_reset_s, cap

    def _order_finding(self) -> None:
        """The 'order' finding: IMU stamps out of arrival order, re-ordered or late."""
        counts, largest = self._reorder.counters, self._reorder.largest_ns
        window = self.options.reorder_window_s
        if counts['late']:
            self._findings['order'] = Finding('order', WARN, (
                f'{counts["late"]} IMU samples arrived more than reorder_window_s '
                f'({window * 1e3:g} ms) after a newer stamp (by up to '
                f'{largest["late"] / 1e6:.4g} ms): not re-ordered, rejected as out_of_order; '
                'check the driver clock, or raise reorder_window_s above that'))
        else:
            self._findings['order'] = Finding('order', OK, (
                f'{counts["reordered"]} IMU samples re-ordered by header stamp (by up to '
                f'{largest["reordered"] / 1e6:.4g} ms, within reorder_window_s '
                f'{window * 1e3:g} ms)'))

    def _check_units(self) -> None:
        if self.options.use_odom is False and self.config.speed_mps <= 0:
            raise ConfigError('speed_mps: use_odom is false, so speed_mps is the speed of every '
                              'sample and must be > 0')

    def _build(self) -> None:
        """The pipeline and the noise floor for the decided noise variance."""
        cfg, opt, variance = self.config, self.options, self.noise_variance
        assert variance is not None  # called once the noise is decided
        self.pipeline = InversionPipeline(
            cfg, self.bank if self.bank is not None else self.theta, variance,
            start_chainage_m=self._start_chainage, stuck_s=opt.stuck_s,
            backward_reset_s=opt.backward_reset_s, nominal=self.theta)
        self._speed_changed = 0  # the new pipeline's speed_change count seen so far
        self.noise = NoiseFloor(self.theta, cfg.band, cfg.band_order, cfg.rate_hz, variance)
        self.v_invalid = self.noise.speed_for(cfg.noise_limit_m)
        self.v_degraded = max(self.noise.speed_for(cfg.noise_limit_m / 2), self.v_invalid)
        self._findings['noise'] = Finding('noise', OK, (
            f'sensor noise {np.sqrt(variance):.3g} m/s^2 ({self.noise_source}): the '
            f'band is unobservable below {self.v_invalid:.3g} m/s, degraded below '
            f'{max(self.v_degraded, cfg.min_design_speed_mps):.3g} m/s'))

    def _note_variances(self, cov: np.ndarray, absent: np.ndarray) -> None:
        """Keep the configured axis' variances of the first NOISE_SAMPLES samples."""
        room = NOISE_SAMPLES - self._received
        if room <= 0 or self._fixed_variance is not None:
            return
        col = 4 * AXES.index(self.config.accel_axis[-1])
        head = cov[:room]
        var = head[:, col]
        known = ~absent[:room] & np.any(head != 0, axis=1) & np.isfinite(var) & (var > 0)
        self._reported.extend(var[known].tolist())

    def _decide_noise(self) -> None:
        if self._reported:
            self.noise_variance = float(np.median(self._reported))
            self.noise_source = f'median of {len(self._reported)} IMU-reported variances'
        else:
            self.noise_variance = self.config.noise_std_mps2 ** 2
            self.noise_source = 'noise_std_mps2: the IMU reports no covariance'
        self._build()

    # ------------------------------------------------------------------ checks at arrival
    def _mounting_finding(self) -> None:
        """The 'mounting' finding, once the first block has given an estimate."""
        m = self.mounting
        if m.version != self._mounting_version:
            self._mounting_version = m.version
            self._findings['mounting'] = Finding('mounting', m.level, m.message)

    def _frame_check(self, frames: np.ndarray) -> None:
        expected = self.config.frame_id
        if frames.size <= SMALL and all(isinstance(f, str) and f == expected for f in frames):
            return  # what frame_mask finds, without its conversion to str
        match = frame_mask(frames, expected)
        if match is None or match.all():
            return
        other = str(frames[~match][0])
        if self.options.wrong_frame_policy == 'accept':
            self._counts['wrong_frame_accepted'] += int((~match).sum())
            self._findings['frame'] = Finding('frame', WARN, (
                f'IMU frame_id {other!r} is not {self.config.frame_id!r}: accepted; set '
                f'frame_id to {other!r} (or wrong_frame_policy to reject)'))
        else:
            self._findings['frame'] = Finding('frame', WARN, (
                f'IMU frame_id {other!r} is not {self.config.frame_id!r}: rejected; set '
                f'frame_id to {other!r} or wrong_frame_policy to accept'))

    def _gravity_flags(self, accel: np.ndarray, finite: np.ndarray) -> np.ndarray:
        """INVALID where the running mean of the three axes does not put gravity on the
        configured axis and sign (off when gravity_mps2 is 0); ``finite`` (T,): the rows that
        feed the mean (no NaN, within the saturation limit)."""
        cfg = self.config
        flags = np.zeros(accel.shape[0], np.uint8)
        if cfg.gravity_mps2 == 0 or not finite.any():
            return flags
        rows = accel[finite]
        alpha = min(1.0, 1.0 / (GRAVITY_TAU_S * cfg.rate_hz))
        if self._gravity is None:
            self._gravity = rows[0].copy()
        zi = ((1.0 - alpha) * self._gravity)[:, None]
        mean, _ = lfilter([alpha], [1.0, alpha - 1.0], rows.T, axis=1, zi=zi)  # (3, N)
        self._gravity = mean[:, -1].copy()
        col, sign = self._axis
        up = sign * mean[col]
        top = np.argmax(np.abs(mean), axis=0)
        good = (top == col) & (np.abs(up - cfg.gravity_mps2)
                               <= GRAVITY_TOLERANCE * cfg.gravity_mps2)
        flags[finite] = np.where(good, _VALID, _INVALID)
        self._counts['gravity_invalid'] += int((~good).sum())
        self._gravity_finding(mean[:, -1].tolist(), bool(not good[-1]))
        return flags

    def _gravity_flags_small(self, data: list[list[float]], finite: list[bool]) -> np.ndarray:
        """``_gravity_flags`` of a few samples (rows of accel as lists) in Python floats:
        lfilter's recursion (direct form II transposed: y = z + b0 x, z = b1 x - a1 y with
        b1 = 0) and the same decisions, bit-identical."""
        cfg = self.config
        g = cfg.gravity_mps2
        if g == 0 or not any(finite):
            return np.zeros(len(finite), np.uint8)
        alpha = min(1.0, 1.0 / (GRAVITY_TAU_S * cfg.rate_hz))
        a1, tolerance = alpha - 1.0, GRAVITY_TOLERANCE * g
        col, sign = self._axis
        start = data[finite.index(True)] if self._gravity is None else self._gravity.tolist()
        z0, z1, z2 = ((1.0 - alpha) * m for m in start)
        y, good, flags = start, True, []
        for (x0, x1, x2), ok in zip(data, finite, strict=True):
            if ok:
                y = [z0 + alpha * x0, z1 + alpha * x1, z2 + alpha * x2]
                z0, z1, z2 = x0 * 0.0 - y[0] * a1, x1 * 0.0 - y[1] * a1, x2 * 0.0 - y[2] * a1
                good = _largest(y) == col and abs(sign * y[col] - g) <= tolerance
            flags.append(_INVALID if ok and not good else _VALID)
        self._gravity = np.array(y)
        self._counts['gravity_invalid'] += flags.count(_INVALID)
        self._gravity_finding(y, not good)
        return np.array(flags, np.uint8)

    def _later(self, key: str, make: Callable[[], Finding]) -> None:
        """Finding ``key`` is ``make()``, made when the findings are read: the checks of every
        live push would otherwise format a message per sample."""
        self._lazy[key] = make
        self._findings.setdefault(key, None)  # its place in the order

    @property
    def _axis(self) -> tuple[int, float]:
        """Column (0..2) and sign (+-1.0) of the configured vertical axis."""
        return _axis_of(self.config)

    def _rate_flags(self, stamps: np.ndarray, finite: np.ndarray) -> np.ndarray:
        """INVALID from the sample after a block of RATE_BLOCK stamp steps whose median step
        disagrees with rate_hz by more than rate_tolerance (until a block agrees); ``finite``
        (T,): rows without NaN."""
        flags = np.zeros(stamps.size, np.uint8)
        idx = np.flatnonzero(finite)
        if idx.size == 0:
            return flags
        t = stamps[idx]
        prev = np.concatenate([[self._rate_prev if self._rate_prev is not None else t[0]],
                               t[:-1]])
        steps = t - prev
        self._rate_prev = int(t[-1])
        nonzero = steps != 0  # backward steps too: under jitter the stamps telescope
        fill = self._rate_fill
        cum = np.concatenate([[fill], fill + np.cumsum(nonzero)])  # open-block step count
        pool = np.concatenate([self._rate_steps[:fill], steps[nonzero]])
        state = np.full(idx.size, self._rate_state, np.uint8)
        full = pool.size // RATE_BLOCK * RATE_BLOCK
        counted = self._count(pool[:full])
        ends = np.arange(1, len(counted) + 1) * RATE_BLOCK
        for done, block in zip(np.searchsorted(cum[1:], ends).tolist(), counted, strict=True):
            state[done + 1:] = self._rate_block(block)  # from the sample after the block's last
        rest = pool[full:]
        self._rate_steps[:rest.size] = rest
        self._rate_fill = rest.size
        flags[idx] = state
        self._counts['rate_invalid'] += int((state == _INVALID).sum())
        return flags

    def _rate_flags_small(self, stamps: np.ndarray, finite: list[bool]) -> np.ndarray:
        """``_rate_flags`` of a few samples, one after the other (steps wrap as int64)."""
        flags = [0] * len(finite)
        state = self._rate_state
        prev, invalid = self._rate_prev, 0
        for i, (t, ok) in enumerate(zip(stamps.tolist(), finite, strict=True)):
            if not ok:
                continue
            step = (t - (t if prev is None else prev) + (1 << 63)) % (1 << 64) - (1 << 63)
            prev, flags[i] = t, state
            invalid += state == _INVALID
            if step != 0:
                self._rate_steps[self._rate_fill] = step
                self._rate_fill += 1
                if self._rate_fill == RATE_BLOCK:
                    state, self._rate_fill = self._rate_block(self._count(self._rate_steps)[0]), 0
        self._rate_prev = prev
        self._counts['rate_invalid'] += invalid
        return np.array(flags, np.uint8)

    def _count(self, steps: np.ndarray) -> list[CountedSteps]:
        """Each block of RATE_BLOCK stamp steps (ns) of ``steps`` counted (``input.rate``)."""
        return count_blocks(steps.reshape(-1, RATE_BLOCK), 1e9 / self.config.rate_hz,
                            self.config.gap_factor)

    def _rate_block(self, counted: CountedSteps) -> int:
        """The verdict on one full block of RATE_BLOCK stamp steps (``counted``): the 'rate' and
        'jitter' findings; returns the quality code of the samples after it: INVALID at another
        rate, DEGRADED after samples lost without a gap (the record closes up around them: its
        time axis is compressed), counted as ``lost``, and under stamp jitter beyond
        JITTER_TOLERANCE periods (stamps reorder: re-ordered, their times wrong; lost ones
        counted while a period locks), counted as ``jitter`` (:mod:`railgsa_ros.input.rate`)."""
        cfg = self.config
        measured = counted.rate_hz  # counted per stamp: robust to jitter and lost samples
        ok = abs(measured / cfg.rate_hz - 1.0) <= cfg.rate_tolerance
        lost = counted.lost if ok and counted.lost_significant else 0
        self._counts['lost'] += lost
        text = (f'measured IMU rate {measured:.6g} Hz, rate_hz {cfg.rate_hz:g}' if ok else
                f'measured IMU rate {measured:.6g} Hz differs from rate_hz {cfg.rate_hz:g} '
                f'by {abs(measured / cfg.rate_hz - 1) * 100:.3g} %: set rate_hz to '
                f'{measured:.6g}; outputs are INVALID until then')
        if lost:
            text += (f'; {lost} samples lost between stamps closer than a gap (steps of 2 or '
                     'more periods): outputs DEGRADED until a block has none')
        self._findings['rate'] = Finding('rate', ERROR if not ok else WARN if lost else OK,
                                         text)
        self._jitter_finding(counted.jitter_s, counted.heavy)
        heavy = ok and counted.heavy
        self._rate_state = _INVALID if not ok else _DEGRADED if lost or heavy else _VALID
        return self._rate_state

    def _jitter_finding(self, jitter_s: float, heavy: bool) -> None:
        """The 'jitter' finding of one rate block (robust std of the stamp errors, s)."""
        share = jitter_s * self.config.rate_hz
        level = f'IMU stamp jitter {jitter_s * 1e3:.3g} ms std ({share:.0%} of the period)'
        if heavy:
            self._counts['jitter'] += RATE_BLOCK
            self._findings['jitter'] = Finding('jitter', WARN, (
                f'{level} exceeds {JITTER_TOLERANCE:.0%}: stamps reorder (re-ordered within '
                'reorder_window_s, their times stay wrong), and from about 35 % no lost sample '
                'can be told from jitter; outputs DEGRADED '
                'until a block has less: stamp the samples with the sensor clock, not on '
                'arrival'))
        elif 'jitter' in self._findings:  # reported once it was too much
            self._findings['jitter'] = Finding('jitter', OK, f'{level}: harmless')

    # ------------------------------------------------------------------ odometry and release
    def _add_odometry(self, t: int, v: float) -> None:
        if self._odom_t.size and t <= self._odom_t[-1]:
            if t < self._odom_t[-1] - self.options.backward_reset_s * 1e9:
                self._counts['odom_time_reset'] += 1  # a new odometry stream
                # the old one still gives the speed of the old IMU stream's last samples
                self._odom_old = (self._odom_t, self._odom_v)
                self._odom_t, self._odom_v = self._odom_t[:0], self._odom_v[:0]
            else:
                self._counts['odom_out_of_order'] += 1
                return
        elif self._odom_t.size and abs(v - self._odom_v[-1]) > _speed_step(
                t - int(self._odom_t[-1])):
            self._counts['odom_implausible'] += 1  # a jump no train makes: a glitch, a slide
            return
        self._odom_t = np.append(self._odom_t, np.int64(t))
        self._odom_v = np.append(self._odom_v, v)

    def _odometry_finding(self) -> None:
        c = self._counts
        bad = {k: c[k] for k in ('odom_nan', 'odom_implausible', 'odom_out_of_order') if c[k]}
        if bad:
            text = ', '.join(f'{k[5:]} {v}' for k, v in bad.items())
            self._findings['odometry'] = Finding('odometry', WARN, (
                f'odometry samples ignored ({text}): check the odometry source'))

    def _ready(self) -> int:
        """Number of held samples (a prefix) whose speed decision is final."""
        held = self._held
        if not self.options.use_odom or not len(held):
            return len(held)
        newest_odom = self._odom_t[-1] if self._odom_t.size else np.iinfo(np.int64).min
        timeout = np.int64(round(self.options.odom_timeout_s * 1e9))
        ready = (held.stamps <= newest_odom) | (held.arrival + HOLD_SAMPLES < self._received)
        if self._newest_imu > _NO_STAMP + timeout:
            ready |= held.stamps <= self._newest_imu - timeout
        return len(held) if ready.all() else int(np.argmin(ready))

    def _speeds(self, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(speed m/s, known) at the stamps; unknown speeds are 0 (the chainage holds)."""
        if not self.options.use_odom:
            return np.full(stamps.size, self.config.speed_mps), np.ones(stamps.size, bool)
        timeout = round(self.options.odom_timeout_s * 1e9)
        speed, known, keep = _held_speeds(self._odom_t, self._odom_v, stamps, timeout)
        self._odom_t, self._odom_v = self._odom_t[keep:], self._odom_v[keep:]  # older: unused
        if self._odom_old is not None and not known.all():  # before an odometry time reset
            old, in_old, _ = _held_speeds(*self._odom_old, stamps, timeout)
            speed, known = np.where(known, speed, old), known | in_old
        return speed, known

    def _speed_quality(self, speed: np.ndarray, known: np.ndarray) -> np.ndarray:
        cfg = self.config
        v_deg, v_min, v_max = self.v_degraded, cfg.min_design_speed_mps, cfg.max_speed_mps
        if speed.size <= SMALL:  # the same comparisons per sample
            return np.array([max(_INVALID if not k or v < self.v_invalid else _VALID,
                                 _DEGRADED if v < v_deg or v < v_min or v > v_max else _VALID)
                             for v, k in zip(np.abs(speed).tolist(), known.tolist(),
                                             strict=True)], np.uint8)
        v = np.abs(speed)
        q = np.where(~known | (v < self.v_invalid), _INVALID, _VALID)
        slow = (v < v_deg) | (v < v_min) | (v > v_max)
        return np.maximum(q, np.where(slow, _DEGRADED, _VALID)).astype(np.uint8)

    def _release(self, final: bool) -> Output:
        """Push the held samples whose decisions are final into the filters."""
        if self.pipeline is None:
            if not final and self._received < NOISE_SAMPLES:
                return self._empty()
            if not self._received:
                return self._empty()
            self._decide_noise()
        pipeline = self.start()
        count = len(self._held) if final else self._ready()
        if count == 0:
            return self._empty()
        stamps, accel, vert, frames, flags = self._held.pop(count)
        speed, known = self._speeds(stamps)
        if count <= SMALL:
            v, k = speed.tolist(), known.tolist()
            self._speed_finding(k.count(False), sum(x < 0 for x in v), k[-1])
            if any(ok and abs(x) < STANDSTILL_MPS for x, ok in zip(v, k, strict=True)):
                self._rest_check(accel, speed, known)
        else:
            self._speed_finding(known.size - int(np.count_nonzero(known)),
                                int(np.count_nonzero(speed < 0)), bool(known[-1]))
            self._rest_check(accel, speed, known)
        quality = np.maximum(flags, self._speed_quality(speed, known))
        checked = frames.astype(str) if self.options.wrong_frame_policy == 'reject' else None
        before = pipeline.accepted
        missed = self._missed_distance(stamps, speed, known)
        if not missed:  # the usual case: one push
            out = pipeline.push(stamps, vert, speed, checked, quality)
        else:  # the chainage moves on where the speed is known again
            parts, lo = [], 0
            for at, metres in (*missed, (count, 0.0)):
                parts.append(pipeline.push(stamps[lo:at], vert[lo:at], speed[lo:at],
                                           None if checked is None else checked[lo:at],
                                           quality[lo:at]))
                pipeline.add_distance(metres)
                lo = at
            out = Output.concat(parts, self._channels)
        self._reject_finding(count, pipeline.accepted - before)
        return self.finish(out)

    def _missed_distance(self, stamps: np.ndarray, speed: np.ndarray, known: np.ndarray
                         ) -> list[tuple[int, float]]:
        """Where a released sample with a known speed follows samples without one (no
        odometry for longer than odom_timeout_s: their speed is 0, the chainage held): its
        index in the chunk and the distance (m) the held chainage missed, the speed taken as
        linear from the last known sample before the gap to this one. Carries the newest known
        sample and the open gap across calls."""
        if self._gap_span is None and (bool(known.all()) if known.size > SMALL
                                       else all(known.tolist())):
            self._known_at = (int(stamps[-1]), float(speed[-1]))
            return []
        missed = []
        for i, (t, v, k) in enumerate(zip(stamps.tolist(), speed.tolist(), known.tolist(),
                                          strict=True)):
            if not k:
                self._gap_span = (t if self._gap_span is None else self._gap_span[0], t)
                continue
            if self._gap_span is not None and self._known_at is not None:
                (ta, va), (t1, tn) = self._known_at, self._gap_span
                if ta < t1 <= tn < t:  # one stream (a time reset adds no distance)
                    # linear speed over [ta, t] less the trapezoids to and from speed 0
                    missed.append((i, 0.5e-9 * ((va + v) * (t - ta) - va * (t1 - ta)
                                                - v * (t - tn))))
            self._gap_span, self._known_at = None, (t, v)
        return missed

    def _acceleration_finding(self, changed: int) -> None:
        """WARN while outputs are DEGRADED for the speed change across their band window
        (``changed``: the pipeline's count so far), OK again once outputs come without."""
        if changed == self._speed_changed and 'acceleration' not in self._findings:
            return  # the usual case: steady speed, nothing reported yet
        total = changed + self._retired['speed_change']
        tol = self.config.window_speed_tolerance
        if changed != self._speed_changed:
            self._speed_changed = changed
            self._findings['acceleration'] = Finding('acceleration', WARN, (
                f'{total} outputs DEGRADED so far: the speed changed by more than {tol:.0%} '
                'across their band window (acceleration, braking), so the time-domain band '
                'maps wavelengths off the band; the band on distance (--grid) follows the '
                'speed'))
        elif (shown := self._findings['acceleration']) is not None and shown.level != OK:
            self._findings['acceleration'] = Finding('acceleration', OK, (
                f'speed steady across the band windows of the latest outputs; {total} '
                'earlier outputs were DEGRADED by speed changes (acceleration, braking)'))

    def _speed_finding(self, unknown: int, reverse: int, last_known: bool) -> None:
        """Count the samples of a release without a speed and at negative speed; the 'speed'
        finding (``last_known``: the newest one has a speed)."""
        self._counts['speed_unknown'] += unknown
        self._counts['reverse'] += reverse
        total, options, v_fixed = self._counts['reverse'], self.options, self.config.speed_mps
        lost = bool(unknown) and not last_known
        self._later('speed', lambda: _speed_verdict(options, v_fixed, lost, reverse, total))

    def _gravity_finding(self, last: list[float], bad: bool) -> None:
        """The 'gravity' finding from the newest running mean ``last`` (3 m/s^2) and whether
        it failed the check."""
        cfg = self.config
        self._later('gravity', lambda: _gravity_verdict(cfg, last, bad))

    def _rest_check(self, accel: np.ndarray, speed: np.ndarray, known: np.ndarray) -> None:
        """Standing still, the accelerometer reads gravity alone: the magnitude of the mean
        specific force over every sample at rest checks the scale factor (which scales u) and
        the bias (finding 'rest', WARN beyond REST_TOLERANCE; off when gravity_mps2 is 0)."""
        g = self.config.gravity_mps2
        rest = known & (np.abs(speed) < STANDSTILL_MPS)
        if g == 0 or not rest.any():  # moving: no more masks
            return
        rest &= np.isfinite(accel).all(axis=1)
        if not rest.any():
            return
        total, count = self._rest
        self._rest = (total + accel[rest].sum(axis=0), count + int(rest.sum()))
        if self._rest[1] < REST_S * self.config.rate_hz:
            return
        magnitude = float(np.linalg.norm(self._rest[0] / self._rest[1]))
        error = magnitude / g - 1.0
        text = (f'at rest the accelerometer reads {magnitude:.4f} m/s^2 against gravity_mps2 '
                f'{g:g} ({error * 100:+.2f} %: scale factor and bias together')
        if abs(error) <= REST_TOLERANCE:
            self._findings['rest'] = Finding('rest', OK, text + ')')
        else:
            self._findings['rest'] = Finding('rest', WARN, (
                f'{text}, more than {REST_TOLERANCE * 100:g} %): the irregularity scales with '
                'the scale factor; calibrate the IMU or check its units'))

    def _reject_finding(self, pushed: int, accepted: int) -> None:
        """ERROR while every sample is rejected: since the start, or for REJECT_RUN_S."""
        if accepted:
            self._reject_run = 0
            if 'rejected' in self._findings:
                self._findings['rejected'] = Finding('rejected', OK, 'samples accepted')
            return
        self._reject_run += pushed
        counters = self.counters
        if counters.get('accepted', 0) and self._reject_run < REJECT_RUN_S * self.config.rate_hz:
            return
        reasons = {r: counters.get(r, 0) for r in REASONS if counters.get(r, 0)}
        if not reasons:
            return
        top = max(reasons, key=lambda r: reasons[r])
        text = ', '.join(f'{k} {v}' for k, v in reasons.items())
        self._findings['rejected'] = Finding('rejected', ERROR, (
            f'every IMU sample is rejected ({text}): {_HINTS[top]}'))

    def finish(self, out: Output) -> Output:
        """Count pipeline outputs by quality, the 'acceleration' finding, and set u = NaN
        where INVALID."""
        if not len(out) or out.quality is None:
            return out
        counts = quality_counts(out.quality)
        self._counts.update(counts)
        if self.pipeline is not None:
            self._acceleration_finding(self.pipeline.speed_changed)
        if not counts['invalid']:
            return out
        invalid = np.asarray(out.quality == _INVALID)
        u = np.array(out.u_m, dtype=float)
        u[..., invalid] = np.nan
        return Output(out.stamps_ns, out.chainage_m, u, out.quality, out.speed_mps,
                      out.gap_std_m)
