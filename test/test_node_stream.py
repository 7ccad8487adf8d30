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

RATE = 1000.0
G = 9.80665
BIAS_UG = (20.0, -30.0, 50.0)
# Configured IEEE 1293 bias plus the thermal zero bias at the constant 25 degC ambient.
# What the node's drawn unit (seed 1) outputs level and rolled 90 degrees at 25 degC.
LEVEL = unit_output((0.0, 0.0, 9.80665), bias_ug=BIAS_UG)
ROLLED = unit_output((0.0, 9.80665, 0.0), bias_ug=BIAS_UG)


@pytest.fixture(scope='module')
def setup(tmp_path_factory):
    directory = tmp_path_factory.mktemp('stream')
    domain = domain_id('stream')
    node = NodeProcess(domain, directory, {
        'sample_rate_hz': RATE, 'qos.depth': 10000, 'model.bias_ug': list(BIAS_UG),
        'state_file': str(directory / 'state.json'), 'trace_dir': str(directory / 'traces'),
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
    client.spin_until(lambda: len(imu.samples) > 100, 60, 'the first samples')
    imu.clear()
    client.spin_for(10.0)
    stamps = np.array([s[0] for s in imu.samples], dtype=np.int64)
    accel = np.array([s[1:] for s in imu.samples])
    expected = (stamps[-1] - stamps[0]) * RATE / 1e9 + 1
    # The window is wall time: a subscriber running late drains a backlog into it.
    assert len(stamps) == pytest.approx(10.0 * RATE, rel=0.2)
    assert abs(len(stamps) - expected) <= 1, 'samples lost between the first and the last'
    spacing = np.diff(stamps)
    assert np.max(np.abs(spacing - 1e9 / RATE)) <= 1000, 'stamps not evenly spaced'

    message = imu.last_message
    assert message.header.frame_id == 'qfa_imu'
    assert message.orientation_covariance[0] == -1.0
    assert message.angular_velocity_covariance[0] == -1.0
    covariance = np.asarray(message.linear_acceleration_covariance).reshape(3, 3)
    assert np.all(np.diag(covariance) > 0)
    assert np.count_nonzero(covariance - np.diag(np.diag(covariance))) == 0
    # Per-sample scatter matches the advertised variance (white noise dominates).
    assert accel[:, 0].var() == pytest.approx(covariance[0, 0], rel=0.3)

    mean = accel.mean(axis=0)
    margin = 5 * math.sqrt(covariance[0, 0] / len(accel)) + 10e-6 * G
    assert np.all(np.abs(mean - LEVEL) < margin)

    assert 80 <= len(temperatures) <= 120
    assert temperatures[-1].header.frame_id == 'qfa_imu'
    readings = np.array([t.temperature for t in temperatures])
    # The on-board sensor's reading: 0.02 degC rms noise, 0.004 degC steps.
    assert readings.mean() == pytest.approx(25.0, abs=0.01)
    assert readings.std() == pytest.approx(math.sqrt(temperatures[-1].variance), rel=0.3)
    assert np.diff(np.array([t.header.stamp.sec * 10**9 + t.header.stamp.nanosec
                             for t in temperatures])).min() == 100_000_000
    assert 8 <= len(diagnostics) <= 12, 'diagnostics not at about 1 Hz'
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


def test_orientation_changes_the_running_sensor_at_once(setup):
    client, imu = setup['client'], setup['imu']
    result, = client.set_parameters({'input.roll': math.pi / 2})
    assert result.successful, result.reason
    # The loops follow a 1 g step within a few ms; skip those samples.
    mean = mean_accel(client, imu, 500, settle_s=0.05)
    assert mean[1] == pytest.approx(ROLLED[1], abs=2e-3)
    assert mean[2] == pytest.approx(ROLLED[2], abs=2e-3)
    result, = client.set_parameters({'input.roll': 0.0})
    assert result.successful


def test_sigterm_closes_the_recording_cleanly(setup):
    status = setup['node'].stop(signal.SIGTERM)
    assert status == 0, setup['node'].log()
    files = sorted((setup['directory'] / 'recordings').glob('*.mcap'))
    assert files, setup['node'].log()
    with AnyReader(files) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts['/imu/data_raw'] > 10000
        assert counts['/imu/temperature'] > 100
        assert counts['/diagnostics'] >= 10
        connection = next(c for c in reader.connections if c.topic == '/imu/data_raw')
        _, _, raw = next(reader.messages(connections=[connection]))
        message = reader.deserialize(raw, connection.msgtype)
        assert message.header.frame_id == 'qfa_imu'
    assert not list((setup['directory'] / 'recordings').glob('*.part'))


@pytest.mark.parametrize('parameters, words', [
    ({'sample_rate_hz': -1000.0}, 'sample_rate_hz'),
    ({'sample_rate_hz': 3000.0, 'loop_rate_hz': 10000.0}, 'integer multiple'),
])
def test_invalid_start_parameters_stop_the_node_with_the_reason(tmp_path, parameters, words):
    node = NodeProcess(domain_id('start' + str(parameters)), tmp_path, parameters)
    status = node.wait(60)
    assert status == 2
    assert words in node.log()
