"""Bag replay and recording core (no ROS): opening bags, selection, remapping, pacing, QoS and
the split MCAP writer used by the recorder node."""
