"""The full IMU on the Earth: trajectories, gyros and an independent strapdown INS."""

import dataclasses
import math
import os
import sys

import numpy as np
from numpy.testing import assert_allclose
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import nnls

from qfa_ros.model import earth
from qfa_ros.model import trajectory as tr
from qfa_ros.model.allan import allan_deviation
from qfa_ros.model.gyro import DEG_PER_HOUR, GyroConfig, GyroTriad
from qfa_ros.model.noise import flicker_component_variance, MICRO_G, NoiseConfig
from qfa_ros.model.triad import QfaTriad, TriadConfig

sys.path.insert(0, os.path.dirname(__file__))
import strapdown  # noqa: E402

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
    # 200 hours of one unit at 1 Hz: the gyro model alone (its noise terms scale with
    # the sample period, and the flicker floor sits under the ARW until about 1600 s,
    # so a long record is needed). Fit of the Allan variance with the ARW,
    # bias-instability and rate-random-walk terms (IEEE 952 annex C), non-negative.
    config = GyroConfig()
    rate_hz = 1.0
    gyro = GyroTriad(config, rate_hz, np.random.default_rng(7))
    n = int(200 * 3600 * rate_hz)
    out, _ = gyro.run(np.zeros((n, 3)), np.zeros((n, 3)), np.full(n, config.reference_c))
    for axis in range(3):
        taus, adev = allan_deviation(out[:, axis], 1.0 / rate_hz)
        keep = taus < taus[-1] / 3
        taus, avar = taus[keep], adev[keep] ** 2
        basis = np.stack([1 / taus, np.ones_like(taus), taus / 3], axis=-1)
        coef, _ = nnls(basis / avar[:, None], np.ones_like(avar))
        assert math.sqrt(coef[0]) == pytest.approx(config.arw, rel=0.10)
        assert config.bias_instability / 1.5 < math.sqrt(coef[1]) \
            < config.bias_instability * 1.5


def _error_model(t_end, latitude, accel_bias_n, gyro_bias_n, times):
    """
    Integrate the linear ENU error model of a stationary INS with a height aid.

    States: east/north position error, east/north velocity error, attitude error psi
    (C_est = (I - [psi x]) C_true). Titterton & Weston eq. 12.9-12.10 with v = 0::

        dv' = f^n x psi + C b_a - 2 w_ie x dv
        psi' = -w_ie x psi + dw_en(dv) + dw_ie(dlat) - C b_g
    """
    g = float(earth.normal_gravity(latitude))
    r_n, r_e = earth.radii_of_curvature(latitude)
    w_ie = earth.earth_rate_enu(latitude)
    f_n = np.array([0.0, 0.0, g])

    def rates(_, x):
        dp, dv, psi = x[0:2], np.array([x[2], x[3], 0.0]), x[4:7]
        dlat = dp[1] / r_n
        dv_dot = np.cross(f_n, psi) + accel_bias_n - 2 * np.cross(w_ie, dv)
        dw_en = np.array([-dv[1] / r_n, dv[0] / r_e, dv[0] * math.tan(latitude) / r_e])
        dw_ie = earth.EARTH_RATE * np.array([0.0, -math.sin(latitude), math.cos(latitude)]) \
            * dlat
        psi_dot = -np.cross(w_ie, psi) + dw_en + dw_ie - gyro_bias_n
        return np.concatenate([dv[:2], dv_dot[:2], psi_dot])

    solution = solve_ivp(rates, (0.0, t_end), np.zeros(7), t_eval=times, rtol=1e-9,
                         atol=1e-12)
    return solution.y.T


def _static_hour(accel_bias, gyro_bias):
    """Navigate one hour at rest (x north, 45 deg) with the configured constant errors."""
    rate_hz = 100.0
    config = TriadConfig(loop_rate_hz=1000.0, sample_rate_hz=rate_hz, crossover_hz=40.0,
                         bias=tuple(accel_bias), gyro=GyroConfig().with_errors(turn_on_bias=0.0))
    static = tr.static(45.0, yaw=math.pi / 2)
    triad = QfaTriad(config, rng=11, profile=static)
    # The unit's turn-on bias, configured instead of drawn (the rest of the draw stays).
    triad.gyro.unit = dataclasses.replace(triad.gyro.unit, bias=np.asarray(gyro_bias))
    out = triad.run_for(3600.0, chunk_samples=20000)
    position, attitude = _navigate(static, out, rate_hz, hold_height=True)
    k = static.kinematics(np.array([0.0]))
    body_to_nav = k['dcm'][0]
    unit = triad.gyro.unit
    rate_b = k['angular_rate'][0]
    sensed = (np.eye(3) + unit.misalignment) @ rate_b
    gyro_bias_b = sensed * (1 + unit.scale_factor + unit.asymmetry * np.sign(sensed)) \
        - rate_b + unit.bias + unit.g_sensitivity @ k['specific_force'][0]
    times = np.arange(60.0, 3600.0 + 1, 60.0)
    index = (times * rate_hz).astype(int) - 1
    # attitude_error is in body axes: e_b = -C^T psi for C_est = (I - [psi x]) C.
    measured = np.column_stack([position[index, :2], -attitude[index] @ body_to_nav.T])
    return times, measured, body_to_nav, gyro_bias_b


@pytest.mark.xfail(strict=True, reason='open (issue 15): the north position departs from the '
                   'linear error model by about 370 m RMS whatever the configured biases; '
                   'east and the gyro-bias terms fit, the cause is not yet found')
def test_static_hour_drifts_as_the_configured_errors_predict():
    # One hour at rest, level, x north, with accelerometer biases (100, -80, 0) ug and
    # gyro biases (0.02, -0.015, 0.05) deg/h (x north, y west, z up) on top of the
    # default noise and unit draw; the accelerometer loops run at 1 kHz (at rest the
    # physics does not depend on the loop rate). The free-inertial error - Schuler
    # oscillation (84 min) from the accelerometer and horizontal gyro biases, heading
    # from the vertical gyro bias - follows the linear error model of the configured
    # errors within the stated factor: per east, north position and heading, the RMS
    # difference is below 25 % of the predicted RMS (the rest is the configured noise).
    # (Each well above what the default noise does in an hour: the 0.003 deg/h/sqrt(h)
    # rate random walk alone moves the position by about 200 m.)
    accel_bias = np.array([100.0, -80.0, 0.0]) * MICRO_G
    gyro_bias = np.array([0.02, -0.015, 0.05]) * DEG_PER_HOUR
    times, measured, body_to_nav, gyro_bias_b = _static_hour(accel_bias, gyro_bias)
    predicted = _error_model(3600.0, LAT45, body_to_nav @ accel_bias,
                             body_to_nav @ gyro_bias_b, times)
    model = np.column_stack([predicted[:, 0:2], predicted[:, 4:7]])
    for column in (0, 1, 4):  # east, north position; heading
        rms_model = np.sqrt(np.mean(model[:, column] ** 2))
        rms_diff = np.sqrt(np.mean((measured[:, column] - model[:, column]) ** 2))
        assert rms_diff < 0.25 * rms_model, (column, rms_diff, rms_model)
    # The errors are there: kilometres in an hour.
    assert np.max(np.abs(predicted[:, 1])) > 500.0
    # Models with the accelerometer or the gyro biases' signs flipped fit far worse.
    for accel_sign, gyro_sign in ((-1, 1), (1, -1)):
        wrong = _error_model(3600.0, LAT45, accel_sign * body_to_nav @ accel_bias,
                             gyro_sign * body_to_nav @ gyro_bias_b, times)
        wrong = np.column_stack([wrong[:, 0:2], wrong[:, 4:7]])
        assert np.sqrt(np.mean((measured[:, :2] - wrong[:, :2]) ** 2)) \
            > 2 * np.sqrt(np.mean((measured[:, :2] - model[:, :2]) ** 2))
