"""Installer health check, ROS-free: IMU, odometry and node checks on collected samples.

``railgsa_ros.nodes.health_check`` collects an :class:`Observation` on a live system;
:func:`checklist` turns it into PASS/WARN/FAIL items (see docs/check.md).
"""

from railgsa_ros.health.checklist import Observation, checklist
from railgsa_ros.health.items import FAIL, PASS, WARN, Item, exit_code, format_items, items_json

__all__ = ['FAIL', 'PASS', 'WARN', 'Item', 'Observation', 'checklist', 'exit_code',
           'format_items', 'items_json']
