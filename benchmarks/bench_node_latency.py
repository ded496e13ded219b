"""CPU, latency and loss of irregularity_node and uncertainty_node against a bare relay.

One run measures, at each input rate (default 1 and 4 kHz), ``irregularity_node`` and then
``uncertainty_node``, each side by side with the baseline: a bare typed rclpy relay (subscribe
imu/data with the nodes' QoS, republish every message on relay/imu) fed by the same IMU
publisher at the same time, so that node and relay see the same load of the shared machine.
Every process sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a ROS_DOMAIN_ID reserved for the
run.

- The publisher sends pre-serialized Imu messages (nominal stamps t0 + k / rate, simulated
  car-body acceleration at 20 m/s) once both readers matched; the receiver reads both outputs
  with raw subscriptions in a thread of its own (a Python executor could not take 2 x 4 kHz).
  Publish and receive times are CLOCK_MONOTONIC, shared by the processes.
- CPU: utime + stime of each measured process (/proc/<pid>/stat) over the publishing window,
  in % of one core.
- Latency (ms): relay: receive time of relay/imu stamped k minus publish time of sample k.
  Node: its band filter has a fixed delay of D samples (read from its /diagnostics) and its
  stamp re-ordering holds each sample until one W = reorder_window_s x rate samples newer has
  arrived (the default 50 ms: W = 50 at 1 kHz), both delays by design, so output k is computed
  when sample k + D + W arrives: receive time of output k minus publish time of sample
  k + D + W. uncertainty_node works in batches every ``process_period_s`` (50 ms), so its
  latency includes up to one period by design.
- Lost: samples 0..N-1-D without their output (the last D wait for input that never comes).
  Every subject's reader and writer histories hold one second (``imu_qos_depth`` and
  ``output_qos_depth`` = rate).

Prints a table with the node/relay ratios and the issue's targets: irregularity_node CPU <=
relay, uncertainty_node CPU <= 1.5x relay at 1 kHz, p99 <= relay's, no loss at 4 kHz.

``--core delay-line`` measures the shell's floor instead: irregularity_node with its core (the
input policy and the filters) replaced by a delay line that returns each sample W samples
later, so that everything else (intake thread, decoding, lock, pacing, encoding, publishing,
diagnostics) runs as in the node; the targets are not checked then.

Usage: python benchmarks/bench_node_latency.py [--duration 20] [--rates 1000 4000]
       [--nodes irregularity_node] [--process-period 0.005] [--core delay-line]
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
import threading
import time

import numpy as np

from railgsa_ros.input.options import REORDER_WINDOW_S
from railgsa_ros.system import reserve_domain

SPEED_MPS = 20.0
IMU_TOPIC, RELAY_TOPIC = 'imu/data', 'relay/imu'
#: subject -> (output topic, its message type, diagnostics task with band_delay_samples)
SUBJECTS = {'relay': (RELAY_TOPIC, 'sensor_msgs/msg/Imu', None),
            'irregularity_node': ('track/irregularity', 'geometry_msgs/msg/PointStamped',
                                  'irregularity_node: inversion'),
            'uncertainty_node': ('track/irregularity_band', 'geometry_msgs/msg/Vector3Stamped',
                                 'uncertainty_node: uncertainty')}
T0_STAMP_NS = 1_000_000_000_000
LEAD_S = 2.0  #: after the reader matched: time for the subject's output to match the receiver


def history_depth(rate_hz: float) -> int:
    """Every subject's imu/data reader and output writer history: one second of samples (the
    nodes' rule, docs/nodes.md: 1000 at 1 kHz, so 4000 at 4 kHz)."""
    return max(1000, round(rate_hz))


def _ros_env(domain_id: int) -> dict[str, str]:
    return dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED='1')


def _acceleration(n: int, rate_hz: float) -> np.ndarray:
    """Car-body specific force (m/s^2, gravity included) over a 1 mm multi-sine track."""
    from railgsa_ros.simulate import simulate
    from railgsa_ros.vehicle import VehicleParams

    x = np.arange(n) * SPEED_MPS / rate_hz
    u = sum(1e-3 * np.sin(2 * np.pi * x / wl + ph) for wl, ph in ((5.0, 0.3), (11.0, 1.0),
                                                                   (23.0, 2.0)))
    return simulate(u, 1.0 / rate_hz, VehicleParams())[0] + 9.80665


def role_shell(ros_args: list[str]) -> int:
    """irregularity_node with a delay line for its core (``--core delay-line``): each IMU
    sample comes out, as an output of zeros at the configured speed, once W = the default
    re-order window x rate_hz newer samples arrived (the policy's stamp hold; its band delay
    is 0: the filters are never built)."""
    from collections import deque

    from railgsa_ros.inverse.pipeline import Output
    from railgsa_ros.nodes.imu_conversion import ImuBatch
    from railgsa_ros.nodes.irregularity_node import IrregularityNode
    from railgsa_ros.nodes.lifecycle import run

    class DelayLineNode(IrregularityNode):
        def core_imu(self, batch: ImuBatch | None) -> Output | None:
            if batch is None:
                return None
            line = self.__dict__.setdefault('_line', deque())
            line.extend(batch.stamps_ns.tolist())
            count = len(line) - round(REORDER_WINDOW_S * self._values['rate_hz'])
            stamps = np.array([line.popleft() for _ in range(max(0, count))], np.int64)
            zeros = np.zeros(stamps.size)
            return Output(stamps, zeros, zeros, np.zeros(stamps.size, np.uint8),
                          zeros + self._values['speed_mps'])

    return run(DelayLineNode, ros_args)


def _spin_until_signal(node: object) -> None:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
        rclpy.spin(node)


def role_publish(args: argparse.Namespace) -> None:
    """Publish ``rate`` serialized Imu messages a second for ``duration`` s once the subject
    subscribed; save the publish times."""
    import rclpy
    from sensor_msgs.msg import Imu

    from railgsa_ros.bag.cdr import encode
    from railgsa_ros.bag.messages import IMU, imu_values
    from railgsa_ros.nodes.qos import sensor_qos

    n = int(args.duration * args.rate)
    period_ns = round(1e9 / args.rate)
    stamps = T0_STAMP_NS + np.arange(n) * period_ns
    accel = np.zeros((n, 3))
    accel[:, 2] = _acceleration(n, args.rate)
    raws = encode(IMU, stamps, ['imu_link'], imu_values(accel, 1e-4))
    rclpy.init()
    node = rclpy.create_node('bench_imu_publisher')
    pub = node.create_publisher(Imu, IMU_TOPIC, sensor_qos())
    deadline = time.monotonic() + 60.0
    while pub.get_subscription_count() < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(LEAD_S)
    Path(args.out, 'started').touch()
    sent = np.zeros(n, np.int64)
    start = time.monotonic_ns()
    k = 0
    while k < n:
        due = min(n, (time.monotonic_ns() - start) // period_ns + 1)
        for i in range(k, due):
            sent[i] = time.monotonic_ns()
            pub.publish(raws[i])
        k = due
        time.sleep(max(0.0, (start + k * period_ns - time.monotonic_ns()) * 1e-9))
    time.sleep(1.0)
    np.savez(Path(args.out) / 'publish.npz', stamps=stamps, sent=sent)
    node.destroy_node()
    rclpy.try_shutdown()


def role_relay(args: argparse.Namespace) -> None:
    """The baseline: subscribe imu/data with the nodes' QoS and republish each message."""
    import rclpy
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.qos import output_qos, sensor_qos

    rclpy.init()
    node = rclpy.create_node('bench_relay')
    depth = history_depth(args.rate)
    pub = node.create_publisher(Imu, RELAY_TOPIC, output_qos(depth))
    node.create_subscription(Imu, IMU_TOPIC, pub.publish, sensor_qos(depth))
    _spin_until_signal(node)
    rclpy.try_shutdown()


def role_receive(args: argparse.Namespace) -> None:
    """Record (stamp, receive time) of the relay's and the node's output and the node's
    /diagnostics until SIGINT."""
    from diagnostic_msgs.msg import DiagnosticArray
    import rclpy
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    from railgsa_ros.bag.cdr import decode
    from railgsa_ros.bag.messages import LAYOUTS
    from railgsa_ros.nodes.imu_input import RawSubscription
    from railgsa_ros.nodes.qos import output_qos

    rclpy.init()
    node = rclpy.create_node('bench_receiver')
    subs, log = {}, {}
    for subject in ('relay', args.subject):
        topic, msgtype, _ = SUBJECTS[subject]
        package, _, name = msgtype.split('/')
        msg_cls = getattr(__import__(f'{package}.msg', fromlist=[name]), name)
        subs[subject] = RawSubscription(node, msg_cls, topic, output_qos(100_000))
        log[subject] = ([], [])
    diag: dict[str, str] = {}
    stop = threading.Event()

    def read() -> None:
        wait_set = _rclpy.WaitSet(len(subs), 0, 0, 0, 0, 0, node.context.handle)
        while not stop.is_set():
            wait_set.clear_entities()
            for sub in subs.values():
                wait_set.add_subscription(sub.handle)
            wait_set.wait(100_000_000)
            now = time.monotonic_ns()
            for subject, sub in subs.items():
                got = sub.take(100_000)
                log[subject][0].extend(got)
                log[subject][1].extend([now] * len(got))

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            diag.update({f'{status.name}/{kv.key}': kv.value for kv in status.values})

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    _spin_until_signal(node)
    stop.set()
    reader.join(5.0)
    out = Path(args.out)
    for subject, (raws, times) in log.items():
        stamps = decode(LAYOUTS[SUBJECTS[subject][1]], raws).stamps_ns
        np.savez(out / f'receive_{subject}.npz', stamps=stamps, times=np.array(times, np.int64))
    (out / 'diagnostics.json').write_text(json.dumps(diag, indent=1))
    for sub in subs.values():
        sub.destroy()
    rclpy.try_shutdown()


def _cpu_seconds(pid: int) -> float:
    """utime + stime of a process from /proc, in s."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _latencies(pub: dict, rec: dict, delay: int) -> tuple[np.ndarray, int]:
    """Latency (ms) per received output and the number of inputs 0..N-1-delay not received."""
    stamps, sent = pub['stamps'], pub['sent']
    n = stamps.size - delay
    index = np.searchsorted(stamps, rec['stamps'])
    ok = (index < n) & (stamps[np.minimum(index, stamps.size - 1)] == rec['stamps'])
    index, times = index[ok], rec['times'][ok]
    first = np.unique(index, return_index=True)[1]  # each output once
    lat = (times[first] - sent[index[first] + delay]) * 1e-6
    return lat, n - first.size


def _subject_command(subject: str, me: list[str], common: list[str], rate: float,
                     period_s: float | None, core: str) -> list[str]:
    if subject == 'relay':
        return [*me, 'relay', *common]
    period = [] if period_s is None or subject != 'irregularity_node' else \
        ['-p', f'process_period_s:={period_s!r}']
    node = [*me, 'shell'] if core == 'delay-line' else \
        [sys.executable, '-m', f'railgsa_ros.nodes.{subject}']
    return [*node, '--ros-args',
            '-p', f'speed_mps:={SPEED_MPS}', '-p', 'use_odom:=false', '-p', f'rate_hz:={rate:g}',
            '-p', f'imu_qos_depth:={history_depth(rate)}',
            '-p', f'output_qos_depth:={history_depth(rate)}', *period]


def _summary(lat: np.ndarray, lost: int, cpu: float, delay: int, code: object) -> dict:
    p50, p99 = np.percentile(lat, [50, 99]) if lat.size else (np.nan, np.nan)
    return {'cpu': cpu, 'p50': p50, 'p99': p99, 'max': lat.max() if lat.size else np.nan,
            'received': lat.size, 'lost': lost, 'delay': delay, 'exit': code}


def measure(node: str, rate: float, duration: float, domain: int,
            period_s: float | None = None, core: str = 'inversion') -> dict[str, dict]:
    """One node side by side with the relay at one rate: per process CPU %, latencies, lost,
    band delay, exit code."""
    env = _ros_env(domain)
    me = [sys.executable, str(Path(__file__).resolve())]
    with tempfile.TemporaryDirectory(prefix='bench_node_latency_') as tmp:
        common = ['--out', tmp, '--duration', str(duration), '--rate', str(rate),
                  '--subject', node]
        receiver = subprocess.Popen([*me, 'receive', *common], env=env)
        procs = {s: subprocess.Popen(_subject_command(s, me, common, rate, period_s, core),
                                     env=env)
                 for s in ('relay', node)}
        publisher = subprocess.Popen([*me, 'publish', *common], env=env)
        while not Path(tmp, 'started').exists() and publisher.poll() is None:
            time.sleep(0.01)
        cpu0, wall0 = {s: _cpu_seconds(p.pid) for s, p in procs.items()}, time.monotonic()
        publisher.wait()
        wall = time.monotonic() - wall0 - 1.0  # the publisher's last second is idle
        cpu = {s: 100 * (_cpu_seconds(p.pid) - cpu0[s]) / wall for s, p in procs.items()}
        time.sleep(1.0)  # the last outputs arrive
        codes = {}
        for name, p in (*procs.items(), ('receiver', receiver)):
            p.send_signal(signal.SIGINT)
            try:
                codes[name] = p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                codes[name] = 'killed'
        if publisher.returncode != 0 or not Path(tmp, f'receive_{node}.npz').exists():
            raise SystemExit(f'{node} at {rate:g} Hz: publisher exit {publisher.returncode}, '
                             f'receiver {codes["receiver"]}')
        pub = dict(np.load(Path(tmp) / 'publish.npz'))
        rec = {s: dict(np.load(Path(tmp) / f'receive_{s}.npz')) for s in procs}
        diag = json.loads((Path(tmp) / 'diagnostics.json').read_text())
    delay = int(diag.get(f'{SUBJECTS[node][2]}/band_delay_samples', -1))
    if delay < 0:
        raise SystemExit(f'{node} published no /diagnostics (exit code {codes[node]})')
    hold = round(REORDER_WINDOW_S * rate)  # the nodes' default reorder_window_s, samples
    out = {}
    for subject, d in (('relay', 0), (node, delay + hold)):
        lat, lost = _latencies(pub, rec[subject], d)
        out[subject] = _summary(lat, lost, cpu[subject], d, codes[subject])
    return out


def report(rows: dict[tuple[float, str], dict], load: tuple[float, float],
           core: str = 'inversion') -> bool:
    """Print the table (each node against the relay of its own run) and the targets; whether
    every target was met (``core`` 'delay-line': the shell's floor, no targets)."""
    print(f'\nload average before / after: {load[0]:.1f} / {load[1]:.1f} (2 shared cores)')
    print('| rate Hz | process | CPU % of a core | p50 ms | p99 ms | max ms | lost | '
          'CPU / relay | p99 / relay |')
    print('|---|---|---|---|---|---|---|---|---|')
    for (rate, node), pair in rows.items():
        base = pair['relay']
        for subject, r in (('relay', base), (node, pair[node])):
            label = f'relay (beside {node})' if subject == 'relay' else \
                node if core == 'inversion' else f'{node} with a {core} core'
            print(f'| {rate:g} | {label} | {r["cpu"]:.1f} | {r["p50"]:.2f} | {r["p99"]:.2f} | '
                  f'{r["max"]:.1f} | {r["lost"]} | {r["cpu"] / base["cpu"]:.2f} | '
                  f'{r["p99"] / base["p99"]:.2f} |')
    if core != 'inversion':
        print(f'(the node\'s core replaced by a {core}: the shell\'s floor, no targets)')
        return True
    checks = []
    rates = sorted({rate for rate, _ in rows})
    nodes = {node for _, node in rows}
    for node, cpu_ratio in (('irregularity_node', 1.0), ('uncertainty_node', 1.5)):
        if node in nodes:
            pair = rows[(rates[0], node)]
            checks.append((f'{node} CPU <= {cpu_ratio:g} x relay at {rates[0]:g} Hz',
                           pair[node]['cpu'] <= cpu_ratio * pair['relay']['cpu']))
    for rate in rates if 'irregularity_node' in nodes else ():
        pair = rows[(rate, 'irregularity_node')]
        checks.append((f'irregularity_node p99 <= relay p99 at {rate:g} Hz',
                       pair['irregularity_node']['p99'] <= pair['relay']['p99']))
    for node in sorted(nodes):
        checks.append((f'{node} no loss at {rates[-1]:g} Hz', rows[(rates[-1], node)][node][
            'lost'] == 0))
    for text, ok in checks:
        print(f'{"PASS" if ok else "FAIL"}  {text}')
    return all(ok for _, ok in checks)


def drive(args: argparse.Namespace) -> int:
    """Both nodes (each beside the relay) at every rate, then the table."""
    domain, _held = reserve_domain()
    load0 = os.getloadavg()[0]
    rows = {}
    for rate in args.rates:
        for node in args.nodes:
            rows[(rate, node)] = pair = measure(node, rate, args.duration, domain,
                                                args.process_period, args.core)
            for subject, r in pair.items():
                print(f'{subject} at {rate:g} Hz: CPU {r["cpu"]:.1f} %, p50 {r["p50"]:.2f} ms, '
                      f'p99 {r["p99"]:.2f} ms, lost {r["lost"]}, D + W {r["delay"]}, '
                      f'exit {r["exit"]}', flush=True)
    report(rows, (load0, os.getloadavg()[0]), args.core)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('role', nargs='?', default='drive',
                        choices=['drive', 'publish', 'relay', 'receive'])
    parser.add_argument('--duration', type=float, default=20.0,
                        help='s of IMU data per subject and rate; more than the band delay '
                        '(about 7 s) so that the nodes emit outputs')
    parser.add_argument('--rates', type=float, nargs='+', default=[1000.0, 4000.0],
                        help='IMU rates, Hz')
    parser.add_argument('--nodes', nargs='+', default=['irregularity_node', 'uncertainty_node'],
                        choices=['irregularity_node', 'uncertainty_node'],
                        help='the nodes measured (default: both)')
    parser.add_argument('--process-period', type=float,
                        help="irregularity_node's process_period_s (default: the node's, "
                        '2 ms: pairs at 1 kHz)')
    parser.add_argument('--core', choices=['inversion', 'delay-line'], default='inversion',
                        help="irregularity_node's core: the inversion (default), or a delay "
                        "line that returns each sample W later (the shell's floor)")
    parser.add_argument('--rate', type=float, default=1000.0, help='(internal) IMU rate, Hz')
    parser.add_argument('--out', help='(internal) directory for the roles\' results')
    parser.add_argument('--subject', choices=sorted(SUBJECTS), default='irregularity_node',
                        help='(internal) the node measured beside the relay')
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ['shell']:  # a node process: its arguments are ROS arguments
        return role_shell(argv)
    args = parser.parse_args(argv)
    if args.core != 'inversion' and 'uncertainty_node' in args.nodes:
        parser.error('--core delay-line replaces irregularity_node\'s core: add --nodes '
                     'irregularity_node')
    if args.role == 'drive' and args.duration <= 10.0:
        parser.error('--duration must exceed 10 s: the nodes emit nothing during their band '
                     'delay')
    if args.role == 'drive':
        return drive(args)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    {'publish': role_publish, 'relay': role_relay, 'receive': role_receive}[args.role](args)
    return 0


if __name__ == '__main__':
    sys.exit(main())
