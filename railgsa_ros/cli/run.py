"""``railgsa run``: start irregularity_node and uncertainty_node (and optionally the recorder)
from one params file, as ``ros2 launch railgsa_ros railgsa.launch.py`` does with a ROS install.

The params file is checked first, as rcl will read it for the namespace given (sections
``/**``, ``/**/<node>``, ``/<ns>/<node>``; a bare ``<node>:`` applies only in the root
namespace), with the nodes' own names and the core's checks of the values; and both nodes must
get the same value of every parameter that decides their outputs (inversion, vehicle, input
policy, idle flush), or the band stamps would not be those of track/irregularity. Any problem
is one line, exit 2, before anything starts. Then the nodes run as child processes
(``system.System``) in the environment's ROS domain and discovery range (ROS_DOMAIN_ID,
ROS_AUTOMATIC_DISCOVERY_RANGE: a deployment talks to the train's other computers), each in a
process group of its own, so that a terminal's Ctrl-C reaches only ``railgsa run``. SIGINT,
SIGTERM and SIGHUP (the terminal closed) are forwarded once to them (nodes first, then the
recorder, so that it gets their last outputs; SIGHUP as SIGTERM); a node that exits on its own
stops the others and makes the exit code non-zero.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
import re
import signal
import sys
import threading
from typing import Any

NODES = ('irregularity_node', 'uncertainty_node')
OUTPUTS = ('track/irregularity', 'track/irregularity_band', 'track/sensitivity')
#: parameters both nodes declare that may differ without changing any output
TRANSPORT = frozenset({'imu_qos_depth', 'imu_reliability', 'odom_reliability',
                       'output_qos_depth', 'flush_rate_hz', 'hardware_id', 'autostart'})
#: the stop requests forwarded to the nodes, each as the signal sent to them
FORWARDED: dict[int, int] = {signal.SIGINT: signal.SIGINT, signal.SIGTERM: signal.SIGTERM,
             signal.SIGHUP: signal.SIGTERM}
NAME = re.compile(r'[A-Za-z_][A-Za-z0-9_]*')
#: longest wait for a stopped node (its last band delay published at the flush pace), s
STOP_TIMEOUT_S = 60.0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``run`` subcommand."""
    p = subparsers.add_parser(
        'run', help='start irregularity_node and uncertainty_node from one params file',
        description='Start irregularity_node and uncertainty_node (and with --record the '
                    'recorder) as child processes, both from the same params file, in a '
                    'namespace; the equivalent of ros2 launch railgsa_ros railgsa.launch.py. '
                    'Runs until Ctrl-C / SIGTERM (forwarded to the nodes) or until a node '
                    'fails (exit code non-zero).')
    p.add_argument('--params', metavar='FILE',
                   help='ROS params file for both nodes (shared values under "/**:", each '
                   'node\'s own under "/**/irregularity_node:" and "/**/uncertainty_node:", as '
                   'config/railgsa.yaml); default: the built-in defaults')
    p.add_argument('--namespace', default='', metavar='NS',
                   help='namespace of both nodes and their topics (e.g. train1: '
                   '/train1/imu/data -> /train1/track/irregularity)')
    p.add_argument('--record', metavar='OUT',
                   help='also record the nodes\' outputs and /diagnostics into the bag OUT')
    p.set_defaults(func=run)


def namespace_of(text: str) -> str:
    """``train1`` or ``/a/b`` as an absolute namespace (``/`` for none); ConfigError if it is
    not a ROS namespace."""
    parts = text.strip().strip('/').split('/') if text.strip('/ ') else []
    bad = [p for p in parts if not NAME.fullmatch(p)]
    if bad:
        from railgsa_ros.errors import ConfigError
        raise ConfigError(f'--namespace: {text!r} is not a ROS namespace (names of letters, '
                          'digits and _ separated by /)')
    return '/' + '/'.join(parts)


def node_values(path: str, namespace: str) -> dict[str, dict[str, Any]]:
    """Node -> every parameter value it will run with (the file's over the defaults), read as
    rcl will for ``namespace``; ConfigError naming the file for anything the nodes would
    refuse, and when the two nodes' outputs could differ."""
    from railgsa_ros.config import load_yaml, ros_parameters
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.nodes.specs import (
        ALL_PARAMETER_NAMES,
        INVERSION_SPECS,
        IRREGULARITY_SPECS,
        NODE_SPECS,
        UNCERTAINTY_SPECS,
        VEHICLE_SPECS,
        vehicle_values,
    )
    from railgsa_ros.uncertainty import UncertaintyConfig

    common = (*INVERSION_SPECS, *VEHICLE_SPECS, *NODE_SPECS)
    specs = {NODES[0]: (*common, *IRREGULARITY_SPECS), NODES[1]: (*common, *UNCERTAINTY_SPECS)}
    doc = load_yaml(path)
    values = {}
    for node, own in specs.items():
        defaults = {s.name: s.default for s in own}
        given = ros_parameters(doc, node, {*defaults, 'autostart'}, path,
                               shared_known=ALL_PARAMETER_NAMES, namespace=namespace)
        values[node] = {**defaults, **given}
        InversionConfig.from_mapping({s.name: values[node][s.name] for s in INVERSION_SPECS},
                                     f'{path}: {node}')
        try:
            vehicle_values(values[node])
        except ConfigError as exc:
            raise ConfigError(f'{path}: {node}: {exc}') from None
    names = {f.name for f in fields(UncertaintyConfig)} | {s.name for s in INVERSION_SPECS}
    UncertaintyConfig.from_mapping({k: v for k, v in values[NODES[1]].items() if k in names},
                                   f'{path}: {NODES[1]}')
    differ = sorted(s.name for s in common if s.name not in TRANSPORT
                    and values[NODES[0]][s.name] != values[NODES[1]][s.name])
    if differ:
        first = differ[0]
        raise ConfigError(
            f'{path}: {NODES[0]} and {NODES[1]} get different values of {", ".join(differ)} '
            f'({first}: {values[NODES[0]][first]!r} and {values[NODES[1]][first]!r}): put them '
            'once under "/**:" (the band must have the stamps of track/irregularity)')
    return values


def ros_args(params: str | None, namespace: str) -> list[str]:
    """The nodes' ``--ros-args``: the params file and the namespace."""
    args = ['--params-file', str(Path(params).resolve())] if params else []
    return args + (['-r', f'__ns:={namespace}'] if namespace != '/' else [])


def record_topics(namespace: str) -> list[str]:
    """The recorded topics: the nodes' outputs in ``namespace`` and /diagnostics."""
    prefix = namespace.rstrip('/')
    return [f'{prefix}/{t}' for t in OUTPUTS] + ['/diagnostics']


def forward_signals(stop: threading.Event, received: list[int]) -> Mapping[int, Any]:
    """SIGINT/SIGTERM/SIGHUP set ``stop`` and are noted in ``received`` (as the signal to
    forward, ``FORWARDED``); returns the old handlers."""
    def handler(signum: int, _frame: Any) -> None:
        received.append(FORWARDED[signum])
        stop.set()
    return {s: signal.signal(s, handler) for s in FORWARDED}


def run(args: argparse.Namespace) -> int:
    """Check, start, supervise, stop; 0 after a forwarded signal with every node exiting 0."""
    from railgsa_ros.system import System, env_domain

    env_domain()  # a ROS_DOMAIN_ID that is no domain id: one line now, not two failed nodes
    namespace = namespace_of(args.namespace)
    if args.params:
        node_values(args.params, namespace)
    stop = threading.Event()
    received: list[int] = []  # the signals that asked us to stop
    previous = forward_signals(stop, received)
    try:
        with System(None, localhost=False) as system:
            if args.record:
                system.command('record', '--out', args.record, '--topics',
                               *record_topics(namespace))
            for node in NODES:
                system.node(node, ros_args(args.params, namespace))
            ended = system.watch(stop)
            sig = received[0] if received else signal.SIGINT
            results = {p.name: p.stop(sig, STOP_TIMEOUT_S).rc for p in reversed(system.processes)}
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if ended is not None:
        print(f'error: {ended.name} exited with code {ended.proc.returncode}: stopped the '
              'others', file=sys.stderr)
        return ended.proc.returncode if ended.proc.returncode > 0 else 1
    failed = {name: rc for name, rc in results.items() if rc != 0}
    if failed:
        print('error: ' + ', '.join(f'{n} exited with code {rc}' for n, rc in failed.items()),
              file=sys.stderr)
        return 1
    return 0
