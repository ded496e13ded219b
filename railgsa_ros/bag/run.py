"""A simulated run (``railgsa_ros.scenario.Run``) as ROS 2 message streams, for bags and nodes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from railgsa_ros.bag import cdr
from railgsa_ros.bag.messages import (
    IMU,
    ODOMETRY,
    POINT_STAMPED,
    history_depth,
    imu_values,
    odometry_values,
    qos,
)
from railgsa_ros.bag.writer import BagWriter, Batch

IMU_TOPIC = '/imu/data'
ODOM_TOPIC = '/odom'
TRUTH_TOPIC = '/track/irregularity_truth'
WRITE_CHUNK = 50_000  # IMU samples serialised at a time: bounded memory for long runs


def sample_indices(stamps_ns: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of the first sample at or after each tick of a ``rate_hz`` clock that starts at
    the first stamp: how a slower sensor (odometry) samples the same run."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    if stamps_ns.size == 0:
        return np.zeros(0, dtype=np.int64)
    period = 1e9 / rate_hz
    ticks = stamps_ns[0] + np.round(
        np.arange(int((stamps_ns[-1] - stamps_ns[0]) // period) + 1) * period).astype(np.int64)
    return np.unique(np.searchsorted(stamps_ns, ticks, side='left'))


class RunEncoder:
    """Serialises slices of a run as Imu, Odometry and PointStamped (truth) CDR messages.

    ``accel_variance``: accelerometer variance per axis in (m/s^2)^2 (REP 145 covariance
    diagonal; 0 = unknown; None = ``run.accel_covariance``). Imu frame: ``frame_id``, else
    ``run.frame_id``, else imu_link. Odometry samples the run at ``odom_rate_hz`` with
    pose.position.x = chainage (m) and twist.twist.linear.x = speed (m/s). Truth: point.x =
    chainage (m), point.z = irregularity (m) at every IMU stamp, frame ``track``.
    """

    def __init__(self, run: Any, accel_variance: float | None = None,
                 odom_rate_hz: float = 50.0, frame_id: str | None = None) -> None:
        self.run = run
        self.frame_id = frame_id or getattr(run, 'frame_id', 'imu_link')
        if accel_variance is None:
            accel_variance = getattr(run, 'accel_covariance', 0.0)
        self.accel_variance = float(accel_variance)
        self.odom_rate_hz = float(odom_rate_hz)
        self.stamps_ns = np.asarray(run.stamps_ns, dtype=np.int64)
        self.odom_index = sample_indices(self.stamps_ns, odom_rate_hz)
        self.imu_rate_hz = _mean_rate(self.stamps_ns)

    def __len__(self) -> int:
        return self.stamps_ns.size

    def encode(self, start: int = 0, stop: int | None = None,
               offset_ns: int = 0) -> dict[str, Batch]:
        """Messages of IMU samples [start, stop), stamps shifted by ``offset_ns``: a dict
        'imu'|'odom'|'truth' -> (stamps_ns, raw CDR messages)."""
        stop = len(self) if stop is None else stop
        run = self.run
        stamps = self.stamps_ns[start:stop] + offset_ns
        odom = self.odom_index[(self.odom_index >= start) & (self.odom_index < stop)]
        odom_stamps = self.stamps_ns[odom] + offset_ns
        chainage = np.asarray(run.chainage_m, dtype=float)
        truth = np.zeros((stamps.size, 3))
        truth[:, 0] = chainage[start:stop]
        truth[:, 2] = np.asarray(run.truth_u_m, dtype=float)[start:stop]
        odom_values = odometry_values(chainage[odom], np.asarray(run.speed_mps)[odom])
        return {
            'imu': (stamps, cdr.encode(IMU, stamps, [self.frame_id],
                                       imu_values(run.accel[start:stop], self.accel_variance))),
            'odom': (odom_stamps, cdr.encode(ODOMETRY, odom_stamps, ['odom', 'base_link'],
                                             odom_values)),
            'truth': (stamps, cdr.encode(POINT_STAMPED, stamps, ['track'], truth)),
        }

    def topics(self) -> dict[str, tuple[str, str, Any]]:
        """key -> (bag topic, message type, offered QoS): BEST_EFFORT for the IMU (sensor data,
        depth for 1 s), RELIABLE for odometry and truth."""
        return {
            'imu': (IMU_TOPIC, IMU.msgtype, qos(False, history_depth(self.imu_rate_hz))),
            'odom': (ODOM_TOPIC, ODOMETRY.msgtype, qos(True, history_depth(self.odom_rate_hz))),
            'truth': (TRUTH_TOPIC, POINT_STAMPED.msgtype,
                      qos(True, history_depth(self.imu_rate_hz))),
        }


def _mean_rate(stamps_ns: np.ndarray) -> float:
    """Mean sample rate (Hz) of a stamp sequence (1 Hz if it has fewer than two samples)."""
    if stamps_ns.size < 2 or stamps_ns[-1] <= stamps_ns[0]:
        return 1.0
    return (stamps_ns.size - 1) * 1e9 / float(stamps_ns[-1] - stamps_ns[0])


def write_run(path: str | Path, run: Any, storage: str = 'mcap', compression: str | None = None,
              accel_variance: float | None = None, odom_rate_hz: float = 50.0,
              offset_ns: int = 0,
              overwrite: bool = False) -> Path:
    """Write a run as a rosbag2 bag with ``/imu/data``, ``/odom`` and
    ``/track/irregularity_truth``; header stamp = log time = run stamp + ``offset_ns``.
    Returns the bag path."""
    encoder = RunEncoder(run, accel_variance, odom_rate_hz)
    with BagWriter(path, storage, compression, overwrite) as bag:
        topics = encoder.topics()
        for topic, msgtype, offered in topics.values():
            bag.add_topic(topic, msgtype, offered)
        for start in range(0, len(encoder), WRITE_CHUNK):
            batches = encoder.encode(start, start + WRITE_CHUNK, offset_ns)
            bag.write_batches({topics[k][0]: batch for k, batch in batches.items()})
    return Path(path)
