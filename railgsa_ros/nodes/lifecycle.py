"""Managed (lifecycle) node base shared by irregularity_node and uncertainty_node, and ``run``.

Transitions (REP-free summary; docs/nodes.md has the table):

- configure: declare and validate the parameters, build the model (``configure``); a
  ConfigError is logged, kept in ``config_error`` and the node stays unconfigured;
- activate: subscriptions and diagnostics on (``activate``), lifecycle publishers enabled;
- deactivate: input waiting in the reader processed, the filters flushed and every output
  published (paced) and acknowledged, then subscriptions and diagnostics off (``deactivate``),
  publishers disabled;
- cleanup / shutdown: the model and every interface released (``release``).

A transition the current state does not have (cleanup or configure while active, activate while
unconfigured, any unknown id) is answered ``success: false`` on ``~/change_state``
(rcl_lifecycle logs one WARN line); the node keeps its state and keeps running (rclpy raises
RCLError for it inside the service callback, which ended the process with exit 1).

Parameter ``autostart`` (default true): ``autostart()``, called at the end of the subclass
constructor, walks the node to active and raises ConfigError when configuring fails; ``run`` turns
that into exit code 2 and one line.
Each process start gets a ``boot_id`` and a wall-clock ``started_ns`` for /diagnostics, so a
restart is visible there. Each activation logs one line (``describe``): method, band, topics.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import suppress
import time
from typing import Any
import uuid

from lifecycle_msgs.srv import ChangeState
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.lifecycle import LifecycleState, Node, TransitionCallbackReturn

from railgsa_ros.errors import ConfigError
from railgsa_ros.nodes import console_main
from railgsa_ros.nodes.params import ParamSpec, declare
from railgsa_ros.nodes.process import run_node, spin_until_stopped

AUTOSTART = ParamSpec('autostart', True, 'configure and activate at start-up (false: wait for '
                      '~/change_state)', read_only=True)
SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
#: one id per process: a node restarted by a supervisor shows a new one on /diagnostics
BOOT_ID = uuid.uuid4().hex[:12]
STARTED_NS = time.time_ns()


class ManagedNode(Node):
    """A lifecycle node; subclasses set NODE_NAME and SPECS (their parameters) and implement
    configure, activate, deactivate and release."""

    NODE_NAME = ''
    SPECS: tuple[ParamSpec, ...] = ()

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.config_error: str | None = None
        self.activations = 0  #: transitions to active in this process
        self._autostarting = False  # autostart reports a failed configure itself (exit 2)
        for service in self.services:
            if service.srv_type is ChangeState:
                service.callback = self._refusing_invalid(service.callback)

    def _refusing_invalid(self, answer: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
        """The ``~/change_state`` callback ``answer``, with a transition the current state does
        not have answered ``success: false`` instead of raising RCLError (rcl_lifecycle logs
        the WARN line)."""
        def guarded(request: Any, response: Any) -> Any:
            try:
                return answer(request, response)
            except rclpy_implementation.RCLError:
                response.success = False
                return response
        return guarded

    def autostart(self) -> None:
        """With parameter autostart (default true): ``start()``."""
        if declare(self, (AUTOSTART,))['autostart']:
            self._autostarting = True
            try:
                self.start()
            finally:
                self._autostarting = False

    def start(self) -> None:
        """Configure then activate; ConfigError with the reason if either fails."""
        if self.trigger_configure() != SUCCESS:
            raise ConfigError(self.config_error or 'configure failed')
        if self.trigger_activate() != SUCCESS:
            raise ConfigError('activate failed')

    @classmethod
    def parameter_names(cls) -> frozenset[str]:
        """Every parameter the node declares (a params file may set no other)."""
        return frozenset(s.name for s in (*cls.SPECS, AUTOSTART))

    def finish(self) -> None:
        """Shut down through the lifecycle: deactivate (pending input processed, filters
        flushed, outputs published and acknowledged), then release; nothing when the node
        was already shut down (``~/change_state`` shutdown)."""
        with suppress(rclpy_implementation.RCLError):  # finalized: released already
            self.trigger_shutdown()

    def guarded(self, step: Callable[[], Any], what: str, recover: Callable[[], None]) -> Any:
        """``step()`` of the core, or None when it raised: the exception is counted as
        ``internal_error`` (in the subclass's ``_counts``), logged at most once a second and
        ``recover()`` rebuilds the core (chainage continued): a node survives anything the core
        trips on."""
        try:
            return step()
        except Exception as exc:
            self._counts['internal_error'] += 1
            self.get_logger().error(f'{what} failed, filters reset: {exc!r}',
                                    throttle_duration_sec=1.0)
            recover()
            return None

    def lifecycle_values(self) -> dict[str, object]:
        """Process and lifecycle facts for /diagnostics."""
        return {'boot_id': BOOT_ID, 'started_unix_s': STARTED_NS / 1e9,
                'activations': self.activations}

    # ------------------------------------------------------------------ transitions
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.configure()
        except ConfigError as exc:
            self.config_error = str(exc)
            if not self._autostarting:
                self.get_logger().error(f'configure failed: {exc}')
            self.release()
            return FAILURE
        self.config_error = None
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.activate()
        self.activations += 1
        self.get_logger().info(self.describe())
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.deactivate()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.release()
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.deactivate()
        self.release()
        return super().on_shutdown(state)

    # ------------------------------------------------------------------ for subclasses
    def configure(self) -> None:
        """Declare/read the parameters and build the model; ConfigError if invalid."""
        raise NotImplementedError

    def activate(self) -> None:
        """Create the subscriptions and timers (publishers are lifecycle publishers)."""
        raise NotImplementedError

    def deactivate(self) -> None:
        """Destroy what ``activate`` created; harmless when not active."""
        raise NotImplementedError

    def release(self) -> None:
        """Drop the model and the publishers; harmless when not configured."""
        raise NotImplementedError

    def describe(self) -> str:
        """The one line logged at each activation (the start-up line): method, band, topics."""
        raise NotImplementedError

    def topic_line(self, inputs: Sequence[str], outputs: Sequence[str]) -> str:
        """``in, in -> out, out`` with every topic name resolved (namespace, remaps)."""
        def names(topics: Sequence[str]) -> str:
            return ', '.join(self.resolve_topic_name(t) for t in topics)
        return f'{names(inputs)} -> {names(outputs)}'


def run(factory: type[ManagedNode], args: list[str] | None = None) -> int:
    """Build the node and spin until SIGINT/SIGTERM (``process.run_node``): exit code 0, or 2
    with one line ``error: <reason>`` for a bad ``--params-file`` (missing, malformed, unknown
    keys, no section for the node) or when autostart fails on bad parameters. A stop request
    shuts the node down through its lifecycle (``finish``: pending input processed, the filters
    flushed, every output published and acknowledged) and the process exits 0."""
    def session(node: ManagedNode, executor: SingleThreadedExecutor,
                stopped: Callable[[], bool]) -> None:
        spin_until_stopped(node, executor, stopped)
        node.finish()

    return console_main(lambda ros_args: run_node(
        factory, ros_args, session=session,
        params=(factory.NODE_NAME, factory.parameter_names())), args)
