"""bag_replay_node and ``railgsa replay`` against bags written by rosbags and mcap_ros2.

A raw subscriber in the test process receives what the node publishes; the truth is what the
bag writers were given (test_playback_bags). Timing is checked loosely here (the receive span is
the bag span / rate, never shorter, at most 50 % + 0.3 s longer on a loaded machine); fidelity
figures: benchmarks/bench_replay_timing.py.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time
from typing import Any

import pytest
from test_playback_bags import T0, make_bag, typestore, write_rosbags

from railgsa_ros.cli.main import main as cli_main

pytestmark = pytest.mark.ros
NS = 1_000_000_000


class Sink:
    """Raw subscriptions on one node: topic -> [(monotonic ns, bytes)]."""

    def __init__(self, ros_context: Any, spin: Callable[[Any], Any], topics: dict[str, Any],
                 use_sim_time: bool = False) -> None:
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.got: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics}
        self.sim_now: list[int] = []
        self.node = Node('sink', context=ros_context,
                         parameter_overrides=[Parameter('use_sim_time', value=use_sim_time)])
        profile = QoSProfile(depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT)
        for topic, cls in topics.items():
            self.node.create_subscription(cls, topic, self._callback(topic), profile, raw=True)
        spin(self.node)

    def _callback(self, topic: str) -> Callable[[bytes], None]:
        def record(data: bytes) -> None:
            self.got[topic].append((time.monotonic_ns(), bytes(data)))
            self.sim_now.append(self.node.get_clock().now().nanoseconds)
        return record

    def raws(self, topic: str) -> list[bytes]:
        return [raw for _, raw in self.got[topic]]


def replayer(ros_context: Any, bag: Path, **params: Any) -> Any:
    """A BagReplayNode on the test context; lists become string-array parameters."""
    from rclpy.parameter import Parameter

    from railgsa_ros.nodes.bag_replay_node import BagReplayNode

    overrides = [Parameter('bag_path', value=str(bag)),
                 Parameter('wait_for_subscribers', value=15.0)]
    for name, value in params.items():
        overrides.append(Parameter(name, Parameter.Type.STRING_ARRAY, value)
                         if isinstance(value, list) else Parameter(name, value=value))
    return BagReplayNode(context=ros_context, parameter_overrides=overrides)


def imu_class() -> Any:
    from sensor_msgs.msg import Imu
    return Imu


@pytest.mark.parametrize(('kind', 'rate'), [('rosbags-mcap', 1.0), ('rosbags-sqlite3', 1.0),
                                            ('mcap_ros2-bare', 1.0), ('rosbags-mcap-zstd', 5.0)])
def test_replay_delivers_every_message_with_bag_timing(kind: str, rate: float, tmp_path: Path,
                                                       ros_context: Any, spin: Any) -> None:
    bag, written = make_bag(kind, tmp_path, 1000)
    sink = Sink(ros_context, spin, {'/imu/data': imu_class()})
    node = replayer(ros_context, bag, rate=rate)
    try:
        assert node.play() == 1000
        deadline = time.monotonic() + 5.0
        while len(sink.got['/imu/data']) < 1000 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        node.destroy_node()
    assert sink.raws('/imu/data') == [raw for _, _, raw in written]
    span = (sink.got['/imu/data'][-1][0] - sink.got['/imu/data'][0][0]) / NS
    ideal = 0.999 / rate
    # paced, not a burst; no upper bound: a starved receiver sees the span stretched (the
    # schedule's own accuracy is tested in test_playback_schedule.py)
    assert span > 0.9 * ideal - 0.02, span


def test_topics_and_remap(tmp_path: Path, ros_context: Any, spin: Any) -> None:
    from std_msgs.msg import String

    ts = typestore()
    notes = [bytes(ts.serialize_cdr(ts.types['std_msgs/msg/String'](f'n{j}'),
                                    'std_msgs/msg/String')) for j in range(10)]
    written = write_rosbags(tmp_path / 'bag', 200, extra={'/note': ('std_msgs/msg/String',
                                                                    notes)})
    sink = Sink(ros_context, spin, {'/imu_raw': imu_class(), '/imu/data': imu_class(),
                                    '/note': String})
    node = replayer(ros_context, tmp_path / 'bag', topics=['/imu/data'],
                    remaps=['/imu/data:=/imu_raw'])
    try:
        node.play()
        time.sleep(0.3)
    finally:
        node.destroy_node()
    assert sink.raws('/imu_raw') == [raw for topic, _, raw in written if topic == '/imu/data']
    assert sink.got['/imu/data'] == [] and sink.got['/note'] == []


def test_clock_drives_sim_time(tmp_path: Path, ros_context: Any, spin: Any) -> None:
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock

    write_rosbags(tmp_path / 'bag', 400)
    sink = Sink(ros_context, spin, {'/imu/data': imu_class(), '/clock': Clock},
                use_sim_time=True)
    node = replayer(ros_context, tmp_path / 'bag', clock_hz=100.0)
    try:
        node.play()
        time.sleep(0.2)
    finally:
        node.destroy_node()
    clocks = [deserialize_message(raw, Clock).clock for raw in sink.raws('/clock')]
    stamps = [c.sec * NS + c.nanosec for c in clocks]
    assert len(stamps) >= 30 and stamps == sorted(stamps)
    assert stamps[0] >= T0 and stamps[-1] <= T0 + 399_000_000
    seen = sink.sim_now[len(sink.sim_now) // 2:]  # the node's clock follows the bag's
    assert all(T0 <= t <= T0 + 400_000_000 for t in seen)
    assert sink.node.get_clock().now().nanoseconds >= T0 + 300_000_000


def test_loop_repeats_until_stopped(tmp_path: Path, ros_context: Any, spin: Any) -> None:
    written = write_rosbags(tmp_path / 'bag', 100)
    sink = Sink(ros_context, spin, {'/imu/data': imu_class()})
    node = replayer(ros_context, tmp_path / 'bag', loop=True)
    thread = threading.Thread(target=node.play)
    thread.start()
    try:
        deadline = time.monotonic() + 10.0
        while len(sink.got['/imu/data']) < 250 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        node.stop()
        thread.join(5.0)
        node.destroy_node()
    assert not thread.is_alive()
    got = sink.raws('/imu/data')
    assert len(got) >= 250
    assert got == ([raw for _, _, raw in written] * (len(got) // 100 + 1))[:len(got)]


def test_start_and_duration_select_the_window(tmp_path: Path, ros_context: Any,
                                              spin: Any) -> None:
    written = write_rosbags(tmp_path / 'bag', 1000)
    sink = Sink(ros_context, spin, {'/imu/data': imu_class()})
    node = replayer(ros_context, tmp_path / 'bag', start_offset=0.3, duration=0.2)
    try:
        assert node.play() == 200
        time.sleep(0.2)
    finally:
        node.destroy_node()
    assert sink.raws('/imu/data') == [raw for _, _, raw in written[300:500]]


def test_unknown_types_are_skipped(tmp_path: Path, ros_context: Any, capfd: Any) -> None:
    from rosbags.rosbag2 import Writer
    from test_playback_bags import IMU, imu_cdr

    with Writer(tmp_path / 'bag', version=9) as writer:
        odd = writer.add_connection('/odd', 'railgsa_test/msg/Odd', msgdef='float64 x',
                                    rihs01='RIHS01_' + 'ab' * 32)
        imu = writer.add_connection('/imu/data', IMU, typestore=typestore())
        writer.write(odd, T0, b'\x00\x01\x00\x00' + bytes(8))
        writer.write(imu, T0 + 1, imu_cdr(0))
    node = replayer(ros_context, tmp_path / 'bag', wait_for_subscribers=0.0)
    try:
        assert node.topics == ['/imu/data']
        assert node.play() == 1
    finally:
        node.destroy_node()
    assert 'skipping /odd: type railgsa_test/msg/Odd is not available' in capfd.readouterr().err


@pytest.mark.parametrize('kind', ['empty-dir', 'no-messages', 'truncated-mcap',
                                  'corrupt-sqlite3'])
def test_cli_bad_bag_exits_2_naming_it(kind: str, tmp_path: Path, ros_domain: int,
                                       capsys: Any) -> None:
    from test_playback_bags import damaged_bag

    path, named = damaged_bag(kind, tmp_path)
    assert cli_main(['replay', str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f'error: {named}: ')


def test_cli_missing_bag_subprocess(tmp_path: Path, ros_domain: int) -> None:
    missing = tmp_path / 'nope.mcap'
    proc = subprocess.run([sys.executable, '-m', 'railgsa_ros.cli.main', 'replay', str(missing),
                           '--rate', '2'], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f'error: {missing}: no such bag'


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_cli_loop_stops_cleanly_on_signal(sig: int, tmp_path: Path, ros_context: Any,
                                          spin: Any, wait_for: Any) -> None:
    write_rosbags(tmp_path / 'bag', 100)
    sink = Sink(ros_context, spin, {'/imu/data': imu_class()})
    proc = subprocess.Popen([sys.executable, '-m', 'railgsa_ros.cli.main', 'replay',
                             str(tmp_path / 'bag'), '--loop'], stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: len(sink.got['/imu/data']) > 150, 30.0)
        proc.send_signal(sig)
        err = proc.communicate(timeout=20)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0 and 'Traceback' not in err
    assert 'published' in err.strip().splitlines()[-1]


def write_with_malformed(path: Path, n: int, bad: dict[int, bytes]) -> list[bytes]:
    """n good Imu at 1 kHz on /imu/data with ``bad`` (index -> bytes) in between; returns
    the good messages in order."""
    from rosbags.rosbag2 import Writer
    from test_playback_bags import IMU, PERIOD, imu_cdr

    good = []
    with Writer(path, version=9) as writer:
        imu = writer.add_connection('/imu/data', IMU, typestore=typestore())
        for i in range(n):
            data = bad.get(i, imu_cdr(i))
            writer.write(imu, T0 + i * PERIOD, data)
            if i not in bad:
                good.append(data)
    return good


def test_malformed_messages_are_counted_and_never_published(tmp_path: Path, ros_context: Any,
                                                            spin: Any, capfd: Any) -> None:
    """A 0-byte and a truncated Imu in the bag stalled a RELIABLE subscriber: they are skipped
    and counted; a typed RELIABLE subscriber (as a node) gets every good message."""
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from test_playback_bags import imu_cdr

    from railgsa_ros.playback.source import BagSource

    bad = {100: b'', 500: imu_cdr(500)[:40], 501: b'\x00\x01\x00\x00'}
    good = write_with_malformed(tmp_path / 'bag', 1000, bad)
    with BagSource(tmp_path / 'bag') as source:  # ROS-free: the skip and the count
        assert [d for _, _, d in source.messages(['/imu/data'])] == good
        assert source.malformed == {'/imu/data': 3}
    got: list[Any] = []
    sink = Node('typed_sink', context=ros_context)
    sink.create_subscription(imu_class(), '/imu/data', got.append, QoSProfile(
        depth=5000, reliability=ReliabilityPolicy.RELIABLE))
    spin(sink)
    node = replayer(ros_context, tmp_path / 'bag', rate=5.0, reliable=True)
    try:
        assert node.play() == len(good) == 997
        deadline = time.monotonic() + 10.0
        while len(got) < len(good) and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        node.destroy_node()
    assert [m.linear_acceleration.z for m in got] == [float(i) for i in range(1000)
                                                      if i not in bad]
    assert 'skipped 3 malformed message(s) on /imu/data' in capfd.readouterr().err


def test_subscriber_wait_needs_every_graph_subscriber_matched_and_settled() -> None:
    from railgsa_ros.playback.waiting import SubscriberWait

    wait = SubscriberWait(['/imu/data'], min_subscribers=1, settle_s=0.25)
    assert not wait.update({'/imu/data': (0, 0), '/clock': (0, 0)}, 0.0)
    assert wait.lonely == ['/imu/data']
    # one node matched, a second one discovered in the graph but not matched yet
    assert not wait.update({'/imu/data': (1, 2), '/clock': (0, 0)}, 0.1)
    assert not wait.update({'/imu/data': (2, 2), '/clock': (0, 0)}, 0.2)  # matched: settle
    assert not wait.update({'/imu/data': (2, 2), '/clock': (0, 0)}, 0.4)
    assert wait.update({'/imu/data': (2, 2), '/clock': (0, 0)}, 0.45)
    # a subscriber appearing during the settle time restarts it; /clock needs only the graph's
    assert not wait.update({'/imu/data': (2, 2), '/clock': (0, 1)}, 0.5)
    assert wait.lonely == ['/clock']
    assert not wait.update({'/imu/data': (2, 2), '/clock': (1, 1)}, 0.6)
    assert wait.update({'/imu/data': (2, 2), '/clock': (1, 1)}, 0.85)


def test_cli_replay_waits_for_a_subscriber_started_after_it(tmp_path: Path, ros_context: Any,
                                                            spin: Any, wait_for: Any) -> None:
    """``railgsa replay BAG`` with the defaults, a subscriber started once the replay is ready
    to play: it gets every message from the first on (without the wait it missed ~0.7 s)."""
    written = write_rosbags(tmp_path / 'bag', 300)
    log = tmp_path / 'replay.err'
    with log.open('w') as err:
        proc = subprocess.Popen([sys.executable, '-m', 'railgsa_ros.cli.main', 'replay',
                                 str(tmp_path / 'bag')], stderr=err, text=True)
    try:
        assert wait_for(lambda: 'waiting up to 10 s' in log.read_text(), 30.0), log.read_text()
        sink = Sink(ros_context, spin, {'/imu/data': imu_class()})
        assert proc.wait(30) == 0
        wait_for(lambda: len(sink.got['/imu/data']) >= 300, 5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
    got = sink.raws('/imu/data')
    missing = [i for i, (_, _, raw) in enumerate(written) if raw not in set(got)]
    assert got == [raw for _, _, raw in written], (missing, log.read_text())


def test_cli_replay_waits_10_s_by_default_and_no_wait_is_0() -> None:
    from railgsa_ros.cli.main import build_parser

    def wait(*args: str) -> float:
        return build_parser().parse_args(['replay', 'bag', *args]).wait_timeout
    assert (wait(), wait('--no-wait'), wait('--wait-timeout', '3'),
            wait('--wait-for-subscribers', '30')) == (10.0, 0.0, 3.0, 30.0)
    with pytest.raises(SystemExit):
        wait('--no-wait', '--wait-timeout', '3')
