"""Parameter specs shared by irregularity_node and uncertainty_node (same names and defaults).

- INVERSION_SPECS: one per InversionConfig field (defaults = config/irregularity.yaml).
- VEHICLE_SPECS: m_s, m_us, k_s, k_us, c with the paper's Table 1 defaults, and the physical
  bounds, units and descriptions of ``vehicle`` (PARAM_BOUNDS: the same in vehicle files and
  the CLI).
- NODE_SPECS: the input/output parameters of the nodes (odometry, frame policy, input QoS,
  stuck sensor and backward time limits, idle flush and output pacing) and LOCATION_SPECS
  (line, track, direction, km_origin).
- IRREGULARITY_SPECS: irregularity_node's own (its process period, the grid topic).
- UNCERTAINTY_SPECS: uncertainty_node's own (UncertaintyConfig fields and its extras).
- ALL_PARAMETER_NAMES: every name either node declares (for params files shared with ``/**``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from railgsa_ros.input.options import REORDER_WINDOW_S
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.grid import DEFAULT_STEP_M
from railgsa_ros.location import DIRECTIONS
from railgsa_ros.nodes.params import ParamSpec
from railgsa_ros.qos import MIN_SENSOR_DEPTH, OUTPUT_DEPTH, RELIABILITIES, SENSOR_DEPTH
from railgsa_ros.uncertainty.config import UncertaintyConfig
from railgsa_ros.vehicle import (
    PARAM_BOUNDS,
    PARAM_DOCS,
    PARAM_NAMES,
    PARAM_UNITS,
    VehicleParams,
    load_vehicle,
)

INVERSION_SPECS = tuple(ParamSpec(f.name, f.default, f.metadata['doc'], f.metadata['bounds'],
                                  f.metadata['choices']) for f in fields(InversionConfig))
VEHICLE_SPECS = tuple(ParamSpec(n, getattr(VehicleParams(), n),
                                f'{PARAM_DOCS[n]}, {PARAM_UNITS[n]}', PARAM_BOUNDS[n])
                      for n in PARAM_NAMES)
#: where the run is: the offline params-file keys (railgsa invert/review read the same names from
#: a node section) with the meaning of ``location.Reference``; reported on /diagnostics
LOCATION_SPECS = (
    ParamSpec('line', '', 'line id of the run', read_only=True),
    ParamSpec('track', '', 'track id of the run', read_only=True),
    ParamSpec('direction', DIRECTIONS[0], 'the km-posts increase or decrease along the run',
              choices=DIRECTIONS, read_only=True),
    ParamSpec('km_origin', 0.0, 'km-post of chainage 0 (the first IMU sample of the node); '
              'km = km_origin +- chainage / 1000, km', (-1e5, 1e5), read_only=True),
)
NODE_SPECS = (
    ParamSpec('vehicle_file', '', 'YAML file with a "vehicle:" section; when set, its values '
              'replace m_s, m_us, k_s, k_us, c at start-up', read_only=True),
    ParamSpec('use_odom', True, 'take the speed from odom (twist.twist.linear.x); speed_mps is '
              'the fallback while no odometry arrives', read_only=True),
    ParamSpec('odom_timeout_s', 1.0, 'odometry older than this (IMU stamp minus odom stamp) is '
              'missing, s', (0.01, 3600.0)),
    ParamSpec('wrong_frame_policy', 'accept', 'IMU samples whose frame_id is not frame_id: '
              "accept (a driver's own frame, used with a WARN finding) or reject (strict)",
              choices=('accept', 'reject')),
    ParamSpec('imu_qos_depth', SENSOR_DEPTH, 'imu/data reader history, samples',
              (MIN_SENSOR_DEPTH, 100_000), read_only=True),
    ParamSpec('imu_reliability', RELIABILITIES[0], 'imu/data subscription: best_effort (live '
              'sensors) or reliable (a faster-than-real-time replay with a reliable publisher; '
              'it matches no best-effort publisher)', choices=RELIABILITIES, read_only=True),
    ParamSpec('odom_reliability', RELIABILITIES[0], 'odom subscription: best_effort or reliable',
              choices=RELIABILITIES, read_only=True),
    ParamSpec('output_qos_depth', OUTPUT_DEPTH, 'per-sample output pacing: at most '
              'output_qos_depth / 8 messages per 10 ms (the writer is RELIABLE KEEP_ALL), '
              'samples', (1, 100_000), read_only=True),
    ParamSpec('hardware_id', '', "hardware_id on /diagnostics ('' = the frame_id of the "
              'IMU messages)', read_only=True),
    ParamSpec('stuck_s', 0.5, 'IMU samples repeating one value for longer than this are '
              'rejected as stuck (a frozen sensor), s; 0 = off', (0.0, 3600.0)),
    ParamSpec('backward_reset_s', 1.0, 'stamps going backwards by more than this (a looped bag, '
              'a sim-time reset) restart the filters instead of being rejected, s',
              (0.001, 1e6)),
    ParamSpec('reorder_window_s', REORDER_WINDOW_S, 'IMU samples are re-ordered by header '
              'stamp within this window (stamps locally out of arrival order: bursts, several '
              'threads, receipt jitter); it delays every output by as much; later ones are '
              'rejected as out_of_order; 0 = off, s', (0.0, 0.5)),
    ParamSpec('idle_flush_s', 2.0, 'no IMU message for this long (steady clock) ends the stream: '
              'the samples pending in the band filter (about 7 s) are flushed and published; '
              'keep it above max_bridge_s (1.2 s) so that a bridged dropout is no stream end, s',
              (0.05, 3600.0)),
    ParamSpec('flush_rate_hz', 1000.0, 'flushed outputs are published at this rate on top of '
              'the live ones, in slices of at most output_qos_depth / 8 per 10 ms, messages/s',
              (10.0, 1e6), read_only=True),
    *LOCATION_SPECS,
)
#: irregularity_node: pairs of samples at 1 kHz: a call's fixed cost (core ~95 us plus
#: decoding, publishing and the reader's wake-up) is several samples' worth; pairs keep the CPU
#: below the relay's (benchmarks/bench_node_latency.py, docs/nodes.md "CPU against latency")
IRREGULARITY_PERIOD = ParamSpec(
    'process_period_s', 0.002, 'IMU samples wait for company: handed to the policy once '
    'round(process_period_s x rate_hz) of them are in, or when the first has waited this long '
    '(less CPU per sample, at most this much more latency); 0: as they arrive, s',
    (0.0, 1.0), read_only=True)
#: irregularity_node: the profile on the chainage grid as a second topic: off by default (a
#: second policy with the wider pre-band, about the cost of the first)
IRREGULARITY_GRID = (
    ParamSpec('publish_grid', False, 'also publish track/irregularity_grid: the profile on '
              'chainage multiples of grid_step_m, band-passed on distance', read_only=True),
    ParamSpec('grid_step_m', DEFAULT_STEP_M, 'chainage step of track/irregularity_grid, m',
              (0.01, 10.0), read_only=True))
IRREGULARITY_SPECS = (IRREGULARITY_PERIOD, *IRREGULARITY_GRID)
UNCERTAINTY_SPECS = (
    *(ParamSpec(f.name, f.default, f.metadata['doc'], f.metadata['bounds'], f.metadata['choices'])
      for f in fields(UncertaintyConfig) if f.name != 'inversion'),
    ParamSpec('uncertainty_file', '', 'YAML of uncertain parameters (schema of '
              'config/uncertainty.yaml); empty: Table 3 around the nominal vehicle'),
    ParamSpec('process_period_s', 0.05, 'IMU samples are processed in batches of '
              'round(process_period_s x rate_hz), or when the first has waited this long, s',
              (0.001, 1.0)),
    ParamSpec('sensitivity_qos_depth', 10, 'track/sensitivity writer history (RELIABLE)',
              (1, 10_000)),
)
#: the parameters of irregularity_node and uncertainty_node, and ``autostart``
ALL_PARAMETER_NAMES = frozenset(s.name for s in (*INVERSION_SPECS, *VEHICLE_SPECS, *NODE_SPECS,
                                                  *IRREGULARITY_SPECS, *UNCERTAINTY_SPECS)
                                ) | {'autostart'}
def inversion_config(values: Mapping[str, Any]) -> InversionConfig:
    """The InversionConfig of parameter ``values``; ConfigError with the reason if invalid."""
    return InversionConfig.from_mapping({s.name: values[s.name] for s in INVERSION_SPECS})


def vehicle_values(values: Mapping[str, Any]) -> dict[str, float]:
    """m_s..c from ``vehicle_file`` when set (ConfigError naming the file), else from values."""
    if values['vehicle_file']:
        return load_vehicle(values['vehicle_file']).as_dict()
    return VehicleParams(**{n: values[n] for n in PARAM_NAMES}).as_dict()
