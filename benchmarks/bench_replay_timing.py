"""Replay timing fidelity: a 1 kHz Imu bag played by ``railgsa replay`` into another process.

The subscriber (this process, EventsExecutor, raw, BEST_EFFORT depth 5000) notes the monotonic
receive time of every message. Timing error of message i = receive_i - ideal_i with ideal_i =
A + (t_i - t_0) / rate and A the smallest receive_i - (t_i - t_0) / rate: lateness against the
recorded stamps after removing the best-case transport latency. Baseline of the same run: a
naive player (same bag, same raw publishing, ``time.sleep(t_i - t_(i-1))`` between messages, so
drift accumulates).

    python benchmarks/bench_replay_timing.py [--seconds 10]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np

from railgsa_ros.bag.messages import typestore
from railgsa_ros.qos import record_qos
from railgsa_ros.system import isolated_domain

NS = 1_000_000_000
T0 = 1_700_000_000 * NS


def write_bag(path: Path, seconds: float) -> np.ndarray:
    """A 1 kHz Imu bag (rosbags, MCAP); returns the stamps (ns)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = typestore()
    imu = ts.types['sensor_msgs/msg/Imu']
    vec, quat = ts.types['geometry_msgs/msg/Vector3'], ts.types['geometry_msgs/msg/Quaternion']
    header, stamp = ts.types['std_msgs/msg/Header'], ts.types['builtin_interfaces/msg/Time']
    stamps = T0 + np.arange(round(seconds * 1000), dtype=np.int64) * 1_000_000
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/imu/data', imu.__msgtype__, typestore=ts,
                                     offered_qos_profiles=[record_qos(False, 5)])
        for i, t in enumerate(stamps.tolist()):
            msg = imu(header(stamp(*divmod(t, NS)), 'imu_link'), quat(0.0, 0.0, 0.0, 1.0),
                      np.zeros(9), vec(0.0, 0.0, 0.0), np.zeros(9), vec(0.0, 0.0, 9.81 + i),
                      np.zeros(9))
            writer.write(conn, t, ts.serialize_cdr(msg, imu.__msgtype__))
    return stamps


def naive_player(bag: str, rate: float) -> None:
    """Baseline: publish the bag with relative sleeps between messages."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    from railgsa_ros.playback.source import BagSource

    rclpy.init()
    node = rclpy.create_node('naive_player')
    pub = node.create_publisher(Imu, '/imu/data', QoSProfile(
        depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
    while pub.get_subscription_count() == 0:
        time.sleep(0.01)
    with BagSource(bag) as source:
        messages = list(source.messages(['/imu/data']))
    previous = messages[0][1]
    for _, stamp, raw in messages:
        time.sleep((stamp - previous) / NS / rate)
        previous = stamp
        pub.publish(raw)
    node.destroy_node()
    rclpy.shutdown()


def measure(command: list[str], stamps: np.ndarray, rate: float) -> dict[str, float]:
    """Run ``command`` (a player) and receive its messages; timing error statistics in ms."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('bench_sink', context=context)
    received: list[tuple[int, int]] = []

    def on_message(data: bytes) -> None:
        sec, nsec = struct.unpack_from('<iI', data, 4)
        received.append((time.monotonic_ns(), sec * NS + nsec))

    node.create_subscription(Imu, '/imu/data', on_message, QoSProfile(
        depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True)
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    player = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    expected_end = time.monotonic() + 60 + (stamps[-1] - stamps[0]) / NS / rate
    while player.poll() is None and time.monotonic() < expected_end:
        executor.spin_once(timeout_sec=0.05)
    settle = time.monotonic() + 1.0
    while time.monotonic() < settle:
        executor.spin_once(timeout_sec=0.05)
    player.kill()
    node.destroy_node()
    context.try_shutdown()
    recv = np.array([r for r, _ in received], dtype=np.int64)
    got = np.array([s for _, s in received], dtype=np.int64)
    ideal = (got - stamps[0]) / rate
    error = (recv - ideal) - (recv - ideal).min()
    return {'received': got.size, 'lost': stamps.size - np.unique(got).size,
            'reordered': int(np.sum(np.diff(got) < 0)),
            'p50': np.percentile(error, 50) / 1e6, 'p99': np.percentile(error, 99) / 1e6,
            'max': error.max() / 1e6}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=10.0, help='bag length (s)')
    parser.add_argument('--naive', nargs=2, metavar=('BAG', 'RATE'), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.naive:
        naive_player(args.naive[0], float(args.naive[1]))
        return
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    with isolated_domain(), tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / 'imu'
        stamps = write_bag(bag, args.seconds)
        print(f'1 kHz Imu bag, {stamps.size} messages, ROS_DOMAIN_ID '
              f'{os.environ["ROS_DOMAIN_ID"]}, subscriber in this process')
        print(f'{"player":<18} {"rate":>4} {"recv":>6} {"lost":>5} {"reord":>5} '
              f'{"p50 ms":>8} {"p99 ms":>8} {"max ms":>8} {"p99/baseline":>12}')
        for rate in (1.0, 5.0):
            runs = {
                'railgsa replay': [sys.executable, '-m', 'railgsa_ros.cli.main', 'replay',
                                   str(bag), '--rate', str(rate), '--wait-for-subscribers',
                                   '30'],
                'naive (baseline)': [sys.executable, __file__, '--naive', str(bag), str(rate)],
            }
            results = {name: measure(cmd, stamps, rate) for name, cmd in runs.items()}
            base = results['naive (baseline)']['p99']
            for name, r in results.items():
                print(f'{name:<18} {rate:>4g} {r["received"]:>6} {r["lost"]:>5} '
                      f'{r["reordered"]:>5} {r["p50"]:>8.3f} {r["p99"]:>8.3f} '
                      f'{r["max"]:>8.3f} {r["p99"] / base:>12.3f}')


if __name__ == '__main__':
    main()
