"""The node's truth for INS developers over real DDS: pose, origin, errors, events."""

import math
from pathlib import Path
import signal
import time

from diagnostic_msgs.msg import DiagnosticStatus
from nav_msgs.msg import Odometry
from node_helpers import Client, domain_id, ImuCollector, NodeProcess
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, NavSatFix
from std_srvs.srv import SetBool, Trigger

from qfa_ros.bag.qos import QOS_TRUTH
from qfa_ros.model import motion_scripts, trajectory
from qfa_ros.model.constants import MICRO_G
from qfa_ros.ros.parameter_table import PARAMETERS as PARAMETERS_TABLE
from qfa_ros.ros.service_table import SERVICES
from qfa_ros.ros.topic_table import PUBLISHER, TOPICS

NODE = '/qfa_node'
ROOT = Path(__file__).resolve().parents[1]
ROLL, PITCH, YAW = 0.4, -0.3, 1.1
FEEDBACK_PPM = [800.0, -600.0, 1000.0]
IMU_DEPTH = 1000
PARAMETERS = {'thermal.ambient_profile': 'constant', 'truth.rate_hz': 20.0,
              'input.roll': ROLL, 'input.pitch': PITCH, 'input.yaw': YAW,
              'estimation.realtime': False, 'estimation.feedback.cycles': 1,
              'estimation.feedback.settle_s': 0.2, 'estimation.feedback.average_s': 1.0,
              'qos_overrides./imu/data_raw.publisher.depth': IMU_DEPTH}


PARAMETER_SERVICES = ('/describe_parameters', '/get_parameter_types', '/get_parameters',
                      '/list_parameters', '/set_parameters', '/set_parameters_atomically',
                      '/get_type_description')
"""The services rclpy gives every node (Kilted adds the type description)."""


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


class Truth:
    """Collect the truth topics and the calibration events of the node."""

    def __init__(self, client):
        self.odometry, self.origin, self.errors, self.events = [], [], [], []
        client.subscribe(Odometry, 'truth/odometry', self.odometry.append)
        client.subscribe(NavSatFix, 'truth/origin', self.origin.append, latched=True)
        client.subscribe(Imu, 'truth/imu_errors', self.errors.append)
        client.node.create_subscription(
            DiagnosticStatus, f'{NODE}/calibration_events', self.events.append,
            QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))


@pytest.fixture(scope='module')
def setup(tmp_path_factory):
    directory = tmp_path_factory.mktemp('truth')
    domain = domain_id('truth')
    parameters = {'state_file': '', 'output_dir': str(directory), **PARAMETERS}
    node = NodeProcess(domain, directory, parameters)
    client = Client(domain)
    imu = ImuCollector(client, depth=1000)
    truth = Truth(client)
    client.spin_until(lambda: imu.samples and truth.origin and len(truth.errors) > 2, 60,
                      'the node and its truth')
    yield {'node': node, 'client': client, 'imu': imu, 'truth': truth}
    client.close()
    node.stop(signal.SIGKILL)


def errors_of(message):
    """Return (bias (3,), N (3, 3), K2 (3,)) of a truth/imu_errors message."""
    a = message.linear_acceleration
    return (np.array([a.x, a.y, a.z]),
            np.array(message.linear_acceleration_covariance).reshape(3, 3),
            np.array(message.orientation_covariance[:3]))


def test_static_truth_pose_and_origin(setup):
    client, truth = setup['client'], setup['truth']
    client.spin_until(lambda: len(truth.odometry) > 3, 30, 'truth/odometry')
    origin = truth.origin[-1]
    assert (origin.latitude, origin.longitude, origin.altitude) == (45.0, 0.0, 0.0)
    assert origin.header.frame_id == 'enu_origin'
    odometry = truth.odometry[-1]
    assert odometry.header.frame_id == 'enu_origin' and odometry.child_frame_id == 'imu_link'
    p, q = odometry.pose.pose.position, odometry.pose.pose.orientation
    assert max(abs(p.x), abs(p.y), abs(p.z)) < 1e-9
    expected = trajectory.dcm_to_quaternion(trajectory.euler_to_dcm(ROLL, PITCH, YAW))
    assert np.allclose([q.x, q.y, q.z, q.w], expected, atol=1e-9)
    # The truth is stamped as a sample of the stream: on the 1 kHz grid of imu/data_raw.
    imu_stamp = setup['imu'].samples[-1][0]
    assert (stamp_ns(odometry.header) - imu_stamp) % 1_000_000 == 0


def test_each_truth_message_is_a_new_sample_instant(setup):
    # The truth timer (20 Hz here) and the sensor thread (a batch every stream.batch_s,
    # 0.1 s) run apart: a tick that finds no new sample must publish nothing, not the last
    # sample's truth again (issue 38: 3 % of the messages repeated stamp and state at the
    # default 10 Hz, half of them at 20 Hz).
    client, truth = setup['client'], setup['truth']
    count = len(truth.odometry)
    client.spin_until(lambda: len(truth.odometry) > count + 40 and len(truth.errors) > 40,
                      60, '40 more truth messages', progress=lambda: len(truth.odometry))
    for topic, messages in (('truth/odometry', truth.odometry),
                            ('truth/imu_errors', truth.errors)):
        stamps = np.array([stamp_ns(m.header) for m in messages])
        assert np.all(np.diff(stamps) > 0), (topic, np.sum(np.diff(stamps) <= 0), len(stamps))
    # docs/ins.md states the truth's QoS by hand (docs/node.md's table is generated).
    assert (QOS_TRUTH.reliability, QOS_TRUTH.depth, QOS_TRUTH.durability) == \
        ('reliable', 10, 'volatile')
    rows = [line for line in (ROOT / 'docs' / 'ins.md').read_text().splitlines()
            if line.startswith('| ') and any(cell.strip() in ('`truth/odometry`',
                                                              '`/truth/odometry`')
                                             for cell in line.split('|')[1:3])]
    assert rows and all('reliable, depth 10' in row for row in rows), rows


def test_the_node_offers_the_topics_and_services_of_its_tables(setup):
    # What the node offers, seen from another participant, is what the topic and service
    # tables say (the interface docs are generated from them): each topic with its type,
    # reliability and durability, none it should not have; every service, and no other.
    # Discovery does not carry the history depth: test_node_params.py compares it in process.
    client = setup['client']
    graph = client.node
    values = {spec.name: spec.default for spec in PARAMETERS_TABLE} | PARAMETERS

    def endpoints(spec):
        name = spec.name.replace('~', NODE) if spec.name.startswith('~') else \
            '/' + spec.name.lstrip('/')
        infos = (graph.get_publishers_info_by_topic if spec.direction == PUBLISHER
                 else graph.get_subscriptions_info_by_topic)(name)
        return [info for info in infos if info.node_name == NODE.lstrip('/')]

    def services():
        return {name: types for name, types in graph.get_service_names_and_types_by_node(
            NODE.lstrip('/'), '/') if not name.endswith(PARAMETER_SERVICES)}

    expected = {f'{NODE}/{spec.call}': [spec.type_name] for spec in SERVICES}
    client.spin_until(lambda: all(endpoints(spec) for spec in TOPICS if spec.offered(values))
                      and services() == expected, 30, 'the node in the graph')
    for spec in TOPICS:
        infos = endpoints(spec)
        if not spec.offered(values):
            assert not infos, spec.name
            continue
        info, = infos
        assert info.topic_type == spec.type_name, spec.name
        qos = info.qos_profile
        assert (qos.reliability.name.lower(), qos.durability.name.lower()) == \
            (spec.qos.reliability, spec.qos.durability), spec.name
    assert services() == expected


def test_error_truth_predicts_the_published_output(setup):
    # The node's drawn unit has a mg turn-on bias, K2 and misalignment: the truth the node
    # publishes, applied to the true specific force, gives the stream's mean within its
    # white noise (the bias-instability state is in the truth).
    client, imu, truth = setup['client'], setup['imu'], setup['truth']
    start = time.time_ns() + 200_000_000
    imu.clear(start)
    client.spin_until(lambda: len(imu.samples) >= 2000, 60, '2000 samples',
                      progress=lambda: len(imu.samples))
    samples = np.array(imu.samples[:2000])
    end = samples[-1, 0]
    client.spin_until(lambda: truth.errors and stamp_ns(truth.errors[-1].header) > end, 30,
                      'the truth of the window')
    window = [m for m in truth.errors if start <= stamp_ns(m.header) <= end]
    # One truth per batch of samples (stream.batch_s 0.1 s: 20 in the 2 s) at most, never
    # one sample's twice; fewer when the machine starves the sensor thread.
    assert len(window) >= 5
    static = motion_scripts.static(45.0, roll=ROLL, pitch=PITCH, yaw=YAW)
    force = static.kinematics(np.zeros(1))['specific_force'][0]
    predicted = []
    for message in window:
        bias, matrix, k2 = errors_of(message)
        predicted.append(bias + (np.eye(3) + matrix) @ force + k2 * force * force)
    mean = samples[:, 1:].mean(axis=0)
    error = mean - force
    assert np.all(np.abs(error) > 50 * MICRO_G)  # the errors are there
    sigma = math.sqrt(imu.last_message.linear_acceleration_covariance[0] / len(samples))
    assert np.all(np.abs(mean - np.mean(predicted, axis=0)) < 6 * sigma + 0.5 * MICRO_G), \
        (mean - np.mean(predicted, axis=0)) / MICRO_G


def test_drift_shows_in_the_truth_and_a_correction_is_an_event(setup):
    client, truth = setup['client'], setup['truth']
    response = client.call(Trigger, f'{NODE}/capture_reference', Trigger.Request())
    assert response.success, response.message
    before = errors_of(truth.errors[-1])[1].diagonal()
    assert all(r.successful for r in client.set_parameters({'drift.feedback_ppm':
                                                            FEEDBACK_PPM}))
    changed = time.time_ns() + 300_000_000
    client.spin_until(lambda: stamp_ns(truth.errors[-1].header) > changed, 30, 'new truth')
    drifted = errors_of(truth.errors[-1])[1].diagonal()
    # The output goes as 1 / k_fb: a feedback drift d is a scale-factor error of -d.
    assert np.allclose((drifted - before) / 1e-6, -np.array(FEEDBACK_PPM), rtol=0.01)
    assert not truth.events
    response = client.call(Trigger, f'{NODE}/estimate_feedback_gain', Trigger.Request())
    assert response.success, response.message
    client.spin_until(lambda: truth.events, 30, 'the calibration event')
    event = truth.events[-1]
    values = {kv.key: kv.value for kv in event.values}
    assert values['kind'] == 'feedback' and event.level == DiagnosticStatus.OK
    steps = np.array([float(values[f'accel_scale_change_ppm_{a}']) for a in 'xyz'])
    # The correction undoes the drift within the schedule's estimate (1 cycle of 1 s).
    assert np.allclose(steps, FEEDBACK_PPM, atol=150.0), steps
    first = int(values['stamp_ns'])
    client.spin_until(lambda: stamp_ns(truth.errors[-1].header) >= first, 30,
                      'the truth after the correction')
    corrected = errors_of(truth.errors[-1])[1].diagonal()
    assert np.all(np.abs(corrected - before) < 150e-6)
    response = client.call(SetBool, f'{NODE}/set_compensation', SetBool.Request(data=False))
    assert response.success, response.message
    client.spin_until(lambda: len(truth.events) == 2, 30, 'the second event')
    values = {kv.key: kv.value for kv in truth.events[-1].values}
    assert values['kind'] == 'set_compensation'
    assert int(values['stamp_ns']) > int({kv.key: kv.value for kv in event.values}[
        'stamp_ns'])


def test_each_correction_is_one_event_even_within_one_tick(setup):
    # The feedback correction of the test before is stored, compensation off. Four
    # switches in a row (milliseconds apart; the truth ticks every 50 ms): four events,
    # each labelled and measured against the one before it, on and off cancelling.
    client, truth = setup['client'], setup['truth']
    count = len(truth.events)
    switches = (True, False, True, False)
    for on in switches:
        response = client.call(SetBool, f'{NODE}/set_compensation', SetBool.Request(data=on))
        assert response.success, response.message
    client.spin_until(lambda: len(truth.events) >= count + len(switches), 30,
                      'one event per switch')
    client.spin_for(0.3)  # a tick or more: no event beyond those
    events = [{kv.key: kv.value for kv in event.values} for event in truth.events[count:]]
    assert len(events) == len(switches), events
    assert [event['kind'] for event in events] == ['set_compensation'] * len(switches)
    steps = np.array([[float(event[f'accel_scale_change_ppm_{a}']) for a in 'xyz']
                      for event in events])
    # On applies the correction (undoing the drift), off takes it back out.
    assert np.allclose(steps[0], FEEDBACK_PPM, atol=150.0), steps
    assert np.allclose(steps[1:], [-steps[0], steps[0], -steps[0]], atol=1.0), steps
    stamps = [int(event['stamp_ns']) for event in events]
    assert stamps == sorted(stamps)


def test_a_new_trajectory_publishes_its_origin(setup):
    client, truth = setup['client'], setup['truth']
    count = len(truth.origin)
    assert all(r.successful for r in client.set_parameters({
        'input.mode': 'trajectory', 'latitude_deg': -20.0, 'longitude_deg': 30.0}))
    client.spin_until(lambda: len(truth.origin) > count and truth.origin[-1].latitude < 0,
                      30, 'the new origin')
    origin = truth.origin[-1]
    assert (origin.latitude, origin.longitude) == pytest.approx((-20.0, 30.0), abs=1e-9)
    # A late subscriber gets it too (transient local).
    late = []
    client.subscribe(NavSatFix, 'truth/origin', late.append, latched=True)
    client.spin_until(lambda: late, 30, 'the latched origin')
    assert late[-1].latitude == pytest.approx(-20.0)
