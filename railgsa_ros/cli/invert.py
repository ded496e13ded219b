"""``railgsa invert``: reconstruct the track irregularity from the IMU stream of a bag.

Runs the nodes' ``InputPolicy`` (every input decision: speed, noise, sanitising, quality) over
the bag in chunks and writes ``t_s,chainage_m,u_m,quality`` (t_s = IMU stamp in s; quality 0
VALID, 1 DEGRADED, 2 INVALID with u = nan) for every accepted sample, or with ``--out`` the
node's ``/track/irregularity`` topic (geometry_msgs/PointStamped, frame ``track``, point.x =
chainage, point.y = quality code, point.z = irregularity, NaN when INVALID, header stamp = log
time = IMU stamp) to a rosbag2 bag. The speed is the bag's odometry (exit 2 without it) unless
``--speed`` fixes it; ``rate_hz`` defaults to the measured IMU rate.
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

CHUNK = 65536  # IMU samples per policy call
REJECTIONS = ('nan', 'wrong_frame', 'saturated', 'stuck', 'out_of_order', 'duplicate')
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
                   help='odometry topic for the speed (default /odom; without odometry, '
                   '--speed is required)')
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


#: the input options of the nodes that the offline commands apply from --params (use_odom is
#: --speed here)
POLICY_PARAMS = ('odom_timeout_s', 'wrong_frame_policy', 'stuck_s', 'backward_reset_s')


def build_config(args: argparse.Namespace, rate_hz: float) -> tuple[object, object]:
    """(InversionConfig, PolicyOptions) from the params file (if any), then the command line.
    rate_hz defaults to the bag's measured rate; a given rate_hz that disagrees with it beyond
    rate_tolerance is a ConfigError (the filters would be designed for another rate)."""
    from railgsa_ros.cli._params import read_params
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.inverse.config import NODE_NAME, InversionConfig
    from railgsa_ros.inverse.policy import PolicyOptions

    known = set(InversionConfig.__dataclass_fields__) | set(POLICY_PARAMS)
    params = read_params(args.params, (NODE_NAME,), known, 'invert') if args.params else {}
    options = {k: params.pop(k) for k in POLICY_PARAMS if k in params}
    given = 'rate_hz' in params
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
    source = args.params or 'command line'
    cfg = InversionConfig.from_mapping(params, source=source)
    if given and abs(rate_hz / cfg.rate_hz - 1.0) > cfg.rate_tolerance:
        off = abs(rate_hz / cfg.rate_hz - 1) * 100
        raise ConfigError(f'{source}: rate_hz {cfg.rate_hz:g} disagrees with the bag\'s measured '
                          f'IMU rate {rate_hz:.6g} Hz by {off:.3g} %: remove rate_hz (the '
                          'default is the measured rate) or correct it')
    try:
        policy = PolicyOptions(use_odom=args.speed is None, **options)
    except ConfigError as exc:
        raise ConfigError(f'{source}: {exc}') from None
    return cfg, policy


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
    """What the bag and the options give the policy: the recorded stream and the settings."""

    stream: object
    config: object
    options: object
    vehicle: object


def measured_rate(stamps_ns: np.ndarray, bag: str, topic: str) -> float:
    """The IMU rate (Hz): 1 / the median positive stamp step; InputError with fewer than two
    distinct stamps."""
    import numpy as np

    from railgsa_ros.errors import InputError

    steps = np.diff(stamps_ns)
    steps = steps[steps > 0]
    if steps.size == 0:
        raise InputError(f'{bag}: {topic} needs at least two distinct stamps')
    return 1e9 / float(np.median(steps))


def load_inputs(args: argparse.Namespace) -> Inputs:
    """Read the bag and build the settings (InputError/ConfigError naming the file); exit 2
    without odometry unless --speed is given."""
    import numpy as np

    from railgsa_ros.bag import read_imu
    from railgsa_ros.errors import ConfigError, InputError
    from railgsa_ros.vehicle import VehicleParams, load_vehicle

    if args.speed is not None and not (np.isfinite(args.speed) and args.speed > 0):
        raise ConfigError(f'--speed: expected a positive number of m/s, got {args.speed!r}')
    stream = read_imu(args.bag, args.imu_topic, args.odom_topic)
    cfg, options = build_config(args, measured_rate(stream.stamps_ns, args.bag, args.imu_topic))
    if args.speed is None and stream.odom_stamps_ns.size == 0:
        raise InputError(f'{args.bag}: no odometry on {args.odom_topic} and no --speed: the '
                         'speed is unknown (give --speed MPS or --odom-topic)')
    vehicle = load_vehicle(args.vehicle) if args.vehicle else VehicleParams()
    return Inputs(stream, cfg, options, vehicle)


def feed(policy: object, stream: object, use_odom: bool, chunk: int = CHUNK) -> list:
    """The offline feeding of a policy (or UncertaintyStream): the odometry in recorded order
    (with ``use_odom``), then the IMU in chunks, then flush; returns every result in order."""
    outs = []
    if use_odom:
        outs.append(policy.odometry(stream.odom_stamps_ns, stream.speed_mps))
    for i in range(0, stream.stamps_ns.size, chunk):
        sl = slice(i, i + chunk)
        outs.append(policy.imu(stream.stamps_ns[sl], stream.accel[sl], stream.frame_ids[sl],
                               stream.covariance[sl]))
    outs.append(policy.flush())
    return outs


def invert_bag(args: argparse.Namespace) -> tuple[object, object, Inputs]:
    """Run the policy over the bag: (Output of every accepted sample, policy, inputs);
    InputError when no sample is usable (every one rejected). With --grid the filters are
    those in front of the chainage grid (``inverse.grid.grid_config``)."""
    from railgsa_ros.errors import InputError
    from railgsa_ros.inverse.grid import grid_config
    from railgsa_ros.inverse.pipeline import Output
    from railgsa_ros.inverse.policy import InputPolicy

    inp = load_inputs(args)
    policy = InputPolicy(grid_config(inp.config) if args.grid is not None else inp.config,
                         inp.vehicle, options=inp.options)
    out = Output.concat(feed(policy, inp.stream, inp.options.use_odom))
    if len(out) == 0:
        counts = policy.counters
        rejected = ', '.join(f'{k} {counts[k]}' for k in REJECTIONS if counts.get(k)) or 'none'
        raise InputError(f'{args.bag}: no usable IMU sample (rejected: {rejected}): '
                         f'{policy.status.message}')
    return out, policy, inp


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
    from railgsa_ros.uncertainty import Band, UncertaintyConfig, UncertaintyStream
    from railgsa_ros.uq.uncertainty_file import load_uncertainty

    base = UncertaintyConfig()
    if args.uncertainty_params:  # the inversion comes from --params (equal to the node's)
        known = set(UncertaintyConfig.__dataclass_fields__) - {'inversion'}
        base = UncertaintyConfig.from_mapping(read_params(
            args.uncertainty_params, ('uncertainty_node',), known, 'invert --bands'),
            args.uncertainty_params)
    stream = UncertaintyStream(base.with_(inversion=inp.config, qoi=''), inp.vehicle,
                               load_uncertainty(args.uncertainty) if args.uncertainty else None,
                               options=inp.options)
    band = Band.concat([update.band for update in
                       feed(stream, inp.stream, inp.options.use_odom)])
    if not (np.array_equal(band.stamps_ns, out.stamps_ns)
            and np.array_equal(band.quality, out.quality)):
        raise InputError(f'{args.bag}: band and irregularity samples differ (internal error)')
    return band


def write_csv(path: str | Path, out: object, band: object | None, overwrite: bool) -> None:
    """``t_s,chainage_m,u_m,quality[,lower_m,mean_m,upper_m]``, stamps printed exactly from
    their ns; quality 0 VALID, 1 DEGRADED, 2 INVALID (u and the band 'nan')."""
    import numpy as np

    from railgsa_ros.fileio import atomic_output

    sec, nsec = np.divmod(out.stamps_ns, 1_000_000_000)
    t = np.char.add(np.char.add(sec.astype(str), '.'), np.char.zfill(nsec.astype(str), 9))
    header = 't_s,chainage_m,u_m,quality'
    values = [out.chainage_m, out.u_m, out.quality]
    if band is not None:
        header += ',lower_m,mean_m,upper_m'
        values += [band.lower_m, band.mean_m, band.upper_m]
    cols = np.column_stack(values)
    fmt = ','.join(['%.4f', '%.9e', '%d'] + ['%.9e'] * (cols.shape[1] - 3))
    body = np.char.add(np.char.add(t, ','), np.array([fmt % tuple(r) for r in cols]))
    with atomic_output(path, overwrite) as tmp:
        tmp.write_text('\n'.join([header, *body]) + '\n', encoding='utf-8')


def write_bag(path: str | Path, out: object, band: object | None, overwrite: bool,
              topic: str = OUT_TOPIC) -> None:
    """The nodes' topics, log time = header stamp = IMU stamp: ``/track/irregularity``
    (PointStamped: x chainage, y quality code, z irregularity, NaN when INVALID) and with a
    band ``/track/irregularity_band`` (Vector3Stamped: x lower, y mean, z upper)."""
    import numpy as np

    from railgsa_ros.bag import BagWriter
    from railgsa_ros.bag.cdr import encode
    from railgsa_ros.bag.messages import POINT_STAMPED, VECTOR3_STAMPED, history_depth, qos

    values = np.zeros((out.stamps_ns.size, 3))
    values[:, 0], values[:, 1], values[:, 2] = out.chainage_m, out.quality, out.u_m
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
    out, policy, inp = invert_bag(args)
    if args.grid is not None:
        out = on_grid(out, inp.config, args.grid)
    band = bands_for(args, inp, out) if args.bands else None
    if args.csv:
        write_csv(args.csv, out, band, args.overwrite)
    else:
        write_bag(args.out, out, band, args.overwrite,
                  GRID_TOPIC if args.grid is not None else OUT_TOPIC)
    for finding in policy.findings:
        if finding.level:
            print(f'warning: {finding.message}', file=sys.stderr)
    if not (out.quality != 2).any():
        print('warning: every output is INVALID (u = nan): see the warnings above, or the run '
              'is shorter than the band window', file=sys.stderr)
    counts = ', '.join(f'{k} {v}' for k, v in sorted(policy.counters.items()))
    print(f'{len(out)} samples ({policy.config.method}, band {policy.config.band}, delay '
          f'{policy.delay_samples} samples); {counts}', file=sys.stderr)
    return 0
