"""Speed of ``railgsa review`` on one core, against reading the same bag alone.

A simulated run (German low track with two dips, ADXL355 at ``--rate``, ``--speed`` m/s,
``--seconds`` long, MCAP zstd) is written once (not timed). Then, pinned to one CPU:
- baseline: ``bag.read_imu`` of the bag (what any review must at least do);
- the same through rosbags, the general path that the MCAP fast path of ``bag.reader`` skips;
- review, nominal only: ``build_review`` + ``write_review`` with ``--no-uncertainty``;
- review, full: the same with the uncertainty node's default configuration (band, windows,
  histogram), i.e. ``railgsa review BAG --out DIR``.
BLAS threads are limited to one before numpy is imported. Each row gives wall seconds, times real
time (run duration / wall time, the goal is >= 100x for a 1 kHz bag), the same from the process's
CPU time (what the row costs one core, robust against other load on a shared machine; also
counts the page faults of the kernel) and the ratio to the baseline (wall time),
then the process's peak resident memory during the row (VmHWM, MB, reset before each row through
/proc/self/clear_refs) and the review's own stage times (read, stream, analyse, figures).

Usage: python benchmarks/bench_review_speed.py [--seconds 600] [--rate 1000] [--speed 30]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import tempfile
import time
from unittest import mock

DEFECTS = 'dip@2000:len=6:depth=0.015,dip@5000:len=8:depth=0.02'
START_NS = 1_700_000_000 * 10**9  # realistic positive stamps (jitter may go below 0 at t = 0)


def review_once(bag: Path, out: Path, uncertain: bool) -> dict[str, float]:
    """Stage times (s) of one review written to ``out``."""
    from railgsa_ros.review.build import build_review, write_review
    from railgsa_ros.review.results import ReviewOptions
    from railgsa_ros.uncertainty import UncertaintyConfig
    from railgsa_ros.uncertainty.parameters import table3

    review = build_review(ReviewOptions(bag, UncertaintyConfig(),
                                        dists=table3() if uncertain else None))
    write_review(review, out, overwrite=True)
    return review.timings


def timed(func):
    """(wall s, CPU s, peak resident MB during the call, result) of ``func()``."""
    peak_mb(reset=True)
    wall, cpu = time.perf_counter(), time.process_time()
    result = func()
    return time.perf_counter() - wall, time.process_time() - cpu, peak_mb(), result


def peak_mb(reset: bool = False) -> float:
    """Peak resident memory of this process (VmHWM) since the last reset, MB; ``reset``: start
    a new peak at the current resident memory."""
    if reset:
        Path('/proc/self/clear_refs').write_text('5')
    line = next(x for x in Path('/proc/self/status').read_text().splitlines()
                if x.startswith('VmHWM'))
    return int(line.split()[1]) * 1024 / 1e6


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
    from railgsa_ros.bag import read_imu, reader, write_run
    from railgsa_ros.scenario import run_scenario

    with tempfile.TemporaryDirectory(prefix='bench_review_') as tmp:
        bag = write_run(Path(tmp) / 'run', run_scenario('german-low', args.speed, args.seconds,
                                                         args.rate, 'adxl355', 0,
                                                         defects=DEFECTS, start_ns=START_NS))
        wall, cpu, peak, stream = timed(lambda: read_imu(bag))
        span = (stream.stamps_ns[-1] - stream.stamps_ns[0]) * 1e-9
        samples = stream.stamps_ns.size
        del stream
        rows = [('read_imu alone (baseline)', wall, cpu, peak, {})]
        with mock.patch.object(reader, '_mcap_files', return_value=None):
            rows.append(('read_imu through rosbags', *timed(lambda: read_imu(bag))[:3], {}))
        for label, uncertain in (('review, nominal only', False), ('review, full', True)):
            rows.append((label, *timed(lambda u=uncertain: review_once(bag, Path(tmp) / 'out',
                                                                        u))))
    print(f'{span:.0f} s of {args.rate:g} Hz IMU data ({samples} samples), one CPU, '
          f'OPENBLAS_NUM_THREADS=1, load average {os.getloadavg()[0]:.1f} at the end')
    print(f'{"":<26}{"wall s":>8}{"x real time":>12}{"CPU s":>7}{"x real (CPU)":>13}'
          f'{"/ baseline":>11}{"peak MB":>8}   stages [s]')
    base = rows[0][1]
    for label, wall, cpu, peak, stages in rows:
        parts = ', '.join(f'{k} {v:.2f}' for k, v in stages.items())
        print(f'{label:<26}{wall:8.2f}{span / wall:12.1f}{cpu:7.2f}{span / cpu:13.1f}'
              f'{wall / base:11.2f}{peak:8.0f}   {parts}')


if __name__ == '__main__':
    main()
