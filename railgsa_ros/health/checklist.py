"""The whole checklist from one :class:`Observation` of a live system."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from railgsa_ros.health.imu_checks import (
    gravity_item,
    jitter_item,
    monotonic_item,
    noise_item,
    rate_item,
)
from railgsa_ros.health.items import Item
from railgsa_ros.health.system_checks import TopicStats, node_item, odom_item, output_item
from railgsa_ros.imu import ImuSpec

#: node name -> its per-sample output topic (relative)
NODE_OUTPUTS = {'irregularity_node': 'track/irregularity',
                'uncertainty_node': 'track/irregularity_band'}


@dataclass(frozen=True)
class Observation:
    """What the collector saw in ``duration_s`` seconds: IMU stamps (N,) int64 ns and accel
    (N, 3) m/s^2 in arrival order, odometry stamps (M,) ns and speeds (M,) m/s, the node names
    in the graph and the output topics' statistics."""

    duration_s: float
    imu_stamps_ns: np.ndarray
    imu_accel: np.ndarray
    odom_stamps_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    odom_speed_mps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    nodes: frozenset[str] = frozenset()
    outputs: Mapping[str, TopicStats] = field(default_factory=dict)


def checklist(obs: Observation, spec: ImuSpec, rate_hz: float | None = None) -> list[Item]:
    """Every item, in the order a technician reads them; ``rate_hz`` defaults to the preset's
    output rate."""
    rate_hz = spec.output_rate_hz if rate_hz is None else rate_hz
    stamps, accel = obs.imu_stamps_ns, obs.imu_accel
    received_hz = len(stamps) / obs.duration_s  # the outputs follow what arrives
    items = [rate_item(stamps, rate_hz, obs.duration_s), jitter_item(stamps, rate_hz),
             monotonic_item(stamps), gravity_item(accel), noise_item(stamps, accel, spec),
             odom_item(obs.odom_stamps_ns, obs.odom_speed_mps, obs.duration_s)]
    for node, topic in NODE_OUTPUTS.items():
        items.append(node_item(node, obs.nodes))
        items.append(output_item(topic, obs.outputs.get(topic, TopicStats()), obs.duration_s,
                                 received_hz))
    return items
