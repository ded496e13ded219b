"""Cost and accuracy of the uncertainty stream and uncertainty_node, against the nominal pipeline.

1. In core: a simulated 1 kHz run pushed in 50-sample chunks (the node's 50 ms processing
   period) through the nominal InversionPipeline (baseline) and UncertaintyStream (19-point PEM5
   bank, band quantiles, sensitivity windows). Fraction of one core = CPU time / data duration;
   then, in a second untimed pass, the peak of the memory allocated while building and running
   each (tracemalloc).
2. Live: an IMU publisher at 1 kHz, irregularity_node (the nominal pipeline live: baseline) and
   uncertainty_node as separate processes (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a private
   ROS_DOMAIN_ID); CPU time of each node from /proc over the publishing period, its peak resident
   memory (VmHWM, the whole process: Python, numpy, rclpy), and what each published (read back
   from its /diagnostics).
3. Accuracy: band mean and quantiles against brute-force Monte Carlo through the same inverse
   (paper mode: feedback, no band; the paper profile at 10 m/s, 8 s, noise-free).

BLAS is limited to one thread (set before numpy is imported), as on the loaded 2-core machine
the nodes are measured on.

Usage: python benchmarks/bench_uncertainty_cost.py [--duration 60] [--live 30] [--mc 2000]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time
import tracemalloc

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')  # before numpy: one BLAS thread
import numpy as np

from railgsa_ros.system import reserve_domain

SPEED_MPS = 20.0
CHUNK = 50
TARGET = 0.25  # fraction of one core


def _run(duration_s: float):
    from railgsa_ros.scenario import run_scenario

    return run_scenario('german-low', SPEED_MPS, duration_s, 1000.0, 'adxl355', 3)


def in_core(duration_s: float) -> None:
    """Table 1: CPU fraction of the nominal pipeline and of the uncertainty stream."""
    from railgsa_ros.inverse.pipeline import InversionPipeline
    from railgsa_ros.uncertainty import UncertaintyConfig, UncertaintyStream

    run = _run(duration_s)
    acc, config = run.accel[:, 2], UncertaintyConfig()
    makers = {'nominal pipeline': lambda: InversionPipeline(config.inversion),
              'uncertainty stream': lambda: UncertaintyStream(config)}

    def stream(obj) -> list:
        windows = []
        for lo in range(0, acc.size, CHUNK):
            out = obj.push(run.stamps_ns[lo:lo + CHUNK], acc[lo:lo + CHUNK],
                           run.speed_mps[lo:lo + CHUNK])
            windows += getattr(out, 'windows', [])
        return windows + getattr(obj.flush(), 'windows', [])  # closes the last window

    rows = {}
    for name, make in makers.items():
        obj = make()
        start = time.process_time()
        windows = stream(obj)
        cpu = time.process_time() - start
        tracemalloc.start()  # second pass, untimed: tracing slows allocations down
        stream(make())
        rows[name] = (cpu, windows, tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    base = rows['nominal pipeline'][0]
    print(f'\n1. In core: {duration_s:g} s at 1 kHz ({acc.size} samples) in chunks of {CHUNK} '
          f'and a flush, spectral D1, {config.rule} on Table 3 (19 points)')
    print(f'{"":<20}{"CPU s":>8}{"core fraction":>15}{"ratio":>8}{"peak MB":>9}')
    for name, (cpu, _, peak) in rows.items():
        print(f'{name:<20}{cpu:>8.2f}{cpu / duration_s:>15.4f}{cpu / base:>8.1f}'
              f'{peak / 1e6:>9.1f}')
    windows = rows['uncertainty stream'][1]
    ms = np.array([w.compute_s for w in windows[::len(config.qois)]]) * 1e3
    print(f'sensitivity windows ({config.window_length:g} s, {len(config.qois)} QoIs, n_mc '
          f'{config.n_mc}): {ms.size}, compute per window mean {ms.mean():.1f} ms, max '
          f'{ms.max():.1f} ms')


# ----------------------------------------------------------------------------- live
def _peak_mb(pid: int) -> float:
    """Peak resident memory (VmHWM) of a process, MB."""
    line = next(x for x in Path(f'/proc/{pid}/status').read_text().splitlines()
                if x.startswith('VmHWM'))
    return int(line.split()[1]) * 1024 / 1e6


def _cpu_seconds(pid: int) -> float:
    """utime + stime of a process from /proc, in s."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def role_publish(args: argparse.Namespace) -> None:
    """Publish the simulated run at 1 kHz once both nodes subscribe, then record /diagnostics
    of both nodes for 2 s and write them to ``args.out``."""
    from diagnostic_msgs.msg import DiagnosticArray
    import rclpy
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.qos import sensor_qos

    run = _run(args.live)
    rclpy.init()
    node = rclpy.create_node('bench_uncertainty_publisher')
    pub = node.create_publisher(Imu, 'imu/data', sensor_qos())
    diag: dict[str, str] = {}

    def on_diag(msg: DiagnosticArray) -> None:
        diag.update({f'{s.name}/{kv.key}': kv.value for s in msg.status for kv in s.values})

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    deadline = time.monotonic() + 60.0
    while pub.get_subscription_count() < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    msg = Imu()
    msg.header.frame_id = 'imu_link'
    msg.linear_acceleration_covariance[0] = -1.0
    Path(args.out, 'start').write_text('')
    t0, offset = time.monotonic_ns(), 1_000_000_000_000 - int(run.stamps_ns[0])
    for k, (stamp, acc) in enumerate(zip(run.stamps_ns.tolist(), run.accel[:, 2].tolist(),
                                         strict=True)):
        delay = t0 + k * 1_000_000 - time.monotonic_ns()
        if delay > 0:
            time.sleep(delay * 1e-9)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp + offset, 1_000_000_000)
        msg.linear_acceleration.z = acc
        pub.publish(msg)
    Path(args.out, 'end').write_text('')
    end = time.monotonic() + 2.5
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    Path(args.out, 'diagnostics.json').write_text(json.dumps(diag))
    node.destroy_node()
    rclpy.try_shutdown()


def live(seconds: float) -> None:
    """Table 2: both nodes as processes at 1 kHz."""
    domain, _held = reserve_domain()
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(domain))
    params = ['-p', f'speed_mps:={SPEED_MPS}', '-p', 'use_odom:=false']
    with tempfile.TemporaryDirectory(prefix='bench_uncertainty_') as tmp:
        nodes = {name: subprocess.Popen([sys.executable, '-m', f'railgsa_ros.nodes.{name}',
                                         '--ros-args', *params], env=env)
                 for name in ('irregularity_node', 'uncertainty_node')}
        publisher = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), 'publish',
                                      '--live', str(seconds), '--out', tmp], env=env)
        marks = [Path(tmp, 'start'), Path(tmp, 'end')]
        cpu, wall = {}, {}
        for i, mark in enumerate(marks):
            while not mark.exists() and publisher.poll() is None:
                time.sleep(0.01)
            wall[i] = time.monotonic()
            cpu[i] = {n: _cpu_seconds(p.pid) for n, p in nodes.items()}
        publisher.wait(timeout=60)
        diag = json.loads(Path(tmp, 'diagnostics.json').read_text())
        peaks = {n: _peak_mb(p.pid) for n, p in nodes.items()}
        codes = {}
        for name, proc in nodes.items():
            proc.send_signal(signal.SIGINT)
            with contextlib.suppress(subprocess.TimeoutExpired):
                codes[name] = proc.wait(timeout=20)
            if name not in codes:
                proc.kill()
                codes[name] = 'killed'
    span = wall[1] - wall[0]
    print(f'\n2. Live: {seconds:g} s of IMU at 1 kHz, both nodes as processes, CPU from /proc '
          f'over {span:.1f} s')
    print(f'{"":<20}{"core fraction":>15}{"ratio":>8}{"peak MB":>9}{"received":>10}'
          f'{"published":>11}{"exit":>6}')
    base = cpu[1]['irregularity_node'] - cpu[0]['irregularity_node']
    for name in nodes:
        used = cpu[1][name] - cpu[0][name]
        received = diag.get(f'{name}: imu input/received', '?')
        published = diag.get(f'{name}: inversion/published',
                             diag.get(f'{name}: uncertainty/published', '?'))
        print(f'{name:<20}{used / span:>15.3f}{used / base:>8.1f}{peaks[name]:>9.0f}'
              f'{received:>10}{published:>11}{codes[name]!s:>6}')
    own = diag.get('uncertainty_node: uncertainty/cpu_fraction_of_one_core', '?')
    window = diag.get('uncertainty_node: uncertainty/window_compute_max_ms', '?')
    fraction = (cpu[1]['uncertainty_node'] - cpu[0]['uncertainty_node']) / span
    print(f'uncertainty_node /diagnostics: cpu_fraction_of_one_core {own} (last period), '
          f'window_compute_max_ms {window}; target <= {TARGET}: '
          f'{"PASS" if fraction <= TARGET else "FAIL"}')


# ----------------------------------------------------------------------------- accuracy
def accuracy(samples: int) -> None:
    """Table 3: band vs brute-force Monte Carlo through the same inverse."""
    from railgsa_ros.inverse.config import InversionConfig
    from railgsa_ros.inverse.pipeline import InversionPipeline
    from railgsa_ros.scenario import run_scenario
    from railgsa_ros.uncertainty import UncertaintyConfig, offline_bands
    from railgsa_ros.uncertainty.parameters import table3
    from railgsa_ros.vehicle import PARAM_NAMES, VehicleParams

    run = run_scenario('paper', 10.0, 8.0, 1000.0, 'ideal', 0)
    inversion = InversionConfig(method='feedback', band='none')
    dists = table3()
    xi = np.random.default_rng(11).standard_normal((samples, len(dists)))
    theta = np.tile(VehicleParams().as_array(), (samples, 1))
    theta[:, [PARAM_NAMES.index(n) for n in dists]] = np.stack(
        [d.from_xi(xi[:, i]) for i, d in enumerate(dists.values())], axis=1)
    start = time.process_time()
    pipe = InversionPipeline(inversion, theta)
    u = np.concatenate([pipe.push(run.stamps_ns, run.accel[:, 2], run.speed_mps).u_m,
                        pipe.flush().u_m], axis=1)
    cpu_mc = time.process_time() - start
    mean, (lower, upper) = u.mean(axis=0), np.quantile(u, [0.025, 0.975], axis=0)
    scale = np.abs(run.truth_u_m).max()
    width = np.max(upper - lower)
    print(f'\n3. Accuracy against {samples} brute-force runs of the inverse ({cpu_mc:.1f} CPU s), '
          f'paper profile 10 m/s 8 s, paper mode; scale = max |u| = {scale * 1e3:.2f} mm, '
          f'widest band {width * 1e3:.3f} mm')
    print(f'{"band":<22}{"points":>7}{"CPU s":>7}{"mean err":>10}{"lower err":>11}'
          f'{"upper err":>11}   (max over samples, % of scale)')
    for rule, order, size, germ_samples in (('pem5', 2, 0, 1024), ('pem5', 2, 0, 16384),
                                            ('lstsq', 2, 40, 1024), ('gauss', 3, 0, 1024)):
        config = UncertaintyConfig(inversion=inversion, rule=rule, order=order, rule_size=size,
                                   germ_samples=germ_samples)
        start = time.process_time()
        band = offline_bands(run.stamps_ns, run.accel[:, 2], run.speed_mps, config=config)
        cpu = time.process_time() - start
        errs = [100 * np.max(np.abs(a - b)) / scale for a, b in
                ((band.mean_m, mean), (band.lower_m, lower), (band.upper_m, upper))]
        points = {'pem5': 19, 'gauss': (order + 1) ** len(dists)}.get(rule, size)
        print(f'{f"{rule} p={order} S={germ_samples}":<22}{points:>7}{cpu:>7.2f}{errs[0]:>10.2f}'
              f'{errs[1]:>11.2f}{errs[2]:>11.2f}')
    se = 100 * np.max(u.std(axis=0)) / np.sqrt(samples) / scale
    print(f'Monte Carlo standard error of the mean: {se:.2f} % of scale')


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('role', nargs='?', default='drive', choices=['drive', 'publish'])
    parser.add_argument('--duration', type=float, default=60.0, help='in-core run, s')
    parser.add_argument('--live', type=float, default=30.0, help='live run, s (0: skip)')
    parser.add_argument('--mc', type=int, default=2000, help='brute-force runs (0: skip)')
    parser.add_argument('--out', help='(internal) directory for the publisher\'s results')
    args = parser.parse_args(argv)
    if args.role == 'publish':
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        role_publish(args)
        return 0
    in_core(args.duration)
    if args.live > 0:
        live(args.live)
    if args.mc > 0:
        accuracy(args.mc)
    return 0


if __name__ == '__main__':
    sys.exit(main())
