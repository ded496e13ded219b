"""recorder: records topics as raw CDR into a rosbag2 MCAP bag (playback.recording.BagRecorder).

Parameters (fixed at start-up): ``out`` (bag directory to create), ``topics`` (string array),
``duration`` (s of wall time, 0 = until SIGINT/SIGTERM), ``split`` (s per storage file),
``compress`` (zstd chunks) and ``depth`` (reader history per topic; 0, the default: KEEP_ALL). A
topic is subscribed as soon as a publisher of it appears, with the publishers' reliability
(BEST_EFFORT if any of them is, else RELIABLE), and its offered QoS and type hash are stored.
With KEEP_ALL a RELIABLE message the reader history has no room for is not acknowledged, so its
writer keeps and resends it: a burst faster than this process writes (the nodes' flush on a
loaded machine) slows the writers down instead of being lost, as KEEP_LAST 1000 lost 2.8-3.8 %
of track/irregularity under load. SIGINT/SIGTERM write what is still waiting in the reader
histories, then finish the bag (exit 0). A write error
keeps the finished files readable and exits 2 with one error line naming the file.
"""

from __future__ import annotations

import railgsa_ros.nodes.early_signals  # noqa: F401  (first: exit 0 on a signal from here on)

# isort: split

from collections.abc import Callable, Mapping
from functools import partial
import sys
import threading
import time
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from railgsa_ros import qos
from railgsa_ros.errors import ConfigError
from railgsa_ros.nodes import console_main, parameter_overrides
from railgsa_ros.nodes.bag_replay_node import final_note, message_class
from railgsa_ros.nodes.params import ParamSpec, declare
from railgsa_ros.nodes.process import run_node
from railgsa_ros.nodes.qos import bag_record, from_rclpy, to_rclpy
from railgsa_ros.playback.recording import BagRecorder, TopicSpec
from railgsa_ros.playback.schedule import absolute

NAME = 'recorder'
#: Default reader history: KEEP_ALL (a KEEP_LAST depth when > 0).
DEPTH = 0
#: Most messages ``drain`` writes per topic at the stop (a publisher that never pauses).
DRAIN_MAX = 1_000_000
#: Most messages written per topic after each executor wake-up.
BATCH = 1000
SPECS = (
    ParamSpec('out', '', 'bag directory to create', read_only=True),
    ParamSpec('duration', 0.0, 'recording time (s), 0 = until stopped', bounds=(0.0, 1e9),
              read_only=True),
    ParamSpec('split', 60.0, 'seconds per storage file', bounds=(0.1, 1e6), read_only=True),
    ParamSpec('compress', True, 'zstd-compress the MCAP chunks', read_only=True),
    ParamSpec('depth', DEPTH, 'reader history per topic (messages; 0 = KEEP_ALL)',
              bounds=(0, 1_000_000), read_only=True),
)
#: Period (s) of the topic discovery and of the flush/split check.
DISCOVERY_S = 0.1
FLUSH_S = 1.0


class RecorderNode(Node):
    """Subscribes to the topics (raw) and appends every message to a BagRecorder."""

    def __init__(self, **kwargs: Any) -> None:
        """Read the parameters and create the bag (ConfigError naming it on failure)."""
        super().__init__(NAME, **kwargs)
        values = declare(self, SPECS)
        topics = self.declare_parameter('topics', Parameter.Type.STRING_ARRAY,
                                        ParamSpec('topics', '', 'topics to record')
                                        .descriptor()).value or []
        if not values['out']:
            raise ConfigError('parameter out: no output bag given')
        if not topics:
            raise ConfigError('parameter topics: no topic to record')
        self.waiting = list(dict.fromkeys(absolute(t) for t in topics))
        self.duration_s = values['duration']
        self.depth = values['depth']
        self.bag = BagRecorder(values['out'], values['split'], values['compress'])
        self.started = time.monotonic()
        self.done = False
        self._subs: list[tuple[Any, str, Any]] = []  # (subscription, topic, message class)
        self.create_timer(DISCOVERY_S, self._discover)
        self.create_timer(FLUSH_S, self._flush)
        self.get_logger().info(f'recording {", ".join(self.waiting)} into {self.bag.path}')

    def _discover(self) -> None:
        """Subscribe to every awaited topic that has a publisher now."""
        for topic in list(self.waiting):
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            msgtype = infos[0].topic_type
            cls = message_class(msgtype)
            self.waiting.remove(topic)
            if cls is None:
                self.get_logger().warning(f'not recording {topic}: type {msgtype} is not '
                                          'available in this ROS installation')
                continue
            offered = [i.qos_profile for i in infos if i.topic_type == msgtype]
            type_hash = str(getattr(infos[0], 'topic_type_hash', '') or '')
            self.bag.add_topic(TopicSpec(topic, msgtype, [bag_record(p) for p in offered],
                                         type_hash if type_hash.startswith('RIHS') else ''))
            reader = qos.recording([from_rclpy(p) for p in offered], self.depth)
            self._subs.append((self.create_subscription(
                cls, topic, partial(self._on_message, topic), to_rclpy(reader), raw=True),
                topic, cls))
            self.get_logger().info(f'recording {topic} ({msgtype})')

    def _on_message(self, topic: str, data: bytes) -> None:
        """Append one message, stamped with the node clock at reception (ns)."""
        self.bag.write(topic, self.get_clock().now().nanoseconds, data)

    def _flush(self) -> None:
        """Push data to disk, split files when due, and stop after ``duration``."""
        self.bag.tick(self.get_clock().now().nanoseconds)
        if self.duration_s and time.monotonic() - self.started >= self.duration_s:
            self.done = True

    def drain(self, limit: int = DRAIN_MAX) -> None:
        """Write the messages waiting in the reader histories, ``limit`` per topic at most:
        after each executor wake-up (taken in a loop, without the executor's per-message wait;
        it alone wrote too few messages per second on a loaded machine) and at the stop (what
        was received but not yet written)."""
        for sub, topic, cls in self._subs:
            with sub.handle:
                for _ in range(limit):
                    taken = sub.handle.take_message(cls, True)
                    if taken is None:
                        break
                    self._on_message(topic, taken[0])

    def finish(self) -> None:
        """Close the bag (finishing the file in progress) and log the count."""
        self.bag.close()
        final_note(self, f'recorded {self.bag.message_count} messages into {self.bag.path}')


def run(args: list[str] | None = None, parameters: Mapping[str, Any] | None = None,
        stop: threading.Event | None = None) -> int:
    """Record until ``duration``, SIGINT/SIGTERM or ``stop``; 0 with the bag closed and readable.

    Signals only set a flag, so a message is never cut mid-write. RailGsaError (bad output path,
    write error) propagates after the finished files are made safe; the caller prints it and
    exits 2.
    """
    def session(node: RecorderNode, executor: SingleThreadedExecutor,
                stopped: Callable[[], bool]) -> None:
        while not (stopped() or node.done):
            executor.spin_once(timeout_sec=DISCOVERY_S)
            node.drain(BATCH)
        if rclpy.ok():
            node.drain()

    overrides = parameter_overrides(parameters or {})
    return run_node(lambda: RecorderNode(parameter_overrides=overrides), args, session=session,
                    stop=stop, close=RecorderNode.finish)


def main(args: list[str] | None = None) -> int:
    """Console entry point: 0 when finished or interrupted, 2 with a one-line error."""
    return console_main(run, args)


if __name__ == '__main__':
    sys.exit(main())
