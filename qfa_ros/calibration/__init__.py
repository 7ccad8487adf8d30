"""
Calibration: what the sensor does to estimate and correct itself.

The forward- and feedback-gain self-estimation schedules of Ran et al. 2019, the persisted
calibration state, Liu, Li and Shen's double-exponential temperature fit and its fixed-point
CORDIC evaluation, the paper experiment and the Monte Carlo studies, and Kalibr's
``imu.yaml`` (the noise calibration a VIO/INS tool takes). It may import the sensor model
(``qfa_ros.model``), numpy, scipy, PyYAML and tqdm (progress bars); never ROS, never a bag
format.
"""
