"""Per-sample outputs published without bursts larger than the writer history.

A flush (end of a stream, a reset, a rebuild, deactivate, shutdown) releases the D samples waiting
in the band filter at once: about 7000 messages. Published in one loop they overwrite a writer
history of 1000 before a RELIABLE reader acknowledged them, and they overflow the reader's own
history of 1000 before its executor takes them: measured over loopback, 1905 of 7000 reached a
RELIABLE depth-1000 reader (rclpy SingleThreadedExecutor in its own process); in slices of 250 or
500 every 50 ms, 7000 of 7000. Waiting for acknowledgements alone is no pace: Fast DDS answers
``wait_for_all_acked`` at its heartbeat, up to 3 s per slice (measured mean 0.3-0.7 s).

So the pacer keeps a queue in stamp order and publishes from it at most an eighth of the writer
history per ``PERIOD_S`` (a steady timer while the queue is not empty, yielding to the executor
in between): outputs of live input (one per IMU sample) go out as they come, flushed ones at
``flush_rate_hz`` on top (default 1000/s, the IMU rate: a flush asks no more of a reader than
the live stream). With half the history per period, the live batches of a 5x replay (up
to 2000 outputs after a stall) still overflowed a RELIABLE depth-1000 reader (209 of 19 400 lost
in one run).

Delivery rests on acknowledgement: the publisher is KEEP_ALL (``qos.output(keep_all=True)``),
so the writer never overwrites a message some reader has not acknowledged. When its history is
full of unacknowledged messages (a stalled or saturated reader; Fast DDS: 5000 messages) a
publish waits at most 100 ms and fails; the message stays first in the queue, the pacer counts
``output_blocked`` and tries again after ``BLOCKED_BACKOFF_S``. Only a queue beyond
``QUEUE_LIMIT`` (a reader that acknowledges nothing for minutes) drops its oldest outputs,
counted ``output_dropped`` and logged; ``published`` counts only what the writer took.
``finish`` (deactivate, shutdown) publishes what is left at the same pace, then waits (bounded)
until every matched reader acknowledged everything, so nothing dies with the writer.

Messages are encoded per slice with the vectorised codec (:func:`railgsa_ros.bag.cdr.encode`)
and published serialized: the same bytes rclpy would make from a PointStamped or
Vector3Stamped, without a Python message object per sample. ``lock`` (the node's) is held by
the pacing timer, since the node's reader thread puts outputs.
"""

from __future__ import annotations

from collections import deque
from contextlib import AbstractContextManager
import struct
import time
from typing import Any

import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node

from railgsa_ros.bag.cdr import StampedLayout, encode, encode_rows

PERIOD_S = 0.01  #: pacing timer period while outputs wait, s
#: longest wait for the readers' acknowledgements in ``finish``, s (Fast DDS heartbeat: 3 s)
ACK_TIMEOUT_S = 3.5
SMALL_SLICE = 8  #: slices up to this many messages are filled into a template per message
#: after a publish that found the writer history full of unacknowledged messages, s
BLOCKED_BACKOFF_S = 0.05
#: most outputs queued (2 min at 1 kHz); beyond, the oldest are dropped (counted)
QUEUE_LIMIT = 120_000
#: ``finish`` gives up on a queue that made no progress for this long (readers that acknowledge
#: nothing), s
FINISH_STALL_S = 10.0
Columns = tuple[np.ndarray, np.ndarray, np.ndarray]  #: x, y, z of K messages, each (K,)


class Template:
    """``encode`` for a few messages: the bytes of one message of ``layout`` with header
    ``frame`` (from ``encode_rows``), its stamp and float64 body packed per message (a live
    output is one message, where ``encode``'s fixed cost was some 13 us)."""

    def __init__(self, layout: StampedLayout, frame: str) -> None:
        self._layout, self._frame = layout, frame
        row = encode_rows(layout, np.zeros(1, np.int64), [frame], np.zeros(layout.n_doubles))
        self._head = row[0, :4].tobytes()
        body = row.shape[1] - 8 * layout.n_doubles
        self._middle = row[0, 12:body].tobytes()
        self._pack = struct.Struct(f'<iI{layout.n_doubles}d').pack

    def encode(self, stamps_ns: np.ndarray, columns: Columns) -> list[bytes]:
        """What ``encode(layout, stamps_ns, [frame], np.column_stack(columns))`` returns."""
        if stamps_ns.size > SMALL_SLICE:
            return encode(self._layout, stamps_ns, [self._frame], np.column_stack(columns))
        out = []
        rows = zip(*(np.asarray(c, dtype=float).tolist() for c in columns), strict=True)
        for t, row in zip(stamps_ns.tolist(), rows, strict=True):
            sec, nsec = divmod(t, 1_000_000_000)
            if not -2**31 <= sec < 2**31:  # encode's error
                return encode(self._layout, stamps_ns, [self._frame], np.column_stack(columns))
            data = self._pack(sec, nsec, *row)
            out.append(self._head + data[:8] + self._middle + data[8:])
        return out


class OutputPacer:
    """Queue and paced publisher of stamped 3-vectors (``layout`` PointStamped or
    Vector3Stamped, header.frame_id ``frame``)."""

    def __init__(self, node: Node, publisher: Any, layout: StampedLayout, frame: str,
                 depth: int, flush_rate_hz: float, lock: AbstractContextManager) -> None:
        self._node, self._pub = node, publisher
        self._template = Template(layout, frame)
        self._lock = lock
        self.slice = max(1, depth // 8)  #: most messages published per timer period
        self.flush_rate_hz = float(flush_rate_hz)
        self._queue: deque[tuple[np.ndarray, Columns]] = deque()  # (stamps, x y z) parts
        self.pending = 0  #: messages waiting in the queue
        self.published = 0  #: messages the writer took so far
        self.blocked = 0  #: publishes that found the writer full of unacknowledged messages
        self.dropped = 0  #: messages dropped (queue beyond QUEUE_LIMIT, publisher inactive)
        self.max_pending = 0  #: largest queue seen, messages
        self._retry_at = 0.0  # steady time (s) before which a blocked writer is left alone
        self._live = 0  # messages of live input not yet published (sent at the input's pace)
        self._credit = 0.0  # flushed messages that may go out now (grows at flush_rate_hz)
        self._last = time.monotonic()
        self._timer = node.create_timer(PERIOD_S, self._on_timer,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._timer.cancel()
        self._armed = False  # the timer runs (cancelled while the queue is empty)

    def put(self, stamps_ns: np.ndarray, xyz: Columns, live: int = 0) -> None:
        """Queue outputs (stamps int64 (K,), values x, y, z each (K,)) and publish what the
        pace allows;
        ``live``: input samples just received (each adds at most one output at the input's
        pace; outputs beyond them are flushed ones)."""
        if not stamps_ns.size:
            return
        self._queue.append((stamps_ns, xyz))
        self.pending += stamps_ns.size
        self.max_pending = max(self.max_pending, self.pending)
        self._live += min(live, stamps_ns.size)
        if self.pending > QUEUE_LIMIT:
            self._drop(self.pending - QUEUE_LIMIT)
        self.drain()

    def _on_timer(self) -> None:
        with self._lock:
            self.drain()

    def drain(self) -> int:
        """Publish up to one slice allowed by the pace; returns the count."""
        now = time.monotonic()
        self._credit = min(self._credit + self.flush_rate_hz * (now - self._last), self.slice)
        self._last = now
        budget = min(self._live + int(self._credit), self.slice)
        count = self._publish(budget) if now >= self._retry_at else 0
        from_live = min(count, self._live)
        self._live -= from_live
        self._credit -= count - from_live
        if self.pending and not self._armed:
            self._timer.reset()
            self._armed = True
        elif not self.pending:
            if self._armed:
                self._timer.cancel()
                self._armed = False
            self._live = 0
        return count

    def finish(self) -> bool:
        """Publish everything queued at the pace (blocking; a queue that makes no progress for
        FINISH_STALL_S is dropped, counted), then wait up to ACK_TIMEOUT_S for the readers'
        acknowledgements; whether all were acknowledged."""
        progress = time.monotonic()
        while self.pending:
            if self._publish(self.slice):
                progress = time.monotonic()
            elif time.monotonic() - progress > FINISH_STALL_S:
                self._drop(self.pending)
                break
            if self.pending:
                time.sleep(max(self.slice / self.flush_rate_hz,
                               self._retry_at - time.monotonic()))
        self._timer.cancel()
        self._armed = False
        self._live, self._credit = 0, 0.0
        return bool(self._pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S)))

    def destroy(self) -> None:
        """Release the timer (the publisher belongs to the node)."""
        self._node.destroy_timer(self._timer)

    def _publish(self, budget: int) -> int:
        """Publish up to ``budget`` queued messages in order; returns how many left the queue
        (published, or dropped by an inactive publisher). A message the writer cannot take
        (history full of unacknowledged messages) stays first in the queue."""
        sent = taken = 0
        # a lifecycle publisher that is not active drops what it is given, as its publish does
        active = getattr(self._pub, 'is_activated', True)
        blocked = False
        while self._queue and sent < budget and not blocked:
            stamps, xyz = self._queue[0]
            want = min(budget - sent, stamps.size)
            done = want
            if active:
                done = self._send(stamps[:want], tuple(c[:want] for c in xyz))
                blocked = done < want
                taken += done
            self._advance(done)
            sent += done
        self.pending -= sent
        self.published += taken
        self.dropped += sent - taken
        return sent

    def _send(self, stamps_ns: np.ndarray, xyz: Columns) -> int:
        """Publish these messages; how many the writer took before one found its history full
        of unacknowledged messages (counted in ``blocked``; no retry before BLOCKED_BACKOFF_S).

        Through the publisher's C handle: Publisher.publish first checks each message against
        the message class (a metaclass isinstance), 1.2 of its 2.4 us a message."""
        handle = self._pub.handle
        count = 0
        with handle:
            for data in self._template.encode(stamps_ns, xyz):
                try:
                    handle.publish_raw(data)
                except rclpy_implementation.RCLError:
                    self.blocked += 1
                    self._retry_at = time.monotonic() + BLOCKED_BACKOFF_S
                    break
                count += 1
        return count

    def _advance(self, count: int) -> None:
        """Remove the first ``count`` messages of the queue's first part."""
        stamps, xyz = self._queue[0]
        if count == stamps.size:
            self._queue.popleft()
        elif count:
            self._queue[0] = (stamps[count:], tuple(c[count:] for c in xyz))

    def _drop(self, count: int) -> None:
        """Drop the ``count`` oldest queued messages (counted, logged)."""
        left = count
        while left:
            take = min(left, self._queue[0][0].size)
            self._advance(take)
            left -= take
        self.pending -= count
        self.dropped += count
        self._node.get_logger().error(
            f'{self._pub.topic_name}: {self.dropped} outputs dropped so far: a reader '
            'acknowledges nothing (stalled KEEP_ALL or overloaded)', throttle_duration_sec=10.0)
