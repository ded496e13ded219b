"""Shared fixtures: an isolated ROS 2 domain per test session, contexts, executors, node processes.

Every ROS test runs with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a ROS_DOMAIN_ID reserved
for this session (as ``domain_coordinator`` does: holding a bound localhost TCP port 32768 + id),
so parallel test sessions on one machine never see each other and no traffic leaves loopback.
Tests marked ``ros`` are skipped when rclpy is not importable.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import gc
import importlib.util
from pathlib import Path
import signal
import threading
import time
from typing import Any

import pytest

from railgsa_ros.system import NodeProcess, isolated_domain
from railgsa_ros.threads import limit_blas_threads

limit_blas_threads()  # as every entry point does (railgsa_ros/threads.py)

REPO = Path(__file__).resolve().parents[1]


def _have_rclpy() -> bool:
    """Whether rclpy can be found (without importing it: that takes a second)."""
    try:
        return importlib.util.find_spec('rclpy') is not None
    except (ImportError, ValueError):  # ValueError: sys.modules['rclpy'] is None
        return False


HAVE_RCLPY = _have_rclpy()


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


@pytest.fixture(scope='session', autouse=True)
def ros_domain() -> Iterator[int]:
    """This session's ROS_DOMAIN_ID, localhost only: exported for the whole session (autouse),
    so every subprocess a test starts inherits it."""
    with isolated_domain() as domain:
        yield domain


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
        # a destroyed (lifecycle) node leaves the graph only when it is collected (rclpy issue
        # 1710): collect the test's nodes so that later tests see a graph without them
        gc.collect()
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


@pytest.fixture
def start_node(ros_domain: int, tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    """``start_node('railgsa_ros.nodes.x', ['-p', 'k:=v'])`` -> NodeProcess in this session's
    domain; still-running processes are killed at teardown. Signal only after readiness (e.g.
    after the first message arrived): an early SIGINT hits Python before rclpy is initialised."""
    procs: list[NodeProcess] = []

    def start(module: str, ros_args: list[str] | None = None) -> NodeProcess:
        proc = NodeProcess(module, ['--ros-args', *(ros_args or [])], tmp_path / 'node-logs',
                           cwd=REPO)
        procs.append(proc)
        return proc

    try:
        yield start
    finally:
        for proc in procs:
            if proc.running():
                proc.stop(signal.SIGKILL, timeout=5.0)


@pytest.fixture(scope='session')
def short_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3 s simulated bag (German low track, 25 m/s, ADXL355 at 500 Hz, odometry) for command
    tests that read it and never write into it."""
    from railgsa_ros.bag import write_run
    from railgsa_ros.scenario import run_scenario

    run = run_scenario('german-low', 25.0, 3.0, 500.0, 'adxl355', seed=4,
                       start_ns=1_700_000_000 * 10**9)
    path = tmp_path_factory.mktemp('bags') / 'run'
    write_run(path, run)
    return path
