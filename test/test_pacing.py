"""The output pacer against a writer that refuses messages (issue 22): a KEEP_ALL writer full of
unacknowledged messages makes rclpy's publish raise RCLError after Fast DDS's 100 ms. The
refused message must stay first in the queue and go out later, in order, exactly once;
``published`` counts only what the writer took; only a queue beyond QUEUE_LIMIT drops, counted.

Independent truth: the header stamps decoded from the published bytes by rosbags."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from railgsa_ros.bag.messages import POINT_STAMPED, typestore

pytestmark = pytest.mark.ros
TS = typestore()


class RefusingWriter:
    """A publisher stand-in: ``handle.publish_raw`` keeps the bytes, except that the calls
    numbered in ``refuse`` (0-based, counting refused ones) raise RCLError as a full KEEP_ALL
    writer does."""

    topic_name = '/track/irregularity'

    def __init__(self, refuse: Callable[[int], bool]) -> None:
        self.refuse, self.calls, self.sent = refuse, 0, []
        self.handle = self

    def __enter__(self) -> RefusingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def publish_raw(self, data: bytes) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation

        call, self.calls = self.calls, self.calls + 1
        if self.refuse(call):
            raise rclpy_implementation.RCLError('cannot publish data')
        self.sent.append(data)

    def wait_for_all_acked(self, _timeout: Any) -> bool:
        return True

    def stamps(self) -> list[int]:
        """Header stamps (ns) of the messages taken, decoded by rosbags."""
        out = []
        for data in self.sent:
            stamp = TS.deserialize_cdr(data, POINT_STAMPED.msgtype).header.stamp
            out.append(stamp.sec * 10**9 + stamp.nanosec)
        return out


def _pacer(ros_context: Any, writer: RefusingWriter, flush_rate_hz: float = 1e6) -> Any:
    import threading

    from rclpy.node import Node

    from railgsa_ros.nodes.pacing import OutputPacer

    node = Node('pacer_test', context=ros_context)
    return node, OutputPacer(node, writer, POINT_STAMPED, 'track', 1000, flush_rate_hz,
                             threading.RLock())


def _columns(n: int) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    stamps = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 1_000_000
    return stamps, (np.arange(n, dtype=float), np.zeros(n), np.ones(n))


def test_a_refused_message_is_retried_in_order_and_counted(ros_context: Any,
                                                            monkeypatch: Any) -> None:
    from railgsa_ros.nodes import pacing

    monkeypatch.setattr(pacing, 'BLOCKED_BACKOFF_S', 0.0)
    writer = RefusingWriter(lambda call: call in (3, 4, 40, 41, 42))
    node, pacer = _pacer(ros_context, writer)
    try:
        stamps, xyz = _columns(300)
        pacer.put(stamps[:100], tuple(c[:100] for c in xyz), live=100)
        pacer.put(stamps[100:], tuple(c[100:] for c in xyz), live=0)  # a flush
        for _ in range(100):
            if not pacer.pending:
                break
            pacer.drain()
        assert writer.stamps() == stamps.tolist()  # each once, in order
        assert (pacer.published, pacer.blocked, pacer.dropped) == (300, 5, 0)
    finally:
        pacer.destroy()
        node.destroy_node()


def test_finish_publishes_around_refusals_and_drops_only_a_stalled_queue(
        ros_context: Any, monkeypatch: Any) -> None:
    from railgsa_ros.nodes import pacing

    monkeypatch.setattr(pacing, 'BLOCKED_BACKOFF_S', 0.001)
    writer = RefusingWriter(lambda call: call % 7 == 6)
    node, pacer = _pacer(ros_context, writer)
    try:
        stamps, xyz = _columns(500)
        pacer.put(stamps, xyz)
        assert pacer.finish()
        assert writer.stamps() == stamps.tolist()
        assert pacer.published == 500 and pacer.dropped == 0 and pacer.blocked > 0
    finally:
        pacer.destroy()
        node.destroy_node()
    monkeypatch.setattr(pacing, 'FINISH_STALL_S', 0.2)
    writer = RefusingWriter(lambda call: call >= 10)  # a reader that stops acknowledging
    node, pacer = _pacer(ros_context, writer)
    try:
        stamps, xyz = _columns(50)
        pacer.put(stamps, xyz)
        pacer.finish()
        assert writer.stamps() == stamps[:10].tolist()
        assert (pacer.published, pacer.dropped, pacer.pending) == (10, 40, 0)
    finally:
        pacer.destroy()
        node.destroy_node()


def test_a_queue_beyond_its_limit_drops_its_oldest_outputs_counted(ros_context: Any,
                                                                    monkeypatch: Any) -> None:
    from railgsa_ros.nodes import pacing

    monkeypatch.setattr(pacing, 'QUEUE_LIMIT', 100)
    monkeypatch.setattr(pacing, 'BLOCKED_BACKOFF_S', 0.0)
    writer = RefusingWriter(lambda call: True)  # nothing acknowledged
    node, pacer = _pacer(ros_context, writer)
    try:
        stamps, xyz = _columns(250)
        for k in range(0, 250, 50):
            pacer.put(stamps[k:k + 50], tuple(c[k:k + 50] for c in xyz), live=50)
        assert (pacer.pending, pacer.dropped, pacer.published) == (100, 150, 0)
        writer.refuse = lambda call: False  # the reader acknowledges again
        while pacer.pending:
            pacer.drain()
        assert writer.stamps() == stamps[150:].tolist()  # the newest 100, in order
    finally:
        pacer.destroy()
        node.destroy_node()
