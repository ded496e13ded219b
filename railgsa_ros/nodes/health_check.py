"""The ROS side of ``railgsa check``: listen to a live system for a while and return an
:class:`railgsa_ros.health.Observation` (judged by ``railgsa_ros.health``, ROS-free).

A node of its own context subscribes the IMU (BEST_EFFORT, a deep history: nothing is lost at
1 kHz while the executor is busy), odometry and the nodes' per-sample outputs (BEST_EFFORT,
which matches RELIABLE publishers too). The subscriptions are raw: a callback only keeps the
CDR bytes, decoded vectorised at the end (``bag.cdr``), so that the check keeps up with 1 kHz
streams on a loaded computer. It first waits up to ``DISCOVERY_S`` for every topic to have a
publisher, then records for the requested duration, takes what is still queued, and reads the
node names in the graph. No ``main``: ``railgsa check`` runs it.
"""

from __future__ import annotations

import os
import time

from geometry_msgs.msg import PointStamped, Vector3Stamped
from nav_msgs.msg import Odometry
import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu

from railgsa_ros.bag.cdr import Decoded, decode
from railgsa_ros.bag.messages import FIELDS, LAYOUTS, flatten
from railgsa_ros.health.checklist import NODE_OUTPUTS, Observation
from railgsa_ros.health.system_checks import output_stats
from railgsa_ros.nodes.qos import sensor_qos

DEPTH = 5000  #: reader history of every subscription, messages (5 s at 1 kHz)
DISCOVERY_S = 3.0  #: longest wait for the topics' publishers before recording starts
DRAIN_S = 2.0  #: longest time spent taking what is still queued after the window
TYPES = {'imu': Imu, 'odom': Odometry, NODE_OUTPUTS['irregularity_node']: PointStamped,
         NODE_OUTPUTS['uncertainty_node']: Vector3Stamped}


def decode_messages(msg_cls: type, raws: list[bytes]) -> Decoded:
    """Vectorised CDR decoding; rclpy's deserialiser for anything else (other encodings)."""
    msgtype = msg_cls.__module__.split('.')[0] + '/msg/' + msg_cls.__name__
    try:
        return decode(LAYOUTS[msgtype], raws)
    except ValueError:
        rows = [flatten(deserialize_message(raw, msg_cls), msgtype) for raw in raws]
        layout = LAYOUTS[msgtype]
        return Decoded(np.array([r[0] for r in rows], np.int64),
                       tuple(np.array([r[1][j] for r in rows], dtype=str)
                             for j in range(layout.n_strings)),
                       np.array([r[2] for r in rows], float).reshape(-1, layout.n_doubles))


def _column(msg_cls: type, field: str) -> slice:
    return FIELDS[msg_cls.__module__.split('.')[0] + '/msg/' + msg_cls.__name__][field]


class _Collector(Node):
    """Raw subscriptions that keep the bytes; ``clear`` starts the recording window."""

    def __init__(self, imu_topic: str, odom_topic: str, context: Context) -> None:
        super().__init__(f'railgsa_check_{os.getpid()}', context=context)
        self.topics = {'imu': imu_topic, 'odom': odom_topic,
                       **{t: t for t in NODE_OUTPUTS.values()}}
        self.raws: dict[str, list[bytes]] = {key: [] for key in self.topics}
        for key, topic in self.topics.items():
            self.create_subscription(TYPES[key], topic, self.raws[key].append,
                                     sensor_qos(DEPTH), raw=True)

    def clear(self) -> None:
        for raws in self.raws.values():
            raws.clear()

    def received(self) -> int:
        return sum(map(len, self.raws.values()))

    def all_published(self) -> bool:
        return all(self.count_publishers(t) > 0 for t in self.topics.values())

    def observation(self, duration_s: float) -> Observation:
        imu = decode_messages(Imu, self.raws['imu'])
        odom = decode_messages(Odometry, self.raws['odom'])
        outputs = {}
        for topic in NODE_OUTPUTS.values():
            values = decode_messages(TYPES[topic], self.raws[topic]).values
            outputs[topic] = output_stats(values, TYPES[topic] is PointStamped)
        return Observation(
            duration_s=duration_s, imu_stamps_ns=imu.stamps_ns,
            imu_accel=imu.values[:, _column(Imu, 'linear_acceleration')],
            odom_stamps_ns=odom.stamps_ns,
            odom_speed_mps=odom.values[:, _column(Odometry, 'twist.twist.linear')][:, 0],
            nodes=frozenset(name for name, _ in self.get_node_names_and_namespaces()),
            outputs=outputs)


def _spin_until(executor: SingleThreadedExecutor, deadline: float, done=lambda: False) -> None:
    while time.monotonic() < deadline and not done():
        executor.spin_once(timeout_sec=min(0.1, max(deadline - time.monotonic(), 0.0)))


def _drain(executor: SingleThreadedExecutor, node: _Collector) -> None:
    """Take the messages still queued when the window closed: one callback at a time until a
    call finds nothing ready (taking is far faster than a 1 kHz stream refills the queue),
    DRAIN_S at most."""
    deadline = time.monotonic() + DRAIN_S
    while time.monotonic() < deadline:
        count = node.received()
        executor.spin_once(timeout_sec=0.0)
        if node.received() == count:
            return


def collect(imu_topic: str, odom_topic: str, duration_s: float) -> Observation:
    """Record ``duration_s`` seconds of a live system (after up to DISCOVERY_S of discovery).

    Ctrl-C raises KeyboardInterrupt (the CLI exits 130).
    """
    context = Context()
    rclpy.init(context=context)
    node = None
    try:
        node = _Collector(imu_topic, odom_topic, context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        _spin_until(executor, time.monotonic() + DISCOVERY_S, node.all_published)
        node.clear()
        _spin_until(executor, time.monotonic() + duration_s)
        _drain(executor, node)
        return node.observation(duration_s)
    except ExternalShutdownException:
        raise KeyboardInterrupt from None
    finally:
        if node is not None:
            node.destroy_node()
        context.try_shutdown()
