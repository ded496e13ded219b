"""The arrival checks: gravity, rate and jitter, frame, mounting and rest.

Each monitor sees the IMU samples as they arrive (or, at rest, as they are released), raises
their input quality where its check fails, counts into the stage's counters and keeps its
finding (docs/inversion.md, "Input policy"):

- gravity: the running mean of the three axes must put gravity on ``accel_axis`` and its sign
  (off when gravity_mps2 is 0), else INVALID;
- rate: each block of RATE_BLOCK stamp steps against ``rate_hz`` (``input.rate``: counted per
  stamp): INVALID at another rate, DEGRADED after samples lost without a gap or under heavy
  stamp jitter;
- frame: a driver's own frame_id is accepted with a WARN, or rejected (``wrong_frame_policy``);
- mounting: the finding of ``input.mounting.Mounting`` (tilt, settling);
- rest: standing still, the magnitude of the mean specific force against gravity (scale
  factor and bias);
- rejected: ERROR while every sample is rejected; acceleration: WARN while outputs are
  DEGRADED for the speed change across their band window.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

import numpy as np
from scipy.signal import lfilter

from railgsa_ros.input.findings import ERROR, HINTS, OK, WARN, Finding, Findings
from railgsa_ros.input.mounting import Mounting
from railgsa_ros.input.options import InputOptions
from railgsa_ros.input.rate import JITTER_TOLERANCE, CountedSteps, count_blocks
from railgsa_ros.input.sanitize import REASONS, SMALL, frame_mask
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.observability import STANDSTILL_MPS
from railgsa_ros.inverse.quality import Quality

GRAVITY_TAU_S = 1.0  #: time constant of the per-axis running mean that finds gravity, s
GRAVITY_TOLERANCE = 0.25  #: the vertical axis must read gravity within this fraction
RATE_BLOCK = 512  #: stamp steps per rate measurement (``input.rate``: counted per stamp)
REST_S = 1.0  #: standstill (in samples at rate_hz) before the scale and bias check at rest
REST_TOLERANCE = 0.01  #: at rest |mean specific force| must be gravity within this fraction
REJECT_RUN_S = 1.0  #: status ERROR after this long (in samples at rate_hz) with none accepted
AXES = 'xyz'
_VALID, _DEGRADED, _INVALID = int(Quality.VALID), int(Quality.DEGRADED), int(Quality.INVALID)


def _largest(values: list[float]) -> int:
    """np.argmax(np.abs(values)) of a short list: the first NaN, else the first largest."""
    mags = [abs(v) for v in values]
    return next((k for k, m in enumerate(mags) if m != m), mags.index(max(mags)))


def _axis_of(config: InversionConfig) -> tuple[int, float]:
    """Column (0..2) and sign (+-1.0) of the configured vertical axis."""
    axis = config.accel_axis
    return AXES.index(axis[-1]), -1.0 if axis.startswith('-') else 1.0


def gravity_verdict(cfg: InversionConfig, last: list[float], bad: bool) -> Finding:
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


class Monitor:
    """What every monitor shares: the config it checks against (the stage sets a new one on
    a rebuild), the stage's counters and findings."""

    def __init__(self, config: InversionConfig, counts: Counter[str], findings: Findings
                 ) -> None:
        self.config = config
        self._counts, self._findings = counts, findings


class GravityMonitor(Monitor):
    """Gravity on the configured axis and sign: a per-axis running mean (GRAVITY_TAU_S)."""

    def __init__(self, config: InversionConfig, counts: Counter[str], findings: Findings
                 ) -> None:
        super().__init__(config, counts, findings)
        self._mean: np.ndarray | None = None  # running mean (3,) m/s^2 of the finite rows

    def flags(self, accel: np.ndarray, finite: np.ndarray) -> np.ndarray:
        """INVALID where the running mean of the three axes does not put gravity on the
        configured axis and sign (off when gravity_mps2 is 0); ``finite`` (T,): the rows that
        feed the mean (no NaN, within the saturation limit)."""
        cfg = self.config
        flags = np.zeros(accel.shape[0], np.uint8)
        if cfg.gravity_mps2 == 0 or not finite.any():
            return flags
        rows = accel[finite]
        alpha = min(1.0, 1.0 / (GRAVITY_TAU_S * cfg.rate_hz))
        if self._mean is None:
            self._mean = rows[0].copy()
        zi = ((1.0 - alpha) * self._mean)[:, None]
        mean, _ = lfilter([alpha], [1.0, alpha - 1.0], rows.T, axis=1, zi=zi)  # (3, N)
        self._mean = mean[:, -1].copy()
        col, sign = _axis_of(cfg)
        up = sign * mean[col]
        top = np.argmax(np.abs(mean), axis=0)
        good = (top == col) & (np.abs(up - cfg.gravity_mps2)
                               <= GRAVITY_TOLERANCE * cfg.gravity_mps2)
        flags[finite] = np.where(good, _VALID, _INVALID)
        self._counts['gravity_invalid'] += int((~good).sum())
        self._report(mean[:, -1].tolist(), bool(not good[-1]))
        return flags

    def flags_small(self, data: list[list[float]], finite: list[bool]) -> np.ndarray:
        """``flags`` of a few samples (rows of accel as lists) in Python floats: lfilter's
        recursion (direct form II transposed: y = z + b0 x, z = b1 x - a1 y with b1 = 0) and
        the same decisions, bit-identical."""
        cfg = self.config
        g = cfg.gravity_mps2
        if g == 0 or not any(finite):
            return np.zeros(len(finite), np.uint8)
        alpha = min(1.0, 1.0 / (GRAVITY_TAU_S * cfg.rate_hz))
        a1, tolerance = alpha - 1.0, GRAVITY_TOLERANCE * g
        col, sign = _axis_of(cfg)
        start = data[finite.index(True)] if self._mean is None else self._mean.tolist()
        z0, z1, z2 = ((1.0 - alpha) * m for m in start)
        y, good, flags = start, True, []
        for (x0, x1, x2), ok in zip(data, finite, strict=True):
            if ok:
                y = [z0 + alpha * x0, z1 + alpha * x1, z2 + alpha * x2]
                z0, z1, z2 = x0 * 0.0 - y[0] * a1, x1 * 0.0 - y[1] * a1, x2 * 0.0 - y[2] * a1
                good = _largest(y) == col and abs(sign * y[col] - g) <= tolerance
            flags.append(_INVALID if ok and not good else _VALID)
        self._mean = np.array(y)
        self._counts['gravity_invalid'] += flags.count(_INVALID)
        self._report(y, not good)
        return np.array(flags, np.uint8)

    def _report(self, last: list[float], bad: bool) -> None:
        """The 'gravity' finding from the newest running mean ``last`` (3 m/s^2) and whether
        it failed the check."""
        cfg = self.config
        self._findings.later('gravity', lambda: gravity_verdict(cfg, last, bad))


class RateMonitor(Monitor):
    """The IMU rate, lost samples and stamp jitter, per block of RATE_BLOCK stamp steps."""

    def __init__(self, config: InversionConfig, counts: Counter[str], findings: Findings
                 ) -> None:
        super().__init__(config, counts, findings)
        self._steps = np.zeros(RATE_BLOCK, np.int64)  # stamp steps of the open rate block
        self._fill = 0  # how many of them are filled
        self._prev: int | None = None  # last finite stamp seen
        self._state = _VALID  # quality code after the newest rate block

    def flags(self, stamps: np.ndarray, finite: np.ndarray) -> np.ndarray:
        """INVALID from the sample after a block of RATE_BLOCK stamp steps whose median step
        disagrees with rate_hz by more than rate_tolerance (until a block agrees); ``finite``
        (T,): rows without NaN."""
        flags = np.zeros(stamps.size, np.uint8)
        idx = np.flatnonzero(finite)
        if idx.size == 0:
            return flags
        t = stamps[idx]
        prev = np.concatenate([[self._prev if self._prev is not None else t[0]],
                               t[:-1]])
        steps = t - prev
        self._prev = int(t[-1])
        nonzero = steps != 0  # backward steps too: under jitter the stamps telescope
        fill = self._fill
        cum = np.concatenate([[fill], fill + np.cumsum(nonzero)])  # open-block step count
        pool = np.concatenate([self._steps[:fill], steps[nonzero]])
        state = np.full(idx.size, self._state, np.uint8)
        full = pool.size // RATE_BLOCK * RATE_BLOCK
        counted = self._count(pool[:full])
        ends = np.arange(1, len(counted) + 1) * RATE_BLOCK
        for done, block in zip(np.searchsorted(cum[1:], ends).tolist(), counted, strict=True):
            state[done + 1:] = self._block(block)  # from the sample after the block's last
        rest = pool[full:]
        self._steps[:rest.size] = rest
        self._fill = rest.size
        flags[idx] = state
        self._counts['rate_invalid'] += int((state == _INVALID).sum())
        return flags

    def flags_small(self, stamps: np.ndarray, finite: list[bool]) -> np.ndarray:
        """``flags`` of a few samples, one after the other (steps wrap as int64)."""
        flags = [0] * len(finite)
        state = self._state
        prev, invalid = self._prev, 0
        for i, (t, ok) in enumerate(zip(stamps.tolist(), finite, strict=True)):
            if not ok:
                continue
            step = (t - (t if prev is None else prev) + (1 << 63)) % (1 << 64) - (1 << 63)
            prev, flags[i] = t, state
            invalid += state == _INVALID
            if step != 0:
                self._steps[self._fill] = step
                self._fill += 1
                if self._fill == RATE_BLOCK:
                    state, self._fill = self._block(self._count(self._steps)[0]), 0
        self._prev = prev
        self._counts['rate_invalid'] += invalid
        return np.array(flags, np.uint8)

    def _count(self, steps: np.ndarray) -> list[CountedSteps]:
        """Each block of RATE_BLOCK stamp steps (ns) of ``steps`` counted (``input.rate``)."""
        return count_blocks(steps.reshape(-1, RATE_BLOCK), 1e9 / self.config.rate_hz,
                            self.config.gap_factor)

    def _block(self, counted: CountedSteps) -> int:
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
        self._findings.set('rate', ERROR if not ok else WARN if lost else OK, text)
        self._jitter(counted.jitter_s, counted.heavy)
        heavy = ok and counted.heavy
        self._state = _INVALID if not ok else _DEGRADED if lost or heavy else _VALID
        return self._state

    def _jitter(self, jitter_s: float, heavy: bool) -> None:
        """The 'jitter' finding of one rate block (robust std of the stamp errors, s)."""
        share = jitter_s * self.config.rate_hz
        level = f'IMU stamp jitter {jitter_s * 1e3:.3g} ms std ({share:.0%} of the period)'
        if heavy:
            self._counts['jitter'] += RATE_BLOCK
            self._findings.set('jitter', WARN, (
                f'{level} exceeds {JITTER_TOLERANCE:.0%}: stamps reorder (re-ordered within '
                'reorder_window_s, their times stay wrong), and from about 35 % no lost sample '
                'can be told from jitter; outputs DEGRADED '
                'until a block has less: stamp the samples with the sensor clock, not on '
                'arrival'))
        elif 'jitter' in self._findings:  # reported once it was too much
            self._findings.set('jitter', OK, f'{level}: harmless')



class RestMonitor(Monitor):
    """Standing still, the accelerometer reads gravity alone: the scale factor and bias."""

    def __init__(self, config: InversionConfig, counts: Counter[str], findings: Findings
                 ) -> None:
        super().__init__(config, counts, findings)
        self._rest = (np.zeros(3), 0)  # sum (3,) m/s^2 and count of the samples at rest

    def check(self, accel: np.ndarray, speed: np.ndarray, known: np.ndarray) -> None:
        """The magnitude of the mean specific force over every sample at rest checks the
        scale factor (which scales u) and the bias (finding 'rest', WARN beyond
        REST_TOLERANCE; off when gravity_mps2 is 0)."""
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
            self._findings.set('rest', OK, text + ')')
        else:
            self._findings.set('rest', WARN, (
                f'{text}, more than {REST_TOLERANCE * 100:g} %): the irregularity scales with '
                'the scale factor; calibrate the IMU or check its units'))


class FrameMonitor(Monitor):
    """IMU frame_ids against ``frame_id``: the finding, and the ids the sanitiser rejects
    (``wrong_frame_policy`` reject) or none (accept: a driver's own frame_id is used)."""

    def __init__(self, config: InversionConfig, options: InputOptions, counts: Counter[str],
                 findings: Findings) -> None:
        super().__init__(config, counts, findings)
        self.options = options

    def check(self, frames: np.ndarray) -> None:
        """The 'frame' finding of arriving samples' frame_ids (T,); counts the accepted ones
        of another frame as wrong_frame_accepted."""
        expected = self.config.frame_id
        if frames.size <= SMALL and all(isinstance(f, str) and f == expected for f in frames):
            return  # what frame_mask finds, without its conversion to str
        match = frame_mask(frames, expected)
        if match is None or match.all():
            return
        other = str(frames[~match][0])
        if self.options.wrong_frame_policy == 'accept':
            self._counts['wrong_frame_accepted'] += int((~match).sum())
            self._findings.set('frame', WARN, (
                f'IMU frame_id {other!r} is not {self.config.frame_id!r}: accepted; set '
                f'frame_id to {other!r} (or wrong_frame_policy to reject)'))
        else:
            self._findings.set('frame', WARN, (
                f'IMU frame_id {other!r} is not {self.config.frame_id!r}: rejected; set '
                f'frame_id to {other!r} or wrong_frame_policy to accept'))

    def checked(self, frames: np.ndarray) -> np.ndarray | None:
        """The frame_ids the sanitiser checks: all with wrong_frame_policy reject, else None."""
        return frames.astype(str) if self.options.wrong_frame_policy == 'reject' else None


class MountingMonitor:
    """The 'mounting' finding of ``Mounting`` (gravity estimate and vertical projection),
    once its first block has given an estimate."""

    def __init__(self, mounting: Mounting, findings: Findings) -> None:
        self.mounting = mounting
        self._findings = findings
        self._version = 0  # the decision the finding was made from

    def report(self) -> None:
        m = self.mounting
        if m.version != self._version:
            self._version = m.version
            self._findings.set('mounting', m.level, m.message)


class RejectMonitor(Monitor):
    """The 'rejected' finding: ERROR while every sample is rejected, since the start or for
    REJECT_RUN_S; ``totals``: the stage's counters (read only when none was accepted)."""

    def __init__(self, config: InversionConfig, counts: Counter[str], findings: Findings,
                 totals: Callable[[], dict[str, int]]) -> None:
        super().__init__(config, counts, findings)
        self._totals = totals
        self._run = 0  # samples pushed since the last accepted one

    def check(self, pushed: int, accepted: int) -> None:
        """After a release of ``pushed`` samples of which the sanitiser accepted ``accepted``."""
        if accepted:
            self._run = 0
            if 'rejected' in self._findings:
                self._findings.set('rejected', OK, 'samples accepted')
            return
        self._run += pushed
        counters = self._totals()
        if counters.get('accepted', 0) and self._run < REJECT_RUN_S * self.config.rate_hz:
            return
        reasons = {r: counters.get(r, 0) for r in REASONS if counters.get(r, 0)}
        if not reasons:
            return
        top = max(reasons, key=lambda r: reasons[r])
        text = ', '.join(f'{k} {v}' for k, v in reasons.items())
        self._findings.set('rejected', ERROR,
                           f'every IMU sample is rejected ({text}): {HINTS[top]}')


class AccelerationMonitor(Monitor):
    """The 'acceleration' finding: WARN while outputs are DEGRADED for the speed change across
    their band window, OK again once outputs come without; ``seen``: the running pipeline's
    count so far (0 for a new pipeline)."""

    def __init__(self, config: InversionConfig, counts: Counter[str], findings: Findings
                 ) -> None:
        super().__init__(config, counts, findings)
        self.seen = 0

    def check(self, changed: int, retired: int) -> None:
        """``changed``: the pipeline's speed_change count so far; ``retired``: earlier
        pipelines' (rebuilt)."""
        if changed == self.seen and 'acceleration' not in self._findings:
            return  # the usual case: steady speed, nothing reported yet
        total = changed + retired
        tol = self.config.window_speed_tolerance
        if changed != self.seen:
            self.seen = changed
            self._findings.set('acceleration', WARN, (
                f'{total} outputs DEGRADED so far: the speed changed by more than {tol:.0%} '
                'across their band window (acceleration, braking), so the time-domain band '
                'maps wavelengths off the band; the band on distance (--grid) follows the '
                'speed'))
        elif (shown := self._findings.get('acceleration')) is not None and shown.level != OK:
            self._findings.set('acceleration', OK, (
                f'speed steady across the band windows of the latest outputs; {total} '
                'earlier outputs were DEGRADED by speed changes (acceleration, braking)'))
