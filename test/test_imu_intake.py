"""The IMU intake's reader thread: a signal that comes while it starts (no traceback), and its
size-or-linger batches."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest

VALUES = {'imu_qos_depth': 10, 'idle_flush_s': 2.0, 'imu_reliability': 'best_effort',
          'odom_reliability': 'best_effort', 'use_odom': True, 'rate_hz': 1000.0}


def _intake(ctx: Any) -> tuple[Any, Any]:
    from rclpy.node import Node

    from railgsa_ros.nodes.imu_input import ImuIntake

    node = Node('imu_intake_probe', context=ctx)
    return node, lambda: ImuIntake(node, VALUES, lambda imu, odom: None, lambda: None)


def _reader_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.endswith('_imu_reader')]


@pytest.fixture
def thread_errors(monkeypatch: pytest.MonkeyPatch) -> list[BaseException]:
    """Exceptions that escape any thread during the test."""
    errors: list[BaseException] = []
    monkeypatch.setattr(threading, 'excepthook', lambda args: errors.append(args.exc_value))
    return errors


@pytest.mark.parametrize('started', [False, True], ids=['before-start', 'after-start'])
def test_signal_while_the_reader_starts_shuts_down_cleanly(
        started: bool, ros_context: Any, thread_errors: list[BaseException],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The node's build is interrupted just before or just after the reader started: the
    context's shutdown (the process's way out) does not raise and stops and joins a running
    reader, none is left inside a wait at exit."""
    start = threading.Thread.start

    def interrupted(self: threading.Thread) -> None:
        if started:
            start(self)
        raise KeyboardInterrupt

    _node, build = _intake(ros_context)
    with monkeypatch.context() as patch:
        patch.setattr(threading.Thread, 'start', interrupted)
        with pytest.raises(KeyboardInterrupt):
            build()
    assert len(_reader_threads()) == int(started)
    ros_context.try_shutdown()
    assert _reader_threads() == []
    assert thread_errors == []


def test_context_shut_down_before_the_reader_runs_ends_it_quietly(
        ros_context: Any, thread_errors: list[BaseException],
        monkeypatch: pytest.MonkeyPatch) -> None:
    start = threading.Thread.start

    def late(self: threading.Thread) -> None:  # the signal's shutdown wins the race
        ros_context.try_shutdown()
        start(self)

    _node, build = _intake(ros_context)
    with monkeypatch.context() as patch:
        patch.setattr(threading.Thread, 'start', late)
        intake = build()
    intake.stop()
    for thread in _reader_threads():
        thread.join(2.0)
        assert not thread.is_alive()
    assert thread_errors == []



class Batches:
    """What an intake hands over: (steady time s, IMU message count) per batch."""

    def __init__(self) -> None:
        self.got: list[tuple[float, int]] = []
        self.event = threading.Event()

    def __call__(self, imu: list[bytes], odom: list[bytes]) -> None:
        self.got.append((time.monotonic(), len(imu)))
        self.event.set()


def _batching(ctx: Any, period_s: float, rate_hz: float) -> tuple[Any, Any, Batches]:
    """An intake of ``period_s`` at ``rate_hz`` (batch = round(period x rate)) and a RELIABLE
    publisher on its topic, matched."""
    from rclpy.node import Node
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.imu_input import ImuIntake
    from railgsa_ros.nodes.qos import sensor_qos

    node = Node('imu_batching_probe', context=ctx)
    values = {**VALUES, 'imu_qos_depth': 100, 'imu_reliability': 'reliable', 'use_odom': False,
              'rate_hz': rate_hz}
    batches = Batches()
    intake = ImuIntake(node, values, batches, lambda: None, period_s)
    pub = node.create_publisher(Imu, 'imu/data', sensor_qos(100, 'reliable'))
    deadline = time.monotonic() + 10.0
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert pub.get_subscription_count() == 1
    return intake, pub, batches


def _publish(pub: Any, count: int) -> float:
    """``count`` Imu messages at once; the steady time before the first, s."""
    from ros_helpers import imu_msg

    start = time.monotonic()
    for k in range(count):
        pub.publish(imu_msg(5, k))
    return start


@pytest.mark.ros
def test_a_full_batch_goes_at_once_and_a_partial_one_after_the_period(
        ros_context: Any) -> None:
    """period 1.2 s at 5 Hz: batches of 6. Six messages are handed over together before the
    period ends (the reader sleeps at most while 5 Hz could not have brought them, 0.8 s); two
    wait the period out and go together; none is handed over twice."""
    intake, pub, batches = _batching(ros_context, 1.2, 5.0)
    assert intake.batch == 6
    try:
        start = _publish(pub, 6)
        assert batches.event.wait(5.0)
        assert batches.got[0][1] == 6 and batches.got[0][0] - start < 1.15
        batches.event.clear()
        start = _publish(pub, 2)
        assert batches.event.wait(5.0)
        when, count = batches.got[1]
        assert count == 2 and when - start >= 1.15
        time.sleep(0.2)
        assert len(batches.got) == 2
    finally:
        intake.destroy()


@pytest.mark.ros
def test_without_a_period_every_message_goes_as_it_comes(ros_context: Any) -> None:
    intake, pub, batches = _batching(ros_context, 0.0, 1000.0)
    assert intake.batch == 1
    try:
        _publish(pub, 1)
        assert batches.event.wait(5.0)
        assert batches.got == [(batches.got[0][0], 1)]
    finally:
        intake.destroy()


@pytest.mark.ros
def test_messages_held_for_a_batch_are_taken_after_stop(ros_context: Any) -> None:
    """A stop while messages wait for their batch (deactivate) loses none: ``take`` returns
    them first."""
    intake, pub, batches = _batching(ros_context, 30.0, 10.0)  # batches of 300
    try:
        _publish(pub, 3)
        deadline = time.monotonic() + 5.0
        while len(intake._held[0]) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        intake.stop()
        imu, odom = intake.take(10)
        assert (len(imu), odom, batches.got) == (3, [], [])
    finally:
        intake.destroy()
