"""
Bring two emulated QFA IMUs up as managed nodes, configure them in order, activate them together.

``ros2 launch qfa_ros managed_units.launch.py``: ``qfa_lifecycle_node`` in namespaces
``imu_a`` and ``imu_b`` (the units, seeds and files of :file:`two_units.launch.py`), both
starting unconfigured. ``imu_a`` is configured first, ``imu_b`` once ``imu_a`` is
inactive, and once ``imu_b`` is inactive too both are activated at once, so neither
publishes before both are configured (the order of nav2's lifecycle_manager). A unit whose
configure fails stays unconfigured (its log says why) and nothing is activated; each
handler fires once, so a later ``deactivate`` is not undone by the launch file.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import EmitEvent, RegisterEventHandler
from launch.events import matches_action
from launch_ros.actions import LifecycleNode
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from lifecycle_msgs.msg import Transition

from launch import LaunchDescription

UNITS = (('imu_a', 1), ('imu_b', 2))


def change_state(node, transition_id):
    """Return the action asking ``node`` (a ``LifecycleNode`` action) for a transition."""
    return EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(node),
                                       transition_id=transition_id))


def generate_launch_description():
    """Return the launch description: two managed units and the order of their transitions."""
    params = os.path.join(get_package_share_directory('qfa_ros'), 'config', 'qfa.yaml')
    first, second = nodes = [
        LifecycleNode(package='qfa_ros', executable='qfa_lifecycle_node', name='qfa_node',
                      namespace=unit, parameters=[params, {
                          'seed': seed, 'hardware_id': f'qfa_triad_{unit}',
                          'frame_id': f'{unit}_link',
                          'state_file': f'~/.ros/qfa_ros/calibration_{unit}.json'}],
                      output='screen', emulate_tty=True)
        for unit, seed in UNITS]
    return LaunchDescription([
        *nodes,
        RegisterEventHandler(OnStateTransition(
            target_lifecycle_node=first, goal_state='inactive', handle_once=True,
            entities=[change_state(second, Transition.TRANSITION_CONFIGURE)])),
        RegisterEventHandler(OnStateTransition(
            target_lifecycle_node=second, goal_state='inactive', handle_once=True,
            entities=[change_state(node, Transition.TRANSITION_ACTIVATE) for node in nodes])),
        change_state(first, Transition.TRANSITION_CONFIGURE),
    ])
