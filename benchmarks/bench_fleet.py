"""Fleet ingestion on Dask: speed-up with 1 and 2 workers and the cost per bag-hour.

One pass of ``--minutes`` of 1 kHz data (ADXL355 model, German-low line, 25 m/s) is simulated
and copied into ``--bags`` bags (same content, distinct files: each is a full task). The same
batch is ingested into a fresh database on a LocalCluster of 1 and of 2 worker processes (one
thread each, 127.0.0.1). Printed per run: the cluster's start-up (timed apart: paid once per
batch), wall time, speed-up against the 1-worker run of the same invocation, CPU seconds in the
workers (``PassResult.cpu_s``: reading, inversion, gridding) and in the client (alignment,
DuckDB writes, fusion and trends: this process's CPU time), real-time factor, CPU seconds
per hour of 1 kHz data (bag-hour), the largest worker's peak resident memory and the load
average when the run ended. The machine is shared: the load average is printed next to the
numbers, and a speed-up measured under load is not the idle machine's.

Usage: python benchmarks/bench_fleet.py [--bags 8] [--minutes 10] [--workers 1 2]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import shutil
import tempfile
import time

from railgsa_ros.bag import write_run
from railgsa_ros.fleet import db
from railgsa_ros.fleet.ingest import dask_client, ingest
from railgsa_ros.fleet.passes import PassOptions
from railgsa_ros.scenario import run_scenario


def make_bags(folder: Path, count: int, minutes: float) -> tuple[list[str], float]:
    """``count`` copies of one simulated pass; returns the paths and the pass duration (s)."""
    run = run_scenario('german-low', 25.0, 60.0 * minutes, 1000.0, 'adxl355', seed=1,
                       defects='dip@2000:len=8:depth=7e-3')
    first = write_run(folder / 'pass0', run)  # a rosbag2 directory
    bags = [str(first)]
    for i in range(1, count):
        bags.append(str(shutil.copytree(first, folder / f'pass{i}')))
    return bags, float(run.t_true_s[-1] - run.t_true_s[0])


def measure(bags: list[str], workers: int, folder: Path) -> dict[str, float]:
    """Ingest the batch on a running cluster of ``workers`` workers into a new database: cluster
    start-up, wall, worker and client CPU."""
    path = folder / f'fleet{workers}.duckdb'
    path.unlink(missing_ok=True)
    startup = time.perf_counter()
    with dask_client(None, workers) as client:
        startup = time.perf_counter() - startup
        wall, cpu = time.perf_counter(), time.process_time()
        outcomes = ingest(bags, path, PassOptions(line='bench'), client.scheduler.address)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        rss_kb = max(client.run(peak_rss_kb).values())
    if any(o.status != 'ok' for o in outcomes):
        raise SystemExit(f'ingest failed: {outcomes}')
    con = db.connect(path, read_only=True)
    worker_cpu, data_s = con.execute('SELECT sum(cpu_s), sum(duration_s) FROM passes').fetchone()
    con.close()
    return {'startup': startup, 'wall': wall, 'client': cpu, 'workers': worker_cpu,
            'data': data_s, 'rss_mb': rss_kb / 1024}


def peak_rss_kb() -> int:
    """Peak resident memory of this process (kB; run on each worker): VmHWM, not ru_maxrss,
    which on Linux keeps the parent's resident size at the fork that started the worker."""
    with open('/proc/self/status', encoding='ascii') as status:
        line = next(row for row in status if row.startswith('VmHWM:'))
    return int(line.split()[1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--bags', type=int, default=8)
    parser.add_argument('--minutes', type=float, default=10.0)
    parser.add_argument('--workers', type=int, nargs='+', default=[1, 2])
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix='bench_fleet_'))
    try:
        start = time.perf_counter()
        bags, duration = make_bags(folder, args.bags, args.minutes)
        hours = args.bags * duration / 3600
        print(f'{args.bags} bags of {duration / 60:.1f} min at 1 kHz ({hours:.2f} bag-hours), '
              f'simulated in {time.perf_counter() - start:.0f} s; '
              f'{len(os.sched_getaffinity(0))} CPUs, load average '
              f'{" ".join(f"{x:.1f}" for x in os.getloadavg())}')
        print(f'{"workers":>7} {"start s":>7} {"wall s":>7} {"speed-up":>8} {"worker CPU s":>12} '
              f'{"client CPU s":>12} {"x real time":>11} {"CPU s / bag-hour":>16} '
              f'{"worker peak RSS MB":>18} {"load 1/5/15 min":>15}')
        base = None
        for n in args.workers:
            r = measure(bags, n, folder)
            base = base or r['wall']
            hours = r['data'] / 3600
            print(f'{n:>7} {r["startup"]:>7.1f} {r["wall"]:>7.1f} {base / r["wall"]:>8.2f} '
                  f'{r["workers"]:>12.1f} {r["client"]:>12.1f} {r["data"] / r["wall"]:>11.0f} '
                  f'{(r["workers"] + r["client"]) / hours:>16.1f} {r["rss_mb"]:>18.0f} '
                  f'{" ".join(f"{x:.1f}" for x in os.getloadavg()):>15}')
        print(f'load average after: {" ".join(f"{x:.1f}" for x in os.getloadavg())}')
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == '__main__':
    main()
