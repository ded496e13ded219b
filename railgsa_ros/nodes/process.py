"""The one node process wrapper: every node's ``run`` is ``run_node(build, args, ...)``.

``run_node`` checks ``ROS_DOMAIN_ID`` (``system.env_domain``: a value that is no domain id is
one line and exit 2, not an rclpy traceback) and the ``--params-file`` arguments (optional),
starts rclpy WITHOUT its signal
handlers, builds the node, runs its session and shuts down: the node destroyed, the context
shut down, exit code 0. Signals: started as a node, ``early_signals`` makes SIGINT/SIGTERM exit 0
until the node is built; from then on (and, in any other process, from the start) a signal only
sets the ``stop`` event (``playback.signals.stop_on_signals``), never raising inside rclpy; the
session sees it within ``STOP_POLL_S`` and ends normally (a lifecycle node flushes, a recorder
drains). RailGsaError (bad parameters, an unusable bag) propagates: ``console_main`` prints one
line and exits 2. A failure once the context is shut down is part of stopping, not an error.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from contextlib import ExitStack
import gc
import sys
import threading
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from railgsa_ros.nodes import early_signals
from railgsa_ros.nodes.params import check_params_files
from railgsa_ros.nodes.specs import ALL_PARAMETER_NAMES
from railgsa_ros.playback.signals import stop_on_signals
from railgsa_ros.system import env_domain

STOP_POLL_S = 0.1  #: a stop request is noticed within this, s
#: (node, executor with the node, stopped()) -> None: the node's work until stopped or done
Session = Callable[[Any, SingleThreadedExecutor, Callable[[], bool]], None]


def spin_until_stopped(node: Any, executor: SingleThreadedExecutor,
                       stopped: Callable[[], bool]) -> None:
    """The default session: spin until a stop request."""
    while not stopped():
        executor.spin_once(timeout_sec=STOP_POLL_S)


def run_node(build: Callable[[], Any], args: list[str] | None = None, *,
             session: Session = spin_until_stopped, stop: threading.Event | None = None,
             params: tuple[str, Collection[str]] | None = None,
             close: Callable[[Any], None] | None = None) -> int:
    """Run the node ``build()`` makes with ROS ``args`` until its session ends: exit code 0.

    ``params`` (node name, the parameters it declares): every ``--params-file`` of ``args``
    (default ``sys.argv[1:]``) is checked before rclpy starts (ConfigError naming the file).
    ``stop``: an event that ends the session like a signal (the CLI's). ``close(node)`` runs
    before the node is destroyed, also after an error (the recorder finishes its bag there).
    ConfigError when ``ROS_DOMAIN_ID`` is set to no domain id (before rclpy reads it).
    """
    env_domain()
    if params is not None:
        check_params_files(sys.argv[1:] if args is None else args, *params, ALL_PARAMETER_NAMES)
    stop = stop or threading.Event()
    node = None
    with ExitStack() as signals:
        own = early_signals.installed()
        if not own:
            signals.enter_context(stop_on_signals(stop))
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            node = build()
            gc.freeze()  # the start-up objects leave the cyclic collector: its full passes
            # over them stalled the 1 kHz data path for ~50 ms (benchmarks/bench_node_latency)
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            if own:
                signals.enter_context(stop_on_signals(stop))
            session(node, executor, lambda: stop.is_set() or not rclpy.ok())
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception:
            if rclpy.ok():  # a genuine failure, not one of stopping
                raise
        finally:
            try:
                if node is not None and close is not None:
                    close(node)
            finally:
                _destroy(node)
                rclpy.try_shutdown()
    return 0


def _destroy(node: Any) -> None:
    """Destroy the node; a failure after the context is shut down is part of stopping."""
    if node is None:
        return
    try:
        node.destroy_node()
    except Exception:
        if rclpy.ok():
            raise
