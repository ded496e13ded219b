"""The ROS side of ``railgsa check``: listen to a live system for a while and return an
:class:`railgsa_ros.health.Observation` (judged by ``railgsa_ros.health``, ROS-free).

A node of its own context subscribes the IMU (BEST_EFFORT, a deep history: nothing is lost at
1 kHz while the executor is busy), odometry and the nodes' per-sample outputs (BEST_EFFORT,
which matches RELIABLE publishers too). It first waits up to ``DISCOVERY_S`` for every topic to
have a publisher, then records for the requested duration, and finally reads the node names in
the graph. No ``main``: this module is not a node of its own (the ``railgsa check`` command
runs it).
"""

from __future__ import annotations

import math
import os
import time

from geometry_msgs.msg import PointStamped, Vector3Stamped
from nav_msgs.msg import Odometry
import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Imu

from railgsa_ros.health.checklist import NODE_OUTPUTS, Observation
from railgsa_ros.health.system_checks import TopicStats
from railgsa_ros.nodes.imu_conversion import NS_PER_S
from railgsa_ros.nodes.qos import sensor_qos

IMU_DEPTH = 5000  #: IMU reader history, samples (5 s at 1 kHz)
OUTPUT_DEPTH = 5000  #: output reader history (the band arrives in bursts)
ODOM_DEPTH = 100
DISCOVERY_S = 3.0  #: longest wait for the topics' publishers before recording starts


def _stamp_ns(msg: object) -> int:
    stamp = msg.header.stamp  # type: ignore[attr-defined]
    return stamp.sec * NS_PER_S + stamp.nanosec


class _Collector(Node):
    """Subscriptions that append what arrives; ``clear`` starts the recording window."""

    def __init__(self, imu_topic: str, odom_topic: str, context: Context) -> None:
        super().__init__(f'railgsa_check_{os.getpid()}', context=context)
        self.topics = [imu_topic, odom_topic, *NODE_OUTPUTS.values()]
        self.create_subscription(Imu, imu_topic, self._on_imu, sensor_qos(IMU_DEPTH))
        self.create_subscription(Odometry, odom_topic, self._on_odom, sensor_qos(ODOM_DEPTH))
        self.create_subscription(PointStamped, NODE_OUTPUTS['irregularity_node'],
                                 self._on_output, sensor_qos(OUTPUT_DEPTH))
        self.create_subscription(Vector3Stamped, NODE_OUTPUTS['uncertainty_node'],
                                 self._on_output, sensor_qos(OUTPUT_DEPTH))
        self.clear()

    def clear(self) -> None:
        self.imu: list[tuple[int, float, float, float]] = []
        self.odom: list[tuple[int, float]] = []
        self.outputs = {topic: [0, 0] for topic in NODE_OUTPUTS.values()}

    def _on_imu(self, msg: Imu) -> None:
        a = msg.linear_acceleration
        self.imu.append((_stamp_ns(msg), a.x, a.y, a.z))

    def _on_odom(self, msg: Odometry) -> None:
        self.odom.append((_stamp_ns(msg), msg.twist.twist.linear.x))

    def _on_output(self, msg: PointStamped | Vector3Stamped) -> None:
        if isinstance(msg, PointStamped):
            topic, values = NODE_OUTPUTS['irregularity_node'], (msg.point.x, msg.point.z)
        else:
            topic, values = NODE_OUTPUTS['uncertainty_node'], (msg.vector.x, msg.vector.y,
                                                                msg.vector.z)
        counts = self.outputs[topic]
        counts[0] += 1
        counts[1] += not all(math.isfinite(v) for v in values)

    def all_published(self) -> bool:
        return all(self.count_publishers(t) > 0 for t in self.topics)

    def observation(self, duration_s: float) -> Observation:
        imu = np.array(self.imu, float).reshape(-1, 4)
        odom = np.array(self.odom, float).reshape(-1, 2)
        return Observation(
            duration_s=duration_s,
            imu_stamps_ns=np.array([row[0] for row in self.imu], np.int64),
            imu_accel=imu[:, 1:],
            odom_stamps_ns=np.array([row[0] for row in self.odom], np.int64),
            odom_speed_mps=odom[:, 1],
            nodes=frozenset(name for name, _ in self.get_node_names_and_namespaces()),
            outputs={t: TopicStats(*c) for t, c in self.outputs.items()})


def _spin_until(executor: SingleThreadedExecutor, deadline: float, done=lambda: False) -> None:
    while time.monotonic() < deadline and not done():
        executor.spin_once(timeout_sec=min(0.1, max(deadline - time.monotonic(), 0.0)))


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
        return node.observation(duration_s)
    except ExternalShutdownException:
        raise KeyboardInterrupt from None
    finally:
        if node is not None:
            node.destroy_node()
        context.try_shutdown()
