"""Soak: memory and per-sample cost stay flat over a long run, offline and live.

Offline (``--hours``, default 24): hours of 1 kHz IMU data through the streaming core, the
nominal ``InversionPipeline`` and the ``UncertaintyStream`` (rule bank + windowed sensitivity),
in 1 s chunks. The input is a simulated 10 min run (German-low track at 30 m/s, ADXL355 noise)
repeated with continuous stamps. Per hour-block: resident memory (VmRSS, MB) at its end and the
cost per sample (us). Verdict: RSS growth after the first hour <= 5 MB and no upward trend in cost
(least-squares slope of cost against hour, printed with its ratio to the mean cost).

Live (``--live-minutes``, default 10; 0 skips it): an IMU publisher process at 1 kHz
(bench_node_latency.py's ``publish`` role), ``irregularity_node`` and ``uncertainty_node`` as
processes, all on loopback in a reserved ROS domain. Every minute: each node's VmRSS and CPU
share from /proc, and from its /diagnostics the published count, the irregularity node's latency
p99 and the uncertainty node's window compute time. Verdict: RSS growth after a two-minute
warm-up <= 5 MB; the slopes of latency and window compute time are printed.

Usage: python benchmarks/bench_soak.py [--hours 24] [--live-minutes 10] [--uq-hours H]
"""

from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')  # one BLAS thread before numpy loads

import numpy as np

from railgsa_ros.system import reserve_domain

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_node_latency import _cpu_seconds, _ros_env  # noqa: E402

RATE_HZ = 1000
SPEED_MPS = 30.0
BLOCK_S = 600  # the simulated run that is repeated
CHUNK = RATE_HZ  # samples per push (1 s)
MAX_GROWTH_MB = 5.0
WARM_UP_MIN = 2  #: live minutes before the first windows' allocations have settled


def rss_mb(pid: int | str = 'self') -> float:
    """VmRSS of a process in MB (0 when it is gone)."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024
    except FileNotFoundError:
        pass
    return 0.0


def _input() -> np.ndarray:
    from railgsa_ros.scenario import run_scenario

    run = run_scenario('german-low', speed_mps=SPEED_MPS, duration_s=BLOCK_S, rate_hz=RATE_HZ,
                       sensor='adxl355', seed=7)
    return np.ascontiguousarray(run.accel[:, 2])


def soak_offline(name: str, make: object, hours: float, acc: np.ndarray) -> list[tuple]:
    """Rows (hour, rss MB, us per sample, outputs, non-finite outputs) for one streaming object."""
    core = make()
    per_hour = 3600 * RATE_HZ
    period_ns = 1_000_000_000 // RATE_HZ
    rows, k = [], 0
    for hour in range(1, int(np.ceil(hours)) + 1):
        outputs = bad = 0
        t0 = time.process_time()
        end = min(hour * per_hour, int(hours * per_hour))
        n_hour = end - k
        while k < end:
            i = k % acc.size
            m = min(CHUNK, acc.size - i, end - k)
            stamps = (1_000_000_000 + (k + np.arange(m, dtype=np.int64)) * period_ns)
            out = core.push(stamps, acc[i:i + m], SPEED_MPS)
            u = out.u_m if hasattr(out, 'u_m') else out.band.mean_m
            outputs += u.size
            bad += int(np.count_nonzero(~np.isfinite(u)))
            k += m
        cost = (time.process_time() - t0) / max(n_hour, 1) * 1e6
        rows.append((hour, rss_mb(), cost, outputs, bad))
        print(f'  {name} hour {hour}: {cost:.2f} us/sample, RSS {rows[-1][1]:.1f} MB',
              file=sys.stderr, flush=True)
    return rows


def verdict(rows: list[tuple]) -> tuple[float, float, float, bool]:
    """(RSS growth after hour 1 in MB, cost slope us/h, slope / mean cost, flat?)"""
    hours = np.array([r[0] for r in rows], float)
    rss = np.array([r[1] for r in rows])
    cost = np.array([r[2] for r in rows])
    growth = float(rss[1:].max() - rss[0]) if rss.size > 1 else 0.0
    slope = float(np.polyfit(hours, cost, 1)[0]) if hours.size > 1 else 0.0
    rel = slope / float(cost.mean())
    # "no upward trend": over the whole run the fitted rise stays below 10 % of the mean cost
    flat = growth <= MAX_GROWTH_MB and slope * (hours[-1] - hours[0]) <= 0.1 * cost.mean()
    return growth, slope, rel, flat


def print_offline(name: str, rows: list[tuple]) -> bool:
    growth, slope, rel, flat = verdict(rows)
    print(f'\n### {name}: {len(rows)} h of 1 kHz IMU offline\n')
    print('| hour | VmRSS MB | us/sample | outputs | non-finite |')
    print('|---|---|---|---|---|')
    for hour, rss, cost, outputs, bad in rows:
        print(f'| {hour} | {rss:.1f} | {cost:.2f} | {outputs} | {bad} |')
    print(f'\nRSS growth after hour 1: {growth:+.2f} MB (limit {MAX_GROWTH_MB:g}); cost slope '
          f'{slope:+.4f} us/sample per hour ({rel:+.2%} of the mean per hour); '
          f'{"FLAT" if flat else "NOT FLAT"}')
    return flat


# ---------------------------------------------------------------------- live
class DiagnosticsTap:
    """Latest /diagnostics values per status name, from a background rclpy node."""

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        import rclpy

        rclpy.init()
        self.node = rclpy.create_node('bench_soak_diagnostics')
        self.latest: dict[str, dict[str, str]] = {}
        self.lock = threading.Lock()
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on, 50)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        import rclpy
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):
            rclpy.spin(self.node)

    def _on(self, msg: object) -> None:
        with self.lock:
            for status in msg.status:
                self.latest[status.name] = {kv.key: kv.value for kv in status.values}

    def get(self, name: str, key: str) -> str:
        with self.lock:
            return self.latest.get(name, {}).get(key, '-')

    def close(self) -> None:
        import rclpy

        rclpy.try_shutdown()
        self.thread.join(5.0)


def soak_live(minutes: float) -> bool:
    """Both nodes as processes under a 1 kHz publisher; a row a minute. True when flat."""
    domain, sock = reserve_domain()
    env = _ros_env(domain)
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(domain))
    common = ['-p', 'use_odom:=false', '-p', f'speed_mps:={SPEED_MPS}']
    out = Path(tempfile.mkdtemp(prefix='bench_soak_'))
    logs = {name: out / f'{name}.err' for name in ('irregularity_node', 'uncertainty_node')}
    nodes = {name: subprocess.Popen(
        [sys.executable, '-m', f'railgsa_ros.nodes.{name}', '--ros-args', *common], env=env,
        stdout=subprocess.DEVNULL, stderr=log.open('w')) for name, log in logs.items()}
    tap = DiagnosticsTap()
    publisher = subprocess.Popen(
        [sys.executable, str(HERE / 'bench_node_latency.py'), 'publish', '--duration',
         str(minutes * 60 + 30), '--out', str(out), '--readers', '2'], env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    rows = []
    try:
        cpu0 = {n: (_cpu_seconds(p.pid), time.monotonic()) for n, p in nodes.items()}
        start = time.monotonic()
        for minute in range(1, int(minutes) + 1):
            time.sleep(max(0.0, start + 60 * minute - time.monotonic()))
            row = [minute]
            for name, proc in nodes.items():
                cpu, now = _cpu_seconds(proc.pid), time.monotonic()
                share = (cpu - cpu0[name][0]) / (now - cpu0[name][1])
                cpu0[name] = (cpu, now)
                row += [rss_mb(proc.pid), share]
            irr, unc = 'irregularity_node: inversion', 'uncertainty_node: uncertainty'
            row += [tap.get(irr, 'published'), tap.get(irr, 'latency_p99_ms'),
                    tap.get(unc, 'published'), tap.get(unc, 'window_compute_ms')]
            rows.append(row)
            print(f'  live minute {minute}: {row}', file=sys.stderr, flush=True)
    finally:
        for proc in (publisher, *nodes.values()):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        codes = [p.wait(30) for p in nodes.values()]
        publisher.wait(30)
        tap.close()
        sock.close()
    print(f'\n### live: {int(minutes)} min at 1 kHz through both nodes (exit codes {codes})\n')
    for (name, log), code in zip(logs.items(), codes, strict=True):
        if code != 0:
            print(f'{name} stderr (last lines):\n```\n'
                  + '\n'.join(log.read_text().splitlines()[-15:]) + '\n```\n')
    print('| minute | irregularity RSS MB | CPU | published | latency p99 ms | '
          'uncertainty RSS MB | CPU | published | window compute ms |')
    print('|---|---|---|---|---|---|---|---|---|')
    for m, r1, c1, r2, c2, p1, l1, p2, w2 in rows:
        print(f'| {m} | {r1:.1f} | {c1:.0%} | {p1} | {l1} | {r2:.1f} | {c2:.0%} | {p2} | {w2} |')
    flat = True
    minutes_arr = np.array([r[0] for r in rows], float)
    for name, col, lat_col, lat_name in (('irregularity_node', 1, 6, 'latency p99'),
                                         ('uncertainty_node', 3, 8, 'window compute')):
        rss = np.array([r[col] for r in rows])
        warm = minutes_arr > WARM_UP_MIN
        growth = float(rss[warm].max() - rss[warm][0]) if warm.sum() > 1 else 0.0
        flat &= growth <= MAX_GROWTH_MB
        lat = np.array([float(r[lat_col]) if r[lat_col] != '-' else np.nan for r in rows])
        ok = np.isfinite(lat)
        slope = float(np.polyfit(minutes_arr[ok], lat[ok], 1)[0]) if ok.sum() > 1 else 0.0
        print(f'{name}: RSS {rss[0]:.1f} MB at minute 1, growth after minute {WARM_UP_MIN} '
              f'(warm-up) {growth:+.2f} MB (limit {MAX_GROWTH_MB:g}); {lat_name} slope '
              f'{slope:+.3f} ms per minute')
    return flat and codes == [0, 0]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--hours', type=float, default=24.0, help='offline hours (nominal)')
    parser.add_argument('--uq-hours', type=float, default=None,
                        help='offline hours of the uncertainty stream (default: --hours)')
    parser.add_argument('--live-minutes', type=float, default=10.0, help='0 skips the live part')
    args = parser.parse_args(argv)
    ok = True
    if args.hours > 0:
        from railgsa_ros.inverse.pipeline import InversionPipeline
        from railgsa_ros.uncertainty import UncertaintyConfig, UncertaintyStream

        acc = _input()
        ok &= print_offline('InversionPipeline (nominal, defaults)', soak_offline(
            'nominal', InversionPipeline, args.hours, acc))
        uq_hours = args.hours if args.uq_hours is None else args.uq_hours
        if uq_hours > 0:
            ok &= print_offline('UncertaintyStream (defaults)', soak_offline(
                'uncertainty', lambda: UncertaintyStream(UncertaintyConfig()), uq_hours, acc))
    if args.live_minutes > 0:
        ok &= soak_live(args.live_minutes)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
