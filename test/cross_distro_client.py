"""
A client of one distribution against a node of another, run as a script by any venv's python.

``python test/cross_distro_client.py DOMAIN`` talks to ``/qfa_node`` on ``DOMAIN`` through
this interpreter's rclpy and prints one JSON object: which distribution the client is, the
stamps of the samples a ``SensorDataQoS`` subscriber got, what a late subscriber of the
latched ``~/is_calibrated`` got, a service's answer, and the parameters set and read back
(one change accepted, one refused with its reason). ``test/test_distributions.py`` runs it
with the Jazzy and the Kilted venv's python, each against the other's node.
"""

import json
import math
import sys

from node_helpers import Client
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu
from std_msgs.msg import Bool
from std_srvs.srv import SetBool

from qfa_ros.ros.distro import ros_distribution

SAMPLES = 300
"""Samples the best-effort subscriber waits for."""


def exchange(domain, timeout=60.0):
    """Return what this client got from ``/qfa_node`` on ``domain`` (see the module)."""
    client = Client(domain)
    try:
        stamps = []
        client.node.create_subscription(
            Imu, '/imu/data_raw',
            lambda m: stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
            qos_profile_sensor_data)
        client.spin_until(lambda: len(stamps) >= SAMPLES, timeout, f'{SAMPLES} samples')
        latched = []
        client.subscribe(Bool, '/qfa_node/is_calibrated', lambda m: latched.append(m.data),
                         latched=True)
        client.spin_until(lambda: latched, timeout, 'the latched ~/is_calibrated')
        answer = client.call(SetBool, '/qfa_node/set_compensation', SetBool.Request(data=True),
                             timeout)
        accepted = client.set_parameters({'drift.feedback_ppm': [200.0, -150.0, 300.0]})
        refused = client.set_parameters({'drift.feedback_ppm': [math.nan, 0.0, 0.0]})
        read = client.get_parameters(['drift.feedback_ppm', 'sample_rate_hz'])
        return {
            'client': ros_distribution(),
            'stamps': stamps[:SAMPLES],
            'latched': latched[0],
            'service': [answer.success, answer.message],
            'accepted': [accepted[0].successful, accepted[0].reason],
            'refused': [refused[0].successful, refused[0].reason],
            'read': [list(read[0]), read[1]],
        }
    finally:
        client.close()


if __name__ == '__main__':
    print(json.dumps(exchange(int(sys.argv[1]))))
