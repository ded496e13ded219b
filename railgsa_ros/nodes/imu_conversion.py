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

NS_PER_S = 1_000_000_000
_BAD = (0, 0, '', float('nan'), float('nan'), float('nan'))
_ROW = np.dtype([('sec', np.int64), ('nsec', np.int64), ('frame', object), ('acc_z', float),
                 ('cov0', float), ('cov8', float)])


@dataclass(frozen=True)
class ImuBatch:
    """N Imu messages as arrays; rows flagged ``malformed`` hold placeholders."""

    stamps_ns: np.ndarray    #: int64 (N,), header stamps in ns
    acc_z: np.ndarray        #: float (N,), specific force on z incl. gravity, m/s^2
    frame_ids: np.ndarray    #: object (N,) of str, header.frame_id
    accel_var_z: np.ndarray  #: float (N,), z variance in (m/s^2)^2, NaN if absent or unknown
    malformed: np.ndarray    #: bool (N,)

    def __len__(self) -> int:
        return len(self.stamps_ns)


def _imu_fields(msg: Any) -> tuple[int, int, str, float, float, float]:
    """(sec, nanosec, frame_id, a_z, cov[0], cov[8]); placeholders if a field is unreadable."""
    try:
        stamp, cov = msg.header.stamp, msg.linear_acceleration_covariance
        return (int(stamp.sec), int(stamp.nanosec), str(msg.header.frame_id),
                float(msg.linear_acceleration.z), float(cov[0]), float(cov[8]))
    except (AttributeError, TypeError, ValueError, IndexError, OverflowError):
        return _BAD


def stamps_to_ns(sec: np.ndarray, nanosec: np.ndarray) -> np.ndarray:
    """Combine header stamp fields into int64 nanoseconds."""
    return np.asarray(sec, np.int64) * NS_PER_S + np.asarray(nanosec, np.int64)


def accel_variance_z(cov0: np.ndarray, cov8: np.ndarray) -> np.ndarray:
    """z variance (m/s^2)^2 per REP 145: NaN where absent (cov0 -1 or NaN) or unknown (<= 0)."""
    cov0, cov8 = np.asarray(cov0, float), np.asarray(cov8, float)
    absent = np.isnan(cov0) | (cov0 == -1.0)
    usable = ~absent & np.isfinite(cov8) & (cov8 > 0)
    return np.where(usable, cov8, np.nan)


def imu_batch(msgs: Sequence[Any]) -> ImuBatch:
    """Convert a list of Imu messages in one pass; never raises on a bad message."""
    rows = np.array([_imu_fields(m) for m in msgs], dtype=_ROW)
    sec, nsec = rows['sec'], rows['nsec']
    malformed = ((sec < 0) | (nsec < 0) | (nsec >= NS_PER_S) | ((sec == 0) & (nsec == 0))
                 | (rows['frame'] == ''))
    sec = np.clip(sec, 0, np.iinfo(np.int64).max // NS_PER_S - 1)
    return ImuBatch(stamps_ns=stamps_to_ns(sec, nsec), acc_z=rows['acc_z'],
                    frame_ids=rows['frame'], accel_var_z=accel_variance_z(rows['cov0'],
                                                                          rows['cov8']),
                    malformed=malformed)

def odom_speed(msg: Any) -> tuple[int, float] | None:
    """(stamp ns, forward speed twist.twist.linear.x in m/s), or None if malformed/non-finite."""
    try:
        stamp = msg.header.stamp
        sec, nsec = int(stamp.sec), int(stamp.nanosec)
        speed = float(msg.twist.twist.linear.x)
    except (AttributeError, TypeError, ValueError, OverflowError):
        return None
    if sec < 0 or not 0 <= nsec < NS_PER_S or (sec == 0 and nsec == 0) or not np.isfinite(speed):
        return None
    return sec * NS_PER_S + nsec, speed
