"""``railgsa simulate-passes``: a series of simulated passes over one line, with their truth."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from railgsa_ros.cli.simulate import DEFAULT_START_S, add_gnss_arguments

# Defects a fleet should follow on the default track and speeds (docs/simulation.md): in D1 the
# 8 m dip reads 0.68 x its depth, 4.8 -> 5.5 mm over the default 5 weekly passes, and the 6 m
# dip 0.75 x, 5.2 mm; both between half the EN 13848-5 alert limit (4 mm at 80-120 km/h, the
# fastest default speeds) and the limit (8 mm), and above the default German-low track's own
# D1 peaks (SD 0.9 mm, largest 3.4 mm over 3 km), so they stand out of the background.
DEFAULT_DEFECTS = ('dip@600:len=8:depth=7e-3:growth=4e-5,'
                   'dip@1400:len=6:depth=7e-3:from={new}')


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``simulate-passes`` subcommand."""
    p = subparsers.add_parser(
        'simulate-passes', help='simulate a series of passes over one line (fleet data)',
        description='Write N rosbag2 bags over the same track and line geometry on dates days '
                    'apart, with defects that grow between dates and one that appears from a '
                    'given pass on; speeds, start positions, vehicles, wheel-diameter errors '
                    'and noise differ per pass. GNSS (/gnss/fix) in every bag. Next to each '
                    'truth/PASS.json, truth/truth.csv with one row per pass and defect, and '
                    'line.geojson, the line geometry (docs/simulation.md).')
    p.add_argument('--out', required=True, metavar='DIR', help='directory to create')
    p.add_argument('--passes', type=int, default=5, metavar='N', help='number of passes (5)')
    p.add_argument('--profile', default='german-low', metavar='SPEC',
                   help='track: german-low | german-high | fra-N | paper (default german-low)')
    p.add_argument('--section-km', default='0.3-3.0', metavar='A-B',
                   help='chainage span in km that every pass covers (default 0.3-3.0)')
    p.add_argument('--defects', default=None, metavar='SPEC',
                   help='defects with growth=M_PER_DAY, depths=A/B/... and from=K keys '
                        f'(default "{DEFAULT_DEFECTS}" with K = N/2 + 1)')
    p.add_argument('--days', type=float, default=7.0, metavar='D',
                   help='days between passes (default 7)')
    p.add_argument('--first-date', default='2024-01-08', metavar='YYYY-MM-DD',
                   help='date of the first pass, UTC (default 2024-01-08)')
    p.add_argument('--speed-range', default='15-30', metavar='A-B',
                   help='cruise speeds in m/s, drawn per pass (default 15-30)')
    p.add_argument('--stop-every', type=int, default=3, metavar='K',
                   help='every K-th pass stops once and restarts, clear of the defects '
                        '(default 3; 0 = never)')
    p.add_argument('--vehicle-spread', type=float, default=0.03, metavar='F',
                   help='vehicle parameters drawn within +-F of Table 1 (default 0.03)')
    p.add_argument('--odom-error-max', type=float, default=0.005, metavar='E',
                   help='wheel-diameter errors drawn within +-E (default 0.005)')
    p.add_argument('--rate', type=float, default=None, metavar='HZ',
                   help='IMU rate in Hz (default: the sensor preset rate)')
    p.add_argument('--sensor', default='adxl355', metavar='PRESET', help='IMU preset')
    p.add_argument('--seed', type=int, default=0, metavar='N',
                   help='seed of the series (track, trains, noise; default 0)')
    add_gnss_arguments(p)
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    p.add_argument('--overwrite', action='store_true', help='replace an existing DIR')
    p.set_defaults(func=run)


def series_from_args(args: argparse.Namespace) -> Any:
    """The SeriesSpec of a parsed command line."""
    from datetime import UTC, datetime

    from railgsa_ros.errors import ConfigError
    from railgsa_ros.pass_series import SeriesSpec, parse_growing_defects, parse_range

    if args.passes < 1:
        raise ConfigError(f'--passes: must be >= 1, got {args.passes}')
    try:
        first = datetime.strptime(args.first_date, '%Y-%m-%d').replace(tzinfo=UTC)
    except ValueError:
        raise ConfigError(f'--first-date: expected YYYY-MM-DD, got {args.first_date!r}') from None
    lo, hi = parse_range(args.section_km, '--section-km')
    spec = args.defects if args.defects is not None else \
        DEFAULT_DEFECTS.format(new=args.passes // 2 + 1)
    return SeriesSpec(args.passes, (1e3 * lo, 1e3 * hi), parse_growing_defects(spec, args.passes),
                      first, args.days, parse_range(args.speed_range, '--speed-range'),
                      vehicle_spread=args.vehicle_spread, odom_error_max=args.odom_error_max,
                      stop_every=args.stop_every, seed=args.seed)


def write_series(out: str | Path, series: Any, options: Any, overwrite: bool = False
                 ) -> list[Path]:
    """Write every pass of ``series`` (a SeriesSpec) into directory ``out``, with its truth;
    ``options``: the SimOptions shared by the passes. Returns the bag paths."""
    import csv
    from dataclasses import replace
    import json

    from railgsa_ros.cli.simulate import stream_bag
    from railgsa_ros.fileio import atomic_output
    from railgsa_ros.geo import default_line
    from railgsa_ros.pass_series import plan_series

    plans = plan_series(series)
    line = default_line(max(p.end_m for p in plans))  # a prefix of every pass's GNSS line
    bags = []
    with atomic_output(Path(out), overwrite) as tmp:
        (tmp / 'truth').mkdir(parents=True)
        rows = []
        for plan in plans:
            name = f'pass_{plan.index + 1:02d}'
            pass_options = replace(options, speed_profile=plan.speed_profile, seed=plan.seed,
                                   defects=plan.defect_spec or None, vehicle=plan.vehicle,
                                   start_km=plan.start_m / 1e3,
                                   start_time=plan.start_time_s,
                                   odom_scale_error=plan.odom_scale_error, gnss=True)
            stream_bag(tmp / name, pass_options)
            truth = plan.truth(line, series)
            truth['bag'] = name
            (tmp / 'truth' / f'{name}.json').write_text(json.dumps(truth, indent=1) + '\n')
            rows += [{'pass': truth['pass'], 'bag': name, 'date': truth['date'],
                      'days': truth['days'], 'odom_scale': truth['odom_scale'], **{
                          k: d[k] for k in ('id', 'kind', 'present', 'new', 'centre_km',
                                            'lat_deg', 'lon_deg', 'depth_m', 'length_m')}}
                     for d in truth['defects']]
            bags.append(Path(out) / name)
        (tmp / 'line.geojson').write_text(line_geojson(line) + '\n')
        with (tmp / 'truth' / 'truth.csv').open('w', newline='') as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]) if rows else ['pass'])
            writer.writeheader()
            writer.writerows(rows)
    return bags


def line_geojson(line: Any) -> str:
    """A ``geo.Line`` as a GeoJSON FeatureCollection: one LineString (lon, lat in degrees) with
    the properties line_id and start_m (chainage of the first vertex, m)."""
    import json

    feature = {'type': 'Feature',
               'geometry': {'type': 'LineString',
                            'coordinates': [[lo, la] for la, lo in zip(
                                line.lat_deg.tolist(), line.lon_deg.tolist(), strict=True)]},
               'properties': {'line_id': line.line_id, 'start_m': line.start_m}}
    return json.dumps({'type': 'FeatureCollection', 'features': [feature]})


def run(args: argparse.Namespace) -> int:
    """Plan the series, write every pass and its truth, print one line per pass."""
    import json

    from railgsa_ros.cli.simulate import SimOptions

    options = SimOptions(profile=args.profile, rate=args.rate, sensor=args.sensor,
                         storage=args.storage, line_seed=args.seed, gnss_rate=args.gnss_rate,
                         gnss_noise=args.gnss_noise, gnss_corr=args.gnss_corr,
                         start_time=DEFAULT_START_S)
    bags = write_series(args.out, series_from_args(args), options, args.overwrite)
    for bag in bags:
        truth = json.loads((bag.parent / 'truth' / f'{bag.name}.json').read_text())
        depths = ', '.join(f'{1e3 * d["depth_m"]:.2f}' for d in truth['defects'])
        print(f'{bag}  {truth["date"][:10]}  km {truth["start_km"]:.3f}-'
              f'{truth["end_m"] / 1e3:.3f}  odometry x{truth["odom_scale"]:.4f}  '
              f'depths [mm] {depths}')
    return 0
