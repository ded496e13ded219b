"""``railgsa review``: an offline HTML report of a recorded run (no ROS, no DDS).

Runs the streaming core of irregularity_node and uncertainty_node over the bag in chunks and
writes DIR/report.html with its PNG figures (railgsa_ros.review, docs/review.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
from typing import Any

# the default --min-probability: a maintenance list holds the exceedances more likely than not
# (docs/uq.md, "Exceedance probability": on simulated runs P >= 0.5 kept all 6 real ones with no
# false alarm, where listing every band-edge stretch gave 15 false alarms; docs/review.md,
# "Exceedance probability near a limit": with P(AL) and the central value kept, 2 of 72 real
# alert-limit exceedances near IL missed instead of 13); ReviewOptions (the library) lists every
# candidate unless told
LISTED_PROBABILITY = 0.5


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``review`` subcommand."""
    p = subparsers.add_parser(
        'review', help='offline review of a bag: HTML report with EN 13848-5 exceedances, '
                       '200 m SD, uncertainty band, sensitivities, input health',
        description='Reconstruct the irregularity of a recorded run with the nodes\' streaming '
                    'core (offline, chunked) and write DIR/report.html with PNG figures: '
                    'irregularity with its uncertainty band, EN 13848-5 AL/IL/IAL exceedances '
                    'for the speed class, SD per 200 m, sensitivity indices along the run, the '
                    'surrogate histogram at the worst location and input health; with --truth '
                    'also the error figures and scores.')
    p.add_argument('bag', metavar='BAG', help='rosbag2 bag directory or .mcap/.db3 file')
    p.add_argument('--out', required=True, metavar='DIR', help='report directory to create')
    p.add_argument('--truth', metavar='BAG_OR_CSV',
                   help='ground truth: a bag with /track/irregularity_truth or a CSV x_m,u_m '
                        '(chainage from the run start)')
    p.add_argument('--method', choices=('spectral', 'feedback', 'kalman'),
                   help='inversion method (default: the params file, else spectral)')
    p.add_argument('--band', choices=('d1', 'd2'),
                   help='EN 13848 band (default: the params file, else d1)')
    p.add_argument('--params', metavar='FILE',
                   help='ROS params file: uncertainty_node and/or irregularity_node '
                        'ros__parameters (inversion, rule, quantiles, windows)')
    p.add_argument('--vehicle', metavar='FILE',
                   help='nominal vehicle YAML (default: the params vehicle_file, else Table 1)')
    p.add_argument('--uncertainty', metavar='FILE',
                   help='uncertain parameters YAML (default: the params uncertainty_file, else '
                        'Table 3 around the vehicle)')
    p.add_argument('--no-uncertainty', action='store_true',
                   help='nominal reconstruction only: no band, sensitivities or histogram')
    p.add_argument('--limit-end', choices=('lower', 'upper'), default='lower',
                   help="end of the standard's EN 13848-5 AL/IL ranges to apply, without "
                        '--limits (default lower: strictest)')
    add_standard_options(p)
    p.add_argument('--min-probability', type=float, default=LISTED_PROBABILITY, metavar='P',
                   help='list only exceedances whose probability of passing their limit or '
                        'the alert limit (from the uncertainty band) is at least P, and those '
                        'whose reconstruction passes the alert limit, 0-1 (default '
                        f'{LISTED_PROBABILITY:g}: more likely than not; 0: every band-edge '
                        'stretch); without a band (--no-uncertainty) every exceedance')
    add_topic_options(p)
    add_location_options(p)
    p.add_argument('--json', action='store_true',
                   help='print a JSON summary (counts, worst defect, files written) on stdout')
    p.add_argument('--overwrite', action='store_true', help='replace an existing DIR')
    bar = p.add_mutually_exclusive_group()
    bar.add_argument('--progress', dest='progress', action='store_const', const=True,
                     help='always draw the progress bar on stderr (default: only on a terminal)')
    bar.add_argument('--no-progress', dest='progress', action='store_const', const=False,
                     help='never draw the progress bar')
    p.set_defaults(func=run, progress=None)


LOCATION_KEYS = ('line', 'track', 'direction', 'km_origin')  # params-file keys, as the nodes'


def add_standard_options(p: argparse.ArgumentParser) -> None:
    """--limits and --line-speed: what classes every EN 13848-5 defect (review and fleet)."""
    p.add_argument('--limits', metavar='TABLE.yaml',
                   help="the infrastructure manager's AL/IL/IAL table per speed range "
                        '(config/limits_en13848.yaml; default: the standard\'s table)')
    p.add_argument('--line-speed', metavar='SPEEDS.yaml',
                   help="the line's permitted speed per km range, YAML or CSV from_km,to_km,"
                        'speed_kmh (config/line_speed_example.yaml; default: class by the '
                        'measuring speed)')


def standard_inputs(args: argparse.Namespace) -> tuple[Any, Any]:
    """(limit table or None, line speed or None) of --limits and --line-speed (ConfigError
    naming the file and field)."""
    from railgsa_ros.standards.en13848 import load_limit_table
    from railgsa_ros.standards.line_speed import load_line_speed

    return (load_limit_table(args.limits) if args.limits else None,
            load_line_speed(args.line_speed) if args.line_speed else None)


def bag_topic(name: str) -> str:
    """A topic name as bags record it: fully qualified, a relative name taken in the root
    namespace (a bag has no node namespace to resolve it in: ``imu/data`` is ``/imu/data``)."""
    return name if name.startswith('/') else f'/{name}'


def add_topic_options(p: argparse.ArgumentParser,
                      odom_help: str = 'nav_msgs/Odometry topic (default /odom)') -> None:
    """--imu-topic and --odom-topic of the commands that read bags (names as ``bag_topic``)."""
    p.add_argument('--imu-topic', default='/imu/data', type=bag_topic, metavar='T',
                   help='sensor_msgs/Imu topic (default /imu/data)')
    p.add_argument('--odom-topic', default='/odom', type=bag_topic, metavar='T', help=odom_help)


def add_location_options(p: argparse.ArgumentParser) -> None:
    """--line, --track, --direction, --km-origin, --gnss-topic (railgsa review and invert).
    The direction is checked by ``location.Reference`` (one check for options and params files;
    importing it here would load numpy and the bag readers for ``railgsa --help``)."""
    p.add_argument('--line', help='line id (default: the params file line, else empty)')
    p.add_argument('--track', help='track id (default: the params file track, else empty)')
    p.add_argument('--direction', metavar='increasing|decreasing',
                   help='km-posts increase or decrease along the run (default increasing)')
    p.add_argument('--km-origin', type=float, metavar='KM',
                   help='km-post of the run start, chainage 0 (default 0)')
    p.add_argument('--gnss-topic', default='/gnss/fix', type=bag_topic, metavar='T',
                   help='sensor_msgs/NavSatFix topic, used when present (default /gnss/fix)')


def reference(args: argparse.Namespace, params: dict[str, Any]) -> Any:
    """The location reference: the options, else the params file's keys, else defaults."""
    from railgsa_ros.location import Reference

    values = {k: params[k] for k in LOCATION_KEYS if k in params}
    for key in LOCATION_KEYS:
        if getattr(args, key) is not None:
            values[key] = getattr(args, key)
    if 'km_origin' in values:
        try:
            values['km_origin'] = float(values['km_origin'])
        except (TypeError, ValueError):
            from railgsa_ros.errors import ConfigError

            raise ConfigError(f'km_origin: expected a number of km, got '
                              f'{values["km_origin"]!r}') from None
    given: dict[str, Any] = {k: v if k == 'km_origin' else str(v) for k, v in values.items()}
    return Reference(**given)


def parameters(args: argparse.Namespace) -> dict[str, Any]:
    """Params-file values (irregularity_node, then uncertainty_node on top), then the options."""
    from dataclasses import fields

    from railgsa_ros.cli._params import read_params
    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.uncertainty import UncertaintyConfig

    params: dict[str, Any] = {}
    if args.params:
        known = {f.name for f in (*fields(UncertaintyConfig), *fields(InversionConfig))
                 if f.name != 'inversion'} | {'vehicle_file', 'uncertainty_file',
                                              *LOCATION_KEYS}
        params = read_params(args.params, ('irregularity_node', 'uncertainty_node'), known,
                             'review')
    for name in ('method', 'band'):
        if getattr(args, name) is not None:
            params[name] = getattr(args, name)
    return params


def build_options(args: argparse.Namespace) -> Any:
    """ReviewOptions from the command line (ConfigError naming the option or file)."""
    from dataclasses import fields

    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.models import vehicle_of
    from railgsa_ros.offline import COACH_BAND
    from railgsa_ros.review.results import ReviewOptions
    from railgsa_ros.uncertainty import UncertaintyConfig
    from railgsa_ros.uncertainty.parameters import load_uncertainty, table3, with_discrepancy
    from railgsa_ros.vehicle import VehicleParams

    params = parameters(args)
    known = {f.name for f in fields(UncertaintyConfig)} | {f.name for f in
                                                          fields(InversionConfig)}
    config = UncertaintyConfig.from_mapping({k: v for k, v in params.items() if k in known},
                                            source=args.params or 'command line')
    vehicle_file = args.vehicle or params.get('vehicle_file') or None
    vehicle = vehicle_of(vehicle_file)
    dists = None
    if args.no_uncertainty:
        pass
    elif not isinstance(vehicle, VehicleParams):
        print(f'warning: {COACH_BAND}', file=sys.stderr)
    else:
        source = args.uncertainty or params.get('uncertainty_file') or None
        dists = load_uncertainty(source) if source else table3(vehicle)
        config = with_discrepancy(config, source)
    table, line_speed = standard_inputs(args)
    if table is not None and args.limit_end != 'lower':
        from railgsa_ros.errors import ConfigError

        raise ConfigError("--limit-end: applies to the standard's table, not to --limits")
    return ReviewOptions(Path(args.bag), config, vehicle, dists,
                         Path(args.truth) if args.truth else None, args.limit_end,
                         imu_topic=args.imu_topic, odom_topic=args.odom_topic,
                         rate_from_bag='rate_hz' not in params, gnss_topic=args.gnss_topic,
                         reference=reference(args, params),
                         min_probability=min_probability(args.min_probability),
                         limits=table, line_speed=line_speed)


def min_probability(value: float) -> float:
    """--min-probability checked: a probability in [0, 1]."""
    from railgsa_ros.errors import ConfigError

    if not 0.0 <= value <= 1.0:
        raise ConfigError(f'--min-probability: expected a probability in [0, 1], got {value!r}')
    return value


def outside_line_speed(review: Any) -> str:
    """'' when --line-speed covers the run's km-posts, else what part of the run it leaves out
    (no limit applies there)."""
    speeds = review.limits.line_speed
    if speeds is None:
        return ''
    ref, run = review.location.reference, review.run
    start, end = sorted(float(ref.km(c)) for c in (run.first[1], run.last[1]))
    first, last = speeds.span_km
    if first <= start and end <= last:
        return ''
    return (f'the run covers km {start:.3f}-{end:.3f}, {speeds.name} only km {first:g}-{last:g}: '
            'no limit applies outside')


def run(args: argparse.Namespace) -> int:
    """Build the review, write the report, print where it is and the headline numbers."""
    from railgsa_ros.fileio import refuse_overlap
    from railgsa_ros.review.build import build_review, write_review
    from railgsa_ros.review.exceedances import describe_counts
    from railgsa_ros.review.progress import Progress

    refuse_overlap(args.out, (args.bag, args.truth, args.params, args.vehicle, args.uncertainty,
                              args.limits, args.line_speed))

    options = build_options(args)
    bar = Progress(1000, 'review', enabled=args.progress)
    try:
        review = build_review(options, lambda stage, f: bar.update(round(1000 * f),
                                                                   f'{stage:<10}'))
        report = write_review(review, args.out, args.overwrite,
                              lambda stage, f: bar.update(round(1000 * f), f'{stage:<10}'))
    finally:
        bar.close()
    for finding in review.run.findings:
        if finding.level:
            print(f'warning: {finding.message}', file=sys.stderr)
    outside = outside_line_speed(review)
    if outside:
        print(f'warning: {outside}', file=sys.stderr)
    if args.json:
        import json

        from railgsa_ros.review.outputs import summary

        print(json.dumps(summary(review, report), indent=1))
        return 0
    levels = ', '.join(f'{k} {v}' for k, v in describe_counts(review.exceedances).items())
    total = sum(review.timings.values())
    print(f'{report}\n  {review.duration_s:.1f} s of data reviewed in {total:.1f} s '
          f'({review.duration_s / total:.0f}x real time); exceedances: {levels}')
    return 0
