"""
ROS 2: the node and its collaborators, the only place rclpy is imported.

The node (``QfaNode``) wires small parts: parameters and their validation, the sample
stream (sensor thread, grid, publishing), the schedule runner, ground-truth input,
diagnostics, the calibration-state store, the flight recorder hook and the bounds a
stray participant cannot exceed; plus the Fast
DDS profile and the bag replay publisher. It may import every layer below it
(``bag``, ``calibration``, ``model``).
"""
