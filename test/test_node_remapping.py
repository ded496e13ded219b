"""Node names and namespaces remap like any ROS node's: ``__node`` and ``__ns`` given as global
arguments (what ``--ros-args -r`` on the command line does: ``run`` hands them to rclpy.init)
rename and move each node and every topic it reads and writes, with no second node in the
graph; two trains' node pairs side by side in one domain each consume only their own train's
imu/data and publish only into their own namespace."""

from __future__ import annotations

from collections.abc import Callable, Iterator
import threading
from typing import Any

import numpy as np
import pytest
from ros_helpers import NS, Collector, DiagnosticsLog, imu_msgs, point_row, vector_row

pytestmark = pytest.mark.ros

#: no band filter: every accepted sample comes out at once (short tests); a cheap rule
PARAMS = {'use_odom': False, 'speed_mps': 40.0, 'min_design_speed_mps': 40.0,
          'method': 'feedback', 'band': 'none', 'rule': 'pem3', 'order': 1,
          'window_length': 0.5, 'n_mc': 256, 'germ_samples': 64, 'process_period_s': 0.02}
IRREGULARITY_KEYS = ('use_odom', 'speed_mps', 'min_design_speed_mps', 'method', 'band')
NODES = {'irregularity_node': ('railgsa_ros.nodes.irregularity_node', 'IrregularityNode',
                               IRREGULARITY_KEYS),
         'uncertainty_node': ('railgsa_ros.nodes.uncertainty_node', 'UncertaintyNode',
                              tuple(PARAMS))}


def make_node(name: str, context: Any) -> Any:
    """irregularity_node or uncertainty_node in ``context`` with its keys of PARAMS."""
    import importlib

    from rclpy.parameter import Parameter

    module, cls, keys = NODES[name]
    return getattr(importlib.import_module(module), cls)(
        context=context, parameter_overrides=[Parameter(k, value=PARAMS[k]) for k in keys])


@pytest.fixture
def observer(ros_context: Any) -> Iterator[Any]:
    """A plain node of the session's context, spun in a thread, to look at the graph."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    node = Node('remap_observer', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    yield node
    executor.shutdown(timeout_sec=2.0)
    thread.join(5.0)
    node.destroy_node()


def graph(observer: Any, namespace: str) -> list[tuple[str, str]]:
    """(name, namespace) of every node in ``namespace`` (with repeats)."""
    return sorted(n for n in observer.get_node_names_and_namespaces() if n[1] == namespace)


def readers(observer: Any, topic: str) -> list[tuple[str, str]]:
    return sorted((i.node_name, i.node_namespace)
                  for i in observer.get_subscriptions_info_by_topic(topic))


def writers(observer: Any, topic: str) -> list[tuple[str, str]]:
    return sorted((i.node_name, i.node_namespace)
                  for i in observer.get_publishers_info_by_topic(topic))


@pytest.mark.parametrize('name', sorted(NODES))
def test_global_node_and_namespace_remaps_give_one_node(name: str, ros_domain: int,
                                                        observer: Any,
                                                        wait_for: Callable) -> None:
    import rclpy
    from rclpy.context import Context

    # a namespace per case: the graph may still list the other case's node for a while
    new_name, ns = 'car_7', f'/train_{name.split("_")[0]}'
    ctx = Context()  # global arguments, as ``run`` passes the command line's to rclpy.init
    rclpy.init(context=ctx, domain_id=ros_domain,
               args=['--ros-args', '-r', f'__node:={new_name}', '-r', f'__ns:={ns}'])
    node = make_node(name, ctx)
    try:
        assert (node.get_name(), node.get_namespace()) == (new_name, ns)
        expected = [(new_name, ns)]
        assert wait_for(lambda: readers(observer, f'{ns}/imu/data') == expected, 10.0), \
            readers(observer, f'{ns}/imu/data')
        output = {'irregularity_node': 'track/irregularity',
                  'uncertainty_node': 'track/irregularity_band'}[name]
        assert wait_for(lambda: writers(observer, f'{ns}/{output}') == expected, 10.0)
        # no helper node, no name twice (waited for: the graph may lag behind)
        assert wait_for(lambda: graph(observer, ns) == expected, 10.0), graph(observer, ns)
        assert readers(observer, '/imu/data') == []
    finally:
        node.destroy_node()
        ctx.try_shutdown()


def test_two_trains_side_by_side_each_pair_reads_only_its_own_imu(
        ros_context: Any, observer: Any, wait_for: Callable) -> None:
    from geometry_msgs.msg import PointStamped, Vector3Stamped
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.qos import output_qos, sensor_qos

    trains = ('/train1', '/train2')
    contexts, nodes = [], []
    for train in trains:  # one context per train: its global __ns remap, as two processes
        ctx = Context()
        rclpy.init(context=ctx, domain_id=ros_context.get_domain_id(),
                   args=['--ros-args', '-r', f'__ns:={train}'])
        contexts.append(ctx)
        nodes += [make_node(n, ctx) for n in sorted(NODES)]
    got: dict[tuple[str, str], Collector] = {}  # rows (stamp, x, y, z)
    pubs = {}
    for train in trains:
        got[train, 'irregularity'] = Collector(observer, PointStamped,
                                               f'{train}/track/irregularity', output_qos(),
                                               point_row)
        got[train, 'band'] = Collector(observer, Vector3Stamped,
                                       f'{train}/track/irregularity_band', output_qos(),
                                       vector_row)
        pubs[train] = observer.create_publisher(Imu, f'{train}/imu/data', sensor_qos())
    diagnostics = DiagnosticsLog(observer)
    spinners = []
    for ctx, pair in zip(contexts, (nodes[:2], nodes[2:]), strict=True):
        ex = SingleThreadedExecutor(context=ctx)
        for node in pair:
            ex.add_node(node)
        spinners.append((ex, threading.Thread(target=ex.spin, daemon=True)))
        spinners[-1][1].start()
    try:
        for train in trains:
            want = sorted(NODES)
            assert wait_for(lambda t=train, w=want: [n for n, _ in readers(
                observer, f'{t}/imu/data')] == w, 10.0), readers(observer, f'{train}/imu/data')
            assert wait_for(lambda t=train: observer.count_publishers(
                f'{t}/track/irregularity_band') == 1 and observer.count_publishers(
                f'{t}/track/irregularity') == 1 and pubs[t].get_subscription_count() == 2,
                10.0)
        assert graph(observer, '/train1') == [(n, '/train1') for n in sorted(NODES)]
        assert graph(observer, '/train2') == [(n, '/train2') for n in sorted(NODES)]
        # the trains' streams: disjoint stamps, different signals
        n = 400
        streams = {'/train1': (10 * NS + np.arange(n) * 1_000_000, 9.80665 + 0.01 * np.sin(
                       np.arange(n) / 20)),
                   '/train2': (50 * NS + np.arange(n) * 1_000_000, 9.80665 - 0.02 * np.cos(
                       np.arange(n) / 7))}
        for train, (stamps, acc) in streams.items():
            for m in imu_msgs(stamps, acc):
                pubs[train].publish(m)
        for train, (stamps, _) in streams.items():
            for kind in ('irregularity', 'band'):
                assert wait_for(lambda k=(train, kind), s=stamps: len(got[k]) >= s.size, 15.0), \
                    (train, kind, len(got[(train, kind)]))
        for train, (stamps, _) in streams.items():
            for kind in ('irregularity', 'band'):
                # exactly this train's stamps, each once, in order: nothing of the other
                # train's (a pair reading both topics would output both stamp ranges)
                np.testing.assert_array_equal([row[0] for row in got[(train, kind)].snapshot()],
                                              stamps)
        # /diagnostics tells the trains apart: each status is named by its node's namespace
        want = {f'{t[1:]}/{n}: imu input' for t in trains for n in NODES}
        assert wait_for(lambda: want <= set(diagnostics.latest()), 5.0), \
            sorted(diagnostics.latest())
    finally:
        for ex, thread in spinners:
            ex.shutdown(timeout_sec=2.0)
            thread.join(5.0)
        for node in nodes:
            node.destroy_node()
        for ctx in contexts:
            ctx.try_shutdown()
