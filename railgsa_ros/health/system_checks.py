"""Odometry and node checks: odom arrives with a finite speed, the nodes are in the graph and
their output topics publish finite values."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from railgsa_ros.health.items import FAIL, PASS, WARN, Item

ODOM_MIN_HZ = 1.0  #: slower odometry goes stale (odom_timeout_s defaults to 1 s)
OUTPUT_MIN_FRACTION = 0.5  #: output rate / IMU rate below which an output WARNs


@dataclass(frozen=True)
class TopicStats:
    """Messages received on an output topic and how many carried a NaN or inf."""

    count: int = 0
    nonfinite: int = 0


def odom_item(stamps_ns: np.ndarray, speed_mps: np.ndarray, duration_s: float) -> Item:
    """Odometry rate (messages per second of collection) and its last speed."""
    expected = f'>= {ODOM_MIN_HZ:g} Hz, finite speed'
    count = len(stamps_ns)
    if count == 0:
        return Item('odometry', FAIL, 'no messages', expected,
                    'no odom: the nodes fall back to the speed_mps parameter')
    speed = np.asarray(speed_mps, float)
    rate = count / duration_s
    value = f'{rate:.1f} Hz, speed {speed[-1]:.3g} m/s'
    if not np.isfinite(speed).all():
        return Item('odometry', FAIL, value, expected,
                    f'{int(np.sum(~np.isfinite(speed)))} speeds are NaN or inf')
    if rate < ODOM_MIN_HZ:
        return Item('odometry', WARN, value, expected,
                    'odometry slower than odom_timeout_s: the nodes use speed_mps in between')
    return Item('odometry', PASS, value, expected)


def node_item(name: str, nodes: Collection[str]) -> Item:
    """``name`` is in the ROS graph (any namespace)."""
    if name in nodes:
        return Item(f'node {name}', PASS, 'running', 'running')
    return Item(f'node {name}', FAIL, 'not in the graph', 'running',
                f'start it (python -m railgsa_ros.nodes.{name}) and check ROS_DOMAIN_ID')


def output_item(topic: str, stats: TopicStats, duration_s: float, imu_rate_hz: float) -> Item:
    """``topic`` publishes only finite values, at about ``imu_rate_hz`` (the IMU messages that
    arrived per second: one output per IMU sample)."""
    name = f'output {topic}'
    expected = f'~{imu_rate_hz:.0f} Hz (IMU received), finite' if imu_rate_hz > 0 else 'finite'
    rate = stats.count / duration_s
    value = f'{rate:.1f} Hz, {stats.nonfinite} non-finite'
    if stats.count == 0:
        return Item(name, FAIL, 'no messages', expected,
                    'the node is not publishing: no input, or not active')
    if stats.nonfinite:
        return Item(name, FAIL, value, expected, 'NaN or inf in the output: report a bug')
    if rate < OUTPUT_MIN_FRACTION * imu_rate_hz:
        return Item(name, WARN, value, expected, 'the node falls behind the IMU')
    return Item(name, PASS, value, expected)
