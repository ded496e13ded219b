"""``railgsa invert``: reconstruct the track irregularity from the IMU stream of a bag.

Runs the node's streaming ``InversionPipeline`` over the bag in chunks and writes
``t_s,chainage_m,u_m`` (t_s = IMU stamp in s) for every accepted sample, or with ``--out`` the
node's ``/track/irregularity`` topic (geometry_msgs/PointStamped, frame ``track``, point.x =
chainage, point.z = irregularity, header stamp = log time = IMU stamp) to a rosbag2 bag.
``--bands`` adds ``lower_m,mean_m,upper_m`` (uncertainty_node's ``/track/irregularity_band``)
computed by the node's streaming code (``railgsa_ros.uncertainty.offline_bands``).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

CHUNK = 65536  # IMU samples per pipeline call
OUT_TOPIC = '/track/irregularity'
GRID_TOPIC = '/track/irregularity_grid'  # --grid: the profile at a fixed chainage step
BAND_TOPIC = '/track/irregularity_band'


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``invert`` subcommand."""
    p = subparsers.add_parser(
        'invert', help='reconstruct track irregularity from a bag (CSV or bag output)',
        description='Reconstruct the vertical track irregularity from the car-body '
                    'accelerometer of a rosbag2 bag (MCAP or sqlite3) with the streaming '
                    'pipeline of irregularity_node.')
    p.add_argument('bag', metavar='BAG', help='rosbag2 bag directory or file')
    out = p.add_mutually_exclusive_group(required=True)
    out.add_argument('--csv', metavar='OUT.csv', help='write t_s,chainage_m,u_m')
    out.add_argument('--out', metavar='OUT.mcap', help='write /track/irregularity to a bag')
    p.add_argument('--method', choices=('spectral', 'feedback', 'kalman'),
                   help='inversion method (default: the params file, else spectral)')
    p.add_argument('--band', metavar='BAND',
                   help='d1, d2, d3 (EN 13848), wide (1-200 m), LMIN:LMAX in m (e.g. 2:70) or '
                   'none (default: the params file, else d1)')
    p.add_argument('--grid', type=float, metavar='STEP_M',
                   help='output on a fixed chainage step (m, e.g. 0.25), band-passed on '
                   'distance: t_s is when the wheel passed the point (bag: '
                   '/track/irregularity_grid)')
    p.add_argument('--sensor-delay', metavar='S|PRESET',
                   help="the IMU filter's group delay to compensate: seconds or a sensor "
                   'preset (adxl355, bmi088) for data from a real chip; bags of railgsa '
                   'simulate have none (default: the params file, else 0)')
    p.add_argument('--smoother', action='store_true', help='kalman: offline RTS smoother')
    p.add_argument('--imu-topic', default='/imu/data', metavar='T', help='default /imu/data')
    p.add_argument('--odom-topic', default='/odom', metavar='T',
                   help='odometry topic for the speed (default /odom; ignored when absent)')
    p.add_argument('--params', metavar='FILE',
                   help='ROS params file with irregularity_node: ros__parameters:')
    p.add_argument('--vehicle', metavar='FILE', help='vehicle YAML (default the paper Table 1)')
    p.add_argument('--speed', type=float, metavar='MPS',
                   help='constant speed in m/s, overriding odometry')
    p.add_argument('--bands', action='store_true',
                   help='add the uncertainty band lower_m,mean_m,upper_m (uncertainty_node)')
    p.add_argument('--uncertainty', metavar='FILE',
                   help='uncertain parameters for --bands (default the paper Table 3)')
    p.add_argument('--uncertainty-params', metavar='FILE',
                   help='ROS params file with uncertainty_node: ros__parameters: (rule, order, '
                   'quantiles) for --bands')
    p.add_argument('--overwrite', action='store_true', help='replace an existing output')
    p.set_defaults(func=run)


def build_config(args: argparse.Namespace, rate_hz: float) -> object:
    """Params file (if any), then the command-line choices; rate_hz from the bag unless set."""
    from railgsa_ros.cli._params import read_params
    from railgsa_ros.inverse.config import NODE_NAME, InversionConfig

    known = set(InversionConfig.__dataclass_fields__)
    params = read_params(args.params, (NODE_NAME,), known, 'invert') if args.params else {}
    params.setdefault('rate_hz', rate_hz)
    for name in ('method', 'band'):
        if getattr(args, name) is not None:
            params[name] = getattr(args, name)
    if args.sensor_delay is not None:
        params['sensor_delay_s'] = sensor_delay(args.sensor_delay)
    if args.smoother:
        params['smoother'] = True
    if args.speed is not None:
        params['speed_mps'] = args.speed
    return InversionConfig.from_mapping(params, source=args.params or 'command line')


def sensor_delay(text: str) -> float:
    """--sensor-delay: a number of seconds or the group delay of a sensor preset's filter."""
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.imu import PRESETS
    from railgsa_ros.inverse.sensor import sensor_delay_s

    chips = [name for name in PRESETS if name != 'ideal']  # the ideal sensor has no chip
    if text in chips:
        return sensor_delay_s(text)
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f'--sensor-delay: expected seconds or a preset '
                          f'({", ".join(chips)}), got {text!r}') from None


@dataclass(frozen=True)
class Inputs:
    """What the bag and the options give the pipeline: per-sample arrays and the settings."""

    stamps_ns: np.ndarray
    acc_z: np.ndarray
    speed_mps: np.ndarray
    frame_ids: np.ndarray
    config: object
    vehicle: object
    noise_variance: float | None


def load_inputs(args: argparse.Namespace) -> Inputs:
    """Read the bag and build the pipeline settings (InputError/ConfigError naming the file)."""
    import numpy as np

    from railgsa_ros.bag import read_imu
    from railgsa_ros.errors import ConfigError, InputError
    from railgsa_ros.inverse.pipeline import vertical
    from railgsa_ros.vehicle import VehicleParams, load_vehicle

    if args.speed is not None and not (np.isfinite(args.speed) and args.speed > 0):
        raise ConfigError(f'--speed: expected a positive number of m/s, got {args.speed!r}')
    stream = read_imu(args.bag, args.imu_topic, args.odom_topic)
    stamps = stream.stamps_ns
    steps = np.diff(stamps)
    steps = steps[steps > 0]
    if steps.size == 0:
        raise InputError(f'{args.bag}: {args.imu_topic} needs at least two distinct stamps')
    cfg = build_config(args, 1e9 / float(np.median(steps)))
    vehicle = load_vehicle(args.vehicle) if args.vehicle else VehicleParams()
    variance = stream.accel_variance(cfg.noise_std_mps2 ** 2)[:, 'xyz'.index(cfg.accel_axis[-1])]
    known = variance[np.isfinite(variance)]
    if args.speed is not None or stream.odom_stamps_ns.size == 0:
        speed = np.full(stamps.size, cfg.speed_mps)
    else:  # odometry held: the newest odometry sample at or before each IMU stamp
        idx = np.searchsorted(stream.odom_stamps_ns, stamps, side='right') - 1
        speed = stream.speed_mps[np.clip(idx, 0, None)]
    return Inputs(stamps, vertical(stream.accel, cfg.accel_axis), speed, stream.frame_ids, cfg,
                  vehicle, float(np.median(known)) if known.size else None)


def invert_bag(args: argparse.Namespace) -> tuple[object, object, Inputs]:
    """Run the pipeline over the bag: (Output of every accepted sample, pipeline, inputs)."""
    import numpy as np

    from railgsa_ros.inverse.grid import grid_config
    from railgsa_ros.inverse.pipeline import InversionPipeline, Output

    inp = load_inputs(args)
    pipe = InversionPipeline(grid_config(inp.config) if args.grid is not None else inp.config,
                             inp.vehicle, inp.noise_variance)
    outs = [pipe.push(inp.stamps_ns[i:i + CHUNK], inp.acc_z[i:i + CHUNK],
                      inp.speed_mps[i:i + CHUNK], inp.frame_ids[i:i + CHUNK])
            for i in range(0, inp.stamps_ns.size, CHUNK)]
    outs.append(pipe.flush())
    return Output(*(np.concatenate([getattr(o, f) for o in outs]) for f in
                    ('stamps_ns', 'chainage_m', 'u_m'))), pipe, inp


def on_grid(out: object, config: object, step_m: float) -> object:
    """The output (of a pipeline with ``grid_config(config)``) on chainage multiples of step_m,
    band-passed on distance with config's band (``inverse.grid.ChainageGrid``)."""
    from railgsa_ros.inverse.grid import ChainageGrid, GridOutput

    grid = ChainageGrid.for_config(config, step_m)
    return GridOutput.concat([grid.push(out), grid.flush()])


def bands_for(args: argparse.Namespace, inp: Inputs, out: object) -> object:
    """uncertainty_node's band for the same samples; its stamps equal the pipeline output's."""
    import numpy as np

    from railgsa_ros.cli._params import read_params
    from railgsa_ros.errors import InputError
    from railgsa_ros.uncertainty import UncertaintyConfig, offline_bands
    from railgsa_ros.uq.uncertainty_file import load_uncertainty

    base = UncertaintyConfig()
    if args.uncertainty_params:  # the inversion comes from --params (equal to the node's)
        known = set(UncertaintyConfig.__dataclass_fields__) - {'inversion'}
        base = UncertaintyConfig.from_mapping(read_params(
            args.uncertainty_params, ('uncertainty_node',), known, 'invert --bands'),
            args.uncertainty_params)
    band = offline_bands(inp.stamps_ns, inp.acc_z, inp.speed_mps, inp.frame_ids,
                         config=base.with_(inversion=inp.config), vehicle=inp.vehicle,
                         dists=load_uncertainty(args.uncertainty) if args.uncertainty else None,
                         noise_variance=inp.noise_variance)
    if not np.array_equal(band.stamps_ns, out.stamps_ns):
        raise InputError(f'{args.bag}: band and irregularity stamps differ (internal error)')
    return band


def write_csv(path: str | Path, out: object, band: object | None, overwrite: bool) -> None:
    """``t_s,chainage_m,u_m[,lower_m,mean_m,upper_m]``, stamps printed exactly from their ns."""
    import numpy as np

    from railgsa_ros.fileio import atomic_output

    sec, nsec = np.divmod(out.stamps_ns, 1_000_000_000)
    t = np.char.add(np.char.add(sec.astype(str), '.'), np.char.zfill(nsec.astype(str), 9))
    header = 't_s,chainage_m,u_m'
    values = [out.chainage_m, out.u_m]
    if band is not None:
        header += ',lower_m,mean_m,upper_m'
        values += [band.lower_m, band.mean_m, band.upper_m]
    cols = np.column_stack(values)
    fmt = ','.join(['%.4f'] + ['%.9e'] * (cols.shape[1] - 1))
    body = np.char.add(np.char.add(t, ','), np.array([fmt % tuple(r) for r in cols]))
    with atomic_output(path, overwrite) as tmp:
        tmp.write_text('\n'.join([header, *body]) + '\n', encoding='utf-8')


def write_bag(path: str | Path, out: object, band: object | None, overwrite: bool,
              topic: str = OUT_TOPIC) -> None:
    """The nodes' topics, log time = header stamp = IMU stamp: ``/track/irregularity``
    (PointStamped: x chainage, z irregularity) and with a band ``/track/irregularity_band``
    (Vector3Stamped: x lower, y mean, z upper)."""
    import numpy as np

    from railgsa_ros.bag import BagWriter
    from railgsa_ros.bag.cdr import encode
    from railgsa_ros.bag.messages import POINT_STAMPED, VECTOR3_STAMPED, history_depth, qos

    values = np.zeros((out.stamps_ns.size, 3))
    values[:, 0], values[:, 2] = out.chainage_m, out.u_m
    topics = {topic: (POINT_STAMPED, values)}
    if band is not None:
        topics[BAND_TOPIC] = (VECTOR3_STAMPED,
                              np.column_stack([band.lower_m, band.mean_m, band.upper_m]))
    with BagWriter(path, 'mcap', overwrite=overwrite) as bag:
        for topic, (layout, _) in topics.items():
            bag.add_topic(topic, layout.msgtype, qos(True, history_depth(1000.0)))
        bag.write_batches({topic: (out.stamps_ns, encode(layout, out.stamps_ns, ['track'], v))
                           for topic, (layout, v) in topics.items()})


def run(args: argparse.Namespace) -> int:
    """Invert the bag and write the result; prints a one-line summary to stderr."""
    from railgsa_ros.fileio import refuse_overlap

    refuse_overlap(args.csv or args.out, (args.bag, args.params, args.vehicle, args.uncertainty,
                                          args.uncertainty_params))
    if args.grid is not None and args.bands:
        from railgsa_ros.errors import ConfigError

        raise ConfigError('--bands: the uncertainty band is per IMU sample; not with --grid')
    out, pipe, inp = invert_bag(args)
    if args.grid is not None:
        out = on_grid(out, inp.config, args.grid)
    band = bands_for(args, inp, out) if args.bands else None
    if args.csv:
        write_csv(args.csv, out, band, args.overwrite)
    else:
        write_bag(args.out, out, band, args.overwrite,
                  GRID_TOPIC if args.grid is not None else OUT_TOPIC)
    counts = ', '.join(f'{k} {v}' for k, v in sorted(pipe.counters.items()))
    print(f'{len(out)} samples ({pipe.config.method}, band {pipe.config.band}, delay '
          f'{pipe.delay_samples} samples); {counts}', file=sys.stderr)
    return 0
