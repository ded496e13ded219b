"""Imported first by every node module: SIGINT/SIGTERM exit with code 0 from the first line on.

When the process was started as a node (``python -m railgsa_ros.nodes.<node>`` or its console
script), importing this module replaces the SIGINT and SIGTERM handlers with one that raises
``SystemExit(0)`` once (later signals are ignored): a stop request during the heavy imports, during
``rclpy.init`` or while the node is built ends the process quietly with code 0, and ``finally``
blocks still run. A signal that lands inside an import exits at once with ``os._exit(0)``
instead: an exception raised there is turned into an ImportError by rclpy's extension loader
(rc 1 and a traceback), and nothing needs cleaning up before the node exists. rclpy's own
handlers are not installed (``process.run_node`` starts rclpy without them). Once the node is
built, ``run_node`` replaces these handlers by ones that only set its stop event (raising
anywhere, e.g. inside rclpy's ``take_message``, is turned into a ``RuntimeError`` and exit 1 in
one try of three), and the node stops, flushes and exits 0. Imported by anything else (tests,
the CLI) it changes nothing. No ROS import.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import sys
import threading
from types import FrameType

SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _inside_import(frame: FrameType | None) -> bool:
    """Whether the interrupted frame runs under the import machinery."""
    while frame is not None:
        if frame.f_code.co_filename.startswith('<frozen importlib'):
            return True
        frame = frame.f_back
    return False


def _exit_once(_signum: int, frame: FrameType | None) -> None:
    for sig in SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    if _inside_import(frame):
        sys.stdout.flush()
        os._exit(0)
    raise SystemExit(0)


def install() -> None:
    """SIGINT/SIGTERM raise SystemExit(0) once (main thread only)."""
    if threading.current_thread() is threading.main_thread():
        for sig in SIGNALS:
            signal.signal(sig, _exit_once)


def installed() -> bool:
    """Whether this process's SIGINT handler is this module's."""
    return signal.getsignal(signal.SIGINT) is _exit_once


def started_as_node(argv0: str) -> bool:
    """Whether ``argv0`` (sys.argv[0]) names a module of railgsa_ros/nodes."""
    stem = Path(argv0).stem
    return bool(stem) and not stem.startswith('_') and (Path(__file__).parent
                                                          / f'{stem}.py').is_file()


if sys.argv and started_as_node(sys.argv[0]):
    install()
