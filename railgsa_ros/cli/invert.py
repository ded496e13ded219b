"""``railgsa invert``: reconstruct the track irregularity from the IMU stream of a bag.

Streams the bag in pieces (``offline.Driver``: the nodes' ``InputStage``, every input decision
- speed, noise, sanitising, quality - then the pipeline) and writes as the samples come out:
``t_s,chainage_m,u_m,quality[,lower_m,mean_m,upper_m],km,lat,lon`` (t_s = IMU stamp in s;
quality 0 VALID, 1 DEGRADED, 2 INVALID with u = nan; km-post of the chainage; WGS84 position
from GNSS, nan without) for every accepted sample, or with ``--out`` the node's
``/track/irregularity`` topic (geometry_msgs/PointStamped, frame ``track``, point.x =
chainage, point.y = quality code, point.z = irregularity, NaN when INVALID, header stamp = log
time = IMU stamp) to a rosbag2 bag. The speed is the bag's odometry (exit 2 without it) unless
``--speed`` fixes it, times the odometry scale when the bag has GNSS (``railgsa_ros.location``);
``rate_hz`` defaults to the IMU rate measured on the first piece. ``--bands`` adds
``lower_m,mean_m,upper_m`` (uncertainty_node's ``/track/irregularity_band``) from the node's
streaming code (``UncertaintyStream``) fed the same pieces. Memory: a piece and the filters'
delay lines, whatever the length of the run.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the command imports its modules when it runs (fast --help)
    from typing import TextIO

    import numpy as np

    from railgsa_ros.bag import BagWriter, ImuStream
    from railgsa_ros.input.options import InputOptions
    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.location import Location, Reference
    from railgsa_ros.models import VehicleModel
    from railgsa_ros.offline import Driver, Source
    from railgsa_ros.uncertainty import Band
    from railgsa_ros.vehicle import VehicleParams

REJECTIONS = ('nan', 'wrong_frame', 'saturated', 'stuck', 'out_of_order', 'duplicate',
              'malformed')
OUT_TOPIC = '/track/irregularity'
GRID_TOPIC = '/track/irregularity_grid'  # --grid: the profile at a fixed chainage step
BAND_TOPIC = '/track/irregularity_band'


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``invert`` subcommand."""
    from railgsa_ros.cli.review import add_location_options, add_topic_options

    p = subparsers.add_parser(
        'invert', help='reconstruct track irregularity from a bag (CSV or bag output)',
        description='Reconstruct the vertical track irregularity from the car-body '
                    'accelerometer of a rosbag2 bag (MCAP or sqlite3) with the streaming '
                    'pipeline of irregularity_node.')
    p.add_argument('bag', metavar='BAG', help='rosbag2 bag directory or file')
    out = p.add_mutually_exclusive_group(required=True)
    out.add_argument('--csv', metavar='OUT.csv',
                     help='write t_s,chainage_m,u_m,quality[,lower_m,mean_m,upper_m],km,lat,lon')
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
    p.add_argument('--sensor-delay', metavar='S|CHIP@ODR',
                   help="the IMU filter's group delay to compensate: seconds or the chip's "
                   'datasheet setting (adxl355@1000Hz, bmi088@400Hz, bmi088@400Hz-osr2, ...: '
                   'the delay its low-pass cut-off implies); bags of railgsa simulate with '
                   'the adxl355 or bmi088 model have none (default: the params file, else 0)')
    p.add_argument('--smoother', action='store_true', help='kalman: offline RTS smoother')
    add_topic_options(p, 'odometry topic for the speed (default /odom; without odometry, '
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
    add_location_options(p)
    p.add_argument('--overwrite', action='store_true', help='replace an existing output')
    p.add_argument('--quiet', action='store_true',
                   help='no progress bar (drawn on stderr only on a terminal, with tqdm)')
    p.set_defaults(func=run)


#: the input options of the nodes that the offline commands apply from --params (use_odom is
#: --speed here)
POLICY_PARAMS = ('odom_timeout_s', 'wrong_frame_policy', 'stuck_s', 'backward_reset_s',
                 'reorder_window_s')


def build_config(args: argparse.Namespace, rate_hz: float
                 ) -> tuple[InversionConfig, InputOptions, Reference]:
    """(InversionConfig, InputOptions, location Reference) from the params file (if any), then
    the command line. rate_hz defaults to the bag's measured rate; a given rate_hz that
    disagrees with it beyond rate_tolerance is a ConfigError (the filters would be designed for
    another rate)."""
    from railgsa_ros.cli._params import read_params
    from railgsa_ros.cli.review import LOCATION_KEYS, reference
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.input.options import InputOptions
    from railgsa_ros.inverse.config import NODE_NAME, InversionConfig

    known = set(InversionConfig.__dataclass_fields__) | set(POLICY_PARAMS) | set(LOCATION_KEYS)
    params = read_params(args.params, (NODE_NAME,), known, 'invert') if args.params else {}
    options = {k: params.pop(k) for k in POLICY_PARAMS if k in params}
    location = reference(args, {k: params.pop(k) for k in LOCATION_KEYS if k in params})
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
        policy = InputOptions(use_odom=args.speed is None, **options)
    except ConfigError as exc:
        raise ConfigError(f'{source}: {exc}') from None
    return cfg, policy, location


def sensor_delay(text: str) -> float:
    """--sensor-delay: a number of seconds or the group delay of a chip setting's filter
    (``datasheets``); a delay-free model's name (adxl355, bmi088) is refused: a real chip's
    delay depends on its output-rate and bandwidth setting."""
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.imu import PRESETS
    from railgsa_ros.inverse.sensor import sensor_delay_s

    if '@' in text:
        try:
            return sensor_delay_s(text)
        except ConfigError as exc:
            raise ConfigError(f'--sensor-delay: {exc}') from None
    try:
        return float(text)
    except ValueError:
        settings = ', '.join(name for name in PRESETS if '@' in name)
        raise ConfigError(f'--sensor-delay: expected seconds or a chip setting ({settings}, '
                          f'...), got {text!r}') from None


@dataclass(frozen=True)
class Inputs:
    """What the bag and the options give the driver: the bag's pieces (the first one read to
    measure the rate) and the settings, with the run's location."""

    source: Source
    pieces: Iterator[ImuStream]
    config: InversionConfig
    options: InputOptions
    vehicle: VehicleParams | VehicleModel
    location: Location


def load_inputs(args: argparse.Namespace) -> Inputs:
    """Open the bag and build the settings (InputError/ConfigError naming the file); exit 2
    without odometry unless --speed is given. The rate is measured on the first piece; with
    GNSS in the bag, the location pass runs first (``offline.locate``)."""
    import numpy as np

    from railgsa_ros.errors import ConfigError, InputError
    from railgsa_ros.models import vehicle_of
    from railgsa_ros.offline import Source, chunks, locate, nominal_rate_hz, peek

    if args.speed is not None and not (np.isfinite(args.speed) and args.speed > 0):
        raise ConfigError(f'--speed: expected a positive number of m/s, got {args.speed!r}')
    source = Source(Path(args.bag), args.imu_topic, args.odom_topic, args.gnss_topic)
    first, pieces = peek(chunks(source))
    cfg, options, reference = build_config(args, nominal_rate_hz(first, source))
    if args.speed is None and args.odom_topic not in source.topics():
        raise InputError(f'{args.bag}: no odometry on {args.odom_topic} and no --speed: the '
                         'speed is unknown (give --speed MPS or --odom-topic)')
    vehicle = vehicle_of(args.vehicle or None)
    start = int(first.stamps_ns[0]) if first.stamps_ns.size else 0
    return Inputs(source, pieces, cfg, options, vehicle, locate(source, start, reference))


def make_driver(args: argparse.Namespace, inp: Inputs) -> Driver:
    """The offline driver: the nominal policy (with --grid, the filters in front of the
    chainage grid, ``inverse.grid.grid_config``) and with --bands uncertainty_node's stream for
    the same samples, the odometry scaled as GNSS found it."""
    from railgsa_ros.cli._params import uncertainty_params
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.inverse.grid import grid_config
    from railgsa_ros.offline import COACH_BAND, Driver
    from railgsa_ros.uncertainty import UncertaintyConfig
    from railgsa_ros.uncertainty.parameters import load_uncertainty, table3, with_discrepancy
    from railgsa_ros.vehicle import VehicleParams

    base = UncertaintyConfig()
    if args.uncertainty_params:  # the inversion comes from --params (equal to the node's)
        base = uncertainty_params(args.uncertainty_params, 'invert --bands')
    config = grid_config(inp.config) if args.grid is not None else inp.config
    dists = None
    if args.bands:
        if not isinstance(inp.vehicle, VehicleParams):
            raise ConfigError(f'--bands: {COACH_BAND}')
        dists = load_uncertainty(args.uncertainty) if args.uncertainty else table3(inp.vehicle)
        base = with_discrepancy(base, args.uncertainty)
    return Driver(base.with_(inversion=config, qoi=''), inp.vehicle, dists, inp.options,
                  inp.location.scale.value)


def _times(stamps_ns: np.ndarray) -> np.ndarray:
    """Stamps (ns) as exact decimal seconds (str)."""
    import numpy as np

    sec, nsec = np.divmod(stamps_ns, 1_000_000_000)
    return np.char.add(np.char.add(sec.astype(str), '.'), np.char.zfill(nsec.astype(str), 9))


class CsvRows:
    """``t_s,chainage_m,u_m,quality[,lower_m,mean_m,upper_m],km,lat,lon`` appended chunk by
    chunk to an open file: stamps printed exactly from their ns; quality 0 VALID, 1 DEGRADED,
    2 INVALID (u and the band 'nan'); km-post of the chainage; WGS84 position ('nan' without
    GNSS)."""

    def __init__(self, handle: TextIO, band: bool, location: Location) -> None:
        self.handle, self.band, self.location = handle, band, location
        header = 't_s,chainage_m,u_m,quality' + (',lower_m,mean_m,upper_m' if band else '')
        handle.write(header + ',km,lat,lon\n')

    def write(self, stamps_ns: np.ndarray, chainage_m: np.ndarray, u_m: np.ndarray,
              quality: np.ndarray, band: Band | None = None) -> None:
        import numpy as np

        if stamps_ns.size == 0:
            return
        lat, lon = self.location.lat_lon(chainage_m)
        values = [chainage_m, u_m, quality]
        if self.band:
            if band is None:
                raise AssertionError('a row of the band columns without its band')
            values += [band.lower_m, band.mean_m, band.upper_m]
        values += [self.location.reference.km(chainage_m), lat, lon]
        cols = np.column_stack(values)
        fmt = ','.join(['%.4f', '%.9e', '%d'] + ['%.9e'] * (3 if self.band else 0)
                       + ['%.6f', '%.7f', '%.7f'])
        body = np.char.add(np.char.add(_times(stamps_ns), ','),
                           np.array([fmt % tuple(r) for r in cols]))
        self.handle.write('\n'.join(body.tolist()) + '\n')


class BagBatches:
    """The nodes' topics written batch by batch, log time = header stamp = IMU stamp:
    ``topic`` (PointStamped: x chainage, y quality code, z irregularity, NaN when INVALID) and
    with a band ``/track/irregularity_band`` (Vector3Stamped: x lower, y mean, z upper)."""

    def __init__(self, bag: BagWriter, band: bool, topic: str) -> None:
        from railgsa_ros.bag.messages import POINT_STAMPED, VECTOR3_STAMPED
        from railgsa_ros.qos import history_depth, record_qos

        self.bag, self.topic = bag, topic
        self.topics = {topic: POINT_STAMPED, **({BAND_TOPIC: VECTOR3_STAMPED} if band else {})}
        for name, layout in self.topics.items():
            bag.add_topic(name, layout.msgtype, record_qos(True, history_depth(1000.0)))

    def write(self, stamps_ns: np.ndarray, chainage_m: np.ndarray, u_m: np.ndarray,
              quality: np.ndarray, band: Band | None = None) -> None:
        import numpy as np

        from railgsa_ros.bag.cdr import encode

        if stamps_ns.size == 0:
            return
        values = {self.topic: np.column_stack([chainage_m, quality, u_m])}
        if band is not None:
            values[BAND_TOPIC] = np.column_stack([band.lower_m, band.mean_m, band.upper_m])
        self.bag.write_batches({name: (stamps_ns, encode(self.topics[name], stamps_ns,
                                                          ['track'], v))
                                for name, v in values.items()})


@contextmanager
def output(args: argparse.Namespace, location: Location) -> Iterator[CsvRows | BagBatches]:
    """The CSV rows or bag batches of ``args``, written atomically (nothing left on error)."""
    from railgsa_ros.bag import BagWriter
    from railgsa_ros.fileio import atomic_output

    if args.csv:
        with atomic_output(args.csv, args.overwrite) as tmp, \
                tmp.open('w', encoding='utf-8') as handle:
            yield CsvRows(handle, args.bands, location)
    else:
        with BagWriter(args.out, 'mcap', overwrite=args.overwrite) as bag:
            yield BagBatches(bag, args.bands, GRID_TOPIC if args.grid is not None else OUT_TOPIC)


def run(args: argparse.Namespace) -> int:
    """Invert the bag chunk by chunk, writing as the samples come out (memory bounded by a
    chunk, not the run); prints a one-line summary to stderr."""
    from railgsa_ros.cli._progress import with_progress
    from railgsa_ros.errors import ConfigError, InputError
    from railgsa_ros.fileio import refuse_overlap
    from railgsa_ros.inverse.grid import ChainageGrid
    from railgsa_ros.inverse.pipeline import Output
    from railgsa_ros.offline import COACH_BAND, steps
    from railgsa_ros.vehicle import VehicleParams

    refuse_overlap(args.csv or args.out, (args.bag, args.params, args.vehicle, args.uncertainty,
                                          args.uncertainty_params))
    if args.grid is not None and args.bands:
        raise ConfigError('--bands: the uncertainty band is per IMU sample; not with --grid')
    inp = load_inputs(args)
    if args.bands and not isinstance(inp.vehicle, VehicleParams):
        print(f'warning: --bands: {COACH_BAND}', file=sys.stderr)
        args.bands = False
    driver = make_driver(args, inp)
    grid = ChainageGrid.for_config(inp.config, args.grid) if args.grid is not None else None
    count = usable = 0
    with output(args, inp.location) as sink:
        pieces = with_progress(inp.pieces, args.bag, args.imu_topic, 'invert', args.quiet)
        for step in steps(driver, pieces):
            if grid is None:
                sink.write(step.stamps_ns, step.chainage_m, step.u_m, step.quality, step.band)
                count, usable = count + len(step), usable + int((step.quality != 2).sum())
                continue
            g = grid.push(Output(step.stamps_ns, step.chainage_m, step.u_m, step.quality,
                                 step.speed_mps))
            sink.write(g.stamps_ns, g.chainage_m, g.u_m, g.quality)
            count, usable = count + len(g), usable + int((g.quality != 2).sum())
        if grid is not None:
            g = grid.flush()
            sink.write(g.stamps_ns, g.chainage_m, g.u_m, g.quality)
            count, usable = count + len(g), usable + int((g.quality != 2).sum())
        if count == 0:  # nothing written: the temporary output goes
            counts = driver.counters
            rejected = ', '.join(f'{k} {counts[k]}' for k in REJECTIONS if counts.get(k)) or \
                'none'
            raise InputError(f'{args.bag}: no usable IMU sample (rejected: {rejected}): '
                             f'{driver.nominal.status.message}')
    for finding in driver.nominal.findings:
        if finding.level:
            print(f'warning: {finding.message}', file=sys.stderr)
        elif finding.key == 'mounting':
            print(f'mounting: {finding.message}', file=sys.stderr)
    if usable == 0:
        print('warning: every output is INVALID (u = nan): see the warnings above, or the run '
              'is shorter than the band window', file=sys.stderr)
    scale = inp.location.scale
    if inp.location.track is not None:
        print(f'odometry scale {scale.value:.5f} +- {scale.std:.5f} ({scale.note})',
              file=sys.stderr)
    summary = ', '.join(f'{k} {v}' for k, v in sorted(driver.counters.items()))
    print(f'{count} samples ({driver.nominal.config.method}, band {driver.nominal.config.band}, '
          f'delay {driver.delay_samples} samples); {summary}', file=sys.stderr)
    return 0
