"""The node's stream over real DDS: every sample, REP-145, diagnostics, parameters, shutdown."""

import math
import signal

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
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
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import Temperature
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from qfa_ros.bag.reader import BagSource
from qfa_ros.model.earth import EARTH_RATE, normal_gravity
from qfa_ros.model.noise import flicker_component_variance, NoiseConfig

RATE = 1000.0
LATITUDE = math.radians(45.0)  # the default latitude_deg
G = float(normal_gravity(LATITUDE))
STREAM_S = 7.0
"""Seconds of stream the first test judges (10 until issue 44; no sample lost over 60 s
windows and a 600 s soak: ``bench/node_rate.py``, bench/results/node_rate.md). Its 70
on-board temperature readings (0.02 degC rms, white) hold their mean to 25 degC within
0.01 (4.2 sigma: a 0.02 degC offset fails it but in 1e-5 of runs) and their scatter to the
advertised variance within 30 % (3.5 standard errors); a correct node fails the two in
about 4e-4 of runs (at 10 s: 3e-5)."""
BIAS_UG = (20.0, -30.0, 50.0)  # integral: typed as integers below
# Configured IEEE 1293 bias plus the thermal zero bias at the constant 25 degC ambient.
# What the node's drawn unit (Ran et al. 2019) outputs level and rolled 90 degrees at 25 degC.
LEVEL = unit_output((0.0, 0.0, G), bias_ug=BIAS_UG)
ROLLED = unit_output((0.0, G, 0.0), bias_ug=BIAS_UG)


def stamp_ns(message):
    return message.header.stamp.sec * 10**9 + message.header.stamp.nanosec


@pytest.fixture(scope='module')
def setup(tmp_path_factory):
    directory = tmp_path_factory.mktemp('stream')
    domain = domain_id('stream')
    node = NodeProcess(domain, directory, {
        # Integers, as users type them: converted to doubles at start-up.
        'sample_rate_hz': RATE, 'qos_overrides./imu/data_raw.publisher.depth': 10000,
        'model.bias_ug': [int(b) for b in BIAS_UG],
        'state_file': str(directory / 'state.json'), 'output_dir': str(directory),
        'trace_dir': str(directory / 'traces'),
        'recorder.enabled': True, 'recorder.directory': str(directory / 'recordings'),
        'frame_id': 'qfa_imu'})
    client = Client(domain)
    # 10 s of history on both sides: a test process starved by a busy machine catches up.
    imu = ImuCollector(client, depth=10000)
    yield {'node': node, 'client': client, 'imu': imu, 'directory': directory}
    client.close()
    node.stop(signal.SIGKILL)


def test_stream_delivers_every_sample_evenly_spaced(setup):
    client, imu = setup['client'], setup['imu']
    temperatures, diagnostics, calibrated = [], [], []
    client.subscribe(Temperature, 'imu/temperature', temperatures.append)
    client.subscribe(DiagnosticArray, '/diagnostics', diagnostics.append, depth=10)
    client.subscribe(Bool, '/qfa_node/is_calibrated', calibrated.append, latched=True)
    client.spin_until(lambda: len(imu.samples) > 100 and calibrated, 60, 'the first samples')
    imu.clear()
    # Diagnostics come from the start, samples once the model is warm: count from here.
    temperatures.clear()
    diagnostics.clear()
    # STREAM_S of stream by its stamps: a busy machine may deliver them slower than that.
    client.spin_until(lambda: len(imu.samples) >= STREAM_S * RATE, 60,
                      f'{STREAM_S:g} s of samples',
                      progress=lambda: len(imu.samples))
    stamps = np.array([s[0] for s in imu.samples], dtype=np.int64)
    accel = np.array([s[1:] for s in imu.samples])
    expected = (stamps[-1] - stamps[0]) * RATE / 1e9 + 1
    assert abs(len(stamps) - expected) <= 1, 'samples lost between the first and the last'
    spacing = np.diff(stamps)
    assert np.max(np.abs(spacing - 1e9 / RATE)) <= 1000, 'stamps not evenly spaced'

    message = imu.last_message
    assert message.header.frame_id == 'qfa_imu'
    assert message.orientation_covariance[0] == -1.0
    # The gyros see the Earth rate: level, x east (input.yaw 0), y north at 45 deg.
    rate_covariance = np.asarray(message.angular_velocity_covariance).reshape(3, 3)
    assert np.all(np.diag(rate_covariance) > 0)
    sigma = math.sqrt(rate_covariance[0, 0])
    rate = message.angular_velocity
    expected = (0.0, EARTH_RATE * math.cos(LATITUDE), EARTH_RATE * math.sin(LATITUDE))
    assert np.all(np.abs(np.array([rate.x, rate.y, rate.z]) - expected) < 6 * sigma + 1e-7)
    covariance = np.asarray(message.linear_acceleration_covariance).reshape(3, 3)
    assert np.all(np.diag(covariance) > 0)
    assert np.count_nonzero(covariance - np.diag(np.diag(covariance))) == 0
    # Per-sample scatter matches the advertised variance (white noise dominates).
    assert accel[:, 0].var() == pytest.approx(covariance[0, 0], rel=0.3)

    mean = accel.mean(axis=0)
    # The bias-instability process barely averages over seconds: three of its stationary
    # standard deviations on top of the white noise of the mean.
    noise = NoiseConfig()
    bias_std = math.sqrt(flicker_component_variance(noise) * len(noise.correlation_times))
    margin = 5 * math.sqrt(covariance[0, 0] / len(accel)) + 3 * bias_std
    assert np.all(np.abs(mean - LEVEL) < margin)

    assert len(temperatures) >= 20
    assert temperatures[-1].header.frame_id == 'qfa_imu'
    readings = np.array([t.temperature for t in temperatures])
    # The on-board sensor's reading: 0.02 degC rms noise, 0.004 degC steps.
    assert readings.mean() == pytest.approx(25.0, abs=0.01)
    assert readings.std() == pytest.approx(math.sqrt(temperatures[-1].variance), rel=0.3)
    # 10 Hz on the sample grid, none lost; diagnostics at 1 Hz by their stamps.
    assert set(np.diff([stamp_ns(t) for t in temperatures])) == {100_000_000}
    assert len(diagnostics) >= 3
    assert np.median(np.diff([stamp_ns(d) for d in diagnostics])) == \
        pytest.approx(1e9, rel=0.1), 'diagnostics not at about 1 Hz'
    statuses = {s.name.split(': ')[-1]: s for s in diagnostics[-1].status}
    assert set(statuses) == {'stream', 'calibration', 'temperature', 'input'}
    stream = statuses['stream']
    assert stream.level == DiagnosticStatus.OK
    assert {'loop x': 'closed', 'saturated samples z': '0'}.items() <= \
        {kv.key: kv.value for kv in stream.values}.items()
    assert statuses['calibration'].level == DiagnosticStatus.WARN
    assert 'no reference' in statuses['calibration'].message
    assert 'uncompensated' in statuses['temperature'].message
    assert calibrated and calibrated[-1].data is False


@pytest.mark.parametrize('name, value, words', [
    ('drift.forward_ppm', [math.nan, 0.0, 0.0], 'finite'),
    ('drift.feedback_ppm', [100.0, 200.0], 'exactly 3'),
    ('drift.aging_feedback_ppm_per_year', [1.0, 2.0, 3.0, 4.0], 'exactly 3'),
    ('input.mode', 'flying', 'one of'),
    ('estimation.forward.points', 1, 'estimation.forward.points'),
    ('sample_rate_hz', -1000.0, 'read-only'),
    ('loop_rate_hz', 2500.0, 'read-only'),
])
def test_invalid_parameter_changes_are_rejected_with_the_reason(setup, name, value, words):
    result, = setup['client'].set_parameters({name: value})
    assert not result.successful
    assert words in result.reason


def test_integer_arrays_are_accepted_as_doubles_and_validated(setup):
    client = setup['client']
    assert client.get_parameters(['model.bias_ug']) == [list(BIAS_UG)]
    result, = client.set_parameters({'drift.feedback_ppm': [1, 2, 3]})
    assert result.successful, result.reason
    value, = client.get_parameters(['drift.feedback_ppm'])
    assert value == [1.0, 2.0, 3.0] and all(type(v) is float for v in value)
    result, = client.set_parameters({'drift.feedback_ppm': [1, 2, 10 ** 9]})
    assert not result.successful and 'must be in' in result.reason
    result, = client.set_parameters({'drift.feedback_ppm': [0, 0, 0]})
    assert result.successful, result.reason


def test_a_moving_sensor_refuses_self_estimation(setup):
    client = setup['client']
    results = client.set_parameters({'input.trajectory': 'rate-table',
                                      'input.mode': 'trajectory'})
    assert all(result.successful for result in results), results
    try:
        response = client.call(Trigger, '/qfa_node/capture_reference', Trigger.Request())
        assert not response.success
        assert 'moving' in response.message and 'rest' in response.message
    finally:
        result, = client.set_parameters({'input.mode': 'static'})
        assert result.successful


def test_orientation_changes_the_running_sensor_at_once(setup):
    client, imu = setup['client'], setup['imu']
    result, = client.set_parameters({'input.roll': math.pi / 2})
    assert result.successful, result.reason
    # The loops follow a 1 g step within a few ms; skip those samples.
    mean = mean_accel(client, imu, 500, settle_s=0.2)
    assert mean[1] == pytest.approx(ROLLED[1], abs=2e-3)
    assert mean[2] == pytest.approx(ROLLED[2], abs=2e-3)
    result, = client.set_parameters({'input.roll': 0.0})
    assert result.successful


def test_sigterm_closes_the_recording_cleanly(setup):
    status = setup['node'].stop(signal.SIGTERM)
    assert status == 0, setup['node'].log()
    files = sorted((setup['directory'] / 'recordings').glob('*/*.mcap'))
    assert files, setup['node'].log()
    with AnyReader(files) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        # The node's whole run: more than the STREAM_S the first test took.
        assert counts['/imu/data_raw'] > STREAM_S * RATE
        assert counts['/imu/temperature'] > STREAM_S * 10
        assert counts['/diagnostics'] >= STREAM_S
        # The truth an INS developer replays the recording against (truth.rate_hz 10 Hz).
        assert counts['/truth/imu_errors'] > 50 and counts['/truth/odometry'] > 50
        assert counts['/truth/origin'] >= 1  # and again at each new input (orientation)
        # Latched ~/is_calibrated, as published at start: what the unit said at replay.
        assert counts['/qfa_node/is_calibrated'] >= 1
        connection = next(c for c in reader.connections if c.topic == '/imu/data_raw')
        _, _, raw = next(reader.messages(connections=[connection]))
        message = reader.deserialize(raw, connection.msgtype)
        assert message.header.frame_id == 'qfa_imu'
    assert not list((setup['directory'] / 'recordings').glob('**/*.part'))
    bag, = files[0].parent.parent.iterdir()
    assert (bag / 'metadata.yaml').exists()
    # The recording states the QoS the publisher offered, its override included.
    offered = BagSource(files[0]).topics['/imu/data_raw'].offered_qos
    assert [(q['history'], q['depth'], q['reliability']) for q in offered] == \
        [('keep_last', 10000, 'reliable')]
    # A late subscriber of the replayed origin still gets it: latched as published.
    origin, = BagSource(files[0]).topics['/truth/origin'].offered_qos
    assert (origin['durability'], origin['depth']) == ('transient_local', 1)


INVALID_STARTS = [
    ({'sample_rate_hz': -1000.0}, 'sample_rate_hz'),
    ({'sample_rate_hz': 3000.0, 'loop_rate_hz': 10000.0}, 'integer multiple'),
]


def test_invalid_start_parameters_stop_the_node_with_the_reason(tmp_path):
    # One real start (the process's exit path); each refusal's reason in process below.
    parameters, words = INVALID_STARTS[0]
    node = NodeProcess(domain_id('start' + str(parameters)), tmp_path, parameters)
    status = node.wait(60)
    assert status == 2
    assert words in node.log()
    assert '[FATAL]' in node.log(), 'not through the ROS logger'


@pytest.mark.parametrize('parameters, words', INVALID_STARTS)
def test_invalid_start_parameters_are_refused_by_the_node_with_the_reason(
        tmp_path, parameters, words):
    # What the process above reports: the ValueError of the node's constructor (qfa_node
    # turns it into status 2 and one [FATAL] line).
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from qfa_ros.ros.node import QfaNode

    context = Context()
    rclpy.init(context=context, domain_id=domain_id('start in process'))
    try:
        with pytest.raises(ValueError, match=words):
            QfaNode(context=context, parameter_overrides=[
                Parameter('output_dir', value=str(tmp_path)), Parameter('state_file', value=''),
                *(Parameter(name, value=value) for name, value in parameters.items())])
    finally:
        rclpy.try_shutdown(context=context)
