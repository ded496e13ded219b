"""``railgsa simulate``: a simulated car-body IMU run with ground truth, as a rosbag2 bag."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

DEFAULT_START_S = 1_700_000_000.0  # fixed epoch (2023-11-14): realistic, reproducible stamps


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` subcommand."""
    p = subparsers.add_parser(
        'simulate', help='simulate a car-body IMU run and write it as a rosbag2 bag',
        description='Simulate a vehicle (the quarter car, or a coach file: each wheelset at its '
                    'own delay) on a track profile, measure the car-body acceleration (and a '
                    'coach\'s pitch rate, with a gyro) with a MEMS IMU model and write '
                    '/imu/data (sensor_msgs/Imu), '
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
                   help='IMU preset: ideal | adxl355 | bmi088 (delay-free models; default '
                        'adxl355) or a chip at a datasheet setting, chip@ODRHz[-osr2|-osr4] '
                        '(adxl355@1000Hz, bmi088@400Hz: with its chip filter\'s delay)')
    p.add_argument('--seed', type=int, default=0, metavar='N', help='random seed (default 0)')
    p.add_argument('--defects', default=None, metavar='SPEC',
                   help='isolated defects added to the profile, e.g. '
                        '"dip@150:len=10:depth=0.004,joint@300" (see docs/simulation.md)')
    p.add_argument('--vehicle', default=None, metavar='FILE',
                   help='vehicle YAML: a quarter car (config/vehicle.yaml) or a coach '
                        '(config/vehicles/coach.yaml); default the paper Table 1')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='rosbag2 storage (default mcap)')
    p.add_argument('--compression', choices=('zstd', 'none'), default=None,
                   help='MCAP chunk compression (default zstd for mcap, none for sqlite3)')
    p.add_argument('--odom-rate', type=float, default=50.0, metavar='HZ',
                   help='odometry rate in Hz (default 50)')
    p.add_argument('--start-time', type=float, default=DEFAULT_START_S, metavar='S',
                   help=f'stamp of the first sample in s since the epoch '
                        f'(default {DEFAULT_START_S:.0f})')
    add_location_arguments(p)
    p.add_argument('--overwrite', action='store_true', help='replace an existing PATH')
    p.set_defaults(func=run)


def add_location_arguments(p: argparse.ArgumentParser) -> None:
    """Where the run is and how odometry and GNSS see it."""
    p.add_argument('--start-km', type=float, default=None, metavar='KM',
                   help='chainage of the start in km (default: the profile\'s origin, 0 or '
                        'the CSV\'s first chainage)')
    p.add_argument('--line-seed', type=int, default=None, metavar='N',
                   help='seed of the random track alone (default: drawn from --seed); runs '
                        'with the same line seed pass over the same track')
    p.add_argument('--odom-scale-error', type=float, default=0.0, metavar='E',
                   help='wheel-diameter error: odometry speed and distance x (1 + E), e.g. '
                        '0.004 (default 0)')
    p.add_argument('--gnss', action='store_true',
                   help='also write GNSS fixes (sensor_msgs/NavSatFix) on /gnss/fix along '
                        'the default simulated line (docs/simulation.md)')
    add_gnss_arguments(p)


def add_gnss_arguments(p: argparse.ArgumentParser) -> None:
    """The simulated GNSS receiver's rate and noise (shared with simulate-passes)."""
    p.add_argument('--gnss-rate', type=float, default=5.0, metavar='HZ',
                   help='GNSS fix rate in Hz (default 5)')
    p.add_argument('--gnss-noise', type=float, default=2.0, metavar='M',
                   help='GNSS horizontal noise std in m; vertical twice that (default 2)')
    p.add_argument('--gnss-corr', type=float, default=0.0, metavar='S',
                   help='correlation time of the GNSS noise in s (first-order Gauss-Markov, as '
                        'multipath makes it; default 0 = white)')


def check_positive(**values: float | None) -> None:
    """ConfigError naming the option when a given value is not a positive finite number."""
    import math

    from railgsa_ros.errors import ConfigError

    for name, value in values.items():
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f'--{name.replace("_", "-")}: must be a positive number, '
                              f'got {value:g}')


@dataclass
class SimOptions:
    """One simulated run as the command line describes it (option names without dashes)."""

    profile: str = 'german-low'
    speed: float | None = None
    duration: float | None = None
    rate: float | None = None
    sensor: str = 'adxl355'
    seed: int = 0
    defects: str | None = None
    vehicle: Any = None  # a vehicle YAML path, VehicleParams, theta (5,) or a VehicleModel
    storage: str = 'mcap'
    compression: str | None = None
    odom_rate: float = 50.0
    start_time: float = DEFAULT_START_S
    speed_profile: str | None = None
    start_km: float | None = None
    line_seed: int | None = None
    odom_scale_error: float = 0.0
    gnss: bool = False
    gnss_rate: float = 5.0
    gnss_noise: float = 2.0
    gnss_corr: float = 0.0

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> SimOptions:
        """The options of a parsed command line."""
        return cls(**{f.name: getattr(args, f.name) for f in fields(cls) if hasattr(args, f.name)})

    def velocity(self) -> tuple[Any, float]:
        """(speed: m/s or SpeedProfile, duration s), validated."""
        from railgsa_ros.errors import ConfigError
        from railgsa_ros.speed_profile import parse_speed_profile

        check_positive(speed=self.speed, duration=self.duration, rate=self.rate,
                       odom_rate=self.odom_rate)
        if self.speed is not None and self.speed_profile is not None:
            raise ConfigError('--speed and --speed-profile exclude each other: give one')
        if self.speed_profile is not None:
            profile = parse_speed_profile(self.speed_profile)
            return profile, profile.duration_s if self.duration is None else self.duration
        return (20.0 if self.speed is None else self.speed), \
            (20.0 if self.duration is None else self.duration)

    def stream(self) -> Any:
        """The run as a ``scenario.RunStream``."""
        import math

        from railgsa_ros.errors import ConfigError
        from railgsa_ros.scenario import RunStream

        speed, duration = self.velocity()
        if not 0 <= self.start_time < 2**31:
            raise ConfigError(f'--start-time: must be in [0, 2^31) s, got {self.start_time:g}')
        if not (math.isfinite(self.odom_scale_error) and abs(self.odom_scale_error) < 0.1):
            raise ConfigError(f'--odom-scale-error: expected a fraction within +-0.1, got '
                              f'{self.odom_scale_error:g}')
        if self.start_km is not None and not math.isfinite(self.start_km):
            raise ConfigError(f'--start-km: must be a finite number, got {self.start_km:g}')
        return RunStream(self.profile, speed, duration, self.rate, self.sensor, self.seed,
                         self.defects, self.vehicle, start_ns=round(self.start_time * 1e9),
                         start_m=None if self.start_km is None else 1e3 * self.start_km,
                         line_seed=self.line_seed, odom_scale=1.0 + self.odom_scale_error)

    def gnss_sim(self, stream: Any) -> Any:
        """The GNSS receiver along the default line covering the run (None without --gnss)."""
        if not self.gnss:
            return None
        from railgsa_ros.errors import ConfigError
        from railgsa_ros.geo import GnssSim, GnssSpec, default_line

        if stream.start_m < 0:
            raise ConfigError('--gnss: the simulated line starts at chainage 0; the run starts '
                              f'at {stream.start_m:g} m')
        check_positive(gnss_rate=self.gnss_rate)
        reach = stream.start_m + float(stream.max_speed_mps) * stream.duration_s
        spec = GnssSpec(self.gnss_rate, self.gnss_noise, 2 * self.gnss_noise, self.gnss_corr)
        return GnssSim(default_line(reach), spec, seed=[self.seed, 0x6E55])


def stream_bag(out: str | Path, options: SimOptions, overwrite: bool = False,
               on_chunk: Callable[[Any], None] | None = None) -> tuple[Path, list[Any], Any]:
    """Simulate and write the bag chunk by chunk (bounded memory); returns (bag path, topic
    summaries as written, ``RunSummary`` of the data). ``on_chunk`` sees every Run chunk."""
    from railgsa_ros.bag.run import write_run_chunks
    from railgsa_ros.errors import ConfigError
    from railgsa_ros.fileio import refuse_overlap

    stream = options.stream()
    gnss = options.gnss_sim(stream)
    compression = options.compression
    if compression is None:
        compression = 'zstd' if options.storage == 'mcap' else 'none'
    vehicle_file = options.vehicle if isinstance(options.vehicle, (str, Path)) else None
    refuse_overlap(out, (options.profile[5:] if options.profile.startswith('file:') else None,
                         vehicle_file))
    if Path(out).exists() and not overwrite:
        raise ConfigError(f'{out}: already exists (choose another output path or --overwrite)')
    summary = RunSummary()

    def chunks() -> Any:
        for chunk in stream:
            summary.add(chunk)
            if on_chunk is not None:
                on_chunk(chunk)
            yield chunk

    path, topics = write_run_chunks(out, chunks(), options.storage,
                                    None if compression == 'none' else compression,
                                    odom_rate_hz=options.odom_rate, overwrite=overwrite,
                                    gnss=gnss)
    return path, topics, summary


def simulate_bag(out: str | Path, profile: str = 'german-low', overwrite: bool = False,
                 **options: Any) -> tuple[Path, Any]:
    """Simulate and write the bag; returns (bag path, the whole Run: for short runs).

    ``options``: the fields of SimOptions (m/s, s, Hz); ``speed`` (default 20 m/s) and
    ``speed_profile`` exclude each other; the duration defaults to 20 s or to the profile's.
    """
    from railgsa_ros.scenario import Run

    chunks: list[Any] = []
    path, _, _ = stream_bag(out, SimOptions(profile=profile, **options), overwrite,
                            chunks.append)
    return path, Run.concat(chunks)


class RunSummary:
    """Running statistics of a simulated run, chunk by chunk: accel z, speed, truth."""

    def __init__(self) -> None:
        self.n = 0
        self.frames: set[str] = set()
        self.acc_sum = self.acc_sq = self.u_sq = self.u_peak = 0.0
        self.speed = [float('inf'), -float('inf')]
        self.chainage = [float('inf'), -float('inf')]

    def add(self, chunk: Any) -> None:
        """Fold one Run chunk in."""
        import numpy as np

        if chunk.stamps_ns.size == 0:
            return
        z = chunk.accel[:, 2]
        self.n += z.size
        self.frames.add(chunk.frame_id)
        self.acc_sum += float(z.sum())
        self.acc_sq += float(np.sum(z ** 2))
        self.u_sq += float(np.sum(chunk.truth_u_m ** 2))
        self.u_peak = max(self.u_peak, float(np.abs(chunk.truth_u_m).max()))
        odom = chunk.odom_scale * chunk.speed_mps
        self.speed = [min(self.speed[0], odom.min()), max(self.speed[1], odom.max())]
        self.chainage = [min(self.chainage[0], chunk.chainage_m.min()),
                         max(self.chainage[1], chunk.chainage_m.max())]

    def lines(self) -> list[str]:
        """The data lines of the summary (as ``format_summary`` prints them)."""
        if self.n == 0:
            return []
        mean = self.acc_sum / self.n
        std = max(0.0, self.acc_sq / self.n - mean ** 2) ** 0.5
        return [f'  accel z mean {mean:.4f} m/s^2, std {std:.4f} m/s^2, frame '
                f'{", ".join(sorted(self.frames))}',
                f'  speed {self.speed[0]:.2f}-{self.speed[1]:.2f} m/s (odometry)',
                f'  truth chainage {self.chainage[0]:.1f}-{self.chainage[1]:.1f} m, '
                f'irregularity rms {1e3 * (self.u_sq / self.n) ** 0.5:.3f} mm, '
                f'peak {1e3 * self.u_peak:.3f} mm']


def topic_lines(path: str | Path, topics: list[Any]) -> list[str]:
    """Bag size, one line per topic (count, rate) and the time span."""
    path = Path(path)
    size = sum(f.stat().st_size for f in path.rglob('*') if f.is_file()) if path.is_dir() \
        else path.stat().st_size
    lines = [f'bag {path} ({size / 1e6:.2f} MB)',
             f'  {"topic":<28} {"type":<32} {"count":>7} {"rate [Hz]":>10}']
    for t in topics:
        span = (t.end_ns - t.start_ns) / 1e9
        rate = (t.count - 1) / span if t.count > 1 and span > 0 else float('nan')
        lines.append(f'  {t.topic:<28} {t.msgtype:<32} {t.count:>7} {rate:>10.1f}')
    if topics:
        start = min(t.start_ns for t in topics)
        end = max(t.end_ns for t in topics)
        lines.append(f'  duration {(end - start) / 1e9:.3f} s from stamp {start / 1e9:.3f} s')
    return lines


def format_summary(path: str | Path) -> str:
    """A one-screen summary of a bag read back from disk (reads it whole: short bags)."""
    import numpy as np

    from railgsa_ros.bag import IMU_TOPIC, TRUTH_TOPIC, read_imu, read_stamped, summarize
    from railgsa_ros.bag.messages import POINT_STAMPED

    topics = summarize(path)
    lines = topic_lines(path, topics)
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
    """Simulate and write the bag in chunks, print its summary (from the stream)."""
    path, topics, summary = stream_bag(args.out, SimOptions.from_args(args), args.overwrite)
    print('\n'.join(topic_lines(path, topics) + summary.lines()))
    return 0
