"""Gyro error terms, the Imu encoding with angular rate, truth bags and the ROS seams."""

import math

from nav_msgs.msg import Odometry
import numpy as np
from numpy.testing import assert_allclose
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import Imu

from qfa_ros.bag.imu_cdr import ImuEncoder
from qfa_ros.calibration.estimation import capture_reference
from qfa_ros.calibration.gyro_bias import earth_rate_body, gyro_bias_schedule, GyroBiasSettings
from qfa_ros.calibration.schedule import EstimationError, run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.cli import sim
from qfa_ros.model import earth
from qfa_ros.model import motion_scripts as tr
from qfa_ros.model.constants import DEG_PER_HOUR, PPM
from qfa_ros.model.gyro import GyroConfig, GyroTriad
from qfa_ros.model.trajectory import dcm_to_quaternion
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig
from qfa_ros.ros.input_queue import GroundTruthInput
from qfa_ros.ros.parameter_table import PARAMETERS


def _run(config, rate, force=None, temperature=25.0, seed=0):
    n = len(rate)
    gyro = GyroTriad(config, 100.0, np.random.default_rng(seed))
    force = np.zeros((n, 3)) if force is None else force
    return gyro, gyro.run(rate, force, np.full(n, temperature))


def test_gyro_deterministic_terms_follow_the_output_equation():
    # Noise off, large deterministic spreads: the output equals the IEEE 952 equation
    # of the drawn unit, term by term.
    config = GyroConfig.ideal().with_errors(
        turn_on_bias=1.0 * DEG_PER_HOUR, scale_factor=100 * PPM, scale_factor_asymmetry=50 * PPM,
        misalignment=1e-4, g_sensitivity=0.1 * DEG_PER_HOUR / 9.8, bias_tc=0.01 * DEG_PER_HOUR,
        scale_factor_tc=10 * PPM)
    rate = np.tile([[0.5, -0.3, 0.2]], (4, 1))
    force = np.tile([[1.0, 2.0, 9.8]], (4, 1))
    gyro, (out, saturated) = _run(config, rate, force, temperature=45.0)
    u = gyro.unit
    sensed = (np.eye(3) + u.misalignment) @ rate[0]
    expected = sensed * (1 + u.scale_factor + 20 * u.scale_factor_tc
                         + u.asymmetry * np.sign(sensed)) \
        + u.bias + 20 * u.bias_tc + u.g_sensitivity @ force[0]
    assert_allclose(out, np.tile(expected, (4, 1)), rtol=0, atol=1e-15)
    assert not saturated.any()
    assert np.all(np.diag(u.misalignment) == 0)
    # The same seed draws the same unit; another seed another one.
    assert_allclose(_run(config, rate, force, 45.0, seed=0)[0].unit.bias, u.bias)
    assert not np.allclose(_run(config, rate, force, 45.0, seed=1)[0].unit.bias, u.bias)


def test_gyro_quantization_keeps_the_angle_and_range_clips():
    config = GyroConfig.ideal().with_errors(quantization=1e-6, range=1.0)
    rate = np.full((1000, 3), 3.3e-5)
    rate[:, 2] = 2.0
    gyro, (out, saturated) = _run(config, rate)
    steps = out[:, 0] * gyro.dt / 1e-6
    assert_allclose(steps, np.round(steps), atol=1e-9)
    # Accumulated angle within one quantum of the true angle.
    assert abs(out[:, 0].sum() * gyro.dt - 3.3e-5 * 10.0) <= 1e-6
    assert np.all(out[:, 2] == 1.0) and saturated[:, 2].all()


def test_gyro_output_does_not_depend_on_how_the_samples_are_cut():
    # Every noise term on (blocks of 10 samples at 100 Hz), a moving rate: one run over
    # all samples equals runs and job slices of uneven lengths, some inside a block.
    config = GyroConfig().with_errors(rate_random_walk=1.0 * DEG_PER_HOUR / 60.0,
                                      quantization=1e-7)
    t = np.arange(2500) / 100.0
    rate = np.column_stack([0.1 * np.sin(t), 0.05 * np.cos(3 * t), np.full_like(t, 1e-4)])
    force = np.tile([[0.0, 0.0, 9.8]], (len(t), 1))
    _, (whole, _) = _run(config, rate, force)
    gyro = GyroTriad(config, 100.0, np.random.default_rng(0))
    parts = []
    for a, b in [(0, 1), (1, 100), (100, 357), (357, 1400), (1400, 2500)]:
        call, out, _ = gyro.job(rate[a:b], force[a:b], np.full(b - a, 25.0))
        middle = (b - a) // 3
        call(0, middle)
        call(middle, b - a)
        parts.append(out)
    np.testing.assert_array_equal(np.concatenate(parts), whole)


@pytest.mark.parametrize('name, value', [('arw', -1.0), ('range', 0.0),
                                         ('correlation_times', ()), ('bias_tc', math.nan),
                                         ('range', None), ('reference_c', None),
                                         ('arw', '1'), ('correlation_times', None),
                                         ('correlation_times', ('x',))])
def test_gyro_config_refuses_bad_values(name, value):
    with pytest.raises(ValueError, match=name):
        GyroConfig().with_errors(**{name: value})


def test_imu_encoder_with_rate_equals_rclpy_serialization():
    encoder = ImuEncoder('imu_link', [1e-8, 0, 0, 0, 2e-8, 0, 0, 0, 3e-8],
                         [4e-10, 0, 0, 0, 5e-10, 0, 0, 0, 6e-10])
    stamps = [1_700_000_000_123_456_789, 5]
    accel = [[0.1, -0.2, 9.8], [1.0, 2.0, 3.0]]
    rate = [[1e-5, -2e-5, 3e-5], [0.5, -0.25, 0.125]]
    for data, stamp, a, w in zip(encoder.encode(stamps, accel, rate), stamps, accel, rate):
        message = Imu()
        message.header.frame_id = 'imu_link'
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10 ** 9)
        message.orientation_covariance[0] = -1.0
        message.angular_velocity.x, message.angular_velocity.y, message.angular_velocity.z = w
        message.linear_acceleration.x, message.linear_acceleration.y, \
            message.linear_acceleration.z = a
        message.angular_velocity_covariance = [4e-10, 0., 0., 0., 5e-10, 0., 0., 0., 6e-10]
        message.linear_acceleration_covariance = [1e-8, 0., 0., 0., 2e-8, 0., 0., 0., 3e-8]
        # Equal as messages (rclpy leaves its alignment padding uninitialized).
        assert deserialize_message(data, Imu) == message
        assert len(data) == len(serialize_message(message))


def test_schedules_refuse_a_moving_sensor():
    triad = QfaTriad(TriadConfig(), rng=0, profile=tr.rate_table_turn())
    with pytest.raises(EstimationError, match='moving'):
        run_schedule(triad, capture_reference(triad, CalibrationState()))


def test_gyro_bias_schedule_removes_the_bias_and_keeps_the_earth_rate():
    # Tilted (roll 0.2, pitch 0.1 rad) and turned (yaw 0.7 rad) at 45 deg, a 500 deg/h
    # unit: the schedule levels from the accelerometers, removes the Earth rate of the
    # configured heading, and the corrected output's mean equals the true body rate
    # within the noise of two 5 s means (ARW 0.002 deg/sqrt(h): 0.03 deg/h at 200 Hz)
    # plus the misalignment and scale factor of the unit times the Earth rate.
    config = TriadConfig(loop_rate_hz=2000.0, sample_rate_hz=200.0, crossover_hz=100.0,
                         gyro=GyroConfig(turn_on_bias=500 * DEG_PER_HOUR))
    pose = {'roll': 0.2, 'pitch': 0.1, 'yaw': 0.7}
    triad = QfaTriad(config, rng=5, profile=tr.static(45.0, **pose))
    for roll, pitch, yaw in ((0.0, 0.0, 0.0), (0.2, 0.1, 0.7), (math.pi, -0.3, -2.0)):
        truth = tr.static(45.0, roll=roll, pitch=pitch, yaw=yaw).angular_rate(np.zeros(1))[0]
        assert_allclose(earth_rate_body(45.0, roll, pitch, yaw), truth, atol=1e-15)
    state = CalibrationState()
    result = run_schedule(triad, gyro_bias_schedule(
        triad, state, GyroBiasSettings(duration_s=5.0, yaw=pose['yaw'])))
    assert result.applied and len(state.gyro_bias) == 3
    assert np.max(np.abs(result.estimate)) > 50 * DEG_PER_HOUR
    out = triad.run_for(5.0)
    residual = out.gyro.mean(axis=0) - out.rate_truth.mean(axis=0)
    assert np.all(np.abs(residual) < 0.3 * DEG_PER_HOUR), residual / DEG_PER_HOUR
    # A wrong heading leaves Earth rate in the estimate: 90 degrees off, about 10 deg/h.
    wrong = run_schedule(triad, gyro_bias_schedule(
        triad, CalibrationState(), GyroBiasSettings(duration_s=5.0, yaw=pose['yaw'] + 1.57)))
    assert np.max(np.abs(wrong.estimate - result.estimate)) > 5 * DEG_PER_HOUR
    # Moving (a rate-table turn) or without gyros: refused, nothing written.
    moving = QfaTriad(config, rng=0, profile=tr.rate_table_turn(dwell_s=0.0))
    with pytest.raises(EstimationError, match='moving'):
        run_schedule(moving, gyro_bias_schedule(moving, CalibrationState()))
    plain = QfaTriad(TriadConfig(gyro=None), rng=0)
    with pytest.raises(EstimationError, match='no gyros'):
        run_schedule(plain, gyro_bias_schedule(plain, CalibrationState()))


@pytest.mark.parametrize('bias', [[1e300] * 3, [float('nan')] * 3, [0.0, 0.0, 10.0],
                                  [0.0, 0.0]])
def test_a_gyro_bias_beyond_the_range_is_not_applied(bias):
    # A state file's gyro_bias of 1e300 rad/s was applied before: the node published
    # rates of -1e300 rad/s. Now refused (the node sets such a file aside), nothing written.
    state = CalibrationState(controller_gain=[0.5] * 3, gyro_bias=bias)
    triad = QfaTriad(TriadConfig(), rng=0)
    gain = triad.axes[0].controller.gain
    with pytest.raises(ValueError, match='gyro_bias'):
        state.apply_to(triad)
    assert triad.axes[0].controller.gain == gain
    assert np.all(triad.gyro_bias_correction == 0.0)


def test_static_summary_does_not_depend_on_the_gyros(tmp_path, capsys):
    # qfa-sim static leaves the gyros out when no bag is written: the accelerometers'
    # numbers (and so the summary) are the same as with them, which the bag run has.
    assert sim.main(['static', '--duration', '40', '--seed', '3']) == 0
    without = capsys.readouterr().out
    assert sim.main(['static', '--duration', '40', '--seed', '3', '--out',
                     str(tmp_path / 'static.mcap')]) == 0
    with_gyros = capsys.readouterr().out
    rows = [line for line in without.splitlines() if line.split()[:1] in (['x'], ['y'], ['z'])]
    assert len(rows) == 3
    assert all(row in with_gyros.splitlines() for row in rows)
    with AnyReader([tmp_path / 'static.mcap']) as reader:
        imu = next(c for c in reader.connections if c.topic == '/imu/data_raw')
        message = reader.deserialize(next(reader.messages([imu]))[2], imu.msgtype)
        assert message.angular_velocity_covariance[0] > 0


def test_qfa_sim_trajectory_writes_imu_and_truth(tmp_path, capsys):
    path = tmp_path / 'turn.mcap'
    assert sim.main(['trajectory', '--motion', 'rate-table', '--duration', '3', '--rate',
                     '200', '--truth-rate', '50', '--out', str(path)]) == 0
    assert 'rate-table turn' in capsys.readouterr().out
    truth = tr.rate_table_turn()
    with AnyReader([path]) as reader:
        topics = {c.topic: c for c in reader.connections}
        assert topics['/truth/odometry'].msgtype == 'nav_msgs/msg/Odometry'
        imu = [deserialize_message(raw, Imu) for c, _, raw in
               reader.messages(connections=[topics['/imu/data_raw']])]
        odometry = [deserialize_message(raw, Odometry) for c, _, raw in
                    reader.messages(connections=[topics['/truth/odometry']])]
    assert len(imu) == 600 and len(odometry) == 150
    assert imu[-1].angular_velocity_covariance[0] > 0
    # At rest for the first 10 s: the gyros see the Earth rate (x north, 45 deg).
    mean = np.mean([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                    for m in imu], axis=0)
    expected = truth.angular_rate(np.array([1.0]))[0]
    sigma = math.sqrt(imu[0].angular_velocity_covariance[0] / len(imu))
    assert np.all(np.abs(mean - expected) < 6 * sigma + 3 * GyroConfig().turn_on_bias)
    last = odometry[-1]
    assert last.header.frame_id == 'enu_origin' and last.child_frame_id == 'imu_link'
    q = last.pose.pose.orientation
    assert_allclose([q.x, q.y, q.z, q.w], dcm_to_quaternion(
        truth.kinematics(np.array([3.0]))['dcm'][0]), atol=1e-9)


def test_ground_truth_odometry_gives_specific_force_and_rate():
    values = {spec.name: spec.default for spec in PARAMETERS}
    values['input.mode'] = 'topic'
    truth = GroundTruthInput(values)
    # Yawed 90 deg (x north), accelerating north at 2 m/s^2, turning at 0.1 rad/s.
    q = (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4))
    truth.accept_odometry(0, (0, 0, 0), q, (1.0, 0, 0), (0, 0, 0.1))
    truth.accept_odometry(100_000_000, (0, 0, 0), q, (1.2, 0, 0), (0, 0, 0.1))
    force, rate, stale = truth.inputs(np.array([150_000_000], dtype=np.int64))
    latitude = math.radians(values['latitude_deg'])
    assert_allclose(force[0], [2.0, 0.0, float(earth.normal_gravity(latitude))], atol=1e-9)
    w_ie = earth.EARTH_RATE * math.cos(latitude)
    assert_allclose(rate[0], [w_ie, 0.0, 0.1 + earth.EARTH_RATE * math.sin(latitude)],
                    atol=1e-12)
    assert not stale[0]
    truth.accept_odometry(200_000_000, (0, 0, 0), (0, 0, 0, 0), (1, 0, 0), (0, 0, 0))
    assert truth.rejected == 1
