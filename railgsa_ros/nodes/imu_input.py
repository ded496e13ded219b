"""IMU and odometry intake shared by the railgsa nodes: raw subscriptions read by a thread.

Subscribes ``imu/data`` (depth ``imu_qos_depth``, ``imu_reliability``) and, with ``use_odom``,
``odom`` (``odom_reliability``, the same depth: odometry comes slower than the IMU, so its reader
covers at least as long a stall; a dropped odometry message makes IMU samples INVALID for want of
a speed, a decision that would then depend on the node's load).

Both are serialized (raw) subscriptions of the node itself: its name, namespace and remaps apply
as to any of its subscriptions, and no second node appears in the graph. No executor waits on
them: a reader thread waits on them alone and hands everything waiting over as one batch of bytes,
``on_input(imu, odom)`` (odometry first in the node's use), so a busy node works on growing
batches instead of falling behind and the 1 kHz stream never wakes the executor. Measured
cross-process at 1 kHz (docs/nodes.md): an rclpy executor dispatching raw messages to a callback
that does nothing costs a lifecycle node 25-28 % of a core; this thread, 6 %.
``period_s`` > 0 lets IMU messages wait for company: the messages taken are handed over once
``batch`` = round(``period_s`` x ``rate_hz``) IMU messages are in hand or the first of them has
waited ``period_s`` (a size-or-linger batch, as message brokers batch), or at once when more
arrived while the last batch was processed; 0 hands over whatever arrived, as it arrives. At
1 kHz and 2 ms the node works on pairs: the first sample of a pair waits one period, the
second none, where a fixed 2 ms period made a sample arriving just after a batch started wait
the full 2 ms. Waiting for a larger batch (uncertainty_node: 50 samples at 1 kHz) the thread
sleeps while the missing messages cannot have arrived at ``rate_hz`` instead of waking for
each. After ``idle_flush_s`` without input, ``on_idle()`` is called every ``idle_flush_s`` / 2
(at most 0.1 s).
``convert`` / ``odometry`` decode such batches vectorised (:mod:`imu_conversion`; rclpy's
deserialiser for other encodings), count and drop malformed messages; every input decision
(axis, frame policy, speed, noise, quality) is the core's
:class:`~railgsa_ros.input.stage.InputStage`. ``report`` is the 'imu input' diagnostic task.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack, suppress
import threading
import time
from typing import Any

from nav_msgs.msg import Odometry
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.type_support import check_is_valid_msg_type
from sensor_msgs.msg import Imu

from railgsa_ros.bag.cdr import Fallback
from railgsa_ros.bag.messages import flatten
from railgsa_ros.input.sanitize import REASONS
from railgsa_ros.nodes.diagnostics import OK, STALE, WARN, Report
from railgsa_ros.nodes.imu_conversion import ImuBatch, imu_batch, odometry_speeds
from railgsa_ros.nodes.qos import sensor_qos

MAX_BATCH = 5000  #: IMU messages handed over per batch at most
#: rejection reasons on /diagnostics: the core sanitiser's plus malformed messages
REJECT_REASONS = (*REASONS, 'malformed')
JOIN_TIMEOUT_S = 5.0  #: longest wait for the reader thread to finish its batch on stop


def deserializer(msg_cls: type) -> Fallback:
    """rclpy's general deserialiser as a ``cdr.decode_valid`` fallback for ``msg_cls``."""
    msgtype = f'{msg_cls.__module__.split(".")[0]}/msg/{msg_cls.__name__}'

    def read(raw: bytes) -> tuple:
        msg = deserialize_message(raw, msg_cls)
        stamp, strings, body = flatten(msg, msgtype)
        return stamp, int(msg.header.stamp.nanosec), strings, body
    return read


class RawSubscription:
    """A serialized subscription of ``node`` that no executor waits on (``take`` polls it)."""

    def __init__(self, node: Node, msg_cls: type, topic: str, qos: QoSProfile) -> None:
        check_is_valid_msg_type(msg_cls)  # imports the type support
        self.msg_cls = msg_cls
        with node.handle:
            self.handle = _rclpy.Subscription(node.handle, msg_cls, topic,
                                              qos.get_c_qos_profile())
        self.topic_name: str = self.handle.get_topic_name()

    def take(self, limit: int) -> list[bytes]:
        """Up to ``limit`` waiting messages (bytes), oldest first."""
        out: list[bytes] = []
        with self.handle:
            while len(out) < limit:
                taken = self.handle.take_message(self.msg_cls, True)
                if taken is None:
                    break
                out.append(taken[0])
        return out

    def destroy(self) -> None:
        self.handle.destroy_when_not_in_use()


class ImuIntake:
    """The raw IMU and odometry subscriptions, their reader thread and the conversion;
    ``counts`` holds received, malformed and odom_malformed."""

    def __init__(self, node: Node, values: Mapping[str, Any],
                 on_input: Callable[[list[bytes], list[bytes]], None],
                 on_idle: Callable[[], None], period_s: float = 0.0) -> None:
        self._node, self._on_input, self._on_idle = node, on_input, on_idle
        self.counts: Counter[str] = Counter()
        self.depth = int(values['imu_qos_depth'])  #: reader history, messages
        self.period_s = float(period_s)
        self.rate_hz = float(values['rate_hz'])
        self.batch = max(1, round(self.period_s * self.rate_hz))  #: IMU messages per batch
        self._held: tuple[list[bytes], list[bytes]] = ([], [])  # taken, not handed over yet
        self._idle_ns = int(min(0.1, values['idle_flush_s'] / 2) * 1e9)
        self.imu = RawSubscription(node, Imu, 'imu/data', sensor_qos(
            self.depth, values['imu_reliability']))
        self.odom = RawSubscription(node, Odometry, 'odom', sensor_qos(
            self.depth, values['odom_reliability'])) if values['use_odom'] else None
        self._fallback = {Imu: deserializer(Imu), Odometry: deserializer(Odometry)}
        self._wake = _rclpy.GuardCondition(node.context.handle)
        self._stopping = False
        self._thread = threading.Thread(target=self._read, daemon=True,
                                        name=f'{node.get_name()}_imu_reader')
        # before start: a signal may come at any line, also just after start (the build
        # interrupted, nobody but the shutdown left to stop the reader); stop() joins only a
        # reader that runs, and one that starts after it returns at once
        node.context.on_shutdown(self.stop)
        self._thread.start()

    # ------------------------------------------------------------------ reader thread
    def _read(self) -> None:
        subs = [s.handle for s in (self.imu, self.odom) if s is not None]
        try:
            wait_set = _rclpy.WaitSet(len(subs), 1, 0, 0, 0, 0, self._node.context.handle)
        except Exception:  # the context was shut down (a signal) before the thread ran
            return
        first = 0.0  # steady time at which the oldest held message was taken, s
        while not self._stopping and self._node.context.ok():  # ok(): no stop() after a signal
            try:
                imu, odom = self._held
                if imu or odom:  # wait for the rest of the batch, at most until its deadline
                    deadline = first + self.period_s
                    nap = min(deadline - time.monotonic(),
                              (self.batch - len(imu) - 1) / self.rate_hz)
                    if nap > 0:  # the missing messages cannot have arrived yet
                        self._wait(wait_set, [], int(nap * 1e9))
                    self._wait(wait_set, subs, max(0, int((deadline - time.monotonic()) * 1e9)))
                else:
                    self._wait(wait_set, subs, self._idle_ns)
                if self._stopping:
                    return
                had = bool(imu or odom)
                imu, odom = self.take(MAX_BATCH)
                now = time.monotonic()
                if not (imu or odom):
                    self._on_idle()
                    continue
                if not had:
                    first = now
                if len(imu) >= self.batch or now - first >= self.period_s or len(imu) >= MAX_BATCH:
                    self._held = ([], [])
                    self._on_input(imu, odom)
                else:
                    self._held = (imu, odom)
            except Exception as exc:  # the node must survive anything; the core is guarded
                if self._stopping or not self._node.context.ok():
                    return
                self._node.get_logger().error(f'imu reader: {exc!r}',
                                              throttle_duration_sec=1.0)
                time.sleep(0.01)

    def _wait(self, wait_set: Any, subs: list[Any], timeout_ns: int) -> None:
        """Wait until one of ``subs`` has a message, ``stop`` or ``timeout_ns``."""
        with ExitStack() as in_use:  # none is destroyed while waited on
            for handle in (self._wake, *subs):
                in_use.enter_context(handle)
            wait_set.clear_entities()
            for sub in subs:
                wait_set.add_subscription(sub)
            wait_set.add_guard_condition(self._wake)
            wait_set.wait(timeout_ns)

    def take(self, limit: int) -> tuple[list[bytes], list[bytes]]:
        """The messages held for a batch, then up to ``limit`` more waiting IMU messages and
        every waiting odometry message (the reader thread's, or after ``stop``)."""
        imu, odom = self._held
        self._held = ([], [])
        imu = imu + self.imu.take(limit)
        return imu, odom + ([] if self.odom is None else self.odom.take(self.depth))

    def stop(self) -> None:
        """Stop the reader thread (it finishes the batch in hand); idempotent."""
        if self._stopping:
            return
        self._stopping = True
        with suppress(Exception):  # a context already shut down ends the wait by itself
            self._wake.trigger_guard_condition()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(JOIN_TIMEOUT_S)

    def destroy(self) -> None:
        """Stop the thread and destroy the subscriptions."""
        self.stop()
        for sub in (self.imu, self.odom):
            if sub is not None:
                sub.destroy()
        self._wake.destroy_when_not_in_use()

    # ------------------------------------------------------------------ conversion
    def convert(self, raws: Sequence[bytes]) -> ImuBatch | None:
        """The well-formed messages of serialized Imu messages as arrays (counted: received,
        malformed); None if there is none."""
        self.counts['received'] += len(raws)
        if not raws:
            return None
        batch, bad = imu_batch(raws, self._fallback[Imu])
        self.counts['malformed'] += bad
        return batch if len(batch) else None

    def odometry(self, raws: Sequence[bytes]) -> tuple[Any, Any]:
        """(stamps ns, speeds m/s) of serialized Odometry messages; malformed ones counted as
        odom_malformed and left out."""
        stamps, speeds, bad = odometry_speeds(raws, self._fallback[Odometry])
        self.counts['odom_malformed'] += bad
        return stamps, speeds

    def report(self, totals: Mapping[str, int], delta: Mapping[str, int], elapsed_s: float,
               expected_frame_id: str) -> Report:
        """The 'imu input' task: STALE before the first message, WARN without input in the
        period or with rejections, gaps, time resets, samples later than the re-order window or
        accepted wrong frames in it, else OK;
        totals and period deltas."""
        values: dict[str, object] = {'topic': self.imu.topic_name,
                                     'rate_hz': delta.get('received', 0) / elapsed_s}
        for key in ('received', 'accepted', 'gap', 'reset', 'time_reset', 'bridged',
                    'wrong_frame_accepted', 'odom_received', 'odom_malformed', 'odom_nan',
                    'odom_implausible', 'odom_out_of_order', 'speed_unknown', 'reverse',
                    'gravity_invalid', 'rate_invalid', 'lost', 'jitter', 'speed_change',
                    'reordered', 'late'):
            values[key] = totals.get(key, 0)
        values['rejected'] = sum(totals.get(r, 0) for r in REJECT_REASONS)
        values.update({f'rejected_{r}': totals.get(r, 0) for r in REJECT_REASONS})
        recent = {r: delta[r] for r in (*REJECT_REASONS, 'gap', 'time_reset', 'late',
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
