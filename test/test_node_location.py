"""The live nodes' location parameters: the same params file gives the same km live and offline.

A short bag's serialized /imu/data and /odom messages, in log order, go straight into
irregularity_node and uncertainty_node built from one params file (a ``/**`` section with the
location keys; no transport: the messages a raw subscription would hand over). ``railgsa invert
--params`` of the same bag with the same file is the independent reference for every output's
chainage and for the km each node reports.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from railgsa_ros.bag import write_run
from railgsa_ros.cli.main import main
from railgsa_ros.scenario import run_scenario

pytestmark = pytest.mark.ros

PARAMS = """/**:
  ros__parameters:
    line: 'L7'
    track: 2
    direction: 'decreasing'
    km_origin: 12.5
"""


def _messages(bag: Path) -> list[tuple[str, bytes]]:
    """(topic, serialized message) of /imu/data and /odom in log-time order."""
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        wanted = [c for c in reader.connections if c.topic in ('/imu/data', '/odom')]
        return [(c.topic, bytes(raw)) for c, _, raw in reader.messages(connections=wanted)]


def _ns(t_s: str) -> int:
    """A CSV stamp (s, printed exactly from its ns) back in ns."""
    seconds, _, fraction = t_s.partition('.')
    return int(seconds) * 10**9 + int(fraction.ljust(9, '0')[:9])


def _location(node: Any) -> dict[str, str]:
    """The values of the node's ``location`` status, published now."""
    msg = node._diagnostics.publish()
    (status,) = [s for s in msg.status if s.name.endswith(': location')]
    return {kv.key: kv.value for kv in status.values} | {'message': status.message,
                                                          'level': status.level[0]}


def _fed(node: Any, messages: list[tuple[str, bytes]]) -> tuple[list[int], list[float]]:
    """Every message through ``node`` in batches, then the stream's end (flush); the stamps and
    chainages of its outputs."""
    outs = [node.process([m for t, m in batch if t == '/imu/data'],
                         [m for t, m in batch if t == '/odom'])  # odometry first, as read
            for batch in (messages[k:k + 250] for k in range(0, len(messages), 250))]
    outs.append(node.flush('flush_idle'))  # the band filter's tail
    outs = [o for o in outs if o is not None and len(o)]
    return ([s for o in outs for s in o.stamps_ns.tolist()],
            [c for o in outs for c in o.chainage_m.tolist()])


@pytest.mark.parametrize('module, name', [('irregularity_node', 'IrregularityNode'),
                                          ('uncertainty_node', 'UncertaintyNode')])
def test_live_km_equals_offline_km_for_the_same_params_file(tmp_path: Path, ros_context: Any,
                                                            module: str, name: str) -> None:
    import importlib

    node_class = getattr(importlib.import_module(f'railgsa_ros.nodes.{module}'), name)
    params = tmp_path / 'params.yaml'
    params.write_text(PARAMS)
    run = run_scenario('german-low', 25.0, 4.0, 1000.0, 'adxl355', seed=3,
                       start_ns=1_700_000_000 * 10**9)
    bag = write_run(tmp_path / 'bag', run)
    out = tmp_path / 'offline.csv'
    assert main(['invert', str(bag), '--params', str(params), '--csv', str(out)]) == 0
    with out.open() as handle:
        offline = {_ns(r['t_s']): r for r in csv.DictReader(handle)}

    node = node_class(context=ros_context, cli_args=['--ros-args', '--params-file', str(params)])
    try:
        before = _location(node)
        stamps, chainage = _fed(node, _messages(bag))
        live = _location(node)
    finally:
        node.destroy_node()
    assert before['level'] == 3 and before['message'] == 'no output yet'  # STALE
    assert {k: live[k] for k in ('line', 'track', 'direction', 'km_origin')} == \
        {'line': 'L7', 'track': '2', 'direction': 'decreasing', 'km_origin': '12.5'}
    assert stamps and all(s in offline for s in stamps)
    offline_chainage = np.array([float(offline[s]['chainage_m']) for s in stamps])
    np.testing.assert_allclose(chainage, offline_chainage, rtol=0, atol=1e-4)  # CSV: %.4f m
    newest = offline[int(live['stamp_ns'])]
    assert int(live['stamp_ns']) == stamps[-1]
    assert float(live['chainage_m']) == chainage[-1]  # full precision on /diagnostics
    assert float(live['km']) == pytest.approx(float(newest['km']), abs=1e-6)  # CSV: %.6f km
    assert float(newest['km']) == pytest.approx(12.5 - chainage[-1] / 1000, abs=1e-6)
    assert live['level'] == 0 and live['message'] == f'line L7 track 2, km {float(live["km"]):.3f}'
