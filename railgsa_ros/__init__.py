"""railgsa_ros: track irregularity from car-body acceleration, with uncertainty and sensitivity.

The numerical core (vehicle model, simulation, inversion, UQ) imports no ROS package; the ROS 2
nodes in ``railgsa_ros.nodes`` are thin adapters over it.
"""

__version__ = '0.1.0'
