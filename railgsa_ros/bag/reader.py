"""Reading rosbag2 bags written by any rosbag2 tool (MCAP or sqlite3) with rosbags.

Accepts a bag directory, a directory whose ``metadata.yaml`` is missing (its storage files are
read directly), or a bare ``.mcap``/``.db3`` file. Every failure of an unreadable, empty,
truncated or corrupt bag becomes an InputError that names the path.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from railgsa_ros.bag import cdr
from railgsa_ros.bag.messages import (
    IMU,
    IMU_FIELDS,
    LAYOUTS,
    ODOMETRY,
    ODOMETRY_FIELDS,
    flatten,
    typestore,
)
from railgsa_ros.errors import InputError, RailGsaError

STORAGE_SUFFIXES = ('.mcap', '.db3')


def storage_paths(path: str | Path) -> list[Path]:
    """The paths to hand to rosbags for ``path``; InputError if it cannot be a rosbag2 bag."""
    path = Path(path)
    if path.is_file():
        if path.name == 'metadata.yaml':
            return [path.parent]
        if path.suffix in STORAGE_SUFFIXES:
            return [path]
        raise InputError(f'{path}: not a rosbag2 bag (expected a directory, .mcap or .db3)')
    if not path.is_dir():
        raise InputError(f'{path}: no such bag')
    if (path / 'metadata.yaml').is_file():
        return [path]
    for suffix in STORAGE_SUFFIXES:
        files = sorted(path.glob('*' + suffix))
        if files:
            return files
    raise InputError(f'{path}: not a rosbag2 bag (no metadata.yaml, .mcap or .db3 file)')


def _one_line(exc: BaseException) -> str:
    """A short single-line description of a third-party exception."""
    text = ' '.join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 160 else text[:157] + '...'


@contextmanager
def open_bag(path: str | Path) -> Iterator[AnyReader]:
    """An open rosbags AnyReader; any failure inside the block becomes InputError naming ``path``
    (a RailGsaError passes through unchanged)."""
    try:
        with AnyReader(storage_paths(path), default_typestore=typestore()) as reader:
            yield reader
    except RailGsaError:
        raise
    except Exception as exc:  # rosbags/zstd/sqlite raise many types for a damaged file
        raise InputError(f'{path}: unreadable bag ({_one_line(exc)})') from None


def read_messages(path: str | Path,
                  topics: Sequence[str] | None = None) -> Iterator[tuple[str, int, Any]]:
    """Yield (topic, log_time_ns, message) in log-time order, deserialised with the bag's own
    message definitions; ``topics=None`` reads all topics."""
    with open_bag(path) as reader:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        for conn, log_time, raw in reader.messages(connections=conns):
            yield conn.topic, log_time, reader.deserialize(raw, conn.msgtype)


@dataclass(frozen=True)
class TopicData:
    """One topic decoded as arrays: log times (N,), header stamps (N,) ns, strings, bodies."""

    log_time_ns: np.ndarray
    stamps_ns: np.ndarray
    strings: tuple[np.ndarray, ...]
    values: np.ndarray


def _topic_connections(reader: AnyReader, path: Path, topic: str, msgtype: str) -> list[Any]:
    """Connections of ``topic``; InputError when it is absent or of another type."""
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        have = ', '.join(sorted({c.topic for c in reader.connections})) or 'none'
        raise InputError(f'{path}: no topic {topic} (topics: {have})')
    wrong = sorted({c.msgtype for c in conns} - {msgtype})
    if wrong:
        raise InputError(f'{path}: topic {topic} has type {wrong[0]}, expected {msgtype}')
    return conns


def _read_topics(reader: AnyReader, path: Path,
                 wanted: dict[str, str]) -> dict[str, TopicData]:
    """Decode every message of the ``wanted`` topics (topic -> message type with a fixed layout)
    in one pass over the bag, vectorised when the data are plain CDR."""
    conns = {topic: _topic_connections(reader, path, topic, msgtype)
             for topic, msgtype in wanted.items()}
    collected: dict[str, tuple[list[int], list[Any]]] = {t: ([], []) for t in wanted}
    for conn, log_time, raw in reader.messages(connections=[c for cs in conns.values()
                                                            for c in cs]):
        times, raws = collected[conn.topic]
        times.append(log_time)
        raws.append(raw)
    out = {}
    for topic, msgtype in wanted.items():
        times, raws = collected[topic]
        layout = LAYOUTS[msgtype]
        try:
            dec = cdr.decode(layout, raws)
            stamps, strings, values = dec.stamps_ns, dec.strings, dec.values
        except ValueError:
            flat = [flatten(reader.deserialize(r, msgtype), msgtype) for r in raws]
            stamps = np.array([f[0] for f in flat], dtype=np.int64)
            strings = tuple(np.array([f[1][j] for f in flat], dtype=str)
                            for j in range(layout.n_strings))
            values = np.array([f[2] for f in flat]).reshape(len(flat), layout.n_doubles)
        out[topic] = TopicData(np.array(times, dtype=np.int64), stamps, strings, values)
    return out


def read_stamped(path: str | Path, topic: str, msgtype: str) -> TopicData:
    """Every message of one topic whose type has a fixed layout (``messages.LAYOUTS``: Imu,
    Odometry, PointStamped, Vector3Stamped) as arrays, e.g. the truth of a simulated bag."""
    path = Path(path)
    if msgtype not in LAYOUTS:
        raise ValueError(f'no fixed layout for {msgtype}; use read_messages')
    with open_bag(path) as reader:
        return _read_topics(reader, path, {topic: msgtype})[topic]


@dataclass(frozen=True)
class ImuStream:
    """Accelerometer stream of a bag, in bag (log-time) order.

    stamps_ns (T,) int64: header.stamp (``stamp_source`` 'header'), or the log time when every
    header stamp is zero ('log_time'); accel (T, 3) m/s^2, NaN where REP 145 marks the field
    absent (linear_acceleration_covariance[0] = -1 or NaN); frame_ids (T,) str; covariance (T, 9)
    as recorded ((m/s^2)^2, row-major, zeros = unknown); odom_stamps_ns (M,) and speed_mps (M,)
    from Odometry twist.twist.linear.x (empty when the bag has no odometry topic).
    """

    path: Path
    topic: str
    stamps_ns: np.ndarray
    log_time_ns: np.ndarray
    accel: np.ndarray
    frame_ids: np.ndarray
    covariance: np.ndarray
    odom_stamps_ns: np.ndarray
    speed_mps: np.ndarray
    stamp_source: str = 'header'

    def accel_variance(self, default: float) -> np.ndarray:
        """Per-sample, per-axis variance (T, 3) in (m/s^2)^2: the recorded diagonal, ``default``
        where the covariance is all zeros (unknown), NaN where the field is absent."""
        diag = self.covariance[:, [0, 4, 8]].copy()
        unknown = ~np.any(self.covariance != 0, axis=1)
        diag[unknown] = default
        diag[np.isnan(self.accel[:, 0])] = np.nan
        return diag


def _stamps(data: TopicData) -> tuple[np.ndarray, str]:
    """Header stamps, or log times when the publisher left every header stamp at zero."""
    if data.stamps_ns.size and not np.any(data.stamps_ns):
        return data.log_time_ns, 'log_time'
    return data.stamps_ns, 'header'


def read_imu(path: str | Path, imu_topic: str = '/imu/data',
             odom_topic: str | None = '/odom') -> ImuStream:
    """Read the accelerometer stream (and odometry speeds, if present) of a bag."""
    path = Path(path)
    with open_bag(path) as reader:
        wanted = {imu_topic: IMU.msgtype}
        if odom_topic is not None and any(c.topic == odom_topic for c in reader.connections):
            wanted[odom_topic] = ODOMETRY.msgtype
        data = _read_topics(reader, path, wanted)
    imu, odom = data[imu_topic], data.get(odom_topic)
    if imu.values.shape[0] == 0:
        raise InputError(f'{path}: topic {imu_topic} has no messages')
    cov = imu.values[:, IMU_FIELDS['linear_acceleration_covariance']]
    absent = (cov[:, 0] == -1) | np.isnan(cov[:, 0])
    if np.all(absent):
        raise InputError(f'{path}: {imu_topic} carries no linear acceleration '
                         '(linear_acceleration_covariance[0] is -1 or NaN)')
    accel = imu.values[:, IMU_FIELDS['linear_acceleration']].copy()
    accel[absent] = np.nan
    stamps, source = _stamps(imu)
    if odom is None:
        odom_stamps, speed = np.zeros(0, dtype=np.int64), np.zeros(0)
    else:
        odom_stamps = _stamps(odom)[0]
        speed = odom.values[:, ODOMETRY_FIELDS['twist.twist.linear'].start].copy()
    return ImuStream(path, imu_topic, stamps, imu.log_time_ns, accel, imu.strings[0], cov.copy(),
                     odom_stamps, speed, source)


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: type, message count, first/last log time (ns)."""

    topic: str
    msgtype: str
    count: int
    start_ns: int
    end_ns: int


def summarize(path: str | Path) -> list[TopicSummary]:
    """Per-topic message counts and log-time spans (reads raw messages, decodes none)."""
    with open_bag(path) as reader:
        out = []
        for topic, info in sorted(reader.topics.items()):
            times = np.fromiter((t for _, t, _ in reader.messages(connections=info.connections)),
                                dtype=np.int64)
            if times.size == 0:
                out.append(TopicSummary(topic, info.msgtype or '?', 0, 0, 0))
            else:
                out.append(TopicSummary(topic, info.msgtype or '?', int(times.size),
                                        int(times.min()), int(times.max())))
    return out
