"""Odometry and node checks: odom arrives with a finite speed, the nodes are in the graph and
their output topics publish finite values, except where a sample is flagged INVALID (README, "How
consumers read quality": PointStamped point.y = 2 with point.z NaN; a band NaN in x, y and z)."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from railgsa_ros.health.items import FAIL, PASS, WARN, Item

ODOM_MIN_HZ = 1.0  #: slower odometry goes stale (odom_timeout_s defaults to 1 s)
OUTPUT_MIN_FRACTION = 0.5  #: output rate / IMU rate below which an output WARNs


INVALID = 2  #: quality code of an INVALID sample in PointStamped point.y


@dataclass(frozen=True)
class TopicStats:
    """Messages received on an output topic, how many carried a NaN or inf that the quality
    encoding does not explain (a bug), and how many were flagged INVALID."""

    count: int = 0
    nonfinite: int = 0
    invalid: int = 0


def output_stats(values: np.ndarray, quality_in_y: bool) -> TopicStats:
    """Stats of output messages ``values`` (K, 3): x, y, z of a PointStamped (``quality_in_y``:
    y is the quality code, z NaN when INVALID) or of a band Vector3Stamped (NaN in all three when
    INVALID)."""
    values = np.asarray(values, float).reshape(-1, 3)
    if quality_in_y:
        invalid = (values[:, 1] == INVALID) & np.isnan(values[:, 2]) & np.isfinite(values[:, 0])
    else:
        invalid = np.isnan(values).all(axis=1)
    bad = ~np.isfinite(values).all(axis=1) & ~invalid
    return TopicStats(len(values), int(bad.sum()), int(invalid.sum()))


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
    """``topic`` publishes only finite values or flagged INVALID samples, at about
    ``imu_rate_hz`` (the IMU messages that arrived per second: one output per IMU sample)."""
    name = f'output {topic}'
    expected = f'~{imu_rate_hz:.0f} Hz (IMU received), finite' if imu_rate_hz > 0 else 'finite'
    rate = stats.count / duration_s
    value = f'{rate:.1f} Hz, {stats.nonfinite} non-finite, {stats.invalid} flagged invalid'
    if stats.count == 0:
        return Item(name, FAIL, 'no messages', expected,
                    'the node is not publishing: no input, or not active')
    if stats.nonfinite:
        return Item(name, FAIL, value, expected,
                    'NaN or inf not flagged INVALID in the output: report a bug')
    if stats.invalid == stats.count:
        return Item(name, WARN, value, expected,
                    'every output flagged INVALID: standstill, or see the node\'s /diagnostics '
                    '"input checks"')
    if rate < OUTPUT_MIN_FRACTION * imu_rate_hz:
        return Item(name, WARN, value, expected, 'the node falls behind the IMU')
    return Item(name, PASS, value, expected)
