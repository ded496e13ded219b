"""Speed of ``railgsa review`` on one core, against reading the same bag alone.

A simulated run (German low track with two dips, ADXL355 at ``--rate``, ``--speed`` m/s,
``--seconds`` long, MCAP zstd) is written once (not timed). Then, pinned to one CPU:
- baseline: ``bag.read_imu`` of the bag (what any review must at least do);
- review, nominal only: ``build_review`` + ``write_review`` with ``--no-uncertainty``;
- review, full: the same with the uncertainty node's default configuration (band, windows,
  histogram), i.e. ``railgsa review BAG --out DIR``.
BLAS threads are limited to one before numpy is imported. Each row gives seconds, times real time
(run duration / wall time, the goal is >= 100x for a 1 kHz bag) and the ratio to the baseline,
then the review's own stage times (read, stream, analyse, figures).

Usage: python benchmarks/bench_review_speed.py [--seconds 600] [--rate 1000] [--speed 30]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import tempfile
import time

DEFECTS = 'dip@2000:len=6:depth=0.015,dip@5000:len=8:depth=0.02'
START_NS = 1_700_000_000 * 10**9  # realistic positive stamps (jitter may go below 0 at t = 0)


def review_once(bag: Path, out: Path, uncertain: bool) -> tuple[float, dict[str, float]]:
    """Wall time (s) of one review written to ``out``, and its stage times."""
    from railgsa_ros.review.build import ReviewOptions, build_review, write_review
    from railgsa_ros.uncertainty import UncertaintyConfig
    from railgsa_ros.uq.uncertainty_file import table3

    start = time.perf_counter()
    review = build_review(ReviewOptions(bag, UncertaintyConfig(),
                                        dists=table3() if uncertain else None))
    write_review(review, out, overwrite=True)
    return time.perf_counter() - start, review.timings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=600.0, help='run length, s')
    parser.add_argument('--rate', type=float, default=1000.0, help='IMU rate, Hz')
    parser.add_argument('--speed', type=float, default=30.0, help='m/s')
    args = parser.parse_args()
    if hasattr(os, 'sched_setaffinity'):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    for name in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
        os.environ[name] = '1'  # one core: set before numpy is imported (below)
    from railgsa_ros.bag import read_imu, write_run
    from railgsa_ros.scenario import run_scenario

    with tempfile.TemporaryDirectory(prefix='bench_review_') as tmp:
        bag = write_run(Path(tmp) / 'run', run_scenario('german-low', args.speed, args.seconds,
                                                         args.rate, 'adxl355', 0,
                                                         defects=DEFECTS, start_ns=START_NS))
        start = time.perf_counter()
        stream = read_imu(bag)
        base = time.perf_counter() - start
        span = (stream.stamps_ns[-1] - stream.stamps_ns[0]) * 1e-9
        rows = [('read_imu alone (baseline)', base, {})]
        for label, uncertain in (('review, nominal only', False), ('review, full', True)):
            wall, stages = review_once(bag, Path(tmp) / 'out', uncertain)
            rows.append((label, wall, stages))
    print(f'{span:.0f} s of {args.rate:g} Hz IMU data ({stream.stamps_ns.size} samples), '
          f'one CPU')
    print(f'{"":<28}{"s":>8}{"x real time":>13}{"/ baseline":>12}   stages [s]')
    for label, wall, stages in rows:
        parts = ', '.join(f'{k} {v:.2f}' for k, v in stages.items())
        print(f'{label:<28}{wall:8.2f}{span / wall:13.1f}{wall / base:12.2f}   {parts}')


if __name__ == '__main__':
    main()
