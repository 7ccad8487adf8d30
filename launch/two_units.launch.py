"""
Start two emulated QFA IMUs, ``/imu_a/qfa_node`` and ``/imu_b/qfa_node``.

``ros2 launch qfa_ros two_units.launch.py``: :file:`qfa.launch.py` twice, in namespaces
``imu_a`` and ``imu_b``, with the shipped parameters and, per unit, its own seed (two
units are two draws), ``hardware_id`` (diagnostics tell them apart), ``frame_id`` and
calibration state file.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch_ros.actions import Node

from launch import LaunchDescription

UNITS = (('imu_a', 1), ('imu_b', 2))


def generate_launch_description():
    """Return the launch description: one node per unit."""
    params = os.path.join(get_package_share_directory('qfa_ros'), 'config', 'qfa.yaml')
    return LaunchDescription([
        Node(package='qfa_ros', executable='qfa_node', name='qfa_node', namespace=unit,
             parameters=[params, {
                 'seed': seed, 'hardware_id': f'qfa_triad_{unit}', 'frame_id': f'{unit}_link',
                 'state_file': f'~/.ros/qfa_ros/calibration_{unit}.json'}],
             output='screen', emulate_tty=True)
        for unit, seed in UNITS
    ])
