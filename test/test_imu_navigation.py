"""The full IMU on the Earth: trajectories, gyros and an independent strapdown INS."""

import math
import os
import sys

import numpy as np
from numpy.testing import assert_allclose
import pytest
from statistics_helpers import allan_edf_flicker, allan_edf_white, assert_variance_ratios

from qfa_ros.model import earth
from qfa_ros.model import motion_scripts as tr
from qfa_ros.model.allan import allan_deviation
from qfa_ros.model.gyro import GyroConfig, GyroTriad
from qfa_ros.model.noise import (
    flicker_component_variance,
    gauss_markov_allan_variance,
    NoiseConfig,
)
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig

sys.path.insert(0, os.path.dirname(__file__))
import ins_errors  # noqa: E402
import strapdown  # noqa: E402

from qfa_ros.model.constants import DEG_PER_HOUR, MICRO_G

LAT45 = math.radians(45.0)


def test_earth_constants_against_published_values():
    # TR8350.2: gamma_e, gamma_p at the equator and pole; 15.041 deg/h Earth rate.
    assert_allclose(earth.normal_gravity(0.0), 9.7803253359, rtol=1e-12)
    assert_allclose(earth.normal_gravity(math.pi / 2), 9.8321849378, rtol=1e-10)
    assert_allclose(earth.EARTH_RATE / DEG_PER_HOUR, 15.041, atol=1e-3)
    # Free-air gradient about -3.086e-6 s^-2 at 45 deg.
    gradient = (earth.normal_gravity(LAT45, 1000.0) - earth.normal_gravity(LAT45)) / 1000.0
    assert_allclose(gradient, -3.086e-6, rtol=2e-3)
    r_n, r_e = earth.radii_of_curvature(0.0)
    assert_allclose(r_e, earth.SEMI_MAJOR_AXIS)
    assert_allclose(r_n, earth.SEMI_MAJOR_AXIS * (1 - earth.ECCENTRICITY_SQUARED))
    assert strapdown.gravity(LAT45, 100.0) == pytest.approx(
        float(earth.normal_gravity(LAT45, 100.0)), rel=1e-10)


def test_static_level_north_pointing_sees_earth_rate_and_normal_gravity():
    # 30 s at 45 deg, level, x north: gyros (15.041 cos, 0, 15.041 sin) deg/h and
    # accelerometers (0, 0, gamma), within the configured biases (each 3-sigma of the
    # unit draw and of the mean noise over 30 s).
    config = TriadConfig()
    triad = QfaTriad(config, rng=3, profile=tr.static(45.0, yaw=math.pi / 2))
    out = triad.run_for(30.0)
    gyro = config.gyro
    expected_rate = 15.041 * DEG_PER_HOUR * np.array([math.cos(LAT45), 0.0, math.sin(LAT45)])
    arw_mean = gyro.arw / math.sqrt(30.0)
    gyro_tolerance = 3 * math.hypot(gyro.turn_on_bias, gyro.bias_instability, arw_mean) \
        + 1e-4 * DEG_PER_HOUR  # rounding of 15.041
    assert np.all(np.abs(out.gyro.mean(axis=0) - expected_rate) < gyro_tolerance)
    gravity = float(earth.normal_gravity(LAT45))
    assert gravity == pytest.approx(9.806199, abs=2e-6)
    noise = config.noise
    # The bias-instability process (a Gauss-Markov sum) barely averages over 30 s: its
    # stationary standard deviation, not the Allan floor, bounds the mean.
    bias_std = math.sqrt(flicker_component_variance(noise) * len(noise.correlation_times))
    accel_tolerance = 3 * math.hypot(bias_std, noise.noise_density / math.sqrt(30.0))
    assert_allclose(out.accel.mean(axis=0), [0.0, 0.0, gravity], atol=accel_tolerance)
    assert accel_tolerance < 30 * MICRO_G
    # The reason the schedules refuse to run is absent at rest, present when moving.
    assert triad.is_at_rest() is None
    moving = QfaTriad(TriadConfig(), rng=0, profile=tr.rate_table_turn())
    assert 'moving' in moving.is_at_rest()


@pytest.mark.parametrize('latitude_deg', [90.0, -90.0])
def test_a_body_at_a_pole_sees_the_vertical_earth_rate_and_polar_gravity(latitude_deg):
    # Issue 38: the pole is a location like any other for a body at rest (TR8350.2
    # gamma_p = 9.8321849378 m/s^2; the Earth rate all vertical, +Omega up at the north
    # pole, -Omega at the south pole), in the Python kinematics and in the compiled
    # per-sample means; only a path integrated from its east velocity is refused there.
    earth.check_location(latitude_deg, 0.0, 0.0)
    sign = math.copysign(1.0, latitude_deg)
    for yaw in (0.0, 1.0):
        static = tr.static(latitude_deg, 30.0, 0.0, yaw=yaw)
        k = static.kinematics(np.array([0.0, 0.5]))
        assert_allclose(k['specific_force'], [[0.0, 0.0, 9.8321849378]] * 2, rtol=0,
                        atol=1e-9)
        assert_allclose(k['angular_rate'], [[0.0, 0.0, sign * earth.EARTH_RATE]] * 2,
                        rtol=0, atol=1e-18)
        force, rate = static.sample_means(0.25, 0.001, 3)
        assert_allclose(force, [[0.0, 0.0, 9.8321849378]] * 3, rtol=0, atol=1e-9)
        assert_allclose(rate, [[0.0, 0.0, sign * earth.EARTH_RATE]] * 3, rtol=0, atol=1e-18)
    with pytest.raises(ValueError, match='latitude_deg 89.99: the drive comes within'):
        tr.vehicle_drive(latitude_deg=89.99)
    with pytest.raises(ValueError, match='latitude_deg must be in'):
        earth.check_location(90.001, 0.0, 0.0)


NAN, INF = float('nan'), float('inf')


@pytest.mark.parametrize('script, kwargs, name', [
    ('static', {'yaw': NAN}, 'yaw'),
    ('static', {'roll': INF}, 'roll'),
    ('six_position_tumble', {'dwell_s': NAN}, 'dwell_s'),
    ('six_position_tumble', {'move_s': -1.0}, 'move_s'),
    ('rate_table_turn', {'rate_deg_s': NAN}, 'rate_deg_s'),
    ('rate_table_turn', {'turns': NAN}, 'turns'),
    ('rate_table_turn', {'ramp_s': INF}, 'ramp_s'),
    ('vehicle_drive', {'knot_s': 0.0}, 'knot_s'),
    ('vehicle_drive', {'ramp_s': 0.0}, 'ramp_s'),
    ('vehicle_drive', {'yaw': NAN}, 'yaw'),
    ('vehicle_drive', {'script': [(10.0, NAN, 0.0, 0.0)]}, 'script'),
    ('coning', {'knots_per_cycle': 0}, 'knots_per_cycle'),
    ('coning', {'amplitude_deg': NAN}, 'amplitude_deg'),
    ('coning', {'duration_s': INF}, 'duration_s'),
    ('sculling', {'displacement_m': NAN}, 'displacement_m'),
])
def test_motion_scripts_refuse_a_value_that_is_no_number_by_name(script, kwargs, name):
    # Before, NaN gave a trajectory of NaN poses and a zero knot or ramp a ZeroDivisionError.
    with pytest.raises(ValueError, match=name):
        getattr(tr, script)(**kwargs)



def test_a_body_at_rest_has_one_pose_at_every_instant_and_callers_may_write_it():
    # The node's truth asks a static input for its force and pose ten times a second: a
    # constant motion computes them once and hands out copies.
    static = tr.static(48.0, 11.0, 520.0, roll=0.3, pitch=-0.7, yaw=1.2)
    t = np.linspace(0.0, 3600.0, 1001)
    once, many = static.kinematics(np.array([17.0])), static.kinematics(t)
    for key, value in once.items():
        assert np.array_equal(many[key], np.repeat(value, len(t), axis=0)), key
    pose_once, pose_many = static.local_pose(17.0), static.local_pose(t)
    for value, values in zip(pose_once, pose_many):
        assert np.array_equal(values, np.repeat(value, len(t), axis=0))
    assert_allclose(pose_once[0], [[0.0, 0.0, 0.0]], rtol=0, atol=1e-9)
    assert_allclose(pose_once[2:], np.zeros((2, 1, 3)), rtol=0, atol=0)
    force, rate = static.rest_values()
    assert np.array_equal(many['specific_force'][-1], force)
    many['specific_force'][:] = 0.0
    pose_many[1][:] = 0.0
    assert np.array_equal(static.evaluate(t)[-1], force)
    assert np.array_equal(static.local_pose(t)[1], np.repeat(pose_once[1], len(t), axis=0))

def test_trajectory_kinematics_are_consistent_with_the_pose():
    # Finite differences of the pose reproduce the analytic velocity and body rate.
    drive = tr.vehicle_drive()
    t = np.array([45.0, 120.0, 333.3])
    h = 1e-4
    k, kp, km = (drive.kinematics(t + d) for d in (0.0, h, -h))
    r_n, r_e = earth.radii_of_curvature(k['latitude'])
    north = (kp['latitude'] - km['latitude']) / (2 * h) * (r_n + k['height'])
    assert_allclose(k['velocity'][:, 1], north, atol=1e-6)
    # C^T dC/dt = [w_nb x].
    dcm_dot = (kp['dcm'] - km['dcm']) / (2 * h)
    skew = np.einsum('nji,njk->nik', k['dcm'], dcm_dot)
    assert_allclose(skew[:, 2, 1], k['body_rate'][:, 0], atol=1e-7)
    assert_allclose(skew[:, 1, 0], k['body_rate'][:, 2], atol=1e-7)
    # The compiled per-sample means equal the two-point Gauss means of the kinematics.
    period, start = 0.005, 87.3
    force, rate = drive.sample_means(start, period, 4)
    centres = start + (np.arange(4) + 0.5) * period
    nodes = [drive.kinematics(centres + sign * period / (2 * math.sqrt(3))) for sign in (-1, 1)]
    assert_allclose(force, 0.5 * (nodes[0]['specific_force'] + nodes[1]['specific_force']),
                    rtol=0, atol=1e-12)
    assert_allclose(rate, 0.5 * (nodes[0]['angular_rate'] + nodes[1]['angular_rate']),
                    rtol=0, atol=1e-15)
    assert drive.duration > 600.0
    assert np.ptp(drive.kinematics(np.arange(0, 600, 1.0))['velocity'][:, 0]) > 20.0


def test_csv_round_trip(tmp_path):
    turn = tr.rate_table_turn(turns=1, dwell_s=2.0, ramp_s=2.0)
    path = tmp_path / 'turn.csv'
    tr.save_csv(path, turn, rate_hz=50.0)
    loaded = tr.load_csv(path)
    t = np.linspace(0.0, turn.duration, 200)
    assert_allclose(loaded.kinematics(t)['attitude'], turn.kinematics(t)['attitude'],
                    atol=1e-6)
    assert_allclose(loaded.angular_rate(t), turn.angular_rate(t), atol=1e-4)
    (tmp_path / 'bad.csv').write_text('t,lat\n0,1\n')
    with pytest.raises(ValueError, match='header'):
        tr.load_csv(tmp_path / 'bad.csv')


def _navigate(trajectory, out, rate_hz, **kwargs):
    k0 = trajectory.kinematics(np.array([0.0]))
    positions, dcms, _ = strapdown.navigate(
        out.gyro, out.accel, 1.0 / rate_hz, k0['latitude'][0], k0['longitude'][0],
        k0['height'][0], k0['velocity'][0], k0['dcm'][0], **kwargs)
    truth = trajectory.kinematics(np.arange(1, len(out.gyro) + 1) / rate_hz)
    return (strapdown.position_error(positions, truth['latitude'], truth['longitude'],
                                     truth['height']),
            strapdown.attitude_error(dcms, truth['dcm']))


def test_ideal_imu_drive_integrates_back_to_the_trajectory():
    # Every error off, the QFA loops at their 10 kHz rate, 200 Hz output, 10 minutes.
    rate_hz = 200.0
    drive = tr.vehicle_drive()
    config = TriadConfig(noise=NoiseConfig.off(), gyro=GyroConfig.ideal(),
                         sample_rate_hz=rate_hz)
    triad = QfaTriad(config, rng=0, profile=drive)
    out = triad.run_for(600.0, chunk_samples=2000)
    position, attitude = _navigate(drive, out, rate_hz)
    assert np.max(np.linalg.norm(position, axis=1)) < 1.0
    assert np.max(np.abs(np.degrees(attitude))) < 0.01
    # The drive went somewhere: more than 4 km from the start.
    k = drive.kinematics(np.array([0.0, 600.0]))
    east, north, _ = strapdown.position_error(
        np.array([[k['latitude'][1], k['longitude'][1], 0.0]]), k['latitude'][:1],
        k['longitude'][:1], np.zeros(1))[0]
    assert math.hypot(east, north) > 4000.0


def test_gyro_allan_deviation_matches_its_settings():
    # 5 seeds x 40 hours of one unit at 1 Hz: the gyro model alone (its noise terms scale
    # with the sample period, and the flicker floor sits under the ARW until about
    # 1600 s, so long records are needed). Its Allan variance is the settings':
    # ARW^2 / tau + the Gauss-Markov sum + RRW^2 tau / 3; at 10 s the ARW (99 %), at
    # 3000 s the bias instability and rate random walk (71 %). Each estimate over the
    # model is chi2(edf)/edf, edf the smaller of Greenhall's for white and flicker FM
    # (16 755 and 55; 20 800 and 71 measured over 30 seeds), the 15 of a tau pooled
    # with 15 x edf. Bounds at a false failure of 1e-6 per test over the 32 checks
    # (test/statistics_helpers.py): pooled ARW within 0.8 %, AVAR(3000 s) -25/+30 %.
    config = GyroConfig()
    rate_hz, seeds, taus = 1.0, range(7, 12), (10.0, 3000.0)
    n = int(40 * 3600 * rate_hz)
    variance = flicker_component_variance(config)
    model = np.array([config.arw ** 2 / tau + config.rate_random_walk ** 2 * tau / 3
                      + sum(gauss_markov_allan_variance(tau, variance, t)
                            for t in config.correlation_times) for tau in taus])
    edf = np.array([min(allan_edf_white(n, tau * rate_hz), allan_edf_flicker(n, tau * rate_hz))
                    for tau in taus])
    checks = 3 * len(seeds) * len(taus) + len(taus)
    ratios = []
    for seed in seeds:
        gyro = GyroTriad(config, rate_hz, np.random.default_rng(seed))
        out, _ = gyro.run(np.zeros((n, 3)), np.zeros((n, 3)), np.full(n, config.reference_c))
        for axis in range(3):
            _, adev = allan_deviation(out[:, axis], 1.0 / rate_hz, taus=taus)
            ratios.append(adev ** 2 / model)
    assert_variance_ratios(ratios, edf, checks)


def _static_hour(accel_bias, gyro_bias, seed=11):
    """Navigate one hour at rest (x north, 45 deg): the errors per minute and the pose."""
    rate_hz = 100.0
    config = TriadConfig(loop_rate_hz=1000.0, sample_rate_hz=rate_hz, crossover_hz=40.0,
                         bias=tuple(accel_bias), gyro=GyroConfig(bias=tuple(gyro_bias)))
    static = tr.static(45.0, yaw=math.pi / 2)
    triad = QfaTriad(config, rng=seed, profile=static)
    out = triad.run_for(3600.0, chunk_samples=20000)
    position, attitude = _navigate(static, out, rate_hz, hold_height=True)
    times = np.arange(60.0, 3600.0 + 1, 60.0)
    index = (times * rate_hz).astype(int) - 1
    body_to_nav = static.kinematics(np.array([0.0]))['dcm'][0]
    # attitude_error is in body axes: e_b = -C^T psi for C_est = (I - [psi x]) C.
    measured = np.column_stack([position[index, :2], -attitude[index] @ body_to_nav.T])
    return times, measured, config, static


def _predict(config, static, times, accel_bias=None, gyro_bias=None):
    """
    Return the error model's (mean, std) for ``config`` at rest on ``static``.

    Only the configuration: the known biases, the gyro unit draw's spreads at the
    static rate and force, the gyro and accelerometer noise; the body is at the gyro
    reference temperature (no thermal model).
    """
    k = static.kinematics(np.array([0.0]))
    rate_b, force_b = k['angular_rate'][0], k['specific_force'][0]
    gyro = config.gyro
    model = ins_errors.StaticErrorModel(
        k['latitude'][0], k['dcm'][0],
        np.asarray(config.bias if accel_bias is None else accel_bias),
        np.asarray(gyro.bias if gyro_bias is None else gyro_bias),
        ins_errors.gyro_constant_variance(gyro, rate_b, force_b), gyro=gyro,
        accel_noise=config.noise)
    return model.propagate(times)


def test_static_hour_drifts_as_the_configured_errors_predict():
    # One hour at rest, level, x north, 45 deg, with known accelerometer biases
    # (200, -150, 0) ug and gyro biases (0.06, -0.05, -0.08) deg/h (x north, y west,
    # z up) on top of the default gyro unit draw and the default noise of both triads;
    # the accelerometer loops at 1 kHz (at rest the physics does not depend on the loop
    # rate). The free-inertial error - Schuler oscillation (84 min) from the
    # accelerometer and horizontal gyro biases, heading from the vertical gyro bias and
    # the Schuler velocity - follows the psi-angle error model of the configuration
    # (test/ins_errors.py) within the stated factor: per east and north position and
    # heading, the RMS difference over the hour is below a third of the predicted drift's
    # RMS, and every minute the difference is within 4 standard deviations of what the
    # configured noise and unit spreads add (that band is below a fifth of the drift).
    # The noise is no small correction: the gyro's slow bias-instability terms
    # (stationary 0.009 deg/h) and rate random walk alone move the position by about
    # 870 m (1 sigma) in the hour.
    accel_bias = np.array([200.0, -150.0, 0.0]) * MICRO_G
    gyro_bias = np.array([0.06, -0.05, -0.08]) * DEG_PER_HOUR
    times, measured, config, static = _static_hour(accel_bias, gyro_bias)
    mean, std = _predict(config, static, times)
    columns = [0, 1, 4]  # east, north position; heading
    z = np.abs(measured - mean)[:, columns] / std[:, columns]
    assert np.all(z < 4.0), np.round(z.max(axis=0), 2)
    rms = np.sqrt(np.mean(mean[:, columns] ** 2, axis=0))
    band = np.sqrt(np.mean(std[:, columns] ** 2, axis=0))
    difference = np.sqrt(np.mean((measured - mean)[:, columns] ** 2, axis=0))
    assert np.all(difference < rms / 3), (difference, rms)
    assert np.all(band < rms / 5), (band, rms)
    assert np.max(np.abs(mean[:, :2])) > 5000.0  # kilometres in an hour
    # Predictions from other errors fail the same band: the gyro biases doubled, or
    # either triad's biases with their signs flipped.
    for wrong_accel, wrong_gyro in ((accel_bias, 2 * gyro_bias), (-accel_bias, gyro_bias),
                                    (accel_bias, -gyro_bias)):
        wrong, _ = _predict(config, static, times, wrong_accel, wrong_gyro)
        assert np.any(np.abs(measured - wrong)[:, columns] > 4.0 * std[:, columns])
