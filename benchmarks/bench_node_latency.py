"""Latency and loss of irregularity_node at 1 kHz across processes, against a bare relay.

Five processes on one machine, all with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a private
ROS_DOMAIN_ID: an IMU publisher (1 kHz, nominal stamps t0 + k ms, simulated car-body
acceleration), ``irregularity_node``, a relay node (subscribe imu/data with the node's QoS,
republish on relay/imu), and a receiver subscribed to both outputs. Publish and receive times are
CLOCK_MONOTONIC, shared by the processes.

Latency definitions (ms):
- relay: receive time of relay/imu carrying stamp k minus publish time of IMU sample k;
- node: the band filter has a fixed delay of D samples, so the output for sample k is computed
  when sample k + D arrives. Processing latency = receive time of track/irregularity carrying
  stamp k minus publish time of IMU sample k + D. D is read from the node's /diagnostics.
Lost = IMU samples without their output (the node's last D samples are excluded: they wait for
input that never comes).

Usage: python benchmarks/bench_node_latency.py [--duration 60] [--rate 1000]
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

import numpy as np

from railgsa_ros.system import reserve_domain

SPEED_MPS = 20.0
IMU_TOPIC, RELAY_TOPIC, OUT_TOPIC = 'imu/data', 'relay/imu', 'track/irregularity'


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


def _spin_until_signal(node) -> None:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    with contextlib.suppress(KeyboardInterrupt, ExternalShutdownException):
        rclpy.spin(node)


def role_publish(args: argparse.Namespace) -> None:
    """Publish ``rate`` Imu messages a second for ``duration`` s once two readers matched."""
    import rclpy
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.qos import sensor_qos

    n = int(args.duration * args.rate)
    acc = _acceleration(n, args.rate)
    rclpy.init()
    node = rclpy.create_node('bench_imu_publisher')
    pub = node.create_publisher(Imu, IMU_TOPIC, sensor_qos())
    deadline = time.monotonic() + 30.0
    while pub.get_subscription_count() < args.readers and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(2.0)  # let the outputs of the relay and the node match the receiver
    msg = Imu()
    msg.header.frame_id = 'imu_link'
    msg.orientation_covariance[0] = -1.0
    msg.linear_acceleration_covariance[0] = msg.linear_acceleration_covariance[4] = \
        msg.linear_acceleration_covariance[8] = 1e-4
    period_ns = round(1e9 / args.rate)
    t0_stamp = 1_000_000_000_000
    sent = np.zeros(n, np.int64)
    start = time.monotonic_ns()
    for k in range(n):
        delay = start + k * period_ns - time.monotonic_ns()
        if delay > 0:
            time.sleep(delay * 1e-9)
        stamp = t0_stamp + k * period_ns
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        msg.linear_acceleration.z = float(acc[k])
        sent[k] = time.monotonic_ns()
        pub.publish(msg)
    time.sleep(1.0)
    np.savez(Path(args.out) / 'publish.npz', stamps=t0_stamp + np.arange(n) * period_ns,
             sent=sent)
    node.destroy_node()
    rclpy.try_shutdown()


def role_relay(args: argparse.Namespace) -> None:
    """The baseline: subscribe imu/data with the node's QoS and republish each message."""
    import rclpy
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.qos import output_qos, sensor_qos

    rclpy.init()
    node = rclpy.create_node('bench_relay')
    pub = node.create_publisher(Imu, RELAY_TOPIC, output_qos())
    node.create_subscription(Imu, IMU_TOPIC, pub.publish, sensor_qos())
    _spin_until_signal(node)
    rclpy.try_shutdown()


def role_receive(args: argparse.Namespace) -> None:
    """Record (stamp, receive time) of both outputs and the node's band delay until SIGINT."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PointStamped
    import rclpy
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.qos import output_qos

    log: dict[str, list[tuple[int, int]]] = {'relay': [], 'node': []}
    diag: dict[str, str] = {}

    def record(key: str):
        def callback(msg) -> None:
            now = time.monotonic_ns()
            log[key].append((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                             now))
        return callback

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith('irregularity_node'):
                diag.update({f'{status.name}/{kv.key}': kv.value for kv in status.values})

    rclpy.init()
    node = rclpy.create_node('bench_receiver')
    node.create_subscription(Imu, RELAY_TOPIC, record('relay'), output_qos())
    node.create_subscription(PointStamped, OUT_TOPIC, record('node'), output_qos())
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    _spin_until_signal(node)
    out = Path(args.out)
    np.savez(out / 'receive.npz', **{k: np.array(v, np.int64).reshape(-1, 2)
                                     for k, v in log.items()})
    (out / 'diagnostics.json').write_text(json.dumps(diag, indent=1))
    rclpy.try_shutdown()


def _cpu_seconds(pid: int) -> float:
    """utime + stime of a process from /proc, in s."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _latencies(stamps: np.ndarray, sent: np.ndarray, received: np.ndarray,
               delay: int) -> tuple[np.ndarray, int]:
    """Latency (ms) per received output and the number of inputs 0..N-1-delay not received."""
    index = {int(s): i for i, s in enumerate(stamps)}
    got = np.zeros(len(stamps), bool)
    lat = []
    for stamp, t_rx in received:
        i = index.get(int(stamp))
        if i is None or got[i] or i + delay >= len(stamps):
            continue
        got[i] = True
        lat.append((t_rx - sent[i + delay]) * 1e-6)
    return np.array(lat), int(np.count_nonzero(~got[:len(stamps) - delay]))


def _band_delay(diag: dict[str, str]) -> int | None:
    """The node's band delay D (samples) from its /diagnostics, None if it never reported."""
    for key, value in diag.items():
        if key.endswith('/band_delay_samples'):
            return int(value)
    return None


def drive(args: argparse.Namespace) -> int:
    """Start the processes, run, stop them with SIGINT and print the table."""
    domain, _held = reserve_domain()
    env = _ros_env(domain)
    me = [sys.executable, str(Path(__file__).resolve())]
    with tempfile.TemporaryDirectory(prefix='bench_node_latency_') as tmp:
        common = ['--out', tmp, '--duration', str(args.duration), '--rate', str(args.rate)]
        receiver = subprocess.Popen([*me, 'receive', *common], env=env)
        node = subprocess.Popen([sys.executable, '-m', 'railgsa_ros.nodes.irregularity_node',
                                 '--ros-args', '-p', f'speed_mps:={SPEED_MPS}',
                                 '-p', 'use_odom:=false'], env=env)
        relay = subprocess.Popen([*me, 'relay', *common], env=env)
        time.sleep(1.0)
        cpu0 = {'node': _cpu_seconds(node.pid), 'relay': _cpu_seconds(relay.pid)}
        wall0 = time.monotonic()
        publisher = subprocess.run([*me, 'publish', *common, '--readers', '2'], env=env,
                                   check=False)
        wall = time.monotonic() - wall0
        cpu = {'node': _cpu_seconds(node.pid) - cpu0['node'],
               'relay': _cpu_seconds(relay.pid) - cpu0['relay']}
        codes = {}
        for name, proc in (('node', node), ('relay', relay), ('receiver', receiver)):
            proc.send_signal(signal.SIGINT)
            try:
                codes[name] = proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                codes[name] = 'killed'
        if publisher.returncode != 0:
            print(f'publisher failed with exit code {publisher.returncode}', file=sys.stderr)
            return 1
        pub = np.load(Path(tmp) / 'publish.npz')
        rec = np.load(Path(tmp) / 'receive.npz')
        diag = json.loads((Path(tmp) / 'diagnostics.json').read_text())
    delay = _band_delay(diag)
    if delay is None:
        print(f'irregularity_node published no /diagnostics (exit code {codes["node"]})',
              file=sys.stderr)
        return 1
    rows = {}
    for name, d in (('relay', 0), ('node', delay)):
        lat, lost = _latencies(pub['stamps'], pub['sent'], rec[name], d)
        rows[name] = (lat, lost)
    print(f'\n{len(pub["stamps"])} IMU samples at {args.rate:g} Hz over {args.duration:g} s; '
          f'band delay D = {delay} samples ({delay / args.rate * 1e3:g} ms, not counted)')
    print(f'{"process":<18}{"received":>9}{"lost":>6}{"p50 ms":>9}{"p99 ms":>9}{"max ms":>9}'
          f'{"CPU %":>8}{"exit":>6}')
    for name, label in (('relay', 'relay (baseline)'), ('node', 'irregularity_node')):
        lat, lost = rows[name]
        p50, p99 = np.percentile(lat, [50, 99]) if len(lat) else (np.nan, np.nan)
        top = lat.max() if len(lat) else np.nan
        print(f'{label:<18}{len(lat):>9}{lost:>6}{p50:>9.3f}{p99:>9.3f}{top:>9.3f}'
              f'{100 * cpu[name] / wall:>8.1f}{codes[name]!s:>6}')
    p99_relay = np.percentile(rows['relay'][0], 99)
    p99_node = np.percentile(rows['node'][0], 99)
    ratio = p99_node / p99_relay
    ok = ratio <= 1.5 and rows['node'][1] == 0
    print(f'p99 ratio node/relay = {ratio:.2f} (target <= 1.5); node lost {rows["node"][1]} '
          f'(target 0): {"PASS" if ok else "FAIL"}')
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('role', nargs='?', default='drive',
                        choices=['drive', 'publish', 'relay', 'receive'])
    parser.add_argument('--duration', type=float, default=60.0,
                        help='s of IMU data; more than the band delay (about 7 s) so that the '
                        'node emits outputs')
    parser.add_argument('--rate', type=float, default=1000.0, help='IMU rate, Hz')
    parser.add_argument('--out', help='(internal) directory for the roles\' results')
    parser.add_argument('--readers', type=int, default=2, help='(internal) imu/data readers')
    args = parser.parse_args(argv)
    if args.role == 'drive' and args.duration <= 10.0:
        parser.error('--duration must exceed 10 s: the node emits nothing during its band delay')
    if args.role == 'drive':
        return drive(args)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    {'publish': role_publish, 'relay': role_relay, 'receive': role_receive}[args.role](args)
    return 0


if __name__ == '__main__':
    sys.exit(main())
