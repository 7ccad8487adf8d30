"""
Calibration: what the sensor does to estimate and correct itself.

The forward- and feedback-gain self-estimation schedules of seed 1, the persisted
calibration state, seed 2's double-exponential temperature fit and its fixed-point
CORDIC evaluation, the paper experiment and the Monte Carlo studies. It may import the
sensor model (``qfa_ros.model``), numpy and scipy; never ROS, never a bag format.
"""
