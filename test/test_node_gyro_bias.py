"""The node's gyro bias calibration at rest (``~/calibrate_gyros``) over real DDS."""

import json
import math
import signal
import time

from node_helpers import Client, counted_after, domain_id, NodeProcess
import numpy as np
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger

from qfa_ros.model.constants import DEG_PER_HOUR

NODE = '/qfa_node'
LATITUDE = math.radians(45.0)  # the default latitude_deg
# Level, x east (input.yaw 0): the Earth rate 15.041 deg/h in the body axes.
EARTH = 15.041 * DEG_PER_HOUR * np.array([0.0, math.cos(LATITUDE), math.sin(LATITUDE)])
MEAN_SAMPLES = 1000
"""Samples of each mean rate (1 s at 1 kHz)."""


def mean_rate(client, rates, count):
    """Return the mean angular velocity of ``count`` samples stamped from now on."""
    rates.clear()
    after = time.time_ns() + 200_000_000  # past the node's 0.1 s computed lead
    counted = counted_after(rates, after, stamp=lambda row: row[0])
    client.spin_until(lambda: counted() >= count, 60,
                      f'{count} gyro samples')
    fresh = [r for s, r in rates if s >= after][:count]
    return np.mean(fresh, axis=0)


def test_gyro_bias_at_rest_is_estimated_and_removed(tmp_path):
    # A unit drawn with a 500 deg/h (1 sigma) turn-on bias: the published mean sits far
    # from the Earth rate; after the call it sits on it within the noise of two short
    # means (ARW 0.002 deg/sqrt(h): 0.12 deg/h per 1 s mean at 1 kHz, the bound 1 deg/h).
    domain = domain_id('gyro_bias')
    state_file = tmp_path / 'state.json'
    node = NodeProcess(domain, tmp_path, {
        'gyro.turn_on_bias_deg_per_hr': 500.0, 'state_file': str(state_file),
        'output_dir': str(tmp_path), 'trace_dir': str(tmp_path / 'traces'),
        'gyro_bias.duration_s': 2.0, 'estimation.realtime': True})
    client = Client(domain)
    try:
        rates = []
        client.subscribe(Imu, 'imu/data_raw', lambda m: rates.append((
            m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec,
            (m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z))))
        before = mean_rate(client, rates, MEAN_SAMPLES)
        assert np.max(np.abs(before - EARTH)) > 100 * DEG_PER_HOUR

        # Moving (a rate-table turn): refused, nothing applied.
        assert client.set_parameters({'input.mode': 'trajectory',
                                      'input.trajectory': 'rate-table'})[0].successful
        refused = client.call(Trigger, f'{NODE}/calibrate_gyros', Trigger.Request())
        assert not refused.success and 'moving' in refused.message, refused.message
        assert client.set_parameters({'input.mode': 'static'})[0].successful

        # While it averages (2 s at the node clock) a second call is refused as busy.
        future = client.call_async(Trigger, f'{NODE}/calibrate_gyros', Trigger.Request())
        busy = client.call(Trigger, f'{NODE}/calibrate_gyros', Trigger.Request())
        assert not busy.success and 'busy: gyro_bias' in busy.message, busy.message
        client.spin_until(future.done, 60, 'the gyro bias calibration')
        response = future.result()
        assert response.success, response.message
        assert 'gyro bias [deg/h]' in response.message and 'Earth rate removed' in response.message

        after = mean_rate(client, rates, MEAN_SAMPLES)
        assert np.max(np.abs(after - EARTH)) < 1.0 * DEG_PER_HOUR, (after - EARTH) / DEG_PER_HOUR
        # Kept in the calibration state file, traced like the other schedules.
        stored = np.array(json.loads(state_file.read_text())['gyro_bias'])
        assert np.allclose(stored, before - EARTH, atol=1.0 * DEG_PER_HOUR)
        assert list((tmp_path / 'traces').glob('qfa_gyro_bias_*.mcap'))
    finally:
        client.close()
        node.stop(signal.SIGKILL)
