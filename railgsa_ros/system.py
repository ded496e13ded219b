"""Node processes for the demo and the integration tests: our stand-in for ROS 2 launch.

Each process is ``python -m <module> ...`` with stdout/stderr in log files, an environment with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a reserved ``ROS_DOMAIN_ID`` (as
``domain_coordinator``: a bound localhost TCP port 32768 + id holds the id), readiness by waiting
for a line of its output, and a stop by SIGINT, then SIGTERM, then SIGKILL. Each process leads a
process group of its own: a terminal's Ctrl-C (SIGINT to the foreground group) reaches only the
parent, which forwards exactly one signal; in the parent's group a node got two, and the second,
landing while the interpreter exited, killed it (exit -2, ``railgsa run`` exit 1 in one try of
eight). ROS-free: nothing here imports rclpy.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
import os
from pathlib import Path
import random
import re
import signal
import socket
import subprocess
import sys
import threading
import time

from railgsa_ros.errors import ConfigError

PORT_BASE = 32768
CLI_MODULE = 'railgsa_ros.cli.main'
NODES_PACKAGE = 'railgsa_ros.nodes'


def reserve_domain(seed: int | None = None) -> tuple[int, socket.socket | None]:
    """A free ROS domain id in 1..100 and the socket holding it (None: pid fallback, unheld)."""
    ids = list(range(1, 101))
    random.Random(os.getpid() if seed is None else seed).shuffle(ids)
    for domain in ids:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.bind(('127.0.0.1', PORT_BASE + domain))
        except OSError:
            sock.close()
            continue
        return domain, sock
    return 1 + os.getpid() % 100, None


@contextmanager
def isolated_domain() -> Iterator[int]:
    """Reserve a domain id and export it with localhost-only discovery for this process and its
    children; on exit the id is released and the previous environment restored."""
    names = ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_LOCALHOST_ONLY', 'ROS_DOMAIN_ID')
    saved = {name: os.environ.get(name) for name in names}
    domain, sock = reserve_domain()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    try:
        yield domain
    finally:
        if sock is not None:
            sock.close()
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


#: ROS_DOMAIN_ID values rmw_fastrtps can use (its port formula ends at 232)
MAX_DOMAIN_ID = 232


def env_domain() -> int | None:
    """``ROS_DOMAIN_ID`` of the environment, None when unset or empty; ConfigError when it is
    not a domain id."""
    text = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if not text:
        return None
    if not text.isdigit() or int(text) > MAX_DOMAIN_ID:
        raise ConfigError(f'ROS_DOMAIN_ID: {text!r} is not a domain id (0-{MAX_DOMAIN_ID})')
    return int(text)


@contextmanager
def session_domain() -> Iterator[int]:
    """The domain of a command that starts ROS processes (the demo): ``ROS_DOMAIN_ID`` when
    set (localhost discovery for the children all the same, ``ros_env``), else a reserved one
    (``isolated_domain``)."""
    domain = env_domain()
    if domain is None:
        with isolated_domain() as reserved:
            yield reserved
    else:
        yield domain


def ros_env(base: Mapping[str, str] | None = None, localhost: bool = True) -> dict[str, str]:
    """The environment of a child: ``base`` (default os.environ), localhost discovery (unless
    ``localhost`` is false: the user's own discovery settings, for ``railgsa run`` on a train),
    unbuffered Python output (readiness lines arrive at once)."""
    env = dict(os.environ if base is None else base)
    if localhost:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        env.pop('ROS_LOCALHOST_ONLY', None)
    env['PYTHONUNBUFFERED'] = '1'
    return env


@dataclass(frozen=True)
class NodeResult:
    """Outcome of a process: return code and its captured output."""

    rc: int
    stdout: str
    stderr: str


class NodeProcess:
    """``python -m <module> <args>`` in a process group of its own; stdout/stderr go to
    ``<logdir>/<name>-<ns>.out|.err``, or to this process's own when ``logdir`` is None
    (``railgsa run``: the nodes' lines on the terminal; ``output`` is then empty)."""

    def __init__(self, module: str, args: list[str], logdir: Path | None,
                 name: str | None = None, cwd: Path | None = None,
                 localhost: bool = True) -> None:
        self.name = name or module.rsplit('.', 1)[-1]
        self.out_path = self.err_path = None
        fds: list[int | None] = [None, None]
        if logdir is not None:
            logdir.mkdir(parents=True, exist_ok=True)
            stem = f'{self.name}-{time.monotonic_ns()}'
            self.out_path, self.err_path = logdir / f'{stem}.out', logdir / f'{stem}.err'
            fds = [os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                   for p in (self.out_path, self.err_path)]
        try:
            self.proc = subprocess.Popen([sys.executable, '-m', module, *args], stdout=fds[0],
                                         stderr=fds[1], cwd=cwd, env=ros_env(localhost=localhost),
                                         stdin=subprocess.DEVNULL, process_group=0)
        finally:
            for fd in fds:
                if fd is not None:
                    os.close(fd)

    def running(self) -> bool:
        """Whether the process is still alive."""
        return self.proc.poll() is None

    def output(self) -> str:
        """Everything written so far, stdout then stderr ('' without log files)."""
        return '\n'.join(p.read_text('utf-8', 'replace') for p in (self.out_path, self.err_path)
                         if p is not None)

    def wait_for_line(self, pattern: str, timeout: float, period: float = 0.05) -> bool:
        """Wait until a line of the output matches the regex ``pattern`` (True), the process
        ends or ``timeout`` s pass (False)."""
        regex = re.compile(pattern, re.MULTILINE)
        deadline = time.monotonic() + timeout
        while True:
            if regex.search(self.output()):
                return True
            if not self.running() or time.monotonic() >= deadline:
                return False
            time.sleep(period)

    def wait(self, timeout: float) -> int | None:
        """Wait up to ``timeout`` s for the process to end; its return code or None."""
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0) -> NodeResult:
        """Send ``sig`` (if still running) and wait ``timeout`` s; then SIGTERM and 5 s more,
        then SIGKILL. Returns the result with the whole output."""
        for step, wait_s in ((sig, timeout), (signal.SIGTERM, 5.0), (signal.SIGKILL, None)):
            if not self.running():
                break
            self.proc.send_signal(step)
            try:
                self.proc.wait(wait_s)
            except subprocess.TimeoutExpired:
                continue
        rc = self.proc.wait()
        out, err = (p.read_text('utf-8', 'replace') if p is not None else ''
                    for p in (self.out_path, self.err_path))
        return NodeResult(rc, out, err)


class System:
    """The processes of one run: nodes and ``railgsa`` commands, all stopped (newest first) when
    the ``with`` block ends, also on an error or Ctrl-C."""

    def __init__(self, logdir: Path | None, cwd: Path | None = None,
                 localhost: bool = True) -> None:
        """``logdir``: where each process's output goes (None: this process's stdout/stderr);
        ``localhost``: force localhost discovery (see ``ros_env``)."""
        self.logdir, self.cwd = None if logdir is None else Path(logdir), cwd
        self.localhost = localhost
        self.processes: list[NodeProcess] = []

    def node(self, node: str, ros_args: list[str] | None = None) -> NodeProcess:
        """Start ``railgsa_ros.nodes.<node> --ros-args <ros_args>``."""
        return self._start(f'{NODES_PACKAGE}.{node}', ['--ros-args', *(ros_args or [])], node)

    def command(self, *args: str) -> NodeProcess:
        """Start ``railgsa <args>`` (replay, record, ...)."""
        return self._start(CLI_MODULE, list(args), f'railgsa-{args[0]}')

    def _start(self, module: str, args: list[str], name: str) -> NodeProcess:
        proc = NodeProcess(module, args, self.logdir, name, self.cwd, self.localhost)
        self.processes.append(proc)
        return proc

    def watch(self, stop: threading.Event, period_s: float = 0.1) -> NodeProcess | None:
        """Wait until ``stop`` is set (None) or a process ends (that process)."""
        while not stop.wait(period_s):
            ended = next((p for p in self.processes if not p.running()), None)
            if ended is not None:
                return ended
        return None

    def stop(self) -> dict[str, NodeResult]:
        """Stop every process still running, newest first; name -> result (last of a name)."""
        return {p.name: p.stop() for p in reversed(self.processes)}

    def __enter__(self) -> System:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
