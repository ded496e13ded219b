"""``railgsa fleet``: the track condition database (ingest on Dask, report, query).

``ingest`` inverts each bag on a Dask cluster (a LocalCluster on 127.0.0.1 by default), aligns
the passes of a line, fuses them and follows every defect over time in a DuckDB file;
``report`` writes an HTML trend report; ``query`` lists the defects of a line between two
km-posts as JSON or CSV (railgsa_ros.fleet, docs/fleet.md).
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from railgsa_ros.cli.review import add_location_options, add_standard_options, add_topic_options

if TYPE_CHECKING:
    from railgsa_ros.fleet.ingest import Outcome
    from railgsa_ros.fleet.passes import PassOptions

EXIT_SOME_FAILED = 1
DEFAULT_LINE, DEFAULT_TRACK = 'line', '1'  # when neither the options nor a params file say


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``fleet`` with its ``ingest``, ``report`` and ``query`` subcommands."""
    p = subparsers.add_parser(
        'fleet', help='track condition database: ingest passes on Dask, trend report, query',
        description='Many passes of many trains in one DuckDB file: aligned, fused and trended.')
    sub = p.add_subparsers(title='fleet commands', metavar='FLEET_COMMAND', required=True)

    ing = sub.add_parser('ingest', help='invert bags on Dask and store them in the database',
                         description='Invert each bag (one Dask task per bag), align it on its '
                                     "line's chainage, store it, then re-fuse, re-detect and "
                                     'trend the line. Exit 1 when some bag failed (the others '
                                     'are stored), 2 on bad options.')
    ing.add_argument('bags', nargs='+', metavar='BAG', help='rosbag2 bags (directory or file)')
    ing.add_argument('--db', required=True, metavar='PATH', help='DuckDB file (created if new)')
    ing.add_argument('--scheduler', metavar='ADDRESS',
                     help='an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: a '
                          'LocalCluster on 127.0.0.1)')
    ing.add_argument('--workers', type=int, default=2, metavar='N',
                     help='LocalCluster worker processes, one thread each (default 2)')
    ing.add_argument('--vehicle-id', default='', metavar='NAME', help='vehicle name stored')
    ing.add_argument('--line-geometry', metavar='FILE',
                     help='line geometry for GNSS anchoring: GeoJSON LineString (lon, lat) or '
                          'CSV lat,lon; stored with the line (default: the stored one)')
    ing.add_argument('--geometry-start-km', type=float, metavar='KM',
                     help='km-post of the geometry\'s first vertex (default: the GeoJSON '
                          'Feature\'s start_m property, else 0)')
    ing.add_argument('--params', metavar='FILE', help='ROS params file (as railgsa review)')
    ing.add_argument('--vehicle', metavar='FILE', help='nominal vehicle YAML')
    ing.add_argument('--method', choices=('spectral', 'feedback', 'kalman'))
    ing.add_argument('--band', choices=('d1', 'd2'))
    add_topic_options(ing)
    add_location_options(ing)  # --line, --track, --direction, --km-origin, --gnss-topic
    add_standard_options(ing)  # --limits, --line-speed
    ing.add_argument('--detect-fraction', type=float, metavar='F',
                     help='defects are followed from F x the alert limit of the speed class '
                          '(default 0.5; 0 < F <= 1)')
    ing.set_defaults(func=run_ingest)

    rep = sub.add_parser('report', help='HTML trend report of the database')
    rep.add_argument('--db', required=True, metavar='PATH')
    rep.add_argument('--out', required=True, metavar='DIR', help='report directory to create')
    rep.add_argument('--overwrite', action='store_true', help='replace an existing DIR')
    add_standard_options(rep)
    rep.set_defaults(func=run_report)

    qry = sub.add_parser('query', help='defects of a line between two km-posts')
    qry.add_argument('--db', required=True, metavar='PATH')
    qry.add_argument('--line', required=True)
    qry.add_argument('--track', help='only this track (default: all)')
    qry.add_argument('--from-km', type=float, required=True, metavar='A')
    qry.add_argument('--to-km', type=float, required=True, metavar='B')
    add_standard_options(qry)
    fmt = qry.add_mutually_exclusive_group()
    fmt.add_argument('--json', dest='format', action='store_const', const='json',
                     help='JSON array (default)')
    fmt.add_argument('--csv', dest='format', action='store_const', const='csv')
    qry.set_defaults(func=run_query, format='json')


def pass_options(args: argparse.Namespace) -> PassOptions:
    """PassOptions from the command line (ConfigError naming the option or file): the inversion
    configuration and vehicle exactly as ``railgsa review --no-uncertainty`` builds them."""
    from railgsa_ros.cli.review import build_options
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.fleet.defects import DETECT_FRACTION
    from railgsa_ros.fleet.passes import PassOptions

    if args.workers < 1:
        raise ConfigError(f'--workers: must be at least 1, got {args.workers}')
    fraction = DETECT_FRACTION if args.detect_fraction is None else args.detect_fraction
    if not 0 < fraction <= 1:
        raise ConfigError(f'--detect-fraction: expected 0 < F <= 1, got {fraction}')
    review = build_options(review_namespace(args))
    where = review.reference  # options, else the params file's location keys
    return PassOptions(review.config, review.vehicle, where.line or DEFAULT_LINE,
                       where.track or DEFAULT_TRACK, where.direction, where.km_origin,
                       args.vehicle_id, args.imu_topic, args.odom_topic, args.gnss_topic,
                       rate_from_bag=review.rate_from_bag,
                       detect_fraction=fraction, limits=review.limits,
                       line_speed=review.line_speed)


SHARED = ('params', 'vehicle', 'method', 'band', 'imu_topic', 'odom_topic', 'gnss_topic', 'line',
          'track', 'direction', 'km_origin', 'limits', 'line_speed')  # as in railgsa review


def review_namespace(args: argparse.Namespace) -> argparse.Namespace:
    """``railgsa review BAG --out DIR --no-uncertainty`` as its own parser reads it (every review
    option at its default), with the options ``ingest`` shares with it taken from ``args``."""
    from railgsa_ros.cli import review

    parser = argparse.ArgumentParser()
    review.register(parser.add_subparsers())
    namespace = parser.parse_args(['review', 'BAG', '--out', 'DIR', '--no-uncertainty'])
    for name in SHARED:
        setattr(namespace, name, getattr(args, name))
    return namespace


def said(outcome: Outcome) -> str:
    """'BAG: message', the bag named once (error messages already start with it)."""
    if outcome.message.startswith(outcome.bag):
        return outcome.message
    return f'{outcome.bag}: {outcome.message}'


def run_ingest(args: argparse.Namespace) -> int:
    """Ingest, printing one line per bag and a summary; exit 1 when a bag failed."""
    from railgsa_ros.fileio import refuse_overlap
    from railgsa_ros.fleet import db
    from railgsa_ros.fleet.gnss import load_geometry
    from railgsa_ros.fleet.ingest import ingest

    refuse_overlap(args.db, (*args.bags, args.params, args.vehicle, args.line_geometry,
                             args.limits, args.line_speed))
    options = pass_options(args)
    geometry = None
    if args.line_geometry:
        start = None if args.geometry_start_km is None else 1000.0 * args.geometry_start_km
        geometry = load_geometry(args.line_geometry, start, options.line)

    def show(o: Outcome) -> None:
        label = f'pass {o.pass_id}' if o.pass_id is not None else '-'
        print(f'{o.status:<9} {label:<8} {said(o)}', flush=True)

    with db.damage_named(args.db):
        outcomes = ingest(args.bags, args.db, options, args.scheduler, args.workers, show,
                          geometry)
        for o in outcomes:
            if o.status in ('skipped', 'repaired'):
                show(o)
        con = db.connect(args.db, read_only=True)
        try:
            n_pass, n_def, n_new = con.execute(
                "SELECT (SELECT count(*) FROM passes WHERE line = $l AND track = $t AND status "
                "= 'ok'), count(*), count(*) FILTER (WHERE new) FROM defects WHERE line = $l "
                "AND track = $t", {'l': options.line, 't': options.track}).fetchone() or (0, 0, 0)
        finally:
            con.close()
    bad = [o for o in outcomes if o.status in ('failed', 'unaligned')]
    kept = sum(o.status in ('ok', 'skipped') for o in outcomes)
    print(f'{args.db}: line {options.line} track {options.track}: {n_pass} passes, {n_def} '
          f'defects ({n_new} new); this batch: {kept} stored or skipped, '
          f'{len(bad)} failed')
    for o in bad:
        print(f'  {o.status}: {said(o)}', file=sys.stderr)
    return EXIT_SOME_FAILED if bad else 0


def run_report(args: argparse.Namespace) -> int:
    """Write the report and print its path."""
    from railgsa_ros.cli.review import standard_inputs
    from railgsa_ros.fileio import refuse_overlap
    from railgsa_ros.fleet import db
    from railgsa_ros.fleet.report import write_report

    refuse_overlap(args.out, (args.db, args.limits, args.line_speed))
    with db.damage_named(args.db):
        print(write_report(args.db, args.out, args.overwrite, *standard_inputs(args)))
    return 0


def run_query(args: argparse.Namespace) -> int:
    """Print the defects between the km-posts as JSON or CSV."""
    from railgsa_ros.cli.review import standard_inputs
    from railgsa_ros.fleet import db
    from railgsa_ros.fleet.query import defects_between, line_limits, to_csv, to_json

    table, line_speed = standard_inputs(args)
    with db.damage_named(args.db):
        con = db.connect(args.db, read_only=True)
        try:
            limits = line_limits(con, args.line, args.track, table, line_speed)
            rows = defects_between(con, args.line, args.from_km, args.to_km, args.track,
                                   limits)
        finally:
            con.close()
    sys.stdout.write(to_csv(rows) if args.format == 'csv' else to_json(rows) + '\n')
    return 0
