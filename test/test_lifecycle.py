"""Managed lifecycle of irregularity_node and uncertainty_node (in-process), and SIGINT/SIGTERM at
start-up moments of every node process (exit 0, no traceback)."""

from __future__ import annotations

from collections.abc import Callable
import signal
import time
from typing import Any

import numpy as np
import pytest
from ros_helpers import T0_NS, imu_msgs, serialized
from test_irregularity_node import PARAMS, offline
from test_irregularity_node import run as run

pytestmark = pytest.mark.ros


def _overrides(**params: Any) -> list:
    from rclpy.parameter import Parameter

    return [Parameter(k, value=v) for k, v in {**PARAMS, **params}.items()]


def _state(node: Any) -> str:
    return node._state_machine.current_state[1]


def test_transitions_walk_the_node_through_its_states(run: Any, ros_context: Any) -> None:
    from rclpy.lifecycle import TransitionCallbackReturn as R

    from railgsa_ros.nodes.irregularity_node import IrregularityNode

    node = IrregularityNode(context=ros_context, parameter_overrides=_overrides(autostart=False))
    try:
        assert _state(node) == 'unconfigured' and not node.has_parameter('method')
        assert node.count_subscribers('track/irregularity') == 0
        # imu/data readers of nodes that earlier tests of this process left in the graph
        others = node.count_subscribers('imu/data')
        assert node.trigger_configure() == R.SUCCESS and _state(node) == 'inactive'
        assert node.count_publishers('track/irregularity') == 1
        assert node.count_subscribers('imu/data') == others          # inactive: no input
        stamps, acc = run.stamps_ns[:3000] + T0_NS, run.accel[:3000, 2]
        assert node.process(serialized(imu_msgs(stamps, acc))) is None  # nothing processed
        assert node.trigger_activate() == R.SUCCESS and _state(node) == 'active'
        assert node.count_subscribers('imu/data') == others + 1
        out = node.process(serialized(imu_msgs(stamps, acc)))
        ref = offline(stamps, acc)
        np.testing.assert_array_equal(out.stamps_ns, ref.stamps_ns)
        np.testing.assert_array_equal(out.u_m, ref.u_m)
        assert node.trigger_deactivate() == R.SUCCESS and _state(node) == 'inactive'
        assert node.count_subscribers('imu/data') == others
        assert node.trigger_cleanup() == R.SUCCESS and _state(node) == 'unconfigured'
        assert node.count_publishers('track/irregularity') == 0
        assert node.counters()['accepted'] == 3000              # kept across the cleanup
        assert node.trigger_configure() == R.SUCCESS and node.trigger_activate() == R.SUCCESS
        assert node.activations == 2
    finally:
        node.destroy_node()


def test_uncertainty_node_transitions(run: Any, ros_context: Any) -> None:
    from rclpy.lifecycle import TransitionCallbackReturn as R

    from railgsa_ros.nodes.uncertainty_node import UncertaintyNode

    node = UncertaintyNode(context=ros_context, parameter_overrides=_overrides(autostart=False))
    try:
        band = 'track/irregularity_band'
        assert node.trigger_configure() == R.SUCCESS and node.count_publishers(band) == 1
        assert node.count_subscribers('imu/data') == 0
        assert node.trigger_activate() == R.SUCCESS
        assert node.count_subscribers('imu/data') == 1  # the polled reader
        stamps, acc = run.stamps_ns[:2500] + T0_NS, run.accel[:2500, 2]
        assert len(node.process(serialized(imu_msgs(stamps, acc)))) == \
            2500 - node.stream.delay_samples
        assert node.trigger_deactivate() == R.SUCCESS and node.count_subscribers('imu/data') == 0
        assert node.process(serialized(imu_msgs(stamps, acc))) is None
        assert node.trigger_cleanup() == R.SUCCESS and node.count_publishers(band) == 0
        assert node.counters()['accepted'] == 2500
    finally:
        node.destroy_node()


@pytest.mark.parametrize('module,cls', [('irregularity_node', 'IrregularityNode'),
                                        ('uncertainty_node', 'UncertaintyNode')])
def test_bad_parameters_keep_the_node_unconfigured(module: str, cls: str,
                                                   ros_context: Any) -> None:
    import importlib

    from rclpy.lifecycle import TransitionCallbackReturn as R

    node_cls = getattr(importlib.import_module(f'railgsa_ros.nodes.{module}'), cls)
    node = node_cls(context=ros_context,
                    parameter_overrides=_overrides(autostart=False, method='banana'))
    try:
        assert node.trigger_configure() == R.FAILURE
        assert _state(node) == 'unconfigured'
        assert 'method' in node.config_error and 'banana' in node.config_error
    finally:
        node.destroy_node()


class LifecycleClient:
    """``~/get_state`` and ``~/change_state`` of a node process, called from this process."""

    def __init__(self, node_name: str, context: Any, proc: Any) -> None:
        from lifecycle_msgs.srv import ChangeState, GetState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.node = Node(f'lifecycle_client_{node_name}', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self._get = self.node.create_client(GetState, f'{node_name}/get_state')
        self._change = self.node.create_client(ChangeState, f'{node_name}/change_state')
        if not (self._get.wait_for_service(90.0) and self._change.wait_for_service(10.0)):
            graph = (self.node.get_node_names_and_namespaces(),
                     self.node.get_service_names_and_types())
            raise AssertionError(f'no lifecycle services; node alive: {proc.running()}; '
                                 f'graph: {graph}; stderr: {proc.stop().stderr}')

    def _call(self, cli: Any, req: Any) -> Any:
        """Retried: the graph may still list the services of nodes destroyed by earlier tests,
        and a request sent to those is never answered."""
        import rclpy

        for _ in range(6):
            future = cli.call_async(req)
            rclpy.spin_until_future_complete(self.node, future, self.executor, timeout_sec=10.0)
            if future.done():
                return future.result()
            cli.remove_pending_request(future)
        raise AssertionError(f'no answer to {req}')

    def state(self) -> str:
        from lifecycle_msgs.srv import GetState

        return self._call(self._get, GetState.Request()).current_state.label

    def change(self, transition: int | str) -> bool:
        """Request a transition by id or label; the service's ``success``."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        request = Transition(id=transition) if isinstance(transition, int) else \
            Transition(label=transition)
        return self._call(self._change, ChangeState.Request(transition=request)).success


def test_change_state_service_activates_a_node_started_without_autostart(
        ros_context: Any, wait_for: Callable, start_node: Callable) -> None:
    from lifecycle_msgs.msg import Transition

    params = {**PARAMS, 'autostart': False}
    proc = start_node('railgsa_ros.nodes.irregularity_node',
                      [a for k, v in params.items() for a in ('-p', f'{k}:={str(v).lower()}')])
    client = LifecycleClient('irregularity_node', ros_context, proc)
    assert client.state() == 'unconfigured'
    assert client.node.count_subscribers('imu/data') == 0
    for tid in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
        assert client.change(tid)
    assert client.state() == 'active'
    assert wait_for(lambda: client.node.count_subscribers('imu/data') == 1, 10.0)
    result = proc.stop(signal.SIGTERM)
    assert (result.rc, 'Traceback' in result.stderr) == (0, False), result.stderr


def _invalid_transitions() -> dict[str, tuple[int | str, ...]]:
    """State -> every request its state machine has no transition for (ids of the other
    states' transitions, a label, an id that names no transition)."""
    from lifecycle_msgs.msg import Transition

    t = Transition
    return {
        'active': (t.TRANSITION_CONFIGURE, t.TRANSITION_CLEANUP, t.TRANSITION_ACTIVATE,
                   t.TRANSITION_UNCONFIGURED_SHUTDOWN, t.TRANSITION_INACTIVE_SHUTDOWN,
                   'cleanup', 'configure', 99),
        'inactive': (t.TRANSITION_CONFIGURE, t.TRANSITION_DEACTIVATE,
                     t.TRANSITION_ACTIVE_SHUTDOWN, 'deactivate'),
        'unconfigured': (t.TRANSITION_ACTIVATE, t.TRANSITION_DEACTIVATE, t.TRANSITION_CLEANUP,
                         'activate'),
    }


@pytest.mark.parametrize('module', ['irregularity_node', 'uncertainty_node'])
def test_an_invalid_transition_is_refused_and_the_node_keeps_running(
        module: str, ros_context: Any, wait_for: Callable, start_node: Callable) -> None:
    """Issue 22: cleanup or configure while active killed either node (RCLError out of the
    service callback, exit 1). Every request the current state has no transition for is
    answered false, the state stays, and the node still walks its valid transitions, still
    reads its input when active, shuts down by service and then exits 0 on SIGINT."""
    from lifecycle_msgs.msg import Transition

    t = Transition
    params = [a for k, v in PARAMS.items() for a in ('-p', f'{k}:={str(v).lower()}')]
    proc = start_node(f'railgsa_ros.nodes.{module}', params)
    client = LifecycleClient(module, ros_context, proc)
    assert wait_for(lambda: client.state() == 'active', 60.0)
    invalid = _invalid_transitions()
    for state, valid in (('active', t.TRANSITION_DEACTIVATE), ('inactive', t.TRANSITION_CLEANUP),
                         ('unconfigured', t.TRANSITION_CONFIGURE)):
        for request in invalid[state]:
            assert not client.change(request), (state, request)
            assert proc.running() and client.state() == state, (state, request, proc.output())
        assert client.change(valid)
    assert client.change(t.TRANSITION_ACTIVATE) and client.state() == 'active'
    assert wait_for(lambda: client.node.count_subscribers('imu/data') == 1, 10.0)
    # shut down by service, then SIGINT: the stop finds the node finalized
    assert client.change(t.TRANSITION_ACTIVE_SHUTDOWN) and client.state() == 'finalized'
    result = proc.stop(signal.SIGINT)
    assert (result.rc, 'Traceback' in result.stderr) == (0, False), result.stderr
    assert result.stderr.count('No transition matching') == sum(map(len, invalid.values()))


#: seconds after the node module's first line ran (its handlers are in place): during the heavy
#: imports, rclpy.init, building the model, after readiness. Before that first line (about 60 ms
#: of interpreter start-up) Python's own defaults apply (docs/reliability.md).
MOMENTS = (0.0, 0.2, 0.5, 2.5)


def _catches_sigterm(pid: int) -> bool:
    """Whether process ``pid`` has a SIGTERM handler (SigCgt in /proc/<pid>/status)."""
    try:
        status = open(f'/proc/{pid}/status').read()  # noqa: SIM115
    except FileNotFoundError:
        return False
    mask = int(next(ln for ln in status.splitlines() if ln.startswith('SigCgt:')).split()[1], 16)
    return bool(mask >> (signal.SIGTERM - 1) & 1)


@pytest.mark.parametrize('module', ['irregularity_node', 'uncertainty_node', 'recorder'])
def test_signal_at_any_start_up_moment_exits_0(module: str, start_node: Callable,
                                               wait_for: Callable, tmp_path: Any) -> None:
    args = {'recorder': lambda i: ['-p', f'out:={tmp_path}/bag{i}', '-p', 'topics:=[/x]']}.get(
        module, lambda i: [])
    sigs = (signal.SIGINT, signal.SIGTERM) * 2
    procs = [start_node(f'railgsa_ros.nodes.{module}', args(i)) for i in range(len(MOMENTS))]
    for proc, moment, sig in zip(procs, MOMENTS, sigs, strict=True):
        assert wait_for(lambda p=proc: _catches_sigterm(p.proc.pid), 30.0, 0.001)
        time.sleep(moment)
        proc.proc.send_signal(sig)
    for proc, moment, sig in zip(procs, MOMENTS, sigs, strict=True):
        result = proc.stop(sig)
        assert result.rc == 0, (moment, sig, result.stderr)
        assert 'Traceback' not in result.stderr and 'Error' not in result.stderr, result.stderr
