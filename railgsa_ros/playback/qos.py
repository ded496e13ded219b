"""QoS for replayed topics from the recorded offered profiles, or by message type (no ROS).

A reader history overflows when the executor stalls (docs/nodes.md), so the depth holds one
second of the topic at the replay rate, and at least the recorded depth.
"""

from __future__ import annotations

from dataclasses import dataclass

from rosbags.interfaces import QosDurability, QosReliability

from railgsa_ros.bag.messages import history_depth
from railgsa_ros.playback.source import TopicInfo

#: Types replayed BEST_EFFORT when the bag records no QoS (high-rate sensor streams).
SENSOR_TYPES = frozenset({'sensor_msgs/msg/Imu'})
_DECIDED = (QosReliability.RELIABLE, QosReliability.BEST_EFFORT)
#: History window (s) the depth is sized for.
DEPTH_WINDOW_S = 1.0


@dataclass(frozen=True)
class QosChoice:
    """KEEP_LAST ``depth``; RELIABLE or BEST_EFFORT; TRANSIENT_LOCAL or VOLATILE."""

    reliable: bool
    depth: int
    transient_local: bool = False


def choose_qos(topic: TopicInfo, rate: float) -> QosChoice:
    """QoS for replaying ``topic`` at ``rate`` x real time.

    Recorded profiles decide reliability and durability when every publisher agreed (RELIABLE /
    TRANSIENT_LOCAL only if all were); without them sensor types are BEST_EFFORT, others RELIABLE.
    """
    depth = history_depth(topic.rate_hz * rate, DEPTH_WINDOW_S)
    known = [q for q in topic.offered_qos if q.reliability in _DECIDED]
    if not known:
        return QosChoice(topic.msgtype not in SENSOR_TYPES, depth)
    return QosChoice(
        reliable=all(q.reliability == QosReliability.RELIABLE for q in known),
        depth=max(depth, *(q.depth for q in known)),
        transient_local=all(q.durability == QosDurability.TRANSIENT_LOCAL for q in known))
