"""
Bags: rosbag2-compatible MCAP writing and reading, without ROS.

The MCAP writer (atomic part files, QoS metadata), message definitions, batch CDR
encoding of ``sensor_msgs/Imu``, estimation traces, the flight recorder, scenario bags
and the bag source that replay reads. It may import ``qfa_ros.calibration`` (results
to write) and the model's public constants and outputs, mcap and numpy; never rclpy.
"""
