"""Shared builders and listeners of the ROS tests (issue 14 item 4): Imu and Odometry messages,
their serialized (raw CDR) form as the nodes' subscriptions receive it, header stamps, a
thread-safe collector of one topic's messages (``Collector``) and of /diagnostics
(``DiagnosticsLog``), and a paced burst publisher (``publish_bursts``). rclpy is imported
inside the functions, so that the module imports where the ``ros`` extra is missing (those
tests are skipped)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
import threading
from typing import Any

import numpy as np

NS = 1_000_000_000
G = 9.80665  # standard gravity, m/s^2
T0_NS = NS  # scenario stamps start at 0, which is not a valid header stamp


def stamp_ns(header: Any) -> int:
    """A std_msgs/Header's stamp in ns."""
    return header.stamp.sec * NS + header.stamp.nanosec


def imu_msg(sec: int, nanosec: int, frame: str = 'imu_link',
            acc: Sequence[float] = (0.0, 0.0, G), cov: Sequence[float] | None = None) -> Any:
    """One sensor_msgs/Imu with these header fields (any, also invalid ones), acceleration
    (m/s^2, gravity included) and acceleration covariance (all zeros, REP 145 'unknown',
    unless given). No orientation (REP 145: orientation_covariance[0] = -1; the nodes never
    read it)."""
    from sensor_msgs.msg import Imu

    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = sec, nanosec, frame
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = acc
    if cov is not None:
        m.linear_acceleration_covariance = np.asarray(cov, float)
    m.orientation_covariance[0] = -1.0
    return m


def imu_msgs(stamps_ns: Sequence[int] | np.ndarray, accel: np.ndarray,
             frame: str = 'imu_link', variance: float | None = None,
             absent: bool = False) -> list:
    """Imu messages (``imu_msg``), one per stamp (ns). ``accel``: z only (N,) or all axes
    (N, 3); ``variance``: the covariance diagonal; ``absent``: -1 in its element 0 (REP 145:
    no acceleration estimate)."""
    acc = np.asarray(accel, float)
    acc3 = acc if acc.ndim == 2 else np.column_stack([np.zeros((acc.size, 2)), acc])
    cov = np.zeros(9)
    if variance is not None:
        cov[0::4] = variance
    if absent:
        cov[0] = -1.0
    return [imu_msg(*divmod(int(stamp), NS), frame, a, cov)
            for stamp, a in zip(np.asarray(stamps_ns).tolist(), acc3.tolist(), strict=True)]


def odometry_msg(sec: int, nanosec: int, speed_mps: float) -> Any:
    """nav_msgs/Odometry with these stamp fields (any) and forward speed (twist.linear.x)."""
    from nav_msgs.msg import Odometry

    m = Odometry()
    m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
    m.twist.twist.linear.x = speed_mps
    return m


def odometry(stamp: int, speed_mps: float) -> Any:
    """nav_msgs/Odometry at ``stamp`` (ns) with forward speed ``speed_mps``."""
    return odometry_msg(*divmod(int(stamp), NS), speed_mps)


def serialized(msgs: list) -> list[bytes]:
    """Messages as the nodes' raw subscriptions receive them (``process`` takes bytes)."""
    from rclpy.serialization import serialize_message

    return [serialize_message(m) for m in msgs]


def point_row(msg: Any) -> tuple[int, float, float, float]:
    """A PointStamped as (stamp ns, x, y, z)."""
    return stamp_ns(msg.header), msg.point.x, msg.point.y, msg.point.z


def vector_row(msg: Any) -> tuple[int, float, float, float]:
    """A Vector3Stamped as (stamp ns, x, y, z)."""
    return stamp_ns(msg.header), msg.vector.x, msg.vector.y, msg.vector.z


def header_stamp(msg: Any) -> int:
    """A stamped message's header stamp in ns."""
    return stamp_ns(msg.header)


def statuses(msg: Any, prefix: str) -> dict[str, Any]:
    """The statuses of a DiagnosticArray whose name starts with ``prefix``, by the rest of the
    name (e.g. prefix 'irregularity_node: ' -> 'imu input')."""
    return {s.name[len(prefix):]: s for s in msg.status if s.name.startswith(prefix)}


def values(status: Any) -> dict[str, str]:
    """A DiagnosticStatus's key -> value."""
    return {kv.key: kv.value for kv in status.values}


class Collector:
    """The messages of one topic received by ``node``, each kept as ``row(msg)`` in arrival
    order (thread-safe: the executor appends while the test reads)."""

    def __init__(self, node: Any, msgtype: Any, topic: str, qos: Any,
                 row: Callable[[Any], Any] = lambda msg: msg) -> None:
        self.lock = threading.Lock()
        self.rows: list[Any] = []
        self._row = row
        self.subscription = node.create_subscription(msgtype, topic, self._keep, qos)

    def _keep(self, msg: Any) -> None:
        item = self._row(msg)
        with self.lock:
            self.rows.append(item)

    def __len__(self) -> int:
        with self.lock:
            return len(self.rows)

    def snapshot(self) -> list[Any]:
        """A copy of the rows received so far."""
        with self.lock:
            return list(self.rows)

    def clear(self) -> None:
        """Forget the rows received so far."""
        with self.lock:
            self.rows.clear()


class DiagnosticsLog(Collector):
    """The /diagnostics arrays ``node`` receives: per array that has statuses named
    ``prefix``..., the dict rest of the name -> ``row(status)`` (default: the status itself;
    prefix '' keeps every status under its full name). Thread-safe as Collector."""

    def __init__(self, node: Any, prefix: str = '', row: Callable[[Any], Any] = lambda s: s,
                 qos: Any = 10) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self.prefix = prefix
        self._status = row
        super().__init__(node, DiagnosticArray, '/diagnostics', qos, self._statuses)

    def _statuses(self, msg: Any) -> dict[str, Any]:
        return {name: self._status(s) for name, s in statuses(msg, self.prefix).items()}

    def _keep(self, msg: Any) -> None:
        item = self._row(msg)
        if item:
            with self.lock:
                self.rows.append(item)

    def first(self, pred: Callable[[dict[str, Any]], bool]) -> dict[str, Any] | None:
        """The first array received that satisfies ``pred``, None before there is one."""
        return next((d for d in self.snapshot() if pred(d)), None)

    def latest(self) -> dict[str, Any]:
        """Name -> the newest row of each status received so far."""
        merged: dict[str, Any] = {}
        for report in self.snapshot():
            merged.update(report)
        return merged


def publish_bursts(publisher: Any, msgs: Sequence[Any], rate_hz: float,
                   burst: int | None = None) -> None:
    """Publish ``msgs`` at about ``rate_hz`` (msg/s) in bursts of ``burst`` (default 10 ms
    worth) paced on the monotonic clock; never faster than that when a burst took long."""
    import time

    size = burst or max(1, round(rate_hz / 100))
    due = time.monotonic()
    for i in range(0, len(msgs), size):
        time.sleep(max(0.0, due - time.monotonic()))
        due = time.monotonic() + size / rate_hz  # from this burst's start: no catching up
        for msg in msgs[i:i + size]:
            publisher.publish(msg)


def recorded_stamps(bag: Path) -> dict[str, list[int]]:
    """Topic -> header stamps (ns) of the messages of a recorded bag (rosbags' reader)."""
    from rosbags.highlevel import AnyReader

    from railgsa_ros.bag.messages import typestore

    found: dict[str, list[int]] = {}
    with AnyReader([bag], default_typestore=typestore()) as reader:
        for conn, _, raw in reader.messages():
            stamp = reader.deserialize(raw, conn.msgtype).header.stamp
            found.setdefault(conn.topic, []).append(stamp.sec * 10**9 + stamp.nanosec)
    return found
