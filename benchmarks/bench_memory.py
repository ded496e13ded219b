"""Peak resident memory and speed of the offline commands for 0.5, 2 and 10 hours of 1 kHz data.

For each duration a bag is prepared (not timed): ``--base-seconds`` of a simulated run (German
low track, ADXL355 at 1 kHz, ``--speed`` m/s, two dips) written again and again with continuous
stamps (each copy starts one IMU period after the previous one ends) until the duration is
reached, MCAP with zstd chunks, /imu/data and /odom only. Repeating is what makes 10 h possible
on this machine (simulating it takes longer than the bench should; the ``simulate`` rows run
``railgsa simulate`` itself, for the durations given to ``--simulate-hours``).

Then each command runs as its own process pinned to one CPU with OPENBLAS_NUM_THREADS=1:

- baseline: reading the bag alone (``bag.reader.iter_imu`` over every piece, nothing kept);
- ``railgsa simulate`` of the duration (no repetition) to a bag;
- ``railgsa invert BAG --csv OUT.csv``;
- ``railgsa review BAG --out DIR --no-uncertainty`` (nominal only) and the full review.

Each row prints wall and CPU seconds, times real time from both (CPU time suffers less from
other work on a shared machine), the ratio to the baseline's wall time, the process's peak
resident memory (ru_maxrss of ``os.wait4``) with its ratio to the baseline's, and the machine's
1-minute load average when the row ended (how shared the machine was).

The package is byte-compiled first (``compileall``, as ``pip install`` leaves an installed
package): an editable install under PYTHONDONTWRITEBYTECODE=1 would otherwise compile the
package's modules again in every command (0.1-0.2 s of each, measured).

The recorder (``record`` rows, ``--record-minutes``, default 1 and 3): ``imu_sim_node``
publishes a 1 kHz run live (IMU, odometry, truth), and ``railgsa record`` records /imu/data
and /odom for the given minutes of wall time, pinned to CPU 0, both in a reserved ROS domain
with localhost-only discovery. The row gives the recorder's peak RSS, its CPU time (x real
from CPU: how much faster than real time one core could record), and after the row the
recorded IMU messages per second and the growth of its resident memory after the first
30 s (least-squares slope of VmRSS sampled every 2 s, MB per minute): flat memory is a slope
near 0 and the same peak for both durations.

Usage: python benchmarks/bench_memory.py [--hours 0.5 2 10] [--simulate-hours 0.5]
                                         [--rows baseline invert review-nominal review record]
                                         [--record-minutes 1 3]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import tempfile
import time

DEFECTS = 'dip@2000:len=6:depth=0.015,dip@5000:len=8:depth=0.02'
START_NS = 1_700_000_000 * 10**9
ROWS = ('baseline', 'simulate', 'invert', 'review-nominal', 'review', 'record')
RECORD_WARM_UP_S = 30.0  # recorder RSS before this is start-up, not growth
READ_ONLY = ('import sys\nfrom railgsa_ros.bag.reader import iter_imu\n'
             'n = sum(p.stamps_ns.size for p in iter_imu(sys.argv[1]))\nprint(n)\n')


def make_bag(path: Path, hours: float, base_s: float, speed: float) -> Path:
    """A bag of ``hours`` of 1 kHz data: a simulated run of ``base_s`` repeated with continuous
    stamps (IMU and odometry only)."""
    import numpy as np

    from railgsa_ros.bag import BagWriter, RunEncoder
    from railgsa_ros.scenario import run_scenario

    run = run_scenario('german-low', speed, base_s, 1000.0, 'adxl355', 1, defects=DEFECTS,
                       start_ns=START_NS)
    encoder = RunEncoder(run)
    period = int(np.median(np.diff(run.stamps_ns)))
    span = int(run.stamps_ns[-1] - run.stamps_ns[0]) + period
    copies = int(np.ceil(hours * 3600 / (span * 1e-9)))
    topics = encoder.topics()
    with BagWriter(path, 'mcap', 'zstd') as writer:
        for key in ('imu', 'odom'):
            writer.add_topic(*topics[key])
        for k in range(copies):
            for lo in range(0, len(encoder), 50_000):
                batches = encoder.encode_rows(lo, lo + 50_000, k * span)
                writer.write_batches({topics[key][0]: batches[key] for key in ('imu', 'odom')})
    return path


ONE_THREAD = {'OPENBLAS_NUM_THREADS': '1', 'OMP_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1',
              'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}


def measure(cmd: list[str], env: dict[str, str] | None = None,
            watch: Callable[[int], None] | None = None) -> tuple[float, float, float]:
    """(wall s, CPU s, peak resident MB) of a command run on CPU 0 with one BLAS thread;
    ``watch(pid)`` runs while it does (it returns when the process has ended)."""
    env = {**(os.environ if env is None else env), **ONE_THREAD}
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            preexec_fn=lambda: os.sched_setaffinity(0, {0}))
    if watch is not None:
        watch(proc.pid)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    err = proc.stderr.read().decode(errors='replace') if proc.stderr else ''
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f'{" ".join(cmd)} failed: {err.strip()[-400:]}')
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def byte_compile() -> None:
    """Byte-compile the package's modules, as an installed package has them."""
    import railgsa_ros

    env = {k: v for k, v in os.environ.items() if k != 'PYTHONDONTWRITEBYTECODE'}
    subprocess.run([sys.executable, '-m', 'compileall', '-q',
                    str(Path(railgsa_ros.__file__).parent)], env=env, check=True,
                   stdout=subprocess.DEVNULL)


def rss_samples(pid: int, period_s: float = 2.0) -> list[tuple[float, float]]:
    """(s since the first sample, VmRSS MB) of a process every ``period_s`` until it exits
    (a zombie has no VmRSS line: the samples end there)."""
    samples: list[tuple[float, float]] = []
    start = time.monotonic()
    while True:
        try:
            lines = Path(f'/proc/{pid}/status').read_text().splitlines()
        except OSError:
            return samples
        rss = [int(x.split()[1]) / 1024 for x in lines if x.startswith('VmRSS:')]
        if not rss:
            return samples
        samples.append((time.monotonic() - start, rss[0]))
        time.sleep(period_s)


def record(minutes: float, work: Path) -> tuple[tuple[float, float, float], str]:
    """The recorder row: ``railgsa record`` of a live 1 kHz ``imu_sim_node`` for ``minutes``;
    (wall s, CPU s, peak MB) and a note (IMU messages per second, RSS slope after the
    warm-up)."""
    import numpy as np

    from railgsa_ros.offline import Source
    from railgsa_ros.system import reserve_domain, ros_env

    seconds = minutes * 60
    domain, sock = reserve_domain()
    env = {**ros_env(), 'ROS_DOMAIN_ID': str(domain)}
    publisher = subprocess.Popen(
        [sys.executable, '-m', 'railgsa_ros.nodes.imu_sim_node', '--ros-args',
         '-p', f'duration_s:={seconds + 120:g}', '-p', 'rate_hz:=1000.0',
         '-p', 'speed_mps:=30.0'], env={**env, **ONE_THREAD}, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    samples: list[tuple[float, float]] = []
    try:
        time.sleep(15.0)  # the simulated run is computed at start-up, then published
        if publisher.poll() is not None:
            raise SystemExit(f'imu_sim_node ended early (exit {publisher.returncode})')
        bag = work / 'recorded'
        cmd = [str(Path(sys.executable).parent / 'railgsa'), 'record', '--out', str(bag),
               '--topics', '/imu/data', '/odom', '--duration', f'{seconds:g}']
        row = measure(cmd, env, lambda pid: samples.extend(rss_samples(pid)))
    finally:
        publisher.send_signal(signal.SIGINT)
        publisher.wait(30)
        if sock is not None:
            sock.close()
    count = Source(bag).count('/imu/data')
    t, rss = np.array(samples).T if samples else (np.zeros(0), np.zeros(0))
    late = t >= RECORD_WARM_UP_S
    slope = float(np.polyfit(t[late], rss[late], 1)[0]) * 60 if late.sum() > 2 else np.nan
    shutil.rmtree(bag)
    after = (f'{rss[late][0]:.0f} -> {rss[late][-1]:.0f} MB' if late.any() else 'no samples')
    return row, (f'{count / seconds:.0f} IMU msg/s recorded; RSS after {RECORD_WARM_UP_S:g} s: '
                 f'{after}, slope {slope:+.2f} MB/min')


def command(row: str, bag: Path, work: Path, hours: float, speed: float) -> list[str]:
    """The command line of a row."""
    railgsa = [str(Path(sys.executable).parent / 'railgsa')]
    if row == 'baseline':
        return [sys.executable, '-c', READ_ONLY, str(bag)]
    if row == 'simulate':
        return [*railgsa, 'simulate', '--out', str(work / 'sim'), '--duration',
                str(hours * 3600), '--speed', str(speed), '--rate', '1000', '--overwrite']
    if row == 'invert':
        return [*railgsa, 'invert', str(bag), '--csv', str(work / 'out.csv'), '--overwrite']
    extra = ['--no-uncertainty'] if row == 'review-nominal' else []
    return [*railgsa, 'review', str(bag), '--out', str(work / row), '--overwrite',
            '--no-progress', *extra]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--hours', type=float, nargs='*', default=[0.5, 2.0, 10.0])
    parser.add_argument('--simulate-hours', type=float, nargs='*', default=[0.5],
                        help='durations for the simulate rows')
    parser.add_argument('--rows', nargs='+', choices=ROWS, default=list(ROWS))
    parser.add_argument('--record-minutes', type=float, nargs='*', default=[1.0, 3.0],
                        help='durations of the record rows (wall time)')
    parser.add_argument('--base-seconds', type=float, default=600.0)
    parser.add_argument('--speed', type=float, default=30.0)
    parser.add_argument('--dir', type=Path, default=None, help='work directory (default tmp)')
    args = parser.parse_args()
    work_root = Path(tempfile.mkdtemp(prefix='bench_memory_', dir=args.dir))
    byte_compile()
    print(f'{"hours":>6} {"row":<15} {"wall s":>8} {"x real":>7} {"CPU s":>8} {"x real":>7} '
          f'{"/base":>6} {"peak MB":>8} {"/base":>6} {"load":>5}')
    try:
        for hours in args.hours:
            work = work_root / f'{hours:g}h'
            work.mkdir()
            bag = make_bag(work / 'bag', hours, args.base_seconds, args.speed)
            base: tuple[float, float, float] | None = None
            for row in args.rows:
                if (row == 'simulate' and hours not in args.simulate_hours) or row == 'record':
                    continue
                wall, cpu, mb = measure(command(row, bag, work, hours, args.speed))
                if row == 'baseline':
                    base = (wall, cpu, mb)
                seconds = hours * 3600
                ratio = f'{wall / base[0]:6.2f}' if base else f'{"-":>6}'
                mem = f'{mb / base[2]:6.2f}' if base else f'{"-":>6}'
                print(f'{hours:6g} {row:<15} {wall:8.1f} {seconds / wall:7.0f} {cpu:8.1f} '
                      f'{seconds / cpu:7.0f} {ratio} {mb:8.0f} {mem} {os.getloadavg()[0]:5.1f}',
                      flush=True)
            shutil.rmtree(work)
        for minutes in args.record_minutes if 'record' in args.rows else []:
            (wall, cpu, mb), note = record(minutes, work_root)
            seconds = minutes * 60
            print(f'{minutes / 60:6.3g} {"record":<15} {wall:8.1f} {seconds / wall:7.2f} '
                  f'{cpu:8.1f} {seconds / cpu:7.0f} {"-":>6} {mb:8.0f} {"-":>6} '
                  f'{os.getloadavg()[0]:5.1f}  {note}', flush=True)
    finally:
        shutil.rmtree(work_root, ignore_errors=True)


if __name__ == '__main__':
    main()
