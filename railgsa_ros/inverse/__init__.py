"""Streaming inversion of car-body acceleration to vertical track irregularity (no ROS import).

``pipeline.InversionPipeline`` is the entry point; ``config.InversionConfig`` its parameters.
"""
