"""
Start one emulated QFA IMU with the shipped parameters.

``ros2 launch qfa_ros qfa.launch.py [namespace:=imu1] [params_file:=my.yaml]
[node_name:=qfa_node]``: the node ``qfa_node`` of package ``qfa_ros`` in ``namespace``,
with ``config/qfa.yaml`` (or ``params_file``). Its topics follow the namespace
(``/imu1/imu/data_raw``); ``/diagnostics`` stays global, as diagnostic aggregators expect.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description():
    """Return the launch description: the arguments and the node."""
    default_params = os.path.join(get_package_share_directory('qfa_ros'), 'config', 'qfa.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='',
                              description='Namespace of the node and its topics'),
        DeclareLaunchArgument('node_name', default_value='qfa_node',
                              description='Node name (the parameters file is keyed by it; '
                                          'the shipped one uses /**)'),
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='Parameters file (default: the shipped qfa.yaml)'),
        Node(package='qfa_ros', executable='qfa_node', name=LaunchConfiguration('node_name'),
             namespace=LaunchConfiguration('namespace'),
             parameters=[LaunchConfiguration('params_file')], output='screen',
             emulate_tty=True),
    ])
