"""Bag replay and recording core (no ROS): opening bags, selection, remapping, pacing and
the split MCAP writer used by the recorder node."""
