"""Replay options, selection, remapping, pacing schedule, Pacer and QoS choice (no ROS).

The truth for the schedule is the definition: a message stamped t is due (t - lo) / rate after
the start, loop k adds k periods, and /clock tick j is due j / clock_hz with bag time
lo + (due * rate mod period).
"""

from __future__ import annotations

import math

import pytest
from rosbags.interfaces import QosDurability, QosReliability

from railgsa_ros.errors import ConfigError
from railgsa_ros.playback.pacing import Pacer
from railgsa_ros.playback.schedule import (
    ClockTick,
    Message,
    PlaybackOptions,
    events,
    parse_remaps,
    select_topics,
    window,
)
from railgsa_ros.playback.source import TopicInfo
from railgsa_ros.qos import record_qos, replay

MS = 1_000_000
LO = 5_000 * MS


def stream(stamps: list[int], topic: str = '/a') -> list[tuple[str, int, bytes]]:
    """Messages at the given stamps, payload = their index."""
    return [(topic, t, bytes([i % 256])) for i, t in enumerate(stamps)]


def take(schedule, n: int) -> list:
    """The first n events of a (possibly endless) schedule."""
    return [event for _, event in zip(range(n), schedule, strict=False)]


@pytest.mark.parametrize(('field', 'value'), [('rate', 0.0), ('rate', -1.0),
                                              ('rate', math.inf), ('start_offset_s', -0.1),
                                              ('duration_s', math.nan), ('clock_hz', -5.0)])
def test_options_reject_bad_values(field: str, value: float) -> None:
    name = {'start_offset_s': 'start_offset', 'duration_s': 'duration',
            'clock_hz': 'clock'}.get(field, field)
    with pytest.raises(ConfigError, match=f'^{name}: invalid value'):
        PlaybackOptions(**{field: value})


def test_remaps_parse_and_reject() -> None:
    assert parse_remaps(['/imu/data:=/imu_raw', 'odom:=wheel/odom']) == (
        ('/imu/data', '/imu_raw'), ('/odom', '/wheel/odom'))
    for bad in ['/a', ':=/b', '/a:=', '/a=/b']:
        with pytest.raises(ConfigError, match=r'^remap: '):
            parse_remaps([bad])


def test_topic_selection() -> None:
    topics = {'/imu/data': TopicInfo('/imu/data', 'sensor_msgs/msg/Imu', 10),
              '/odom': TopicInfo('/odom', 'nav_msgs/msg/Odometry', 3),
              '/silent': TopicInfo('/silent', 'std_msgs/msg/String', 0)}
    assert select_topics(topics, []) == ['/imu/data', '/odom']
    assert select_topics(topics, ['odom', '/odom', '/silent']) == ['/odom']
    with pytest.raises(ConfigError, match=r'^topics: /nope not in the bag'):
        select_topics(topics, ['/imu/data', '/nope'])


def test_window() -> None:
    end = LO + 999 * MS
    assert window(LO, end, PlaybackOptions()) == (LO, end + 1)
    assert window(LO, end, PlaybackOptions(start_offset_s=0.3, duration_s=0.2)) == (
        LO + 300 * MS, LO + 500 * MS)
    with pytest.raises(ConfigError, match=r'^start_offset: 2\.0 s is past the end'):
        window(LO, end, PlaybackOptions(start_offset_s=2.0))


@pytest.mark.parametrize('rate', [1.0, 5.0, 0.5])
def test_messages_due_at_stamp_over_rate(rate: float) -> None:
    stamps = [LO + k * MS + (k % 3) * 1000 for k in range(100)]  # jittered 1 kHz
    options = PlaybackOptions(rate=rate, remaps=(('/a', '/b'),))
    out = list(events(lambda: stream(stamps), LO, stamps[-1] + 1, options))
    assert all(isinstance(e, Message) and e.topic == '/b' for e in out)
    assert [e.stamp_ns for e in out] == stamps
    assert [e.due_ns for e in out] == [round((t - LO) / rate) for t in stamps]
    assert [e.data for e in out] == [raw for _, _, raw in stream(stamps)]


def test_loop_repeats_with_one_mean_interval_between_passes() -> None:
    stamps = [LO + k * 2 * MS for k in range(10)]  # 500 Hz, span 18 ms
    options = PlaybackOptions(rate=2.0, loop=True)
    out = take(events(lambda: stream(stamps), LO, stamps[-1] + 1, options), 35)
    period = 20 * MS  # span + one interval
    expected = [round((k // 10 * period + stamps[k % 10] - LO) / 2.0) for k in range(35)]
    assert [e.due_ns for e in out] == expected
    assert [e.stamp_ns for e in out] == [stamps[k % 10] for k in range(35)]


def test_loop_period_is_the_duration_when_given() -> None:
    stamps = [LO + k * MS for k in range(1000)]
    options = PlaybackOptions(loop=True, start_offset_s=0.1, duration_s=0.05)
    lo, hi = window(LO, stamps[-1], options)
    read = lambda: [m for m in stream(stamps) if lo <= m[1] < hi]  # noqa: E731
    out = take(events(read, lo, hi, options), 120)
    assert [e.stamp_ns for e in out[:50]] == stamps[100:150]
    assert out[50].stamp_ns == stamps[100] and out[50].due_ns == 50 * MS
    assert out[119].due_ns == 2 * 50 * MS + 19 * MS


def test_clock_ticks_carry_bag_time_and_restart_with_the_loop() -> None:
    stamps = [LO + k * 10 * MS for k in range(10)]  # 100 Hz, period 100 ms
    options = PlaybackOptions(rate=2.0, loop=True, clock_hz=100.0)
    out = take(events(lambda: stream(stamps), LO, stamps[-1] + 1, options), 60)
    ticks = [e for e in out if isinstance(e, ClockTick)]
    assert [t.due_ns for t in ticks] == [j * 10 * MS for j in range(len(ticks))]
    assert [t.stamp_ns for t in ticks] == [LO + (j * 20 * MS) % (100 * MS)
                                           for j in range(len(ticks))]
    dues = [e.due_ns for e in out]
    assert dues == sorted(dues)
    first = [type(e) for e in out[:2]]
    assert first == [ClockTick, Message]  # the clock is set before the first message


def test_empty_window_is_an_error() -> None:
    with pytest.raises(ConfigError, match=r'^no message in the selected topics and time window'):
        list(events(lambda: [], LO, LO + 1, PlaybackOptions(loop=True)))


class FakeClock:
    """A monotonic ns clock that advances only when slept, by the requested time + 0.1 ms."""

    def __init__(self) -> None:
        self.now = 0
        self.sleeps: list[float] = []

    def __call__(self) -> int:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += round(seconds * 1e9) + 100_000


def test_pacer_waits_in_slices_and_records_lateness() -> None:
    clock = FakeClock()
    pacer = Pacer(clock, clock.sleep)
    assert pacer.wait(120 * MS)
    assert clock.sleeps == [0.05, 0.05, pytest.approx(0.0198)]
    assert clock.now == 120 * MS + 100_000 and pacer.late_max_ns == 100_000
    clock.now += 5 * MS
    assert pacer.wait(121 * MS)  # already late: no sleep
    assert len(clock.sleeps) == 3 and pacer.late_max_ns == 4_100_000
    assert pacer.late_mean_ns == pytest.approx((100_000 + 4_100_000) / 2)
    assert not pacer.wait(10_000 * MS, ok=lambda: False)
    pacer.restart()
    assert pacer.start_ns == clock.now


def test_qos_from_recording_or_type() -> None:
    imu = TopicInfo('/imu/data', 'sensor_msgs/msg/Imu', 1001, [], 0, 1000 * MS)
    odom = TopicInfo('/odom', 'nav_msgs/msg/Odometry', 51, [], 0, 1000 * MS)
    choice = replay(imu, 1.0)
    assert (choice.reliable, choice.depth, choice.transient_local) == (False, 1000, False)
    assert replay(imu, 5.0).depth == 5000
    assert (replay(odom, 1.0).reliable, replay(odom, 1.0).depth) == (True, 50)
    imu.offered_qos = [record_qos(True, 5)]
    assert replay(imu, 1.0).reliable
    imu.offered_qos.append(record_qos(False, 2000))
    assert (replay(imu, 1.0).reliable, replay(imu, 1.0).depth) == (False, 2000)
    latched = record_qos(True, 1)._replace(durability=QosDurability.TRANSIENT_LOCAL)
    odom.offered_qos = [latched, record_qos(False, 1)._replace(reliability=QosReliability.UNKNOWN)]
    assert replay(odom, 1.0).transient_local and replay(odom, 1.0).reliable


def test_reliable_override_keeps_ten_seconds_or_the_whole_topic() -> None:
    imu = TopicInfo('/imu/data', 'sensor_msgs/msg/Imu', 20_001, [record_qos(False, 5)], 0,
                    20_000 * MS)
    assert (replay(imu, 5.0, reliable=True).reliable,
            replay(imu, 5.0, reliable=True).depth) == (True, 20_001)  # the whole topic
    assert replay(imu, 1.0, reliable=True).depth == 10_000  # 10 s at 1 kHz
    odom = TopicInfo('/odom', 'nav_msgs/msg/Odometry', 3, [], 0, 20_000 * MS)
    assert replay(odom, 1.0, reliable=True).depth == 10  # never below the usual minimum
