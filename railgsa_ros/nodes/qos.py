"""The rclpy side of the package's QoS: ``railgsa_ros.qos`` decides, this module converts."""

from __future__ import annotations

from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from railgsa_ros import qos
from railgsa_ros.qos import OUTPUT_DEPTH, SENSOR_DEPTH, Profile


def to_rclpy(profile: Profile) -> QoSProfile:
    """The rclpy profile: the history, reliability and durability of ``profile``."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL if profile.keep_all else HistoryPolicy.KEEP_LAST,
        depth=profile.depth,
        reliability=ReliabilityPolicy.RELIABLE if profile.reliable
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if profile.transient_local
        else DurabilityPolicy.VOLATILE)


def from_rclpy(profile: QoSProfile) -> Profile:
    """The decision-relevant part of an rclpy profile (a publisher's offered QoS)."""
    return Profile(profile.reliability == ReliabilityPolicy.RELIABLE, profile.depth,
                   profile.durability == DurabilityPolicy.TRANSIENT_LOCAL,
                   profile.history == HistoryPolicy.KEEP_ALL)


def bag_record(profile: QoSProfile) -> Qos:
    """An rclpy profile as a rosbags Qos record, every field kept (the enums share values)."""
    def span(duration: Any) -> QosTime:
        return QosTime(*divmod(duration.nanoseconds, 1_000_000_000))
    return Qos(QosHistory(int(profile.history)), profile.depth,
               QosReliability(int(profile.reliability)), QosDurability(int(profile.durability)),
               span(profile.deadline), span(profile.lifespan),
               QosLiveliness(int(profile.liveliness)), span(profile.liveliness_lease_duration),
               profile.avoid_ros_namespace_conventions)


def sensor_qos(depth: int = SENSOR_DEPTH, reliability: str = 'best_effort') -> QoSProfile:
    """``qos.sensor`` in rclpy: for high-rate sensor inputs (imu, odom)."""
    return to_rclpy(qos.sensor(depth, reliability))


def output_qos(depth: int = OUTPUT_DEPTH, keep_all: bool = False) -> QoSProfile:
    """``qos.output`` in rclpy: for outputs (``keep_all``: the paced per-sample ones)."""
    return to_rclpy(qos.output(depth, keep_all))


#: /diagnostics: ``qos.DIAGNOSTICS``.
DIAGNOSTICS_QOS = to_rclpy(qos.DIAGNOSTICS)
