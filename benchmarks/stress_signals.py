"""SIGINT/SIGTERM during a burst of IMU input: how many tries end with exit code 0.

Each try starts a node as its own process (``python -m railgsa_ros.nodes.<node>``), waits until
its imu/data subscription matched this process's publisher, publishes ``--messages`` Imu
messages as fast as rclpy allows (a burst far above 1 kHz) and, at a random moment of the burst,
sends SIGINT or SIGTERM (alternating). A try passes when the process exits 0 without a
traceback within ``--timeout`` s. Prints one line per failing try (its return code and the last
line of its stderr) and at the end ``exit 0: N of M``.

    python benchmarks/stress_signals.py [--tries 50] [--messages 60000]
        [--node irregularity_node|uncertainty_node|both]

Every process runs in a reserved ROS domain with localhost-only discovery.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import random
import signal
import sys
import tempfile
import threading
import time

from railgsa_ros.system import NODES_PACKAGE, NodeProcess, isolated_domain

REPO = Path(__file__).resolve().parents[1]
NODES = ('irregularity_node', 'uncertainty_node')
#: short band delay and no odometry: the nodes start fast and every sample is accepted
ROS_ARGS = ['-p', 'use_odom:=false', '-p', 'speed_mps:=40.0', '-p', 'min_design_speed_mps:=40.0']
T0_NS = 1_000_000_000


def burst(count: int) -> list:
    """``count`` Imu messages 1 ms apart (gravity plus a small sine on z, frame imu_link)."""
    from sensor_msgs.msg import Imu

    msgs = []
    for k in range(count):
        msg = Imu()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(T0_NS + k * 1_000_000,
                                                                1_000_000_000)
        msg.header.frame_id = 'imu_link'
        msg.linear_acceleration.z = 9.80665 + 0.01 * ((k % 50) - 25) / 25.0
        msg.linear_acceleration_covariance[0] = -1.0
        msgs.append(msg)
    return msgs


def one_try(node: str, sig: int, msgs: list, publisher, logdir: Path, timeout: float,
            rng: random.Random) -> tuple[int | None, str]:
    """Start ``node``, signal it during the burst; (return code or None if it hung, stderr)."""
    proc = NodeProcess(f'{NODES_PACKAGE}.{node}', ['--ros-args', *ROS_ARGS], logdir, cwd=REPO)
    deadline = time.monotonic() + 120.0
    while publisher.get_subscription_count() == 0 and proc.running():
        if time.monotonic() > deadline:
            break
        time.sleep(0.05)
    time.sleep(0.2)  # the node's subscription matched our writer too
    stop = threading.Event()

    def send() -> None:
        for msg in msgs:
            if stop.is_set():
                return
            publisher.publish(msg)

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    time.sleep(rng.uniform(0.05, 1.5))  # a random moment of the burst (about 2-3 s long)
    result = proc.stop(sig, timeout=timeout)
    stop.set()
    sender.join(10.0)
    while publisher.get_subscription_count() > 0:  # the node left the graph
        time.sleep(0.05)
    hung = result.rc in (-signal.SIGKILL, -signal.SIGTERM) and sig == signal.SIGINT
    return (None if hung else result.rc), result.stderr


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--tries', type=int, default=50)
    parser.add_argument('--messages', type=int, default=60_000)
    parser.add_argument('--node', choices=(*NODES, 'both'), default='both')
    parser.add_argument('--timeout', type=float, default=20.0,
                        help='seconds to wait for the exit after the signal')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--full', action='store_true',
                        help='print the whole stderr of a failing try')
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    nodes = NODES if args.node == 'both' else (args.node,)
    with isolated_domain(), tempfile.TemporaryDirectory() as tmp:
        import rclpy
        from rclpy.node import Node
        from sensor_msgs.msg import Imu

        from railgsa_ros.nodes.qos import sensor_qos

        rclpy.init()
        driver = Node('stress_signals')
        publisher = driver.create_publisher(Imu, 'imu/data', sensor_qos())
        msgs = burst(args.messages)
        passed = 0
        for k in range(args.tries):
            node = nodes[k % len(nodes)]
            sig = (signal.SIGINT, signal.SIGTERM)[(k // len(nodes)) % 2]
            rc, stderr = one_try(node, sig, msgs, publisher, Path(tmp), args.timeout, rng)
            ok = rc == 0 and 'Traceback' not in stderr
            passed += ok
            if not ok:
                last = stderr if args.full else (stderr.strip().splitlines() or [''])[-1]
                print(f'try {k}: {node} {signal.Signals(sig).name}: rc {rc}: {last}',
                      flush=True)
        driver.destroy_node()
        rclpy.shutdown()
    print(f'exit 0: {passed} of {args.tries}')
    return 0 if passed == args.tries else 1


if __name__ == '__main__':
    sys.exit(main())
