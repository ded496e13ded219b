"""Serialized sensor_msgs/Imu and nav_msgs/Odometry batches to arrays, REP 145 consumer rules.

No rclpy import: the bytes are decoded vectorised (:func:`railgsa_ros.bag.cdr.decode_valid`);
messages that are not plain CDR go through the caller's ``fallback`` (the node passes rclpy's
deserialiser, so other encodings still work).

REP 145 as a consumer: linear acceleration is specific force in the sensor frame *including*
gravity (+9.81 m/s^2 on z at rest, z up), passed on unchanged; the core removes gravity and bias.
The covariance is passed on as sent (9 values); the input policy applies REP 145 to it (element
0 equal to -1 or NaN: the acceleration is absent; all zeros: unknown). A message that cannot be
read (truncated, garbage), or that has a zero or negative stamp, nanoseconds >= 1e9, an empty
frame_id or a string over ``cdr.MAX_STRING`` is *malformed*: counted and left out, never raised.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from railgsa_ros.bag.cdr import Decoded, Fallback, decode_valid
from railgsa_ros.bag.messages import IMU, IMU_FIELDS, ODOMETRY, ODOMETRY_FIELDS

NS_PER_S = 1_000_000_000
_ACCEL = IMU_FIELDS['linear_acceleration']
_COV = IMU_FIELDS['linear_acceleration_covariance']
_GYRO = IMU_FIELDS['angular_velocity']
_GYRO_COV = IMU_FIELDS['angular_velocity_covariance']
_SPEED = ODOMETRY_FIELDS['twist.twist.linear'].start


@dataclass(frozen=True)
class ImuBatch:
    """The well-formed ones of N Imu messages as arrays, in arrival order."""

    stamps_ns: np.ndarray  #: int64 (K,), header stamps in ns
    accel: np.ndarray      #: float (K, 3), specific force x, y, z incl. gravity, m/s^2
    frame_ids: np.ndarray  #: str (K,), header.frame_id
    covariance: np.ndarray  #: float (K, 9), linear_acceleration_covariance as sent (REP 145)
    angular_velocity: np.ndarray  #: float (K, 3), rad/s (a coach's pitch rate: y, REP 103)
    gyro_covariance: np.ndarray  #: float (K, 9), angular_velocity_covariance as sent (REP 145)

    def __len__(self) -> int:
        return len(self.stamps_ns)


def _valid_stamps(dec: Decoded) -> np.ndarray:
    """Rows with a positive stamp and nanoseconds below 1e9 (bool (N,))."""
    return (dec.stamps_ns > 0) & (dec.nanosec < NS_PER_S)  # sec < 0: stamps_ns < 0


def imu_batch(raws: Sequence[bytes], fallback: Fallback | None = None) -> tuple[ImuBatch, int]:
    """Decode serialized Imu messages in one pass; returns the well-formed ones and the count
    of malformed ones. Never raises on a bad message."""
    dec, _ = decode_valid(IMU, raws, fallback)
    good = _valid_stamps(dec) & (dec.strings[0] != '')
    if not good.all():
        dec = Decoded(dec.stamps_ns[good], (dec.strings[0][good],), dec.values[good])
    batch = ImuBatch(dec.stamps_ns, dec.values[:, _ACCEL], dec.strings[0], dec.values[:, _COV],
                     dec.values[:, _GYRO], dec.values[:, _GYRO_COV])
    return batch, len(raws) - len(batch)


def odometry_speeds(raws: Sequence[bytes], fallback: Fallback | None = None) -> \
        tuple[np.ndarray, np.ndarray, int]:
    """(stamps int64 ns, forward speeds twist.twist.linear.x m/s, malformed count) of
    serialized Odometry messages. A NaN or implausible speed is passed on: the input policy
    counts it and ignores it without dropping IMU samples; a malformed stamp drops the
    message."""
    dec, _ = decode_valid(ODOMETRY, raws, fallback)
    good = _valid_stamps(dec)
    return dec.stamps_ns[good], dec.values[good, _SPEED], len(raws) - int(good.sum())
