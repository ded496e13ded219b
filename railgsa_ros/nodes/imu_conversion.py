"""Message batches to arrays: sensor_msgs/Imu and nav_msgs/Odometry, REP 145 consumer rules.

No rclpy import: works on rclpy messages and on rosbags messages alike (same field names).

REP 145 as a consumer: linear acceleration is specific force in the sensor frame *including*
gravity (+9.81 m/s^2 on z at rest, z up), passed on unchanged; the core removes gravity and bias.
The covariance is passed on as sent (9 values); the input policy applies REP 145 to it (element
0 equal to -1 or NaN: the acceleration is absent; all zeros: unknown). A message whose fields
cannot be read as a stamp, a frame and numbers (and 9 covariance values), or that has a zero or
negative stamp, nanoseconds >= 1e9 or an empty frame_id is *malformed*: flagged, never raised.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

NS_PER_S = 1_000_000_000
_NAN3 = (float('nan'),) * 3
_BAD = (0, 0, '', _NAN3, (float('nan'),) * 9)
_ROW = np.dtype([('sec', np.int64), ('nsec', np.int64), ('frame', object), ('accel', float, 3),
                 ('cov', float, 9)])


@dataclass(frozen=True)
class ImuBatch:
    """N Imu messages as arrays; rows flagged ``malformed`` hold placeholders."""

    stamps_ns: np.ndarray  #: int64 (N,), header stamps in ns
    accel: np.ndarray      #: float (N, 3), specific force x, y, z incl. gravity, m/s^2
    frame_ids: np.ndarray  #: object (N,) of str, header.frame_id
    covariance: np.ndarray  #: float (N, 9), linear_acceleration_covariance as sent (REP 145)
    malformed: np.ndarray  #: bool (N,)

    def __len__(self) -> int:
        return len(self.stamps_ns)


def _imu_fields(msg: Any) -> tuple:
    """(sec, nanosec, frame_id, (ax, ay, az), covariance (9,)); placeholders if a field is
    unreadable."""
    try:
        stamp, cov, acc = msg.header.stamp, msg.linear_acceleration_covariance, \
            msg.linear_acceleration
        covariance = tuple(float(c) for c in cov)
        if len(covariance) != 9:
            raise ValueError('linear_acceleration_covariance: expected 9 values')
        return (int(stamp.sec), int(stamp.nanosec), str(msg.header.frame_id),
                (float(acc.x), float(acc.y), float(acc.z)), covariance)
    except (AttributeError, TypeError, ValueError, IndexError, OverflowError):
        return _BAD


def stamps_to_ns(sec: np.ndarray, nanosec: np.ndarray) -> np.ndarray:
    """Combine header stamp fields into int64 nanoseconds."""
    return np.asarray(sec, np.int64) * NS_PER_S + np.asarray(nanosec, np.int64)


def imu_batch(msgs: Sequence[Any]) -> ImuBatch:
    """Convert a list of Imu messages in one pass; never raises on a bad message."""
    rows = np.array([_imu_fields(m) for m in msgs], dtype=_ROW)
    sec, nsec = rows['sec'], rows['nsec']
    malformed = ((sec < 0) | (nsec < 0) | (nsec >= NS_PER_S) | ((sec == 0) & (nsec == 0))
                 | (rows['frame'] == ''))
    sec = np.clip(sec, 0, np.iinfo(np.int64).max // NS_PER_S - 1)
    return ImuBatch(stamps_ns=stamps_to_ns(sec, nsec), accel=rows['accel'],
                    frame_ids=rows['frame'], covariance=rows['cov'], malformed=malformed)

def odom_speed(msg: Any) -> tuple[int, float] | None:
    """(stamp ns, forward speed twist.twist.linear.x in m/s), or None if the stamp is malformed
    or a field unreadable. A NaN or implausible speed is passed on: the input policy counts it
    and ignores it without dropping IMU samples."""
    try:
        stamp = msg.header.stamp
        sec, nsec = int(stamp.sec), int(stamp.nanosec)
        speed = float(msg.twist.twist.linear.x)
    except (AttributeError, TypeError, ValueError, OverflowError):
        return None
    if sec < 0 or not 0 <= nsec < NS_PER_S or (sec == 0 and nsec == 0):
        return None
    return sec * NS_PER_S + nsec, speed
