"""``railgsa demo``: the main job end to end on simulated data, outputs in one directory."""

from __future__ import annotations

import argparse
from pathlib import Path

DEMO_PROFILE = 'german-low'
DEMO_DEFECTS = 'dip@150:len=10:depth=0.004'


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``demo`` subcommand."""
    p = subparsers.add_parser(
        'demo', help='run the demonstration (simulated bag, its summary, Bode diagram)',
        description='Simulate a 20 s run (German low disturbance track with a 4 mm dip, ADXL355 '
                    'at 1 kHz, 20 m/s) into a rosbag2 bag, print its summary and draw the Bode '
                    'diagram. Outputs in DIR are replaced on every run.')
    p.add_argument('--out', default='out/demo', metavar='DIR',
                   help='output directory (default out/demo)')
    p.add_argument('--seed', type=int, default=0, metavar='N', help='random seed (default 0)')
    p.set_defaults(func=run)


def _heading(text: str) -> None:
    """Print a step heading."""
    print(f'\n== {text}')


def run(args: argparse.Namespace) -> int:
    """Run every demonstration step and list the outputs."""
    from railgsa_ros.cli.bode import mode_table, plot_bode
    from railgsa_ros.cli.simulate import format_summary, simulate_bag
    from railgsa_ros.vehicle import VehicleParams

    out = Path(args.out)
    _heading(f'1. simulate: {DEMO_PROFILE} + {DEMO_DEFECTS}, adxl355 at 1 kHz, 20 m/s, 20 s')
    bag, _ = simulate_bag(out / 'simulated_bag', DEMO_PROFILE, speed=20.0, duration=20.0,
                          sensor='adxl355', seed=args.seed, defects=DEMO_DEFECTS,
                          overwrite=True)
    print(format_summary(bag))
    _heading('2. quarter vehicle (paper Table 1): modes, zeros, Bode diagram')
    params = VehicleParams()
    png = plot_bode(params, out / 'bode.png')
    print(mode_table(params))
    _heading('outputs')
    for path in (bag, png):
        print(f'  {path}')
    return 0
