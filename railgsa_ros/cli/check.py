"""``railgsa check``: installer health check of a live system (IMU, odometry, nodes)."""

from __future__ import annotations

import argparse
import math
import sys

from railgsa_ros.errors import ConfigError

MAX_DURATION_S = 3600.0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``check`` subcommand."""
    p = subparsers.add_parser(
        'check', help='health check after mounting: IMU rate, jitter, gravity axis, noise, '
                      'odometry, nodes',
        description='Listen to the live system for --duration seconds and print a checklist '
                    '(PASS/WARN/FAIL with the measured value and the expected range): IMU rate '
                    'and stamp jitter, stamp order, the axis carrying gravity (REP 145: +z), '
                    'the noise density against the sensor preset, odometry, and whether '
                    'irregularity_node and uncertainty_node run and publish. Run it at rest. '
                    'Exit code 0 when nothing FAILed, 1 otherwise, 2 for usage errors.')
    p.add_argument('--imu-topic', default='imu/data', metavar='T',
                   help='IMU topic (default imu/data)')
    p.add_argument('--odom-topic', default='odom', metavar='T',
                   help='odometry topic (default odom)')
    p.add_argument('--duration', type=float, default=10.0, metavar='S',
                   help='seconds to listen (default 10)')
    p.add_argument('--sensor', default='adxl355', metavar='PRESET',
                   help='configured sensor preset: ideal, adxl355 or bmi088 (default adxl355)')
    p.add_argument('--rate', type=float, default=None, metavar='HZ',
                   help="expected IMU rate (default: the preset's output rate)")
    p.add_argument('--json', action='store_true', help='print the checklist as JSON')
    p.set_defaults(func=run)


def _positive(name: str, value: float | None, high: float = math.inf) -> None:
    if value is not None and not (math.isfinite(value) and 0 < value <= high):
        raise ConfigError(f'{name}: expected a number in (0, {high:g}], got {value!r}')


def run(args: argparse.Namespace) -> int:
    """Collect, judge, print; 0 when nothing failed, else 1."""
    from railgsa_ros.health import checklist, exit_code, format_items, items_json
    from railgsa_ros.imu import imu_spec
    from railgsa_ros.system import env_domain

    env_domain()  # a ROS_DOMAIN_ID that is no domain id: one line, not an rclpy traceback
    _positive('--duration', args.duration, MAX_DURATION_S)
    _positive('--rate', args.rate)
    try:
        spec = imu_spec(args.sensor)
    except ConfigError as exc:
        raise ConfigError(f'--{exc}') from None
    from railgsa_ros.nodes.health_check import collect

    if not args.json:
        print(f'railgsa check: listening {args.duration:g} s to {args.imu_topic} '
              f'({args.sensor}), {args.odom_topic} and the nodes ...', file=sys.stderr)
    items = checklist(collect(args.imu_topic, args.odom_topic, args.duration), spec, args.rate)
    print(items_json(items) if args.json else format_items(items))
    return exit_code(items)
