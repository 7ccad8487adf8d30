"""
Reports: figures drawn from this project's bags (matplotlib, no ROS).

It may import ``qfa_ros.bag`` and the layers below it; nothing imports it but the
command-line tools.
"""
