"""Shared fixtures: an isolated ROS 2 domain per test session, contexts, executors, node processes.

Every ROS test runs with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a ROS_DOMAIN_ID reserved
for this session (as ``domain_coordinator`` does: holding a bound localhost TCP port 32768 + id),
so parallel test sessions on one machine never see each other and no traffic leaves loopback.
Tests marked ``ros`` are skipped when rclpy is not importable.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
import importlib.util
import os
from pathlib import Path
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[1]


def _have_rclpy() -> bool:
    """Whether rclpy can be found (without importing it: that takes a second)."""
    try:
        return importlib.util.find_spec('rclpy') is not None
    except (ImportError, ValueError):  # ValueError: sys.modules['rclpy'] is None
        return False


HAVE_RCLPY = _have_rclpy()
_PORT_BASE = 32768


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Skip the tests marked ``ros`` when rclpy is missing."""
    if HAVE_RCLPY:
        return
    skip = pytest.mark.skip(reason='rclpy is not installed (pip install -e .[ros])')
    for item in items:
        if 'ros' in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope='session')
def have_rclpy() -> bool:
    """Whether rclpy is installed (the ``ros`` extra)."""
    return HAVE_RCLPY


def _reserve_domain() -> tuple[int, socket.socket | None]:
    """A free domain id in 1..100 and the socket that holds it (None for the pid fallback)."""
    ids = list(range(1, 101))
    random.Random(os.getpid()).shuffle(ids)
    for domain in ids:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.bind(('127.0.0.1', _PORT_BASE + domain))
        except OSError:
            sock.close()
            continue
        return domain, sock
    return 1 + os.getpid() % 100, None


@pytest.fixture(scope='session', autouse=True)
def ros_domain() -> Iterator[int]:
    """This session's ROS_DOMAIN_ID, localhost only: exported for the whole session (autouse),
    so every subprocess a test starts inherits it."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)
    domain, sock = _reserve_domain()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    try:
        yield domain
    finally:
        if sock is not None:
            sock.close()


@pytest.fixture
def ros_context(ros_domain: int) -> Iterator[Any]:
    """An initialised rclpy Context of its own (not the global one), shut down afterwards."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    try:
        yield ctx
    finally:
        ctx.try_shutdown()


@pytest.fixture
def spin(ros_context: Any) -> Iterator[Callable[[Any], Any]]:
    """A background SingleThreadedExecutor; ``spin(node)`` adds a node and returns it."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=ros_context)
    nodes: list[Any] = []
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()

    def add(node: Any) -> Any:
        executor.add_node(node)
        nodes.append(node)
        return node

    try:
        yield add
    finally:
        executor.shutdown(timeout_sec=2.0)
        thread.join(5.0)
        for node in nodes:
            node.destroy_node()


def wait_until(pred: Callable[[], bool], timeout: float, period: float = 0.01) -> bool:
    """Poll ``pred`` every ``period`` s until it is true (True) or ``timeout`` s pass (False)."""
    deadline = time.monotonic() + timeout
    while True:
        if pred():
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(period)


@pytest.fixture
def wait_for() -> Callable[..., bool]:
    """``wait_for(pred, timeout)``: poll every 10 ms; returns whether pred became true."""
    return wait_until


@dataclass(frozen=True)
class NodeResult:
    """Outcome of a node subprocess: return code and its captured output."""

    rc: int
    stdout: str
    stderr: str


class NodeProcess:
    """A node run as ``python -m <module> --ros-args ...``; stdout/stderr go to files in logdir."""

    def __init__(self, module: str, ros_args: list[str], logdir: Path) -> None:
        logdir.mkdir(parents=True, exist_ok=True)
        stem = f'{module.rsplit(".", 1)[-1]}-{time.monotonic_ns()}'
        self.out_path, self.err_path = logdir / f'{stem}.out', logdir / f'{stem}.err'
        fds = [os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
               for p in (self.out_path, self.err_path)]
        try:
            self.proc = subprocess.Popen(
                [sys.executable, '-m', module, '--ros-args', *ros_args],
                stdout=fds[0], stderr=fds[1], cwd=REPO, env=dict(os.environ))
        finally:
            for fd in fds:
                os.close(fd)

    def running(self) -> bool:
        """Whether the process is still alive."""
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0) -> NodeResult:
        """Send ``sig`` (if still running), wait, kill after ``timeout`` s; return the result."""
        if self.running():
            self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait()
        return NodeResult(rc, self.out_path.read_text('utf-8', 'replace'),
                          self.err_path.read_text('utf-8', 'replace'))


@pytest.fixture
def start_node(ros_domain: int, tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    """``start_node('railgsa_ros.nodes.x', ['-p', 'k:=v'])`` -> NodeProcess in this session's
    domain; still-running processes are killed at teardown. Signal only after readiness (e.g.
    after the first message arrived): an early SIGINT hits Python before rclpy is initialised."""
    procs: list[NodeProcess] = []

    def start(module: str, ros_args: list[str] | None = None) -> NodeProcess:
        proc = NodeProcess(module, list(ros_args or []), tmp_path / 'node-logs')
        procs.append(proc)
        return proc

    try:
        yield start
    finally:
        for proc in procs:
            if proc.running():
                proc.stop(signal.SIGKILL, timeout=5.0)
