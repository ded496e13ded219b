"""``railgsa simulate``: a simulated car-body IMU run with ground truth, as a rosbag2 bag."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

DEFAULT_START_S = 1_700_000_000.0  # fixed epoch (2023-11-14): realistic, reproducible stamps


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` subcommand."""
    p = subparsers.add_parser(
        'simulate', help='simulate a car-body IMU run and write it as a rosbag2 bag',
        description='Simulate the quarter vehicle on a track profile, measure the car-body '
                    'acceleration with a MEMS IMU model and write /imu/data (sensor_msgs/Imu), '
                    '/odom (nav_msgs/Odometry) and /track/irregularity_truth '
                    '(geometry_msgs/PointStamped) to a rosbag2 bag.')
    p.add_argument('--out', required=True, metavar='PATH', help='bag directory to create')
    p.add_argument('--profile', default='german-low', metavar='SPEC',
                   help='german-low | german-high | fra-N (N = 1..6) | paper | file:CSV '
                        '(default german-low)')
    p.add_argument('--speed', type=float, default=None, metavar='MPS',
                   help='constant vehicle speed in m/s (default 20)')
    p.add_argument('--speed-profile', default=None, metavar='SPEC',
                   help='speed profile instead of --speed: segments such as '
                        '"accel:0-30:60s,cruise:30:120s:ripple=0.5,brake:30-0:40s,stop:10s" '
                        'or a preset (station, stop-and-go); see docs/simulation.md')
    p.add_argument('--duration', type=float, default=None, metavar='S',
                   help='duration in s (default 20, or the speed profile\'s duration)')
    p.add_argument('--rate', type=float, default=None, metavar='HZ',
                   help='IMU output rate in Hz (default: the sensor preset rate)')
    p.add_argument('--sensor', default='adxl355', metavar='PRESET',
                   help='IMU preset: ideal | adxl355 | bmi088 (default adxl355)')
    p.add_argument('--seed', type=int, default=0, metavar='N', help='random seed (default 0)')
    p.add_argument('--defects', default=None, metavar='SPEC',
                   help='isolated defects added to the profile, e.g. '
                        '"dip@150:len=10:depth=0.004,joint@300" (see docs/simulation.md)')
    p.add_argument('--vehicle', default=None, metavar='FILE',
                   help='vehicle YAML (default: the paper Table 1)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='rosbag2 storage (default mcap)')
    p.add_argument('--compression', choices=('zstd', 'none'), default=None,
                   help='MCAP chunk compression (default zstd for mcap, none for sqlite3)')
    p.add_argument('--odom-rate', type=float, default=50.0, metavar='HZ',
                   help='odometry rate in Hz (default 50)')
    p.add_argument('--start-time', type=float, default=DEFAULT_START_S, metavar='S',
                   help=f'stamp of the first sample in s since the epoch '
                        f'(default {DEFAULT_START_S:.0f})')
    p.add_argument('--overwrite', action='store_true', help='replace an existing PATH')
    p.set_defaults(func=run)


def check_positive(**values: float | None) -> None:
    """ConfigError naming the option when a given value is not a positive finite number."""
    import math

    from railgsa_ros.errors import ConfigError

    for name, value in values.items():
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f'--{name.replace("_", "-")}: must be a positive number, '
                              f'got {value:g}')


def simulate_bag(out: str | Path, profile: str = 'german-low', speed: float | None = None,
                 duration: float | None = None, rate: float | None = None,
                 sensor: str = 'adxl355',
                 seed: int = 0, defects: str | None = None, vehicle: str | None = None,
                 storage: str = 'mcap', compression: str | None = None,
                 odom_rate: float = 50.0, start_time: float = DEFAULT_START_S,
                 overwrite: bool = False, speed_profile: str | None = None
                 ) -> tuple[Path, Any]:
    """Simulate and write the bag; returns (bag path, Run). Units: m/s, s, Hz.

    ``speed`` (default 20 m/s) and ``speed_profile`` (a spec or preset) exclude each other; the
    duration defaults to 20 s or to the profile's duration (its last speed is held beyond).
    """
    from railgsa_ros.bag import write_run
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.fileio import refuse_overlap
    from railgsa_ros.scenario import run_scenario
    from railgsa_ros.speed_profile import parse_speed_profile

    check_positive(speed=speed, duration=duration, rate=rate, odom_rate=odom_rate)
    if speed is not None and speed_profile is not None:
        raise ConfigError('--speed and --speed-profile exclude each other: give one')
    velocity = parse_speed_profile(speed_profile) if speed_profile is not None else \
        (20.0 if speed is None else speed)
    if duration is None:
        duration = velocity.duration_s if speed_profile is not None else 20.0
    if not 0 <= start_time < 2**31:
        raise ConfigError(f'--start-time: must be in [0, 2^31) s, got {start_time:g}')
    if compression is None:
        compression = 'zstd' if storage == 'mcap' else 'none'
    refuse_overlap(out, (profile[5:] if profile.startswith('file:') else None, vehicle))
    if Path(out).exists() and not overwrite:
        raise ConfigError(f'{out}: already exists (choose another output path or --overwrite)')
    result = run_scenario(profile, velocity, duration, rate, sensor, seed, defects=defects,
                          vehicle=vehicle, start_ns=round(start_time * 1e9))
    path = write_run(out, result, storage, None if compression == 'none' else compression,
                     odom_rate_hz=odom_rate, overwrite=overwrite)
    return path, result


def format_summary(path: str | Path) -> str:
    """A one-screen summary of a bag read back from disk: topics, counts, rates, truth range."""
    import numpy as np

    from railgsa_ros.bag import IMU_TOPIC, TRUTH_TOPIC, read_imu, read_stamped, summarize
    from railgsa_ros.bag.messages import POINT_STAMPED

    path = Path(path)
    size = sum(f.stat().st_size for f in path.rglob('*') if f.is_file()) if path.is_dir() \
        else path.stat().st_size
    lines = [f'bag {path} ({size / 1e6:.2f} MB)',
             f'  {"topic":<28} {"type":<32} {"count":>7} {"rate [Hz]":>10}']
    topics = summarize(path)
    for t in topics:
        span = (t.end_ns - t.start_ns) / 1e9
        rate = (t.count - 1) / span if t.count > 1 and span > 0 else float('nan')
        lines.append(f'  {t.topic:<28} {t.msgtype:<32} {t.count:>7} {rate:>10.1f}')
    if topics:
        start = min(t.start_ns for t in topics)
        end = max(t.end_ns for t in topics)
        lines.append(f'  duration {(end - start) / 1e9:.3f} s from stamp {start / 1e9:.3f} s')
    if any(t.topic == IMU_TOPIC for t in topics):
        stream = read_imu(path)
        acc = stream.accel[np.isfinite(stream.accel[:, 2])]
        lines.append(f'  accel z mean {acc[:, 2].mean():.4f} m/s^2, std {acc[:, 2].std():.4f} '
                     f'm/s^2, frame {", ".join(sorted(set(stream.frame_ids)))}')
        if stream.speed_mps.size:
            lines.append(f'  speed {stream.speed_mps.min():.2f}-{stream.speed_mps.max():.2f} '
                         'm/s')
    if any(t.topic == TRUTH_TOPIC for t in topics):
        pts = read_stamped(path, TRUTH_TOPIC, POINT_STAMPED.msgtype).values[:, [0, 2]]
        lines.append(f'  truth chainage {pts[:, 0].min():.1f}-{pts[:, 0].max():.1f} m, '
                     f'irregularity rms {1e3 * np.sqrt(np.mean(pts[:, 1] ** 2)):.3f} mm, '
                     f'peak {1e3 * np.abs(pts[:, 1]).max():.3f} mm')
    return '\n'.join(lines)


def run(args: argparse.Namespace) -> int:
    """Simulate, write the bag, print its summary."""
    path, _ = simulate_bag(args.out, args.profile, args.speed, args.duration, args.rate,
                           args.sensor, args.seed, args.defects, args.vehicle, args.storage,
                           args.compression, args.odom_rate, args.start_time, args.overwrite,
                           args.speed_profile)
    print(format_summary(path))
    return 0
