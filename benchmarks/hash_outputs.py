"""SHA-256 of every offline output on the project's own and simulated bags.

A refactoring that must not change any output runs this before and after and compares the
lines (``python benchmarks/hash_outputs.py > before.txt``). It runs ``railgsa invert`` (every
method, the grid, the uncertainty band) and ``railgsa review`` (its CSV and GeoJSON files and
the JSON summary) on bags/german_low_dip and on bags it simulates: a stop-and-go speed profile,
the bmi088 preset (jitter, dropouts), a sqlite3 bag with an odometry scale error, a run with
GNSS. The review's HTML and PNG files are left out (they embed figure renderings, not results).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path
import subprocess
import sys
import tempfile

ROOT = Path(__file__).resolve().parent.parent
OWN_BAG = ROOT / 'bags' / 'german_low_dip'

#: simulated bags: name -> ``railgsa simulate`` arguments
SIMULATED = {
    'stop_and_go': ['--speed-profile', 'accel:0-20:10s,cruise:20:10s,brake:20-0:8s,stop:4s,'
                    'accel:0-15:8s', '--sensor', 'adxl355', '--rate', '500', '--seed', '3'],
    'bmi088': ['--sensor', 'bmi088', '--speed', '30', '--duration', '15', '--seed', '4',
               '--defects', 'dip@200:len=8:depth=0.003'],
    'sqlite_scaled': ['--storage', 'sqlite3', '--speed', '15', '--duration', '12',
                      '--rate', '400', '--odom-scale-error', '0.004', '--seed', '5'],
    'gnss': ['--gnss', '--speed', '25', '--duration', '12', '--rate', '500', '--seed', '6'],
}

#: inversions: name -> ``railgsa invert`` arguments (besides the bag and --csv)
INVERSIONS = {
    'spectral': [],
    'feedback': ['--method', 'feedback'],
    'kalman': ['--method', 'kalman'],
    'smoother': ['--method', 'kalman', '--smoother'],
    'grid': ['--grid', '0.25'],
    'bands': ['--bands'],
    'wide': ['--band', 'wide', '--sensor-delay', 'adxl355@1000Hz'],
}

#: summary keys that differ between runs: paths of this run's temporary folder, timing
VOLATILE = ('bag', 'files', 'review_s', 'real_time_factor')
#: which inversions run on which bag (all on the project's bag)
ON_SIMULATED = ('spectral', 'kalman', 'grid', 'bands')


def railgsa(*args: str) -> str:
    """Run ``railgsa ARGS`` with this interpreter; its stdout."""
    done = subprocess.run([sys.executable, '-m', 'railgsa_ros.cli.main', *args],
                          capture_output=True, text=True, check=False)
    if done.returncode:
        raise SystemExit(f'railgsa {" ".join(args)} failed:\n{done.stderr}')
    return done.stdout


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def hash_bag(name: str, bag: Path, work: Path, inversions: tuple[str, ...]) -> list[str]:
    """Lines 'bag/output sha256' for the inversions and the review of one bag."""
    lines = []
    for inv in inversions:
        out = work / f'{name}_{inv}.csv'
        railgsa('invert', str(bag), '--csv', str(out), *INVERSIONS[inv])
        lines.append(f'{name}/invert_{inv} {digest(out)}')
    for label, extra in (('review', []), ('review_nominal', ['--no-uncertainty'])):
        folder = work / f'{name}_{label}'
        summary = json.loads(railgsa('review', str(bag), '--out', str(folder), '--json',
                                     '--no-progress', *extra))
        for key in VOLATILE:
            summary.pop(key, None)
        text = json.dumps(summary, sort_keys=True).encode()
        lines.append(f'{name}/{label}_json {hashlib.sha256(text).hexdigest()}')
        for path in sorted(folder.iterdir()):
            if path.suffix in ('.csv', '.geojson', '.json'):
                lines.append(f'{name}/{label}/{path.name} {digest(path)}')
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true', help="the project's bag only")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for line in hash_bag('german_low_dip', OWN_BAG, work, tuple(INVERSIONS)):
            print(line, flush=True)
        if args.quick:
            return
        for name, sim in SIMULATED.items():
            bag = work / name
            railgsa('simulate', '--out', str(bag), *sim)
            for line in hash_bag(name, bag, work, ON_SIMULATED):
                print(line, flush=True)


if __name__ == '__main__':
    main()
