"""QoS profiles shared by the railgsa nodes.

Measured in rclpy (docs/nodes.md): a 1 kHz IMU stream through a reader history of depth 5 (the
stock sensor-data profile) loses 2-8 % of the samples whenever the executor stalls, so inputs use
a depth of at least 300 (default 1000, one second at 1 kHz). BEST_EFFORT subscriptions match both
BEST_EFFORT and RELIABLE publishers; RELIABLE outputs serve both kinds of subscriber. An input may
be RELIABLE instead (a replay faster than real time): a sample the process cannot take in time is
then resent instead of dropped in the transport, but only a RELIABLE publisher matches it.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Reader history for 1 kHz inputs, in samples (one second).
SENSOR_DEPTH = 1000
#: Writer history for per-sample outputs, in samples (one second at 1 kHz).
OUTPUT_DEPTH = 1000
#: Minimum history depth accepted for a 1 kHz input.
MIN_SENSOR_DEPTH = 300
#: Values of the nodes' input reliability parameters, the live-sensor choice first.
RELIABILITIES = ('best_effort', 'reliable')


def sensor_qos(depth: int = SENSOR_DEPTH, reliability: str = 'best_effort') -> QoSProfile:
    """KEEP_LAST ``depth``, VOLATILE, BEST_EFFORT (or RELIABLE with ``reliability`` 'reliable'):
    for high-rate sensor inputs (imu, odom)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliability == 'reliable'
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def output_qos(depth: int = OUTPUT_DEPTH) -> QoSProfile:
    """RELIABLE, KEEP_LAST ``depth``, VOLATILE: for the per-sample outputs."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


#: /diagnostics: RELIABLE, depth 10 (one array a second).
DIAGNOSTICS_QOS = output_qos(10)
