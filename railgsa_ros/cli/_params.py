"""``--params FILE`` of the offline commands: the nodes' ROS params file, read strictly.

The offline commands apply the inversion (and uncertainty) parameters of the file. Everything
else is refused with one line naming the key and the file (``railgsa_ros.config.ros_parameters``)
unless it only shapes the nodes' ROS transport (QoS depths, reliabilities, timers, diagnostics
ids), which has no offline meaning and cannot change a result.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from railgsa_ros.config import key_list, load_yaml, ros_parameters, section_applies
from railgsa_ros.errors import ConfigError
from railgsa_ros.vehicle import PARAM_NAMES

if TYPE_CHECKING:
    from railgsa_ros.uncertainty.config import UncertaintyConfig

#: node parameters with no offline meaning: accepted and dropped
TRANSPORT = frozenset({'imu_qos_depth', 'imu_reliability', 'odom_reliability',
                       'output_qos_depth', 'hardware_id', 'process_period_s',
                       'sensitivity_qos_depth', 'autostart', 'idle_flush_s', 'flush_rate_hz'})
#: live-node input settings that the offline commands do not apply (refused: a silent
#: default would differ from the node)
NODE_INPUT = ('use_odom', 'odom_timeout_s', 'wrong_frame_policy', 'stuck_s', 'backward_reset_s',
              'reorder_window_s')
VEHICLE_HINT = ('a vehicle parameter: the offline commands take the vehicle from --vehicle FILE '
                '(a "vehicle:" file such as config/vehicle.yaml)')


def read_params(path: str | Path, nodes: Sequence[str], known: Collection[str],
                command: str) -> dict[str, Any]:
    """The ``known`` parameters that params file ``path`` gives ``nodes`` (later nodes on top);
    ConfigError naming the file and the key or section otherwise. Under ``/**`` (a file given
    to both nodes) the names of either node are accepted; those not ``known`` are dropped."""
    doc = load_yaml(path)
    files = {'vehicle_file': VEHICLE_HINT,
             'uncertainty_file': f'railgsa {command} takes it from --uncertainty FILE'}
    refused = {name: VEHICLE_HINT for name in PARAM_NAMES if name not in known}
    refused |= {name: f'a live-node setting that railgsa {command} does not apply (remove it)'
                for name in NODE_INPUT if name not in known}
    if not any(section_applies(key, node) for key in (doc if isinstance(doc, dict) else {})
               for node in nodes):
        sections = ' or '.join(f'"{n}:"' for n in nodes)
        raise ConfigError(f'{path}: no {sections} section with ros__parameters: (nor "/**:")'
                          + _present(doc))
    params: dict[str, Any] = {}
    accepted = set(known) | TRANSPORT | set(files)
    wide = accepted | set(refused) | _node_names()
    for node in nodes:
        params.update(ros_parameters(doc, node, accepted, str(path), refused=refused,
                                     shared_known=wide, required=False))
    for name, hint in files.items():  # '' (the nodes' default) means no file
        if params.get(name) not in ('', None) and name not in known:
            raise ConfigError(f'{path}: {name}: {hint}')
    return {k: v for k, v in params.items() if k in known}


def uncertainty_params(path: str | Path, command: str) -> UncertaintyConfig:
    """The ``uncertainty_node:`` parameters of params file ``path`` over the defaults (band
    quantiles, rule, the sensor terms such as ``clock_std_ppm``); the caller sets the
    inversion."""
    from railgsa_ros.uncertainty.config import UncertaintyConfig

    known = set(UncertaintyConfig.__dataclass_fields__) - {'inversion'}
    return UncertaintyConfig.from_mapping(
        read_params(path, ('uncertainty_node',), known, command), str(path))


def _node_names() -> set[str]:
    """Every inversion and uncertainty parameter name (irregularity_node, uncertainty_node)."""
    from dataclasses import fields

    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.uncertainty.config import UncertaintyConfig

    return {f.name for f in (*fields(InversionConfig), *fields(UncertaintyConfig))} - {
        'inversion'}


def _present(doc: Any) -> str:
    """What the file holds instead, for the error message."""
    if isinstance(doc, dict) and doc:
        return f' (sections: {key_list(doc)})'
    return ' (the file is empty)' if doc is None else ' (not a params file)'
