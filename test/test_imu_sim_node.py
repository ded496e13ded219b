"""imu_sim_node: live rate, stamps and values equal to the offline scenario, sim time, signals."""

from __future__ import annotations

from pathlib import Path
import signal
import time

import numpy as np
import pytest
from ros_helpers import Collector, stamp_ns
import yaml

from railgsa_ros.scenario import run_scenario

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[1]
RUN = {'profile': 'paper', 'speed_mps': 10.0, 'duration_s': 2.0, 'rate_hz': 200.0,
       'sensor': 'adxl355', 'seed': 5, 'defects': 'dip@8:len=4:depth=0.002'}


class Recorder:
    """Subscribes to the simulator's three topics and keeps (arrival s, message) per topic."""

    def __init__(self, ros_context: object) -> None:
        from geometry_msgs.msg import PointStamped
        from nav_msgs.msg import Odometry
        from rclpy.node import Node
        from sensor_msgs.msg import Imu

        from railgsa_ros.nodes.qos import output_qos, sensor_qos

        self.node = Node('recorder', context=ros_context)
        self.got = {key: Collector(self.node, msgtype, topic, qos,
                                   lambda m: (time.monotonic(), m))
                    for key, (msgtype, topic, qos) in {
                        'imu': (Imu, 'imu/data', sensor_qos()),
                        'odom': (Odometry, 'odom', output_qos()),
                        'truth': (PointStamped, 'track/irregularity_truth', output_qos())}.items()}

    def stamps(self, key: str) -> np.ndarray:
        return np.array([stamp_ns(m.header) for _, m in self.got[key].snapshot()],
                        dtype=np.int64)

    def count(self, key: str) -> int:
        return len(self.got[key])


def sim_node(ros_context: object, **overrides: object):
    """An ImuSimNode in the test's context with the RUN parameters and overrides."""
    from rclpy.parameter import Parameter

    from railgsa_ros.nodes.imu_sim_node import ImuSimNode

    params = {**RUN, **overrides}
    return ImuSimNode(context=ros_context,
                      parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


def test_publishes_the_offline_run_at_the_configured_rate(ros_context, spin, wait_for) -> None:
    rec = Recorder(ros_context)
    spin(rec.node)
    node = spin(sim_node(ros_context, frame_id='imu_front'))
    offline = run_scenario(RUN['profile'], RUN['speed_mps'], RUN['duration_s'], RUN['rate_hz'],
                           RUN['sensor'], RUN['seed'], defects=RUN['defects'])
    n = offline.stamps_ns.size
    assert wait_for(lambda: node.published == n, 10.0)
    assert wait_for(lambda: rec.count('truth') == n and rec.count('imu') >= n - 2, 5.0)
    # Rate: paced by the clock. No sample arrives before it is due (late is possible on a loaded
    # machine, early is not), and the whole run takes about its own duration.
    arrivals = np.array([t for t, _ in rec.got['truth'].snapshot()])
    due = (offline.stamps_ns - offline.stamps_ns[0]) / 1e9
    assert np.all(arrivals - arrivals[0] >= due - 0.1)
    assert due[-1] - 0.1 <= arrivals[-1] - arrivals[0] <= due[-1] + 1.5
    # Stamps: the offline stamps shifted by one offset; values: the offline values.
    truth = rec.stamps('truth')
    np.testing.assert_array_equal(truth - truth[0], offline.stamps_ns - offline.stamps_ns[0])
    assert node.offset_ns == truth[0] - offline.stamps_ns[0]
    z = np.array([m.point.z for _, m in rec.got['truth'].snapshot()])
    imu = {stamp_ns(m.header): m for _, m in rec.got['imu'].snapshot()}
    np.testing.assert_array_equal(z, offline.truth_u_m)
    index = {int(s): k for k, s in enumerate(offline.stamps_ns + node.offset_ns)}
    for stamp, msg in imu.items():
        k = index[stamp]
        assert (msg.linear_acceleration.x, msg.linear_acceleration.y,
                msg.linear_acceleration.z) == tuple(offline.accel[k])
        assert msg.header.frame_id == 'imu_front' and msg.orientation_covariance[0] == -1
    assert imu[truth[0]].linear_acceleration_covariance[0] == pytest.approx(
        offline.accel_covariance, rel=1e-12)
    odom = rec.stamps('odom')
    assert odom.size == pytest.approx(RUN['duration_s'] * 50, abs=2)
    assert set(odom) <= set(offline.stamps_ns + node.offset_ns)
    (status,) = node.diagnostics.publish().status
    values = {kv.key: kv.value for kv in status.values}
    assert status.name == 'imu_sim: simulation' and status.message == 'run finished'
    assert values['published'] == values['samples'] == str(n)


def test_follows_the_simulated_clock(ros_context, spin, wait_for) -> None:
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock

    from railgsa_ros.nodes.qos import output_qos

    rec = Recorder(ros_context)
    spin(rec.node)
    node = spin(sim_node(ros_context, publish_period_s=0.005, use_sim_time=True))
    clock_node = spin(Node('clock', context=ros_context))
    clock_pub = clock_node.create_publisher(Clock, '/clock', output_qos(10))
    time.sleep(0.5)
    assert node.published == 0  # no /clock yet: nothing is due
    t0 = 1000 * 10**9

    def tick(t_ns: int) -> bool:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(t_ns, 10**9)
        return wait_for(lambda: (clock_pub.publish(msg), node.get_clock().now().nanoseconds
                                 == t_ns)[1], 5.0)

    assert tick(t0)
    assert wait_for(lambda: node.published == 1, 5.0)
    assert tick(t0 + 500_000_000)
    offline_rel = node.encoder.stamps_ns - node.encoder.stamps_ns[0]
    expected = int(np.searchsorted(offline_rel, 500_000_000, side='right'))
    assert wait_for(lambda: node.published == expected and rec.count('truth') == expected, 5.0)
    time.sleep(0.3)  # the simulated clock stands still: so does the node
    assert node.published == expected
    stamps = rec.stamps('truth')
    assert stamps[0] == t0 and stamps[-1] <= t0 + 500_000_000


def test_params_file_mirrors_the_declared_defaults() -> None:
    from railgsa_ros.config import ros_parameters
    from railgsa_ros.nodes.imu_sim_node import NODE_NAME, SPECS

    doc = yaml.safe_load((REPO / 'config' / 'imu_sim.yaml').read_text())
    assert ros_parameters(doc, NODE_NAME) == {s.name: s.default for s in SPECS}


def test_subprocess_stops_cleanly_on_sigint_and_sigterm(start_node, ros_context, spin,
                                                         wait_for) -> None:
    rec = Recorder(ros_context)
    spin(rec.node)
    for sig in (signal.SIGINT, signal.SIGTERM):
        for attempt in range(2):  # ros_notes section 6: allow one retry for a rare rmw race
            before = rec.count('truth')
            proc = start_node('railgsa_ros.nodes.imu_sim_node',
                              ['--params-file', str(REPO / 'config' / 'imu_sim.yaml'),
                               '-p', 'duration_s:=10.0', '-p', 'rate_hz:=100.0'])
            ready = wait_for(lambda b=before: rec.count('truth') > b + 5, 30.0)
            result = proc.stop(sig)
            assert ready, result.stderr
            if result.rc == 0 or attempt == 1:
                break
        assert result.rc == 0, (sig, result.stderr)
        assert 'Traceback' not in result.stderr


def test_bad_parameter_exits_2_with_one_line(ros_domain: int,
                                             capsys: pytest.CaptureFixture) -> None:
    from railgsa_ros.nodes.imu_sim_node import main

    assert main(['imu_sim_node', '--ros-args', '-p', 'profile:=swiss-9']) == 2
    err = capsys.readouterr().err
    assert err.startswith('error: ') and 'swiss-9' in err and err.count('\n') == 1
    assert main(['imu_sim_node', '--ros-args', '-p', 'rate_hz:=0.5']) == 2
    assert 'rate_hz' in capsys.readouterr().err


def test_a_coach_file_publishes_its_pitch_rate_and_further_imus_live(
        ros_context, spin, wait_for, tmp_path) -> None:
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.qos import sensor_qos

    coach = tmp_path / 'coach.yaml'
    coach.write_text((REPO / 'config' / 'vehicles' / 'coach.yaml').read_text().replace(
        '    x_m: 9.5 ', '    x_m: 9.5\n  - {name: centre, x_m: 0.0} '))
    rec = Recorder(ros_context)
    centre = Collector(rec.node, Imu, 'imu/centre/data', sensor_qos())
    spin(rec.node)
    node = spin(sim_node(ros_context, vehicle_file=str(coach), sensor='bmi088', rate_hz=400.0,
                         duration_s=1.0))
    offline = run_scenario(RUN['profile'], RUN['speed_mps'], 1.0, 400.0, 'bmi088', RUN['seed'],
                           defects=RUN['defects'], vehicle=str(coach))
    n = offline.stamps_ns.size
    assert wait_for(lambda: node.published == n and rec.count('imu') >= n - 2
                    and len(centre.snapshot()) >= n - 2, 10.0)
    index = {int(s): k for k, s in enumerate(offline.stamps_ns + node.offset_ns)}
    for _, msg in rec.got['imu'].snapshot():
        k = index[stamp_ns(msg.header)]
        omega = msg.angular_velocity
        assert (omega.x, omega.y, omega.z) == tuple(offline.gyro[k])
        assert msg.angular_velocity_covariance[0] == offline.gyro_covariance > 0
    for msg in centre.snapshot():
        k = index[stamp_ns(msg.header)]
        acc = msg.linear_acceleration
        assert (acc.x, acc.y, acc.z) == tuple(offline.imu_accel[k, 0])
        assert msg.header.frame_id == 'imu_link_centre'
