"""/diagnostics by convention: STALE before any input, WARN when input stops, full-precision
values, hardware_id from the IMU frame_id or the parameter."""

from __future__ import annotations

from collections.abc import Callable
import time
from typing import Any

import numpy as np
import pytest
from ros_helpers import NS, DiagnosticsLog, G, imu_msgs

pytestmark = pytest.mark.ros

STALE, OK, WARN = b'\x03', b'\x00', b'\x01'


def test_values_keep_full_precision_and_hardware_id_prefers_the_parameter() -> None:
    from railgsa_ros.nodes.diagnostics import HardwareId, format_value

    for value in (time.time(), 1 / 3, 1796157401.0883606, 2.13e6, -0.0):
        assert float(format_value(value)) == value
    assert format_value(1796157401.25) == '1796157401.25'  # 6 significant digits: 1.79616e+09
    assert format_value(float('nan')) == 'nan' and format_value(7) == '7'
    hw = HardwareId('')
    assert str(hw) == ''
    hw.see(['imu_a', 'imu_b'])
    assert str(hw) == 'imu_b'
    hw.parameter = 'bogie1/adxl355'
    assert str(hw) == 'bogie1/adxl355'


def test_idle_node_is_stale_then_ok_then_warns_when_input_stops(
        ros_context: Any, spin: Callable, wait_for: Callable) -> None:
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Imu

    from railgsa_ros.nodes.irregularity_node import IrregularityNode
    from railgsa_ros.nodes.qos import sensor_qos

    spin(IrregularityNode(context=ros_context, parameter_overrides=[
        Parameter('use_odom', value=False), Parameter('idle_flush_s', value=3600.0)]))
    test = Node('diagnostics_test', context=ros_context)
    reports = DiagnosticsLog(test, 'irregularity_node: ')
    imu = test.create_publisher(Imu, 'imu/data', sensor_qos())
    spin(test)
    assert wait_for(lambda: len(reports), 10.0)
    first = reports.snapshot()[0]
    assert {name: s.level for name, s in first.items()} == {
        'imu input': STALE, 'inversion': STALE, 'input checks': STALE, 'location': STALE}
    assert first['imu input'].message == 'no IMU input yet'
    assert {s.hardware_id for s in first.values()} == {''}
    started = {kv.key: kv.value for kv in first['inversion'].values}['started_unix_s']
    assert abs(float(started) - time.time()) < 600 and repr(float(started)) == started

    assert wait_for(lambda: imu.get_subscription_count() > 0, 10.0)
    for msg in imu_msgs(1_700_000_000 * NS + np.arange(200) * 1_000_000, np.full(200, G)):
        imu.publish(msg)

    def received(d: dict) -> str:
        return {kv.key: kv.value for kv in d['imu input'].values}['received']
    assert wait_for(lambda: reports.first(lambda d: received(d) == '200'), 10.0)
    fed = reports.first(lambda d: received(d) == '200')
    assert fed['imu input'].level in (OK, WARN)  # WARN: the one period may see a gap
    assert fed['imu input'].hardware_id == 'imu_link'
    assert fed['input checks'].level != STALE
    n = len(reports)
    assert wait_for(lambda: len(reports) > n + 1, 10.0)  # a whole period without input
    idle = reports.snapshot()[-1]['imu input']
    assert (idle.level, idle.message) == (WARN, 'no IMU input in the last period')
    assert idle.hardware_id == 'imu_link'
    test.destroy_node()
