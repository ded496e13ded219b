"""The IMU intake's reader thread under a signal that comes while it starts (no traceback)."""

from __future__ import annotations

import threading
from typing import Any

import pytest

VALUES = {'imu_qos_depth': 10, 'idle_flush_s': 2.0, 'imu_reliability': 'best_effort',
          'odom_reliability': 'best_effort', 'use_odom': True}


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

