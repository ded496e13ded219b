"""ROS 2 nodes (thin adapters over the core) and the helpers they share."""
