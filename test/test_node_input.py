"""Ground-truth topic input: the loops measure it; bad and stale input never propagate."""

import math
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import AccelStamped
from node_helpers import (
    Client,
    domain_id,
    ImuCollector,
    mean_accel,
    NodeProcess,
    unit_output,
)
import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy

INPUT = (1.0, -2.0, 9.0)


class GroundTruth:
    """Publish AccelStamped at 200 Hz, stamped with the clock, like a simulator would."""

    def __init__(self, client):
        self.node = client.node
        self.value = INPUT
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.publisher = self.node.create_publisher(AccelStamped, '/input/accel', qos)
        self.timer = self.node.create_timer(0.005, self.timer_callback)

    def timer_callback(self):
        message = AccelStamped()
        message.header.stamp = self.node.get_clock().now().to_msg()
        message.accel.linear.x, message.accel.linear.y, message.accel.linear.z = self.value
        self.publisher.publish(message)


def input_status(diagnostics):
    return next(s for s in diagnostics[-1].status if s.name.endswith('input'))


def rejections(diagnostics):
    return {kv.key: kv.value for kv in input_status(diagnostics).values}


@pytest.fixture(scope='module')
def setup(tmp_path_factory):
    directory = tmp_path_factory.mktemp('input')
    domain = domain_id('input')
    node = NodeProcess(domain, directory, {
        'qos_overrides./imu/data_raw.publisher.depth': 1000,
        'input.mode': 'topic', 'input.topic_type': 'accel',
        'input.timeout_s': 0.2, 'state_file': str(directory / 'state.json'),
        'output_dir': str(directory), 'trace_dir': str(directory / 'traces')})
    client = Client(domain)
    imu = ImuCollector(client)
    diagnostics = []
    client.subscribe(DiagnosticArray, '/diagnostics', diagnostics.append, depth=10)
    yield {'node': node, 'client': client, 'imu': imu, 'diagnostics': diagnostics}
    client.close()
    node.stop(signal.SIGKILL)


def test_stream_pauses_until_ground_truth_arrives(setup):
    client, diagnostics = setup['client'], setup['diagnostics']
    client.spin_until(lambda: diagnostics, 60, 'diagnostics')
    status = input_status(diagnostics)
    assert status.level == DiagnosticStatus.WARN
    assert 'no ground-truth input yet' in status.message
    assert not setup['imu'].samples


def test_loops_measure_the_ground_truth_and_reject_non_finite_input(setup):
    client, imu, diagnostics = setup['client'], setup['imu'], setup['diagnostics']
    truth = GroundTruth(client)
    client.spin_until(lambda: len(imu.samples) > 50, 60, 'samples from the topic input')
    mean = mean_accel(client, imu, 500, settle_s=0.2)
    assert mean == pytest.approx(unit_output(INPUT), abs=2e-3)

    truth.value = (math.nan, 0.0, math.inf)
    imu.clear()
    diagnostics.clear()
    # Bad input until the node's diagnostics report it rejected (no fixed wait).
    client.spin_until(lambda: diagnostics and int(rejections(diagnostics)['rejected inputs']),
                      60, 'the rejection of the non-finite input')
    assert 'non-finite' in rejections(diagnostics)['last rejection']
    truth.value = INPUT
    count = len(imu.samples)
    client.spin_until(lambda: len(imu.samples) > count + 300, 60, 'samples after the bad input')
    assert np.all(np.isfinite(np.array(imu.samples)))

    truth.timer.cancel()
    diagnostics.clear()
    client.spin_until(lambda: diagnostics and 'stale' in input_status(diagnostics).message,
                      60, 'the stale-input diagnosis')
    # Samples stamped before the diagnosis may still be on their way; later ones must not come.
    imu.clear(time.time_ns())
    client.spin_for(0.5)
    assert not imu.samples, 'samples published from a stale input'
