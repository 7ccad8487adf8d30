"""Process-wide interpreter settings: the qfa_node entry point's, never an in-process node's."""

import gc
import subprocess
import sys
import threading

from node_helpers import domain_id
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu

from qfa_ros.cli.node import SWITCH_INTERVAL_S


def test_an_in_process_node_leaves_the_interpreter_settings_alone(tmp_path):
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from qfa_ros.ros.node import QfaNode

    switch_interval, frozen = sys.getswitchinterval(), gc.get_freeze_count()
    context = Context()
    rclpy.init(context=context, domain_id=domain_id('in-process settings'))
    node = QfaNode(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(tmp_path)), Parameter('state_file', value=''),
        Parameter('sample_rate_hz', value=100.0)])
    listener = Node('qfa_settings_listener', context=context)
    executor = SingleThreadedExecutor(context=context)
    try:
        received = threading.Event()
        listener.create_subscription(Imu, 'imu/data_raw', lambda message: received.set(),
                                     qos_profile_sensor_data)
        executor.add_node(listener)
        executor.add_node(node)
        # The sensor thread has warmed up and run its first batch once a sample arrives:
        # the points where the qfa_node process changes its interpreter settings.
        for _ in range(600):
            executor.spin_once(timeout_sec=0.1)
            if received.is_set():
                break
        assert received.is_set(), 'no sample from the in-process node'
        assert sys.getswitchinterval() == switch_interval
        assert gc.get_freeze_count() == frozen
    finally:
        executor.shutdown()
        node.close()
        listener.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_the_process_tuning_sets_the_switch_interval_and_freezes_the_start_up_objects():
    # In a process of its own: the settings are process-wide.
    script = ('import gc, sys\n'
              'from qfa_ros.cli.node import ProcessTuning\n'
              'before = sys.getswitchinterval()\n'
              'tuning = ProcessTuning()\n'
              'tuning.warmed()\n'
              'tuning.streaming()\n'
              'print(before, sys.getswitchinterval(), gc.get_freeze_count())\n')
    result = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    before, after, frozen = result.stdout.split()
    assert float(before) == 0.005
    assert float(after) == pytest.approx(SWITCH_INTERVAL_S, rel=1e-6)  # kept in whole us
    assert int(frozen) > 1000
