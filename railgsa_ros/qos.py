"""Every QoS decision of the package, as plain data (no ROS): ``nodes/qos.py`` converts to rclpy.

Measured in rclpy (docs/nodes.md): a 1 kHz IMU stream through a reader history of depth 5 (the
stock sensor-data profile) loses 2-8 % of the samples whenever the executor stalls, so inputs use
a depth of at least 300 (default 1000, one second at 1 kHz). BEST_EFFORT subscriptions match both
BEST_EFFORT and RELIABLE publishers; RELIABLE outputs serve both kinds of subscriber. An input may
be RELIABLE instead (a replay faster than real time): a sample the process cannot take in time is
then resent instead of dropped in the transport, but only a RELIABLE publisher matches it.

Replay: the depth holds one second of the topic at the replay rate, and at least the recorded
depth. ``reliable`` overrides the reliability of every topic (as ``ros2 bag play
--qos-profile-overrides-path``); the writer history then holds RELIABLE_WINDOW_S at the replay
rate (or the whole topic), so that reliable flow control resends whatever a stalled reader missed
instead of overwriting it. Recording subscribes with the publishers' reliability and durability
and a KEEP_ALL history: a RELIABLE message the recorder has no room for is not acknowledged, so
its writer resends it (KEEP_LAST would overwrite the oldest one unwritten and acknowledge anyway).

Per-sample outputs are KEEP_ALL (``output(keep_all=True)``): the writer never overwrites a
message a reader has not acknowledged; a publish into a history full of unacknowledged messages
waits (Fast DDS: 5000 messages, at most 100 ms) and then fails, and the node's pacer retries it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
import math
from typing import TYPE_CHECKING

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

if TYPE_CHECKING:
    from railgsa_ros.playback.source import TopicInfo

#: Reader history for 1 kHz inputs, in samples (one second).
SENSOR_DEPTH = 1000
#: Writer history for per-sample outputs, in samples (one second at 1 kHz).
OUTPUT_DEPTH = 1000
#: Minimum history depth accepted for a 1 kHz input.
MIN_SENSOR_DEPTH = 300
#: Values of the nodes' input reliability parameters, the live-sensor choice first.
RELIABILITIES = ('best_effort', 'reliable')
#: Types replayed BEST_EFFORT when the bag records no QoS (high-rate sensor streams).
SENSOR_TYPES = frozenset({'sensor_msgs/msg/Imu'})
#: History window (s) a replayed topic's depth is sized for.
DEPTH_WINDOW_S = 1.0
#: History window (s) of wall time with the RELIABLE replay override: the longest reader stall
#: covered.
RELIABLE_WINDOW_S = 10.0
_DECIDED = (QosReliability.RELIABLE, QosReliability.BEST_EFFORT)
_ZERO = QosTime(0, 0)


@dataclass(frozen=True)
class Profile:
    """KEEP_LAST ``depth`` (KEEP_ALL with ``keep_all``); RELIABLE or BEST_EFFORT;
    TRANSIENT_LOCAL or VOLATILE."""

    reliable: bool
    depth: int
    transient_local: bool = False
    keep_all: bool = False


def history_depth(rate_hz: float, window_s: float = 1.0) -> int:
    """KEEP_LAST depth holding ``window_s`` of messages at ``rate_hz`` (>= 10): 1000 at 1 kHz."""
    return max(10, math.ceil(rate_hz * window_s))


def record_qos(reliable: bool, depth: int) -> Qos:
    """A rosbag2 offered-QoS record: KEEP_LAST ``depth``, VOLATILE, RELIABLE or BEST_EFFORT."""
    reliability = QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT
    return Qos(QosHistory.KEEP_LAST, int(depth), reliability, QosDurability.VOLATILE,
               _ZERO, _ZERO, QosLiveliness.AUTOMATIC, _ZERO, False)


def sensor(depth: int = SENSOR_DEPTH, reliability: str = 'best_effort') -> Profile:
    """High-rate sensor inputs (imu, odom): VOLATILE, BEST_EFFORT (RELIABLE with
    ``reliability`` 'reliable')."""
    return Profile(reliability == 'reliable', depth)


def output(depth: int = OUTPUT_DEPTH, keep_all: bool = False) -> Profile:
    """Outputs: RELIABLE, VOLATILE; ``keep_all``: KEEP_ALL, the writer never overwrites a
    message a reader has not acknowledged (a publish waits instead, bounded)."""
    return Profile(True, depth, keep_all=keep_all)


#: /diagnostics: RELIABLE, depth 10 (one array a second).
DIAGNOSTICS = output(10)
#: /clock, as ros2 bag play: RELIABLE, KEEP_LAST 1 (use_sim_time subscribers are BEST_EFFORT).
CLOCK = Profile(True, 1)


def replay(topic: TopicInfo, rate: float, reliable: bool = False) -> Profile:
    """Writer QoS for replaying ``topic`` at ``rate`` x real time.

    Recorded profiles decide reliability and durability when every publisher agreed (RELIABLE /
    TRANSIENT_LOCAL only if all were); without them sensor types are BEST_EFFORT, others RELIABLE.
    ``reliable``: RELIABLE for every topic, with a history of RELIABLE_WINDOW_S at ``rate``, at
    most the whole topic.
    """
    depth = history_depth(topic.rate_hz * rate, DEPTH_WINDOW_S)
    known = [q for q in topic.offered_qos if q.reliability in _DECIDED]
    if not known:
        choice = Profile(topic.msgtype not in SENSOR_TYPES, depth)
    else:
        choice = Profile(
            reliable=all(q.reliability == QosReliability.RELIABLE for q in known),
            depth=max(depth, *(q.depth for q in known)),
            transient_local=all(q.durability == QosDurability.TRANSIENT_LOCAL for q in known))
    if not reliable:
        return choice
    deep = min(topic.count, history_depth(topic.rate_hz * rate, RELIABLE_WINDOW_S))
    return replace(choice, reliable=True, depth=max(choice.depth, deep))


def recording(offered: Sequence[Profile], depth: int = 0) -> Profile:
    """Reader QoS for recording a topic its publishers offer with ``offered``: KEEP_ALL (a
    RELIABLE writer then keeps and resends what the recorder has no room for yet), or KEEP_LAST
    ``depth`` when ``depth`` > 0; RELIABLE only if every publisher is; TRANSIENT_LOCAL only if
    every publisher is."""
    return Profile(all(p.reliable for p in offered), max(depth, 1),
                   all(p.transient_local for p in offered), keep_all=depth <= 0)
