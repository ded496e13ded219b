"""QoS for replayed topics from the recorded offered profiles, or by message type (no ROS).

A reader history overflows when the executor stalls (docs/nodes.md), so the depth holds one
second of the topic at the replay rate, and at least the recorded depth. ``reliable`` overrides
the reliability of every topic (as ``ros2 bag play --qos-profile-overrides-path``); the writer
history then holds RELIABLE_WINDOW_S at the replay rate (or the whole topic), so that reliable
flow control resends whatever a stalled reader missed instead of overwriting it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from rosbags.interfaces import QosDurability, QosReliability

from railgsa_ros.bag.messages import history_depth
from railgsa_ros.playback.source import TopicInfo

#: Types replayed BEST_EFFORT when the bag records no QoS (high-rate sensor streams).
SENSOR_TYPES = frozenset({'sensor_msgs/msg/Imu'})
_DECIDED = (QosReliability.RELIABLE, QosReliability.BEST_EFFORT)
#: History window (s) the depth is sized for.
DEPTH_WINDOW_S = 1.0
#: History window (s) of wall time with the RELIABLE override: the longest reader stall covered.
RELIABLE_WINDOW_S = 10.0


@dataclass(frozen=True)
class QosChoice:
    """KEEP_LAST ``depth``; RELIABLE or BEST_EFFORT; TRANSIENT_LOCAL or VOLATILE."""

    reliable: bool
    depth: int
    transient_local: bool = False


def choose_qos(topic: TopicInfo, rate: float, reliable: bool = False) -> QosChoice:
    """QoS for replaying ``topic`` at ``rate`` x real time.

    Recorded profiles decide reliability and durability when every publisher agreed (RELIABLE /
    TRANSIENT_LOCAL only if all were); without them sensor types are BEST_EFFORT, others RELIABLE.
    ``reliable``: RELIABLE for every topic, with a history of RELIABLE_WINDOW_S at ``rate``, at
    most the whole topic.
    """
    depth = history_depth(topic.rate_hz * rate, DEPTH_WINDOW_S)
    known = [q for q in topic.offered_qos if q.reliability in _DECIDED]
    if not known:
        choice = QosChoice(topic.msgtype not in SENSOR_TYPES, depth)
    else:
        choice = QosChoice(
            reliable=all(q.reliability == QosReliability.RELIABLE for q in known),
            depth=max(depth, *(q.depth for q in known)),
            transient_local=all(q.durability == QosDurability.TRANSIENT_LOCAL for q in known))
    if not reliable:
        return choice
    deep = min(topic.count, history_depth(topic.rate_hz * rate, RELIABLE_WINDOW_S))
    return replace(choice, reliable=True, depth=max(choice.depth, deep))
