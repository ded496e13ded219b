"""A simulated run (``railgsa_ros.scenario.Run``) as ROS 2 message streams, for bags and nodes."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from railgsa_ros.bag import cdr
from railgsa_ros.bag.messages import (
    IMU,
    ODOMETRY,
    POINT_STAMPED,
    imu_values,
    odometry_values,
    typestore,
)
from railgsa_ros.bag.reader import TopicSummary
from railgsa_ros.bag.writer import BagWriter, Batch
from railgsa_ros.qos import history_depth, record_qos
from railgsa_ros.ticks import TickSampler

IMU_TOPIC = '/imu/data'
ODOM_TOPIC = '/odom'
TRUTH_TOPIC = '/track/irregularity_truth'
GNSS_TOPIC = '/gnss/fix'
NAVSATFIX = 'sensor_msgs/msg/NavSatFix'
GNSS_FRAME_ID = 'gnss'
WRITE_CHUNK = 50_000  # IMU samples serialised at a time: bounded memory for long runs


def sample_indices(stamps_ns: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of the first sample at or after each tick of a ``rate_hz`` clock that starts at
    the first stamp: how a slower sensor (odometry) samples the same run."""
    return TickSampler(rate_hz).take(stamps_ns)


class RunEncoder:
    """Serialises slices of a run as Imu, Odometry and PointStamped (truth) CDR messages.

    A run with further IMUs (``run.imu_names``, a coach file's) has one more Imu stream each,
    key ``imu:<name>``, frame ``<frame>_<name>``, at the primary's stamps.

    ``accel_variance``: accelerometer variance per axis in (m/s^2)^2 (REP 145 covariance diagonal;
    0 = unknown; None = ``run.accel_covariance``). Imu frame: ``frame_id``, else ``run.frame_id``,
    else imu_link. Angular velocity: ``run.gyro`` (T, 3) rad/s with the variance
    ``run.gyro_covariance`` when the run has one, else absent (REP 145). Odometry samples the run
    at ``odom_rate_hz`` with pose.position.x = chainage at the start + odometer distance (m) and
    twist.twist.linear.x = odometry speed (m/s): both the truth times ``run.odom_scale`` (a
    wheel-diameter error). Truth: point.x = chainage (m), point.z = irregularity (m) at every IMU
    stamp, frame ``track``. ``odom``: the TickSampler of a stream whose earlier chunks were encoded
    before (with ``origin_m``, the stream's first chainage); None for a whole run.
    """

    def __init__(self, run: Any, accel_variance: float | None = None,
                 odom_rate_hz: float = 50.0, frame_id: str | None = None,
                 odom: TickSampler | None = None, origin_m: float | None = None) -> None:
        self.run = run
        self.frame_id = str(frame_id or getattr(run, 'frame_id', None) or 'imu_link')
        if accel_variance is None:
            accel_variance = getattr(run, 'accel_covariance', 0.0)
        self.accel_variance = float(accel_variance)
        self.gyro = getattr(run, 'gyro', None)  # (T, 3) rad/s, None: no gyro
        self.gyro_variance = float(getattr(run, 'gyro_covariance', 0.0))
        self.imu_names = tuple(getattr(run, 'imu_names', ()))  # further IMUs: /imu/<name>/data
        self.odom_rate_hz = float(odom_rate_hz)
        self.stamps_ns = np.asarray(run.stamps_ns, dtype=np.int64)
        self.odom_index = (odom or TickSampler(odom_rate_hz)).take(self.stamps_ns)
        self.imu_rate_hz = float(getattr(run, 'rate_hz', 0.0)) or _mean_rate(self.stamps_ns)
        chainage = np.asarray(run.chainage_m, dtype=float)
        self.origin_m = float(chainage[0]) if origin_m is None and chainage.size else origin_m
        self.odom_scale = float(getattr(run, 'odom_scale', 1.0))

    def __len__(self) -> int:
        return self.stamps_ns.size

    def encode(self, start: int = 0, stop: int | None = None,
               offset_ns: int = 0) -> dict[str, Batch]:
        """Messages of IMU samples [start, stop), stamps shifted by ``offset_ns``: a dict
        'imu'|'odom'|'truth' -> (stamps_ns, raw CDR messages as bytes)."""
        rows = self.encode_rows(start, stop, offset_ns)
        return {key: (stamps, [r.tobytes() for r in block])
                for key, (stamps, block) in rows.items()}

    def encode_rows(self, start: int = 0, stop: int | None = None,
                    offset_ns: int = 0) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """``encode`` with each topic's messages as one (N, L) uint8 array (``cdr.encode_rows``):
        what ``BagWriter.write_batches`` takes without a Python object per message."""
        stop = len(self) if stop is None else stop
        run = self.run
        stamps = self.stamps_ns[start:stop] + offset_ns
        odom = self.odom_index[(self.odom_index >= start) & (self.odom_index < stop)]
        odom_stamps = self.stamps_ns[odom] + offset_ns
        chainage = np.asarray(run.chainage_m, dtype=float)
        truth = np.zeros((stamps.size, 3))
        truth[:, 0] = chainage[start:stop]
        truth[:, 2] = np.asarray(run.truth_u_m, dtype=float)[start:stop]
        odometer = chainage[odom]
        if self.odom_scale != 1.0 and odometer.size:
            odometer = self.origin_m + self.odom_scale * (odometer - self.origin_m)
        odom_values = odometry_values(odometer, self.odom_scale * np.asarray(run.speed_mps)[odom])
        gyro = None if self.gyro is None else self.gyro[start:stop]
        extra = {f'imu:{name}': (stamps, self._imu_rows(
            stamps, run.imu_accel[start:stop, k], f'{self.frame_id}_{name}',
            None if run.imu_gyro is None else run.imu_gyro[start:stop, k]))
            for k, name in enumerate(self.imu_names)}
        return {
            'imu': (stamps, self._imu_rows(stamps, run.accel[start:stop], self.frame_id, gyro)),
            **extra,
            'odom': (odom_stamps, cdr.encode_rows(ODOMETRY, odom_stamps, ['odom', 'base_link'],
                                                  odom_values)),
            'truth': (stamps, cdr.encode_rows(POINT_STAMPED, stamps, ['track'], truth)),
        }

    def _imu_rows(self, stamps: np.ndarray, accel: np.ndarray, frame_id: str,
                  gyro: np.ndarray | None) -> np.ndarray:
        """Imu messages (N, L) of one IMU: accelerometer and, when given, gyro values."""
        return cdr.encode_rows(IMU, stamps, [frame_id], imu_values(
            accel, self.accel_variance, gyro, self.gyro_variance))

    def topics(self) -> dict[str, tuple[str, str, Any]]:
        """key -> (bag topic, message type, offered QoS): BEST_EFFORT for the IMUs (sensor data,
        depth for 1 s; a further IMU <name> on /imu/<name>/data), RELIABLE for odometry and
        truth."""
        imu_qos = record_qos(False, history_depth(self.imu_rate_hz))
        return {
            'imu': (IMU_TOPIC, IMU.msgtype, imu_qos),
            **{f'imu:{name}': (f'/imu/{name}/data', IMU.msgtype, imu_qos)
               for name in self.imu_names},
            'odom': (ODOM_TOPIC, ODOMETRY.msgtype,
                     record_qos(True, history_depth(self.odom_rate_hz))),
            'truth': (TRUTH_TOPIC, POINT_STAMPED.msgtype,
                      record_qos(True, history_depth(self.imu_rate_hz))),
        }


def navsat_messages(fixes: Any, covariance: np.ndarray, offset_ns: int = 0) -> Batch:
    """NavSatFix CDR messages of GNSS fixes (``geo.GnssFixes``): STATUS_FIX by GPS, the given
    ENU position covariance (m^2, row-major), COVARIANCE_TYPE_DIAGONAL_KNOWN, frame ``gnss``.

    rosbags' serializer, not the vectorised codec: NavSatFix mixes int8/uint16/uint8 fields
    with the doubles, and at 1-10 Hz it costs about 20 us a fix (under 1 s per hour).
    """
    store = typestore()
    types = store.types
    fix, status = types[NAVSATFIX], types['sensor_msgs/msg/NavSatStatus']
    header, time = types['std_msgs/msg/Header'], types['builtin_interfaces/msg/Time']
    stamps = np.asarray(fixes.stamps_ns, dtype=np.int64) + offset_ns
    cov = np.asarray(covariance, dtype=np.float64)
    raws = [bytes(store.serialize_cdr(fix(
        header=header(stamp=time(sec=int(t // 10**9), nanosec=int(t % 10**9)),
                      frame_id=GNSS_FRAME_ID),
        status=status(status=status.STATUS_FIX, service=status.SERVICE_GPS),
        latitude=float(la), longitude=float(lo), altitude=float(al), position_covariance=cov,
        position_covariance_type=fix.COVARIANCE_TYPE_DIAGONAL_KNOWN), NAVSATFIX))
        for t, la, lo, al in zip(stamps.tolist(), fixes.lat_deg.tolist(), fixes.lon_deg.tolist(),
                                 fixes.alt_m.tolist(), strict=True)]
    return stamps, raws


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
    return write_run_chunks(path, [run], storage, compression, accel_variance, odom_rate_hz,
                            offset_ns, overwrite)[0]


def write_run_chunks(path: str | Path, chunks: Iterable[Any], storage: str = 'mcap',
                     compression: str | None = None, accel_variance: float | None = None,
                     odom_rate_hz: float = 50.0, offset_ns: int = 0,
                     overwrite: bool = False, gnss: Any = None
                     ) -> tuple[Path, list[TopicSummary]]:
    """``write_run`` for a run that arrives in consecutive chunks (``scenario.RunStream``):
    each chunk is encoded and written before the next is made, so memory stays bounded.
    ``gnss``: a ``geo.GnssSim`` whose fixes go to ``/gnss/fix`` (NavSatFix, RELIABLE).
    Returns (bag path, per-topic counts and log-time spans as written)."""
    odom = TickSampler(odom_rate_hz)
    origin = None
    written: dict[str, list[int]] = {}  # topic -> [count, first, last log time]
    with BagWriter(path, storage, compression, overwrite) as bag:
        topics = None
        for chunk in chunks:
            encoder = RunEncoder(chunk, accel_variance, odom_rate_hz, odom=odom, origin_m=origin)
            origin = encoder.origin_m
            if topics is None:
                topics = encoder.topics()
                if gnss is not None:
                    topics['gnss'] = (GNSS_TOPIC, NAVSATFIX,
                                      record_qos(True, history_depth(gnss.spec.rate_hz)))
                for topic, msgtype, offered in topics.values():
                    bag.add_topic(topic, msgtype, offered)
            for start in range(0, len(encoder), WRITE_CHUNK):
                batches: dict[str, Batch] = {**encoder.encode_rows(start, start + WRITE_CHUNK,
                                                                   offset_ns)}
                if gnss is not None:
                    stop = start + WRITE_CHUNK
                    batches['gnss'] = navsat_messages(
                        gnss.take(chunk.stamps_ns[start:stop], chunk.chainage_m[start:stop]),
                        gnss.covariance, offset_ns)
                bag.write_batches({topics[k][0]: batch for k, batch in batches.items()})
                for key, (stamps, _) in batches.items():
                    if len(stamps):
                        count = written.setdefault(key, [0, int(stamps[0]), 0])
                        count[0] += len(stamps)
                        count[2] = int(stamps[-1])
    declared = topics or {}
    summaries = [TopicSummary(declared[k][0], declared[k][1], *written.get(k, (0, 0, 0)))
                 for k in declared]
    return Path(path), sorted(summaries, key=lambda t: t.topic)
