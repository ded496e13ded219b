"""IMU and odometry intake shared by the railgsa nodes.

Subscribes ``imu/data`` (depth ``imu_qos_depth``, ``imu_reliability``) and, with ``use_odom``,
``odom`` (``odom_reliability``).
The IMU callback takes the message it was called for plus every message already waiting in the
reader history and hands them over as one list, so a busy node works on growing batches instead
of falling behind. ``prepare`` turns such a list into arrays for a core ``push``: malformed
messages dropped and counted, the frame policy applied (warned once), the vertical axis picked
and the speed chosen (fresh odometry, else ``speed_mps``). ``report`` is the 'imu input'
diagnostic task.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from nav_msgs.msg import Odometry
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Imu

from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import vertical
from railgsa_ros.inverse.sanitize import REASONS, frame_mask
from railgsa_ros.nodes.diagnostics import ERROR, OK, WARN, Report
from railgsa_ros.nodes.imu_conversion import NS_PER_S, imu_batch, odom_speed
from railgsa_ros.nodes.qos import sensor_qos

MAX_BATCH = 2000  #: messages handed over per callback at most
ODOM_DEPTH = 50
#: rejection reasons on /diagnostics: the core sanitiser's plus malformed messages
REJECT_REASONS = (*REASONS, 'malformed')


@dataclass(frozen=True)
class Samples:
    """Well-formed samples of one batch: stamps_ns (N,) int64, accel_up (N,) upward specific
    force in m/s^2 (+g at rest), speed_mps (m/s), frame_ids (N,) for the core to check (None
    when the policy accepts any frame) and the first IMU-reported variance of the vertical axis
    in (m/s^2)^2 (None if absent or unknown)."""

    stamps_ns: np.ndarray
    accel_up: np.ndarray
    speed_mps: float
    frame_ids: np.ndarray | None
    reported_variance: float | None


class ImuIntake:
    """Subscriptions and conversion for the IMU and odometry; ``counts`` holds received,
    malformed, wrong_frame_accepted and odom_malformed.

    With ``on_messages`` the IMU subscription calls it with every waiting message; without it
    the subscription belongs to a helper node ``<node>_imu_reader`` that no executor spins and
    the owner polls ``take()`` (the 1 kHz stream then never wakes the executor).
    """

    def __init__(self, node: Node, values: Mapping[str, Any],
                 on_messages: Callable[[list[Imu]], None] | None = None) -> None:
        self._node = node
        self._on_messages = on_messages
        self.counts: Counter[str] = Counter()
        self.depth = int(values['imu_qos_depth'])  #: reader history, messages
        self.odom: tuple[int, float] | None = None  #: newest (stamp ns, speed m/s)
        self.odom_missing = False  #: use_odom but no fresh odometry at the last batch
        self.speed_mps = float(values['speed_mps'])  #: speed used for the last batch
        self._reader = None if on_messages is not None else Node(
            f'{node.get_name()}_imu_reader', context=node.context,
            namespace=node.get_namespace())
        self.sub = (self._reader or node).create_subscription(
            Imu, 'imu/data', self._on_imu,
            sensor_qos(values['imu_qos_depth'], values['imu_reliability']))
        self._odom_sub = node.create_subscription(
            Odometry, 'odom', self._on_odom,
            sensor_qos(ODOM_DEPTH, values['odom_reliability'])) if values['use_odom'] else None

    def destroy(self) -> None:
        """Destroy the subscriptions (and the helper reader node)."""
        if self._reader is not None:
            self._reader.destroy_node()
        else:
            self._node.destroy_subscription(self.sub)
        if self._odom_sub is not None:
            self._node.destroy_subscription(self._odom_sub)

    def take(self, first: list[Imu] | None = None, limit: int = MAX_BATCH) -> list[Imu]:
        """``first`` plus the messages waiting in the reader history, ``limit`` at most."""
        msgs = first or []
        handle = self.sub.handle
        with handle:
            while len(msgs) < limit:
                taken = handle.take_message(Imu, False)
                if taken is None:
                    break
                msgs.append(taken[0])
        return msgs

    def take_waiting(self) -> list[Imu]:
        """The messages waiting now, at most one reader history (bounded while a burst still
        comes in: for the last batch before deactivate and shutdown)."""
        return self.take(limit=self.depth)

    def _on_imu(self, msg: Imu) -> None:
        if self._on_messages is not None:
            self._on_messages(self.take([msg]))

    def _on_odom(self, msg: Odometry) -> None:
        sample = odom_speed(msg)
        if sample is None:
            self.counts['odom_malformed'] += 1
        elif self.odom is None or sample[0] >= self.odom[0]:
            self.odom = sample

    def prepare(self, msgs: Sequence[Any], config: InversionConfig,
                values: Mapping[str, Any]) -> Samples | None:
        """Arrays for the core from a list of Imu messages; None if none is well-formed."""
        self.counts['received'] += len(msgs)
        batch = imu_batch(msgs)
        self.counts['malformed'] += int(batch.malformed.sum())
        good = ~batch.malformed
        if not good.any():
            return None
        stamps, frames = batch.stamps_ns[good], batch.frame_ids[good]
        reject = values['wrong_frame_policy'] == 'reject'
        matches = frame_mask(frames, config.frame_id)
        if matches is not None and not matches.all():
            self._node.get_logger().warning(
                f'IMU frame_id {frames[~matches][0]!r} is not {config.frame_id!r}: samples are '
                f'{"rejected" if reject else "accepted"}', once=True)
            if not reject:
                self.counts['wrong_frame_accepted'] += int((~matches).sum())
        variance = batch.accel_var[good, 'xyz'.index(config.accel_axis[-1])]
        variance = variance[np.isfinite(variance)]
        return Samples(stamps, vertical(batch.accel[good], config.accel_axis),
                       self._speed_for(int(stamps[-1]), values),
                       frames if reject else None,
                       float(variance[0]) if variance.size else None)

    def _speed_for(self, stamp_ns: int, values: Mapping[str, Any]) -> float:
        """Newest odometry speed if fresh (m/s), else the speed_mps parameter."""
        odom = self.odom
        fresh = odom is not None and stamp_ns - odom[0] <= values['odom_timeout_s'] * NS_PER_S
        self.odom_missing = bool(values['use_odom']) and not fresh
        self.speed_mps = odom[1] if fresh else float(values['speed_mps'])
        return self.speed_mps

    def report(self, totals: Mapping[str, int], delta: Mapping[str, int], elapsed_s: float,
               expected_frame_id: str) -> Report:
        """The 'imu input' task: ERROR without input in the period, WARN with rejections, gaps,
        time resets or accepted wrong frames in it, else OK; totals and period deltas."""
        values: dict[str, object] = {'topic': self.sub.topic_name,
                                     'rate_hz': delta.get('received', 0) / elapsed_s}
        for key in ('received', 'accepted', 'gap', 'reset', 'time_reset', 'bridged',
                    'wrong_frame_accepted', 'odom_malformed'):
            values[key] = totals.get(key, 0)
        values['rejected'] = sum(totals.get(r, 0) for r in REJECT_REASONS)
        values.update({f'rejected_{r}': totals.get(r, 0) for r in REJECT_REASONS})
        recent = {r: delta[r] for r in (*REJECT_REASONS, 'gap', 'time_reset',
                                        'wrong_frame_accepted') if delta.get(r, 0)}
        values['last_period'] = ', '.join(f'{k} {v}' for k, v in recent.items()) or 'clean'
        values['expected_frame_id'] = expected_frame_id
        if delta.get('received', 0) == 0:
            return Report(ERROR, 'no IMU input', values)
        if recent:
            return Report(WARN, f'bad input in the last period: {values["last_period"]}', values)
        return Report(OK, 'receiving', values)
