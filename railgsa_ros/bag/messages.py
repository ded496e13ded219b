"""Standard ROS 2 messages as arrays: layouts, REP 145 conventions and the Jazzy typestore.

Sign and frame conventions (REP 103/145): ``imu_link`` z up, specific force including gravity in
m/s^2; no orientation (or no gyro) -> orientation (0, 0, 0, 1) and covariance[0] = -1 for those
fields; angular velocity in rad/s about the body axes (y: pitch, positive nose down); the
accelerometer covariance diagonal is the sensor variance ((m/s^2)^2), all zeros when unknown.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from railgsa_ros.bag.cdr import StampedLayout

IMU = StampedLayout('sensor_msgs/msg/Imu', 1, 37)
ODOMETRY = StampedLayout('nav_msgs/msg/Odometry', 2, 85)
POINT_STAMPED = StampedLayout('geometry_msgs/msg/PointStamped', 1, 3)
VECTOR3_STAMPED = StampedLayout('geometry_msgs/msg/Vector3Stamped', 1, 3)
LAYOUTS = {x.msgtype: x for x in (IMU, ODOMETRY, POINT_STAMPED, VECTOR3_STAMPED)}

# Columns of the float64 body, in CDR field order.
IMU_FIELDS = {'orientation': slice(0, 4), 'orientation_covariance': slice(4, 13),
              'angular_velocity': slice(13, 16), 'angular_velocity_covariance': slice(16, 25),
              'linear_acceleration': slice(25, 28),
              'linear_acceleration_covariance': slice(28, 37)}
ODOMETRY_FIELDS = {'pose.pose.position': slice(0, 3), 'pose.pose.orientation': slice(3, 7),
                   'pose.covariance': slice(7, 43), 'twist.twist.linear': slice(43, 46),
                   'twist.twist.angular': slice(46, 49), 'twist.covariance': slice(49, 85)}
FIELDS = {IMU.msgtype: IMU_FIELDS, ODOMETRY.msgtype: ODOMETRY_FIELDS,
          POINT_STAMPED.msgtype: {'point': slice(0, 3)},
          VECTOR3_STAMPED.msgtype: {'vector': slice(0, 3)}}
STRING_FIELDS = {ODOMETRY.msgtype: ('header.frame_id', 'child_frame_id')}

@lru_cache(maxsize=1)
def typestore() -> Any:
    """The rosbags type store of ROS 2 Jazzy (cached)."""
    return get_typestore(Stores.ROS2_JAZZY)


def imu_values(accel: np.ndarray, accel_variance: float, gyro: np.ndarray | None = None,
               gyro_variance: float = 0.0) -> np.ndarray:
    """Imu float64 bodies (T, 37) with REP 145 sentinels for what the sensor lacks.

    accel: (T, 3) specific force in m/s^2; accel_variance: per-axis variance in (m/s^2)^2, 0 when
    unknown; gyro: (T, 3) angular velocity in rad/s (REP 103 body axes) with its per-axis
    variance in (rad/s)^2, or None for a sensor without a gyro (covariance[0] = -1).
    """
    accel = np.asarray(accel, dtype=float)
    values = np.zeros((accel.shape[0], IMU.n_doubles))
    values[:, IMU_FIELDS['orientation']] = (0.0, 0.0, 0.0, 1.0)
    values[:, IMU_FIELDS['orientation_covariance'].start] = -1.0
    if gyro is None:
        values[:, IMU_FIELDS['angular_velocity_covariance'].start] = -1.0
    else:
        values[:, IMU_FIELDS['angular_velocity']] = gyro
        values[:, IMU_FIELDS['angular_velocity_covariance']] = \
            np.diag(np.full(3, float(gyro_variance))).ravel()
    values[:, IMU_FIELDS['linear_acceleration']] = accel
    values[:, IMU_FIELDS['linear_acceleration_covariance']] = \
        np.diag(np.full(3, float(accel_variance))).ravel()
    return values


def odometry_values(position_x_m: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
    """Odometry bodies (M, 85): pose.position.x = travelled distance (m), twist.linear.x = speed
    (m/s) in the body frame, identity orientation, covariances zero (unknown)."""
    position_x_m = np.asarray(position_x_m, dtype=float)
    values = np.zeros((position_x_m.size, ODOMETRY.n_doubles))
    values[:, ODOMETRY_FIELDS['pose.pose.position'].start] = position_x_m
    values[:, ODOMETRY_FIELDS['pose.pose.orientation'].stop - 1] = 1.0
    values[:, ODOMETRY_FIELDS['twist.twist.linear'].start] = speed_mps
    return values


def _get(msg: Any, dotted: str) -> Any:
    """Attribute lookup along a dotted path."""
    for name in dotted.split('.'):
        msg = getattr(msg, name)
    return msg


def flatten(msg: Any, msgtype: str) -> tuple[int, tuple[str, ...], np.ndarray]:
    """(stamp_ns, strings, float64 body) of a deserialised message of a layout in ``LAYOUTS``.

    The general (slow) counterpart of :func:`railgsa_ros.bag.cdr.decode`.
    """
    body = np.empty(LAYOUTS[msgtype].n_doubles)
    for dotted, cols in FIELDS[msgtype].items():
        value = _get(msg, dotted)
        if isinstance(value, np.ndarray):
            body[cols] = value.ravel()
        else:
            names = ('x', 'y', 'z', 'w')[:cols.stop - cols.start]
            body[cols] = [getattr(value, n) for n in names]
    strings = tuple(str(_get(msg, s)) for s in STRING_FIELDS.get(msgtype, ('header.frame_id',)))
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec), strings, body
