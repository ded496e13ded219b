"""irregularity_node killed (SIGKILL) mid-stream and restarted, next to uncertainty_node and the
recorder: it resumes with a clean state (outputs equal a fresh offline pipeline from the first
sample after the restart, no spike), the restart shows on /diagnostics (new boot_id, first
stamp), and the other two processes keep going (band published during the outage, the bag holds
outputs from before and after)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import signal
import time
from typing import Any

import numpy as np
import pytest
from ros_helpers import (
    T0_NS,
    Collector,
    DiagnosticsLog,
    header_stamp,
    imu_msgs,
    publish_bursts,
    stamp_ns,
    values,
)
from test_irregularity_node import PARAMS, offline

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NODE_ARGS = [a for k, v in PARAMS.items() for a in ('-p', f'{k}:={str(v).lower()}')]
KILL_AT, RESTART_AT = 3000, 4000  # sample indices: kill after, restart before


class Probe:
    """Publishes imu/data; records outputs, band stamps and the irregularity /diagnostics."""

    def __init__(self, ros_context: Any, spin: Callable) -> None:
        from geometry_msgs.msg import PointStamped, Vector3Stamped
        from rclpy.node import Node
        from sensor_msgs.msg import Imu

        from railgsa_ros.nodes.qos import DIAGNOSTICS_QOS, output_qos, sensor_qos

        self.node = spin(Node('fault_probe', context=ros_context))
        self.imu = self.node.create_publisher(Imu, 'imu/data', sensor_qos())
        self.out = Collector(self.node, PointStamped, 'track/irregularity', output_qos(20_000),
                             lambda m: (stamp_ns(m.header), m.point.z))
        self.band = Collector(self.node, Vector3Stamped, 'track/irregularity_band',
                              output_qos(20_000), header_stamp)
        # per /diagnostics array: irregularity_node's task -> its values
        self.diag = DiagnosticsLog(self.node, 'irregularity_node: ', values, DIAGNOSTICS_QOS)

    def inversion(self) -> list[dict[str, str]]:
        """The inversion statuses' values received so far, in order."""
        return [d['inversion'] for d in self.diag.snapshot() if 'inversion' in d]

    def publish(self, msgs: list) -> None:
        """At about 1 kHz, in 20-message bursts."""
        publish_bursts(self.imu, msgs, 1000.0, burst=20)


def test_kill_and_restart_resumes_clean_and_others_keep_going(
        ros_context: Any, spin: Callable, wait_for: Callable, start_node: Callable,
        tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    from railgsa_ros.bag.messages import typestore
    from railgsa_ros.scenario import run_scenario

    run = run_scenario('german-low', speed_mps=40.0, duration_s=8.0, rate_hz=1000.0,
                       sensor='ideal', seed=3)
    stamps, acc = run.stamps_ns + T0_NS, run.accel[:, 2]
    msgs = imu_msgs(stamps, acc)
    bag = tmp_path / 'bag'
    recorder = start_node('railgsa_ros.nodes.recorder', [
        '-p', f'out:={bag}', '-p', 'topics:=[/track/irregularity,/track/irregularity_band]'])
    uncertainty = start_node('railgsa_ros.nodes.uncertainty_node', NODE_ARGS)
    irregularity = start_node('railgsa_ros.nodes.irregularity_node', NODE_ARGS)
    probe = Probe(ros_context, spin)
    node = probe.node
    assert wait_for(lambda: probe.imu.get_subscription_count() >= 2, 90.0)
    assert wait_for(lambda: node.count_subscribers('track/irregularity') >= 2 and
                    node.count_subscribers('track/irregularity_band') >= 2, 60.0)
    assert wait_for(lambda: len(probe.inversion()) > 0, 10.0)
    time.sleep(0.5)
    boot = probe.inversion()[-1]['boot_id']

    probe.publish(msgs[:KILL_AT])
    assert wait_for(lambda: len(probe.out) > 0, 20.0)
    time.sleep(0.3)
    irregularity.proc.send_signal(signal.SIGKILL)
    irregularity.proc.wait(10.0)
    seen: list[int] = []  # the killed node's last outputs may still be in flight: settle

    def settled() -> bool:
        seen.append(len(probe.out))
        return len(seen) >= 5 and len(set(seen[-5:])) == 1
    assert wait_for(settled, 10.0, 0.1)
    before, band_before = len(probe.out), len(probe.band)
    probe.publish(msgs[KILL_AT:RESTART_AT])  # outage: the uncertainty node goes on
    assert wait_for(lambda: len(probe.band) > band_before, 10.0)

    restarted = start_node('railgsa_ros.nodes.irregularity_node', NODE_ARGS)
    assert wait_for(lambda: probe.imu.get_subscription_count() >= 2, 90.0)
    assert wait_for(lambda: any(d['boot_id'] != boot for d in probe.inversion()), 60.0)
    time.sleep(0.5)
    probe.publish(msgs[RESTART_AT:])
    ref = offline(stamps[RESTART_AT:], acc[RESTART_AT:])  # a fresh pipeline
    assert wait_for(lambda: len(probe.out) >= before + ref.stamps_ns.size, 30.0), \
        (len(probe.out) - before, ref.stamps_ns.size)
    assert wait_for(lambda: probe.inversion()[-1].get('first_stamp_ns')
                    == str(stamps[RESTART_AT]), 10.0), probe.inversion()[-1]
    new = probe.out.snapshot()[before:]
    new_t = np.array([o[0] for o in new], np.int64)
    new_u = np.array([o[1] for o in new])
    np.testing.assert_array_equal(new_t, ref.stamps_ns)
    np.testing.assert_allclose(new_u, ref.u_m, rtol=0, atol=1e-15)  # a clean start
    full = offline(stamps, acc).u_m
    assert np.nanmax(np.abs(new_u)) <= 1.2 * np.nanmax(np.abs(full))  # no spike (INVALID: NaN)
    assert uncertainty.running() and recorder.running()

    results = [p.stop(signal.SIGINT) for p in (restarted, uncertainty, recorder)]
    assert [r.rc for r in results] == [0, 0, 0], [r.stderr for r in results]
    with AnyReader([bag], default_typestore=typestore()) as reader:
        recorded = {c.topic: 0 for c in reader.connections}
        irr_stamps = []
        for conn, _, raw in reader.messages():
            recorded[conn.topic] += 1
            if conn.topic == '/track/irregularity':
                irr_stamps.append(stamp_ns(reader.deserialize(raw, conn.msgtype).header))
    assert recorded['/track/irregularity_band'] > 0
    irr_stamps = np.array(irr_stamps)
    assert (irr_stamps < stamps[KILL_AT]).any() and (irr_stamps >= stamps[RESTART_AT]).any()
