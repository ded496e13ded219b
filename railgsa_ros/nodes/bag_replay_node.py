"""bag_replay_node: plays a rosbag2 bag with its recorded timing as raw CDR, optionally /clock.

Parameters (all fixed at start-up): ``bag_path``, ``rate`` (x real time), ``loop``,
``start_offset`` and ``duration`` (s of bag time; duration 0 = to the end), ``topics`` (string
array, empty = all), ``remaps`` (string array of ``FROM:=TO``), ``clock_hz`` (publish
rosgraph_msgs/Clock on /clock at this wall-clock rate, 0 = off), ``wait_for_subscribers`` (s to
wait at most for the subscribers before playing, default ``playback.waiting.WAIT_S``; 0 =
start at once), ``min_subscribers`` (the number of subscribers each played topic
waits for) and ``reliable`` (publish
every topic RELIABLE with a deep history, railgsa_ros.qos.replay, and wait up to ACK_TIMEOUT_S at
the end until every subscriber acknowledged every message, as ``ros2 bag play
--wait-for-all-acked``: a writer that is gone resends nothing). Topics whose type this
ROS installation cannot import are skipped with a warning. Malformed messages (empty, truncated:
``playback.source.well_formed``) are never published; the final note counts them per topic. The
node exits when the bag is played (never with ``loop``).
"""

from __future__ import annotations

import railgsa_ros.nodes.early_signals  # noqa: F401  (first: exit 0 on a signal from here on)

# isort: split

from collections.abc import Mapping
import importlib
import sys
import threading
import time
from typing import Any

from builtin_interfaces.msg import Time
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSCompatibility, qos_check_compatible
from rosgraph_msgs.msg import Clock

from railgsa_ros import qos
from railgsa_ros.errors import InputError, RailGsaError
from railgsa_ros.nodes import console_main, parameter_overrides
from railgsa_ros.nodes.params import ParamSpec, declare
from railgsa_ros.nodes.process import run_node
from railgsa_ros.nodes.qos import to_rclpy
from railgsa_ros.playback.pacing import Pacer
from railgsa_ros.playback.schedule import (
    NS,
    ClockTick,
    PlaybackOptions,
    events,
    parse_remaps,
    select_topics,
    window,
)
from railgsa_ros.playback.source import BagSource
from railgsa_ros.playback.waiting import WAIT_S, SubscriberWait

NAME = 'bag_replay_node'
SPECS = (
    ParamSpec('bag_path', '', 'rosbag2 bag: directory, .mcap or .db3 file', read_only=True),
    ParamSpec('rate', 1.0, 'playback rate (x real time)', bounds=(1e-3, 1e3), read_only=True),
    ParamSpec('loop', False, 'replay the window forever', read_only=True),
    ParamSpec('start_offset', 0.0, 'bag time skipped at the start (s)', bounds=(0.0, 1e9),
              read_only=True),
    ParamSpec('duration', 0.0, 'bag time played (s), 0 = to the end', bounds=(0.0, 1e9),
              read_only=True),
    ParamSpec('clock_hz', 0.0, '/clock publication rate (Hz of wall time), 0 = no /clock',
              bounds=(0.0, 1e4), read_only=True),
    ParamSpec('wait_for_subscribers', WAIT_S, 'wait up to this long (s) until every played topic '
              'has min_subscribers and every subscriber in the graph is matched, 0 = play at '
              'once', bounds=(0.0, 3600.0), read_only=True),
    ParamSpec('min_subscribers', 1, 'with wait_for_subscribers: the subscribers every topic '
              'waits for', bounds=(1, 1000), read_only=True),
    ParamSpec('reliable', False, 'publish every topic RELIABLE, with a history of 10 s at the '
              'replay rate (at most the whole topic), so that slow readers lose nothing',
              read_only=True),
)
ARRAYS = {'topics': 'topics to play (empty = all)', 'remaps': 'topic remaps FROM:=TO'}
#: Longest wait (s) at the end of a reliable replay for the subscribers' acknowledgements.
ACK_TIMEOUT_S = 60.0
ACK_SLICE_S = 0.1  #: s per acknowledgement check, so that stop() ends the wait soon
LINGER_S = 0.3  #: s a best-effort replay stays after its last message (no acknowledgements)


def message_class(msgtype: str) -> Any | None:
    """The rclpy class of ``pkg/msg/Name``, or None when it cannot be imported here."""
    pkg, _, name = msgtype.rpartition('/')
    try:
        return getattr(importlib.import_module(pkg.replace('/', '.')), name)
    except (ImportError, AttributeError, ValueError):
        return None


def final_note(node: Node, text: str) -> None:
    """Log ``text``, or print it to stderr when the context is already shut down."""
    if node.context.ok():
        node.get_logger().info(text)
    else:
        print(f'[{node.get_name()}] {text}', file=sys.stderr)


class BagReplayNode(Node):
    """Opens the bag and creates one publisher per playable topic; ``play()`` replays it."""

    def __init__(self, stop: threading.Event | None = None, **kwargs: Any) -> None:
        """Read the parameters and open the bag (InputError/ConfigError naming it on failure);
        setting ``stop`` ends ``play()``."""
        super().__init__(NAME, **kwargs)
        values = declare(self, SPECS)
        arrays = {name: self.declare_parameter(name, Parameter.Type.STRING_ARRAY,
                                               ParamSpec(name, '', text).descriptor()).value
                  or [] for name, text in ARRAYS.items()}
        if not values['bag_path']:
            raise InputError('parameter bag_path: no bag given')
        self.options = PlaybackOptions(
            rate=values['rate'], loop=values['loop'], start_offset_s=values['start_offset'],
            duration_s=values['duration'], topics=tuple(arrays['topics']),
            remaps=parse_remaps(arrays['remaps']), clock_hz=values['clock_hz'])
        self.wait_s = values['wait_for_subscribers']
        self.min_subscribers = values['min_subscribers']
        self.reliable = values['reliable']
        self._stop = stop or threading.Event()
        self.source = BagSource(values['bag_path'])
        try:
            self._setup()
        except RailGsaError:
            self.source.close()
            raise

    def _setup(self) -> None:
        """Choose the topics and window and create the publishers."""
        topics = select_topics(self.source.topics, self.options.topics)
        remap = dict(self.options.remaps)
        self.publishers_by_topic: dict[str, Any] = {}
        self.topics: list[str] = []
        for name in topics:
            info = self.source.topics[name]
            cls = message_class(info.msgtype)
            if cls is None:
                self.get_logger().warning(f'skipping {name}: type {info.msgtype} is not '
                                          'available in this ROS installation')
                continue
            out = remap.get(name, name)
            self.publishers_by_topic[out] = self.create_publisher(
                cls, out, to_rclpy(qos.replay(info, self.options.rate, self.reliable)))
            self.topics.append(name)
        if not self.topics:
            raise InputError(f'{self.source.path}: no playable topic (types not available)')
        self.clock_pub = (self.create_publisher(Clock, '/clock', to_rclpy(qos.CLOCK))
                          if self.options.clock_hz > 0 else None)
        self.window = window(self.source.start_ns, self.source.end_ns, self.options)

    def _wait_for_subscribers(self) -> None:
        """Wait up to ``wait_for_subscribers`` s until the subscribers there are matched
        (``playback.waiting.SubscriberWait``: every played topic with ``min_subscribers``, every
        compatible subscription of the graph, /clock's included, matched); warn when not."""
        pubs = dict(self.publishers_by_topic)
        if self.clock_pub is not None:
            pubs['/clock'] = self.clock_pub
        self.get_logger().info(f'waiting up to {self.wait_s:g} s for the subscribers of '
                               f'{", ".join(pubs)}')
        wait = SubscriberWait(self.publishers_by_topic, self.min_subscribers)
        deadline = time.monotonic() + self.wait_s
        while self._running() and time.monotonic() < deadline:
            if wait.update({t: (pub.get_subscription_count(), self._graph_subscribers(t, pub))
                            for t, pub in pubs.items()}, time.monotonic()):
                return
            time.sleep(0.01)
        if self._running():
            self.get_logger().warning(
                f'playing after {self.wait_s:g} s without every subscriber matched '
                f'({self.min_subscribers} or more per topic): '
                f'{", ".join(wait.lonely) or "counts still changing"}')

    def _graph_subscribers(self, topic: str, pub: Any) -> int:
        """Subscriptions of ``topic`` in the ROS graph whose QoS can match ``pub``'s."""
        return sum(qos_check_compatible(pub.qos_profile, info.qos_profile)[0]
                   != QoSCompatibility.ERROR
                   for info in self.get_subscriptions_info_by_topic(topic))

    def play(self) -> int:
        """Replay until the end (never with loop), ``stop()`` or shutdown; returns the number of
        messages published."""
        if self.wait_s > 0:
            self._wait_for_subscribers()
        lo, hi = self.window
        self.get_logger().info(f'playing {self.source.path} ({", ".join(self.topics)}) at '
                               f'{self.options.rate:g}x from {lo / NS:.3f} s')
        pacer = Pacer()
        published = 0
        schedule = events(lambda: self.source.messages(self.topics, lo, hi), lo, hi, self.options)
        for event in schedule:
            if not pacer.wait(event.due_ns, self._running):
                break
            if isinstance(event, ClockTick):
                sec, nanosec = divmod(event.stamp_ns, NS)
                self.clock_pub.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
            else:
                self.publishers_by_topic[event.topic].publish(event.data)
                published += 1
        if self.reliable and self._running():
            self._wait_for_acks()
        elif published and self._running():  # best effort: nothing to acknowledge, but a
            # writer destroyed at once can take its last samples with it before a reader on
            # this host took them (CI: 299 of 300 delivered in one run of ten)
            self._stop.wait(LINGER_S)
        skipped = ''.join(f'; skipped {n} malformed message(s) on {topic}'
                          for topic, n in sorted(self.source.malformed.items()))
        final_note(self, f'published {published} messages; lateness mean '
                         f'{pacer.late_mean_ns / 1e6:.3f} ms, max '
                         f'{pacer.late_max_ns / 1e6:.3f} ms{skipped}')
        return published

    def _wait_for_acks(self) -> None:
        """Wait up to ACK_TIMEOUT_S (in slices, so that ``stop()`` ends it) until every
        subscriber acknowledged every message; warn naming the topics that are not."""
        deadline = time.monotonic() + ACK_TIMEOUT_S
        pending = list(self.publishers_by_topic)
        while pending and time.monotonic() < deadline and self._running():
            pending = [t for t in pending if not self.publishers_by_topic[t].wait_for_all_acked(
                Duration(seconds=ACK_SLICE_S))]
        if pending and self._running():
            self.get_logger().warning(f'not acknowledged after {ACK_TIMEOUT_S:g} s: '
                                      f'{", ".join(pending)}')

    def stop(self) -> None:
        """Make ``play()`` return within one pacing slice (thread-safe)."""
        self._stop.set()

    def _running(self) -> bool:
        """Whether playback should go on."""
        return self.context.ok() and not self._stop.is_set()

    def destroy_node(self) -> None:
        """Close the bag, then destroy the node."""
        self.source.close()
        super().destroy_node()


def run(args: list[str] | None = None, parameters: Mapping[str, Any] | None = None,
        stop: threading.Event | None = None) -> int:
    """Replay with ROS ``args`` and parameter overrides; 0 when done or stopped by SIGINT,
    SIGTERM or ``stop``. RailGsaError propagates (the caller prints it and exits 2).
    """
    stop = stop or threading.Event()
    return run_node(
        lambda: BagReplayNode(stop, parameter_overrides=parameter_overrides(parameters or {})),
        args, session=lambda node, _executor, _stopped: node.play(), stop=stop)


def main(args: list[str] | None = None) -> int:
    """Console entry point: exit 0 when done, 2 with a one-line error for bad input."""
    return console_main(run, args)


if __name__ == '__main__':
    sys.exit(main())
