"""The input stage: every decision about IMU and odometry input, once per stream (no ROS import).

``stage.InputStage`` is the entry point; it hands the accepted samples to the pipelines of
``railgsa_ros.inverse``, which only filter.
"""
