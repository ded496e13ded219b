"""Sensor mounting: the gravity direction in the sensor frame, the tilt, the vertical projection.

A sensor mounted rotated by an angle theta reads the car-body vertical acceleration times
cos(theta) on its up axis plus sin(theta) times the lateral/longitudinal acceleration: a 25 deg
tilt makes every dip 9 % too shallow. :class:`Mounting` (owned by the input policy, the same
object live and offline) estimates the direction of gravity from the 3-axis specific force and
turns it into the vertical acceleration u . a, where u is the car-body up direction in the sensor
frame (docs/inversion.md, "Mounting"):

- estimate: the per-axis median of the means of the last WINDOW_S of BLOCK_S blocks of finite
  samples (the first block FIRST_S), normalised (braking, curves and cant put quasi-static
  accelerations on the mean for tens of seconds; the median ignores them while they fill less
  than half of the window);
  settled after SETTLE_S. Blocks count samples, so the estimate is the same for any batching.
- ``mounting`` 'axis': u is ``accel_axis``; 'rotation': ``accel_axis`` turned by
  ``mount_roll_deg`` (about x) then ``mount_pitch_deg`` (about y), see :func:`up_vector`;
  'estimate' (default): ``accel_axis`` while the estimate is within ``tilt_tolerance_deg`` of it
  (an upright sensor's samples are used exactly as before), else the estimate.
- u changes only at block ends, ramped linearly over the next block (no step reaches the band
  filters); once settled it turns at most SLEW_DEG_S.
- quality: DEGRADED while the axis in use is further than ``tilt_tolerance_deg`` from the
  estimate, in 'estimate' mode while it projects on an estimate not yet settled or one tilted
  beyond ``max_tilt_deg``. The finding says the tilt, roll and pitch and what to set.

``vertical_small`` for live pushes (up to ``sanitize.SMALL`` samples): the same operations in the
same order as the numpy paths, bit-identical (test_core_batching.py).
"""

from __future__ import annotations

import math

import numpy as np

from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.quality import Quality

BLOCK_S = 1.0  #: samples per block mean, s (at rate_hz)
FIRST_S = 0.25  #: the first block is this short: the first estimate comes within taper_s
WINDOW_S = 120.0  #: the estimate is the median of the block means of this long, s
SETTLE_S = 30.0  #: the estimate is settled after this long of blocks, s
SLEW_DEG_S = 0.1  #: a settled projection axis turns at most this fast, deg/s
OK, WARN = 0, 1
AXES = 'xyz'
_VALID, _DEGRADED = int(Quality.VALID), int(Quality.DEGRADED)
Vector = tuple[float, float, float]


def axis_vector(axis: str) -> Vector:
    """Unit vector of an axis name ('z', '-y', ...)."""
    sign = -1.0 if axis.startswith('-') else 1.0
    col = AXES.index(axis[-1])
    return tuple(sign if k == col else 0.0 for k in range(3))  # type: ignore[return-value]


def rotation(roll_deg: float, pitch_deg: float) -> np.ndarray:
    """R = Ry(pitch) Rx(roll) (3, 3): the sensor reads a_sensor = R^T a_body (roll about x,
    then pitch about y; scipy ``Rotation.from_euler('xy', [roll, pitch], degrees=True)``)."""
    r, p = math.radians(roll_deg), math.radians(pitch_deg)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)],
                   [0.0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0],
                   [-math.sin(p), 0.0, math.cos(p)]])
    return ry @ rx


def up_vector(axis: str, roll_deg: float = 0.0, pitch_deg: float = 0.0) -> Vector:
    """Car-body up in the sensor frame: R^T e_axis (unit)."""
    u = rotation(roll_deg, pitch_deg).T @ np.array(axis_vector(axis))
    return (float(u[0]), float(u[1]), float(u[2]))


def angle_deg(a: Vector, b: Vector) -> float:
    """Angle between two unit vectors, deg (atan2: accurate at small angles)."""
    cross = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return math.degrees(math.atan2(math.sqrt(sum(c * c for c in cross)), dot))


def roll_pitch_deg(up: Vector, axis: str) -> tuple[float, float] | None:
    """(mount_roll_deg, mount_pitch_deg) whose :func:`up_vector` is ``up``, for accel_axis
    'z' or '-z' (None for the others)."""
    if axis[-1] != 'z':
        return None
    s = -1.0 if axis.startswith('-') else 1.0
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, -s * up[0]))))
    return math.degrees(math.atan2(s * up[1], s * up[2])), pitch


def _toward(a: Vector, b: Vector, max_deg: float) -> Vector:
    """``a`` turned toward ``b`` by at most max_deg (``b`` itself when closer)."""
    angle = angle_deg(a, b)
    if angle <= max_deg:
        return b
    f = max_deg / angle
    v = [x + f * (y - x) for x, y in zip(a, b, strict=True)]
    n = math.sqrt(sum(x * x for x in v))
    return (v[0] / n, v[1] / n, v[2] / n)


def _median(values: np.ndarray) -> tuple[float, float, float]:
    """Per-row median of values (3, n): the middle value, or the mean of the two."""
    n = values.shape[1]
    k = n // 2
    part = np.partition(values, [k - 1, k] if n % 2 == 0 else k, axis=1)
    mid = part[:, k] if n % 2 else (part[:, k - 1] + part[:, k]) / 2
    return float(mid[0]), float(mid[1]), float(mid[2])


class Mounting:
    """The gravity estimate and the vertical projection of one IMU stream (module text)."""

    def __init__(self, config: InversionConfig) -> None:
        self.block = max(1, round(BLOCK_S * config.rate_hz))  # samples per block
        self._means = np.zeros((3, max(1, round(WINDOW_S / BLOCK_S))))  # ring of block means
        self._sum = [0.0, 0.0, 0.0]
        # usable samples in the open block; the first block starts as if this many had come
        self._first = min(self.block, max(1, round(FIRST_S * config.rate_hz)))
        self._count = self.block - self._first
        self.blocks = 0  #: blocks completed
        self.degraded = 0  #: samples flagged DEGRADED for their mounting
        self.gravity: Vector | None = None  #: estimated unit direction of gravity (sensor frame)
        self.level = OK  #: level of the 'mounting' finding
        self.version = 0  #: decisions made (the finding changes with it; 0: none yet)
        self._state: tuple[Vector, float, float, bool, bool] | None = None  # for ``message``
        self.configure(config)

    def configure(self, config: InversionConfig) -> None:
        """(Re)read the mounting parameters; the estimate is kept (the filters restart)."""
        self.config = config
        sat = config.saturation_mps2
        self._limit = sat - config.saturation_margin_mps2 if sat > 0 else math.inf
        self.axis = axis_vector(config.accel_axis)
        self._col, self._sign = AXES.index(config.accel_axis[-1]), self.axis[AXES.index(
            config.accel_axis[-1])]
        self.configured = up_vector(config.accel_axis, config.mount_roll_deg,
                                    config.mount_pitch_deg) \
            if config.mounting == 'rotation' else self.axis
        start = self.configured
        self._use_estimate = False
        if config.mounting == 'estimate' and self.gravity is not None and \
                angle_deg(self.gravity, self.axis) > config.tilt_tolerance_deg:
            start, self._use_estimate = self.gravity, True
        self._from = self._to = start
        self._delta = (0.0, 0.0, 0.0)
        # before the first estimate DEGRADED (inside the warm-up while taper_s >= FIRST_S)
        self._flag = _DEGRADED if config.gravity_mps2 != 0 else _VALID
        if self.gravity is not None:
            self._decide(self.gravity, ramp=False)

    @property
    def limit(self) -> float:
        """Saturation limit, m/s^2: a row with an axis at or beyond it feeds no estimate (the
        sanitiser rejects it; inf without a saturation check)."""
        return self._limit

    @property
    def settled(self) -> bool:
        """Whether SETTLE_S of blocks have been seen."""
        return self.blocks >= round(SETTLE_S / BLOCK_S)

    @property
    def tilt_deg(self) -> float:
        """Angle between the estimated gravity and ``accel_axis``, deg (NaN before any)."""
        return angle_deg(self.gravity, self.axis) if self.gravity is not None else math.nan

    @property
    def in_use(self) -> Vector:
        """The up direction the newest sample was projected on (end of the current ramp)."""
        return self._to

    def vertical(self, accel: np.ndarray, finite: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Upward specific force (T,) m/s^2 of accel (T, 3) and the quality codes (T,) uint8;
        ``finite`` (T,) bool: rows without NaN. Only finite rows within the saturation limit
        on every axis feed the estimate. The block sums of the whole chunk at once (cumsum:
        sequential, as the scalar path adds), then the decisions block by block, then the
        projection of every row with its block's axis ramp."""
        b, start = self.block, self._count
        if float(np.max(np.abs(accel), initial=0.0)) < self._limit:  # NaN fails: the mask
            ok = finite
        else:
            ok = finite & (np.abs(accel) < self._limit).all(axis=1)
        every = bool(ok.all())
        params = [(self._from, self._delta, self._flag)]
        for total in self._block_sums(accel if every else accel[ok]):
            self._end_block(total)
            params.append((self._from, self._delta, self._flag))
        # usable rows since the open block's start, and blocks completed before each row
        count = start + (np.arange(1, ok.size + 1) if every else np.cumsum(ok))
        segment = np.concatenate([[start], count[:-1]]) // b if len(params) > 1 else None
        codes = [p[2] for p in params]
        if segment is None or min(codes) == max(codes):
            flags = np.full(ok.size, codes[0], np.uint8)
        else:
            flags = np.array(codes, np.uint8)[segment]
        self.degraded += int(np.count_nonzero(flags == _DEGRADED))
        exact = [p[0] == self.axis and p[1] == (0.0, 0.0, 0.0) for p in params]
        pick = self._sign * accel[:, self._col]
        if all(exact):
            return pick, flags
        if segment is None:
            segment = np.zeros(ok.size, np.int64)
        ramp = (count - segment * b) / b
        sizes = np.bincount(segment, minlength=len(params))
        f = np.repeat(np.array([p[0] for p in params]).T, sizes, axis=1)  # (3, T)
        d = np.repeat(np.array([p[1] for p in params]).T, sizes, axis=1)
        vert = accel[:, 0] * (f[0] + ramp * d[0]) + accel[:, 1] * (
            f[1] + ramp * d[1]) + accel[:, 2] * (f[2] + ramp * d[2])
        if any(exact):
            vert = np.where(np.repeat(exact, sizes), pick, vert)
        return vert, flags

    def _block_sums(self, rows: np.ndarray) -> list[np.ndarray]:
        """Sums (3,) of the blocks that ``rows`` (usable, in order) complete; the open block's
        sum and count carried. Each sum is the sequential one (cumsum from 0.0 or the carried
        sum), bit for bit what the scalar path adds."""
        b, need = self.block, self.block - self._count
        head = np.cumsum(np.vstack([[self._sum], rows[:need]]), axis=0)[-1]
        if rows.shape[0] < need:
            self._sum, self._count = head.tolist(), self._count + rows.shape[0]
            return []
        rest = rows[need:]
        nb = rest.shape[0] // b
        full = np.zeros((3, nb, b + 1))  # each block from 0.0, along the contiguous axis
        full[:, :, 1:] = rest[:nb * b].T.reshape(3, nb, b)
        tail = rest[nb * b:]
        self._sum = np.cumsum(np.vstack([[0.0, 0.0, 0.0], tail]), axis=0)[-1].tolist()
        self._count = tail.shape[0]
        return [head, *np.cumsum(full, axis=2)[:, :, -1].T]

    def vertical_small(self, data: list[list[float]], finite: list[bool]
                       ) -> tuple[np.ndarray, np.ndarray]:
        """``vertical`` of a few rows (accel and finite as lists) in Python floats, the same
        operations in the same order."""
        vert, flags = [], []
        s0, s1, s2, lim = *self._sum, self._limit
        for (x, y, z), ok in zip(data, finite, strict=True):
            if ok and -lim < x < lim and -lim < y < lim and -lim < z < lim:
                self._count += 1
                s0, s1, s2 = s0 + x, s1 + y, s2 + z
            if self._from == self._to == self.axis:
                vert.append(self._sign * (x, y, z)[self._col])
            else:
                r = self._count / self.block
                (f0, f1, f2), (d0, d1, d2) = self._from, self._delta
                vert.append(x * (f0 + r * d0) + y * (f1 + r * d1) + z * (f2 + r * d2))
            flags.append(self._flag)
            self.degraded += self._flag == _DEGRADED
            if self._count == self.block:
                self._count, self._sum = 0, [0.0, 0.0, 0.0]
                self._end_block(np.array([s0, s1, s2]))
                s0, s1, s2 = 0.0, 0.0, 0.0
        self._sum = [s0, s1, s2]
        return np.array(vert), np.array(flags, np.uint8)

    def _end_block(self, total: np.ndarray) -> None:
        """A block is complete (its sum (3,)): its mean into the window, a new estimate and
        decision."""
        self._means[:, self.blocks % self._means.shape[1]] = total / (
            self.block if self.blocks else self._first)
        self.blocks += 1
        if self.config.gravity_mps2 == 0:  # the driver removed gravity: nothing to estimate
            return
        m0, m1, m2 = _median(self._means[:, :min(self.blocks, self._means.shape[1])])
        norm = math.hypot(m0, m1, m2)
        if not 0 < norm < math.inf:
            return
        self.gravity = (m0 / norm, m1 / norm, m2 / norm)
        self._decide(self.gravity, ramp=True)

    def _decide(self, g: Vector, ramp: bool) -> None:
        """Axis for the next block (ramped from the current one), its quality and finding."""
        cfg = self.config
        tol, tilt = cfg.tilt_tolerance_deg, angle_deg(g, self.axis)
        target = self.configured
        if cfg.mounting == 'estimate':
            self._use_estimate = tilt > (tol / 2 if self._use_estimate else tol)
            target = g if self._use_estimate else self.axis
        current = self._to
        if ramp:
            step = SLEW_DEG_S * self.block / cfg.rate_hz if self.settled else 180.0
            new = _toward(current, target, step)
            self._from, self._to = current, new
            self._delta = (new[0] - current[0], new[1] - current[1], new[2] - current[2])
        lag = angle_deg(self._to, g)
        unsettled = cfg.mounting == 'estimate' and self._use_estimate and not self.settled
        steep = cfg.mounting == 'estimate' and tilt > cfg.max_tilt_deg
        degraded = lag > tol or unsettled or steep
        self._flag = _DEGRADED if degraded else _VALID
        self.level = WARN if degraded else OK
        self._state = (g, tilt, lag, unsettled, steep)
        self.version += 1

    @property
    def message(self) -> str:
        """The 'mounting' finding's one line ('' before the first decision): formatted only
        when asked (not at every block)."""
        if self._state is None:
            return ''
        g, tilt, lag, unsettled, steep = self._state
        cfg = self.config
        rp = roll_pitch_deg(g, cfg.accel_axis)
        angles = f' (roll {rp[0]:+.2f} deg, pitch {rp[1]:+.2f} deg)' if rp else \
            f' (gravity direction {g[0]:+.4f} {g[1]:+.4f} {g[2]:+.4f})'
        state = 'settled' if self.settled else f'settling: {self.blocks} of ' \
            f'{round(SETTLE_S / BLOCK_S)} blocks of {BLOCK_S:g} s'
        text = (f'sensor tilted {tilt:.2f} deg from {cfg.accel_axis}{angles}, estimated from '
                f'gravity ({state}); mounting {cfg.mounting}')
        if steep:
            return (f'{text}: beyond max_tilt_deg {cfg.max_tilt_deg:g}: remount the sensor or '
                    'set accel_axis to the nearest axis; outputs are DEGRADED')
        if unsettled:
            return f'{text}: outputs are DEGRADED until the estimate settles'
        if lag > cfg.tilt_tolerance_deg:
            fix = (f'set mount_roll_deg {rp[0]:.2f} and mount_pitch_deg {rp[1]:.2f} with '
                   'mounting rotation, or ' if rp else '') + 'set mounting estimate'
            what = 'the configured rotation' if cfg.mounting == 'rotation' else (
                cfg.accel_axis if cfg.mounting == 'axis' else 'the axis in use')
            return (f'{text}: gravity is {lag:.2f} deg off {what} (tilt_tolerance_deg '
                    f'{cfg.tilt_tolerance_deg:g}): {fix}; outputs are DEGRADED')
        return text + (': projected on the estimate' if self._use_estimate else '')

