"""rosbag2 input and output (rosbags and mcap; no ROS installation needed).

``write_run``/``read_imu`` move simulated runs and IMU streams in and out of bags, ``BagWriter``
writes arbitrary standard messages, ``read_messages`` iterates any bag.
"""

from railgsa_ros.bag.reader import (
    ImuStream,
    TopicData,
    TopicSummary,
    open_bag,
    read_imu,
    read_messages,
    read_stamped,
    summarize,
)
from railgsa_ros.bag.run import IMU_TOPIC, ODOM_TOPIC, TRUTH_TOPIC, RunEncoder, write_run
from railgsa_ros.bag.writer import BagWriter

__all__ = ['IMU_TOPIC', 'ODOM_TOPIC', 'TRUTH_TOPIC', 'BagWriter', 'ImuStream', 'RunEncoder',
           'TopicData', 'TopicSummary', 'open_bag', 'read_imu', 'read_messages', 'read_stamped',
           'summarize', 'write_run']
