"""IMU and odometry intake shared by the railgsa nodes: subscriptions and conversion only.

Subscribes ``imu/data`` (depth ``imu_qos_depth``, ``imu_reliability``) and, with ``use_odom``,
``odom`` (``odom_reliability``, the same depth: odometry comes slower than the IMU, so its reader
covers at least as long a stall; a dropped odometry message makes IMU samples INVALID for want of
a speed, a decision that would then depend on the node's load).
The IMU callback takes the message it was called for plus every message already waiting in the
reader history and hands them over as one list, so a busy node works on growing batches instead
of falling behind. ``convert`` turns such a list into arrays (malformed messages dropped and
counted); every input decision (axis, frame policy, speed, noise, quality) is the core's
:class:`~railgsa_ros.inverse.policy.InputPolicy`. ``report`` is the 'imu input' diagnostic task.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import Imu

from railgsa_ros.inverse.sanitize import REASONS
from railgsa_ros.nodes.diagnostics import OK, STALE, WARN, Report
from railgsa_ros.nodes.imu_conversion import ImuBatch, imu_batch, odom_speed
from railgsa_ros.nodes.qos import sensor_qos

MAX_BATCH = 2000  #: messages handed over per callback at most
#: rejection reasons on /diagnostics: the core sanitiser's plus malformed messages
REJECT_REASONS = (*REASONS, 'malformed')


class ImuIntake:
    """Subscriptions and conversion for the IMU and odometry; ``counts`` holds received,
    malformed and odom_malformed.

    With ``on_messages`` the IMU subscription calls it with every waiting message; without it
    the subscription belongs to a helper node ``<node>_imu_reader`` that no executor spins and
    the owner polls ``take()`` (the 1 kHz stream then never wakes the executor).
    ``on_odometry(stamp_ns, speed_mps)`` gets every odometry message with a valid stamp.
    """

    def __init__(self, node: Node, values: Mapping[str, Any],
                 on_messages: Callable[[list[Imu]], None] | None = None,
                 on_odometry: Callable[[int, float], None] | None = None) -> None:
        self._node = node
        self._on_messages = on_messages
        self._on_odometry = on_odometry
        self.counts: Counter[str] = Counter()
        self.depth = int(values['imu_qos_depth'])  #: reader history, messages
        self._reader = None if on_messages is not None else Node(
            f'{node.get_name()}_imu_reader', context=node.context,
            namespace=node.get_namespace())
        self.sub = (self._reader or node).create_subscription(
            Imu, 'imu/data', self._on_imu,
            sensor_qos(values['imu_qos_depth'], values['imu_reliability']))
        self._odom_sub = node.create_subscription(
            Odometry, 'odom', self._on_odom,
            sensor_qos(self.depth, values['odom_reliability'])) if values['use_odom'] else None

    def destroy(self) -> None:
        """Destroy the subscriptions (and the helper reader node)."""
        if self._reader is not None:
            self._reader.destroy_node()
        else:
            self._node.destroy_subscription(self.sub)
        if self._odom_sub is not None:
            self._node.destroy_subscription(self._odom_sub)

    def take(self, first: list[Imu] | None = None, limit: int = MAX_BATCH) -> list[Imu]:
        """``first`` plus the messages waiting in the reader history, ``limit`` at most; then
        every odometry message waiting goes to ``on_odometry`` first, so the policy knows the
        odometry that arrived with these IMU samples before it gets them: its speed decisions
        (odom_timeout_s) then depend on the stamps, not on how the executor interleaved the two
        topics (a batch of 2000 spans 2 s, more than the timeout)."""
        msgs = first or []
        handle = self.sub.handle
        with handle:
            while len(msgs) < limit:
                taken = handle.take_message(Imu, False)
                if taken is None:
                    break
                msgs.append(taken[0])
        self.take_odometry()
        return msgs

    def take_odometry(self) -> None:
        """Hand every odometry message waiting in its reader history to ``on_odometry``."""
        if self._odom_sub is None:
            return
        handle = self._odom_sub.handle
        while True:
            with handle:
                taken = handle.take_message(Odometry, False)
            if taken is None:
                return
            self._on_odom(taken[0])

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
        elif self._on_odometry is not None:
            self._on_odometry(*sample)

    def convert(self, msgs: Sequence[Any]) -> ImuBatch | None:
        """The well-formed messages of a list as arrays (counted: received, malformed); None if
        there is none."""
        self.counts['received'] += len(msgs)
        batch = imu_batch(msgs)
        bad = int(batch.malformed.sum())
        self.counts['malformed'] += bad
        if bad == len(batch):
            return None
        if not bad:
            return batch
        good = ~batch.malformed
        return ImuBatch(batch.stamps_ns[good], batch.accel[good], batch.frame_ids[good],
                        batch.covariance[good], batch.malformed[good])

    def report(self, totals: Mapping[str, int], delta: Mapping[str, int], elapsed_s: float,
               expected_frame_id: str) -> Report:
        """The 'imu input' task: STALE before the first message, WARN without input in the
        period or with rejections, gaps, time resets or accepted wrong frames in it, else OK;
        totals and period deltas."""
        values: dict[str, object] = {'topic': self.sub.topic_name,
                                     'rate_hz': delta.get('received', 0) / elapsed_s}
        for key in ('received', 'accepted', 'gap', 'reset', 'time_reset', 'bridged',
                    'wrong_frame_accepted', 'odom_received', 'odom_malformed', 'odom_nan',
                    'odom_implausible', 'odom_out_of_order', 'speed_unknown', 'reverse',
                    'gravity_invalid', 'rate_invalid'):
            values[key] = totals.get(key, 0)
        values['rejected'] = sum(totals.get(r, 0) for r in REJECT_REASONS)
        values.update({f'rejected_{r}': totals.get(r, 0) for r in REJECT_REASONS})
        recent = {r: delta[r] for r in (*REJECT_REASONS, 'gap', 'time_reset',
                                        'wrong_frame_accepted') if delta.get(r, 0)}
        values['last_period'] = ', '.join(f'{k} {v}' for k, v in recent.items()) or 'clean'
        values['expected_frame_id'] = expected_frame_id
        if totals.get('received', 0) == 0:
            return Report(STALE, 'no IMU input yet', values)
        if delta.get('received', 0) == 0:
            return Report(WARN, 'no IMU input in the last period', values)
        if recent:
            return Report(WARN, f'bad input in the last period: {values["last_period"]}', values)
        return Report(OK, 'receiving', values)
