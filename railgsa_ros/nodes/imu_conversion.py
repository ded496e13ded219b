"""Message batches to arrays: sensor_msgs/Imu and nav_msgs/Odometry, REP 145 consumer rules.

No rclpy import: works on rclpy messages and on rosbags messages alike (same field names).

REP 145 as a consumer: linear acceleration is specific force in the sensor frame *including*
gravity (+9.81 m/s^2 on z at rest, z up), passed on unchanged; the core removes gravity and bias.
Covariance: element 0 equal to -1 or NaN means the field is absent, all zeros means unknown; in
both cases the variance is NaN (use the configured noise). A message whose fields cannot be read
as a stamp, a frame and numbers, or that has a zero or negative stamp, nanoseconds >= 1e9 or an
empty frame_id is *malformed*: it is flagged, never raised.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from railgsa_ros.inverse.sanitize import SPEED_LIMIT_MPS

NS_PER_S = 1_000_000_000
_NAN3 = (float('nan'),) * 3
_BAD = (0, 0, '', _NAN3, float('nan'), _NAN3)
_ROW = np.dtype([('sec', np.int64), ('nsec', np.int64), ('frame', object), ('accel', float, 3),
                 ('cov0', float), ('var', float, 3)])


@dataclass(frozen=True)
class ImuBatch:
    """N Imu messages as arrays; rows flagged ``malformed`` hold placeholders."""

    stamps_ns: np.ndarray  #: int64 (N,), header stamps in ns
    accel: np.ndarray      #: float (N, 3), specific force x, y, z incl. gravity, m/s^2
    frame_ids: np.ndarray  #: object (N,) of str, header.frame_id
    accel_var: np.ndarray  #: float (N, 3), x, y, z variances (m/s^2)^2, NaN if absent/unknown
    malformed: np.ndarray  #: bool (N,)

    def __len__(self) -> int:
        return len(self.stamps_ns)


def _imu_fields(msg: Any) -> tuple:
    """(sec, nanosec, frame_id, (ax, ay, az), cov[0], (cov[0], cov[4], cov[8])); placeholders
    if a field is unreadable."""
    try:
        stamp, cov, acc = msg.header.stamp, msg.linear_acceleration_covariance, \
            msg.linear_acceleration
        return (int(stamp.sec), int(stamp.nanosec), str(msg.header.frame_id),
                (float(acc.x), float(acc.y), float(acc.z)), float(cov[0]),
                (float(cov[0]), float(cov[4]), float(cov[8])))
    except (AttributeError, TypeError, ValueError, IndexError, OverflowError):
        return _BAD


def stamps_to_ns(sec: np.ndarray, nanosec: np.ndarray) -> np.ndarray:
    """Combine header stamp fields into int64 nanoseconds."""
    return np.asarray(sec, np.int64) * NS_PER_S + np.asarray(nanosec, np.int64)


def accel_variances(cov0: np.ndarray, diag: np.ndarray) -> np.ndarray:
    """Variances (m/s^2)^2 from covariance diagonals (N, 3) per REP 145: NaN where the field is
    absent (cov0 = -1 or NaN) or the variance unknown (zero, negative or non-finite)."""
    cov0, diag = np.asarray(cov0, float), np.asarray(diag, float)
    absent = (np.isnan(cov0) | (cov0 == -1.0))[..., None]
    usable = ~absent & np.isfinite(diag) & (diag > 0)
    return np.where(usable, diag, np.nan)


def imu_batch(msgs: Sequence[Any]) -> ImuBatch:
    """Convert a list of Imu messages in one pass; never raises on a bad message."""
    rows = np.array([_imu_fields(m) for m in msgs], dtype=_ROW)
    sec, nsec = rows['sec'], rows['nsec']
    malformed = ((sec < 0) | (nsec < 0) | (nsec >= NS_PER_S) | ((sec == 0) & (nsec == 0))
                 | (rows['frame'] == ''))
    sec = np.clip(sec, 0, np.iinfo(np.int64).max // NS_PER_S - 1)
    return ImuBatch(stamps_ns=stamps_to_ns(sec, nsec), accel=rows['accel'],
                    frame_ids=rows['frame'], accel_var=accel_variances(rows['cov0'], rows['var']),
                    malformed=malformed)

def odom_speed(msg: Any) -> tuple[int, float] | None:
    """(stamp ns, forward speed twist.twist.linear.x in m/s), or None if malformed, non-finite or
    beyond SPEED_LIMIT_MPS."""
    try:
        stamp = msg.header.stamp
        sec, nsec = int(stamp.sec), int(stamp.nanosec)
        speed = float(msg.twist.twist.linear.x)
    except (AttributeError, TypeError, ValueError, OverflowError):
        return None
    if (sec < 0 or not 0 <= nsec < NS_PER_S or (sec == 0 and nsec == 0)
            or not abs(speed) <= SPEED_LIMIT_MPS):
        return None
    return sec * NS_PER_S + nsec, speed
