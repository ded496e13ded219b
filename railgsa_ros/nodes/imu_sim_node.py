"""imu_sim_node: publishes a simulated car-body IMU run live, as ``railgsa simulate`` bags it.

The whole run (``scenario.run_scenario``) is computed at start-up; a timer then publishes every
sample whose stamp is due on the node clock: wall time, or ``/clock`` with ``use_sim_time``.
Stamps are the run's sensor stamps shifted so that the first sample falls on the first tick.
Messages are the same CDR bytes as in a bag (``bag.RunEncoder``), published raw.

Topics: ``imu/data`` (sensor_msgs/Imu, BEST_EFFORT, depth 1 s of samples; a coach file's
further IMUs on ``imu/<name>/data``), ``odom``
(nav_msgs/Odometry) and ``track/irregularity_truth`` (geometry_msgs/PointStamped), RELIABLE;
``/diagnostics`` once a second (samples published, rate).
"""

from __future__ import annotations

import railgsa_ros.nodes.early_signals  # noqa: F401  (first: exit 0 on a signal from here on)

# isort: split

import sys

from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Imu

from railgsa_ros.bag import RunEncoder
from railgsa_ros.imu import PRESETS
from railgsa_ros.nodes import console_main
from railgsa_ros.nodes.diagnostics import OK, STALE, DiagnosticsPublisher, Report
from railgsa_ros.nodes.params import ParamSpec, declare
from railgsa_ros.nodes.process import run_node
from railgsa_ros.nodes.qos import output_qos, sensor_qos
from railgsa_ros.qos import MIN_SENSOR_DEPTH, history_depth
from railgsa_ros.scenario import run_scenario

NODE_NAME = 'imu_sim'
SPECS = (
    ParamSpec('profile', 'german-low',
              'track profile: german-low | german-high | fra-N | paper | file:CSV',
              read_only=True),
    ParamSpec('defects', '', 'defects added to the profile, e.g. dip@150:len=10:depth=0.004 '
              '(empty: none)', read_only=True),
    ParamSpec('speed_mps', 20.0, 'vehicle speed, m/s', bounds=(0.1, 150.0), read_only=True),
    ParamSpec('duration_s', 60.0, 'length of the simulated run (computed at start-up), s',
              bounds=(0.1, 3600.0), read_only=True),
    ParamSpec('rate_hz', 1000.0, 'IMU output rate, Hz', bounds=(1.0, 10000.0), read_only=True),
    ParamSpec('sensor', 'adxl355', 'IMU model preset', choices=tuple(PRESETS), read_only=True),
    ParamSpec('seed', 0, 'random seed of track and sensor', bounds=(0, 2**31 - 1),
              read_only=True),
    ParamSpec('vehicle_file', '', 'vehicle YAML, quarter car or coach (model: coach; a coach\'s '
              'pitch rate goes to angular_velocity.y when the sensor has a gyro); empty: the '
              'paper Table 1', read_only=True),
    ParamSpec('odom_rate_hz', 50.0, 'odometry rate, Hz', bounds=(0.1, 1000.0), read_only=True),
    ParamSpec('publish_period_s', 0.01, 'timer period; each tick publishes every sample due, s',
              bounds=(0.001, 0.5), read_only=True),
    ParamSpec('frame_id', 'imu_link', 'frame of the Imu messages (REP 145)', read_only=True),
)


class ImuSimNode(Node):
    """Simulates the run at construction (ConfigError on bad parameters), then plays it."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare(self, SPECS)
        self.run = run_scenario(p['profile'], p['speed_mps'], p['duration_s'], p['rate_hz'],
                                p['sensor'], p['seed'], defects=p['defects'] or None,
                                vehicle=p['vehicle_file'] or None)
        self.encoder = RunEncoder(self.run, odom_rate_hz=p['odom_rate_hz'],
                                  frame_id=p['frame_id'])
        depth = max(MIN_SENSOR_DEPTH, history_depth(p['rate_hz']))
        self._pubs = {
            'imu': self.create_publisher(Imu, 'imu/data', sensor_qos(depth)),
            'odom': self.create_publisher(Odometry, 'odom',
                                          output_qos(history_depth(p['odom_rate_hz']))),
            'truth': self.create_publisher(PointStamped, 'track/irregularity_truth',
                                           output_qos(depth)),
        }
        for name in self.encoder.imu_names:  # a coach file's further IMUs
            self._pubs[f'imu:{name}'] = self.create_publisher(Imu, f'imu/{name}/data',
                                                              sensor_qos(depth))
        self.offset_ns: int | None = None
        self.published = 0
        self._timer = self.create_timer(p['publish_period_s'], self._tick)
        self._counted = 0
        self.diagnostics = DiagnosticsPublisher(self, hardware_id=f'imu_sim/{p["sensor"]}')
        self.diagnostics.add('simulation', self._report)
        self.get_logger().info(
            f'simulated {len(self.encoder)} samples ({p["duration_s"]:g} s at '
            f'{p["rate_hz"]:g} Hz, {p["profile"]}, {p["sensor"]}); publishing')

    def _tick(self) -> None:
        """Publish every sample whose shifted stamp is at or before the node clock."""
        now = self.get_clock().now().nanoseconds
        if now == 0:  # use_sim_time and no /clock message yet
            return
        stamps = self.encoder.stamps_ns
        if self.offset_ns is None:
            self.offset_ns = now - int(stamps[0])
        due = int(np.searchsorted(stamps, now - self.offset_ns, side='right'))
        if due > self.published:
            for key, (_, raws) in self.encoder.encode(self.published, due,
                                                      self.offset_ns).items():
                publish = self._pubs[key].publish
                for raw in raws:
                    publish(raw)
            self.published = due
        if self.published == len(self.encoder):
            self._timer.cancel()
            self.get_logger().info('run finished: all samples published')

    def _report(self, elapsed_s: float) -> Report:
        """Diagnostics: samples published in total and per second over the last period."""
        rate, self._counted = (self.published - self._counted) / elapsed_s, self.published
        values = {'published': self.published, 'samples': len(self.encoder),
                  'rate_hz': rate, 'sensor': self.run.sensor.name}
        if self.published == len(self.encoder):
            return Report(OK, 'run finished', values)
        if self.offset_ns is None:
            return Report(STALE, 'waiting for the clock (use_sim_time without /clock)', values)
        return Report(OK, 'publishing', values)


def run(args: list[str] | None = None) -> int:
    """Spin until SIGINT/SIGTERM (0); a bad parameter raises RailGsaError."""
    return run_node(ImuSimNode, args)


def main(args: list[str] | None = None) -> int:
    """Console script ``imu_sim_node``: spin until SIGINT/SIGTERM (exit 0); bad parameter ->
    one-line error, exit 2."""
    return console_main(run, args)


if __name__ == '__main__':
    sys.exit(main())
