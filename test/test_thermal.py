"""Tests of the chunk-wise thermal model."""

import math

import numpy as np
import numpy.testing as npt
import pytest
from statistics_helpers import clipped_normal_moments, normal_bound

from qfa_ros.model.constants import MICRO_G, STANDARD_GRAVITY
from qfa_ros.model.thermal import AMBIENT_PROFILES, ThermalChunk, ThermalConfig, ThermalModel


def _run_chunked(model, total, dt, rng):
    chunks = []
    while total:
        n = min(total, int(rng.integers(1, 4000)))
        chunks.append(model.run(n, dt))
        total -= n
    return ThermalChunk(*(np.concatenate(arrays) for arrays in zip(*chunks)))


@pytest.mark.parametrize('profile', AMBIENT_PROFILES)
@pytest.mark.parametrize('seed', [0, 1])
def test_chunked_run_equals_long_run(profile, seed):
    config = ThermalConfig(ambient_profile=profile, cycle_period_s=20.0, sensor_tau_s=3.0,
                           probe_tau_s=0.5, room_correlation_s=2.0,
                           hysteresis_m_s2=(5 * MICRO_G, 0.0, 10 * MICRO_G))
    long_run = ThermalModel(config, np.random.default_rng(seed)).run(25000, 1e-3)
    chunked = _run_chunked(ThermalModel(config, np.random.default_rng(seed)), 25000, 1e-3,
                           np.random.default_rng(seed + 100))
    for name in ThermalChunk._fields:
        npt.assert_array_equal(getattr(chunked, name), getattr(long_run, name), err_msg=name)


def test_same_seed_same_output_and_reset_replays():
    config = ThermalConfig(ambient_profile='room', room_correlation_s=1.0)
    first = ThermalModel(config, np.random.default_rng(7))
    a = first.run(3000, 1e-3)
    b = ThermalModel(config, np.random.default_rng(7)).run(3000, 1e-3)
    c = ThermalModel(config, np.random.default_rng(8)).run(3000, 1e-3)
    npt.assert_array_equal(a.v_temp, b.v_temp)
    npt.assert_array_equal(a.ambient_c, b.ambient_c)
    assert not np.array_equal(a.ambient_c, c.ambient_c)
    first.reset()
    npt.assert_array_equal(first.run(3000, 1e-3).v_temp, a.v_temp)


def test_parent_generator_use_does_not_shift_the_stream():
    config = ThermalConfig(ambient_profile='room', room_correlation_s=1.0)
    parent = np.random.default_rng(9)
    model = ThermalModel(config, parent)
    head = model.run(100, 1e-3)
    parent.standard_normal(1000)  # another consumer of the same generator
    tail = model.run(100, 1e-3)
    reference = ThermalModel(config, np.random.default_rng(9)).run(200, 1e-3)
    npt.assert_array_equal(np.r_[head.ambient_c, tail.ambient_c], reference.ambient_c)


@pytest.mark.parametrize('tau, dt', [(2.0, 1e-3), (300.0, 0.1), (0.05, 0.01)])
def test_lag_step_response_is_exact(tau, dt):
    config = ThermalConfig(ambient_profile='constant', ambient_c=30.0, initial_sensor_c=-10.0,
                           sensor_tau_s=tau)
    chunk = ThermalModel(config, np.random.default_rng(0)).run(2000, dt)
    expected = 30.0 - 40.0 * np.exp(-chunk.time / tau)
    npt.assert_allclose(chunk.sensor_c, expected, rtol=0, atol=1e-10)


def test_lag_ramp_response_is_exact():
    rate, tau = 0.05, 20.0
    config = ThermalConfig(ambient_profile='ramp', ambient_c=0.0, ramp_rate_c_per_s=rate,
                           ramp_limits_c=(-100.0, 100.0), sensor_tau_s=tau)
    chunk = ThermalModel(config, np.random.default_rng(0)).run(5000, 0.1)
    expected = rate * chunk.time - rate * tau * (1.0 - np.exp(-chunk.time / tau))
    npt.assert_allclose(chunk.sensor_c, expected, rtol=0, atol=1e-10)


@pytest.mark.parametrize('shape', ['trapezoid', 'sine'])
def test_cycle_profile_bounds_and_period(shape):
    config = ThermalConfig(cycle_shape=shape, cycle_period_s=100.0, cycle_dwell_fraction=0.3)
    model = ThermalModel(config, np.random.default_rng(0))
    chunk = model.run(20000, 0.01)
    assert chunk.ambient_c.max() == pytest.approx(70.0)
    assert chunk.ambient_c.min() == pytest.approx(-40.0)
    assert chunk.ambient_c[0] == pytest.approx(15.0)
    npt.assert_allclose(chunk.ambient_c[10000:], chunk.ambient_c[:10000], atol=1e-9)
    if shape == 'trapezoid':
        on_plateau = np.isclose(np.abs(chunk.ambient_c - 15.0), 55.0)
        assert on_plateau.mean() == pytest.approx(0.3, abs=0.002)


@pytest.mark.parametrize('seed', [3, 4])
def test_room_profile_stays_bounded_and_wanders(seed):
    config = ThermalConfig(ambient_profile='room', ambient_c=22.0, room_correlation_s=5.0)
    chunk = ThermalModel(config, np.random.default_rng(seed)).run(100000, 0.01)
    assert np.all(np.abs(chunk.ambient_c - 22.0) < 1.5)
    assert chunk.ambient_c.std() > 0.2


def test_temperature_sensor_noise_and_quantization():
    # The reading's error is the sensor noise (normal, sigma 1 mV) plus the rounding
    # (uniform over one LSB and independent of it: sigma is 1.6 LSB, so the normal's
    # characteristic function at 2 pi / LSB is e^-53), i.i.d. per sample. Its mean and
    # variance per seed and pooled over 5 seeds x 50 000 samples are normal with the
    # standard errors below (variance: (mu4 - var^2) / n); bounds at a false failure of
    # 1e-6 per test over the 12 checks (z 5.4: 3.4 % of the variance per seed).
    config = ThermalConfig(ambient_profile='constant', ambient_c=31.3, tsensor_noise_v=1e-3,
                           adc_bits=12)
    lsb, sigma = config.adc_lsb_v, 1e-3
    variance = sigma ** 2 + lsb ** 2 / 12
    mu4 = 3 * sigma ** 4 + 6 * sigma ** 2 * lsb ** 2 / 12 + lsb ** 4 / 80
    seeds, n = range(5, 10), 50000
    z = normal_bound(2 * len(seeds) + 2)
    errors = []
    for seed in seeds:
        chunk = ThermalModel(config, np.random.default_rng(seed)).run(n, 1e-3)
        npt.assert_allclose(chunk.v_temp_true, 0.75 + 0.01 * 6.3, rtol=1e-12)
        npt.assert_array_equal(chunk.v_temp, chunk.adc_code * lsb)
        errors.append(chunk.v_temp - chunk.v_temp_true)
    for error in errors + [np.concatenate(errors)]:
        assert abs(error.mean()) < z * math.sqrt(variance / error.size)
        assert abs(error.var() - variance) < z * math.sqrt((mu4 - variance ** 2) / error.size)


def test_noiseless_sensor_rounds_to_adc_grid():
    config = ThermalConfig(tsensor_noise_v=0.0, cycle_period_s=10.0, sensor_tau_s=1.0)
    chunk = ThermalModel(config, np.random.default_rng(0)).run(5000, 1e-3)
    expected = np.rint(chunk.v_temp_true / config.adc_lsb_v) * config.adc_lsb_v
    npt.assert_array_equal(chunk.v_temp, expected)


def test_default_bias_is_qfa_like():
    model = ThermalModel(ThermalConfig(), np.random.default_rng(0))
    temperature = np.linspace(-40.0, 70.0, 2201)
    bias = model.zero_bias(temperature)
    p2p = np.ptp(bias, axis=0)
    assert np.all((p2p > 200 * MICRO_G) & (p2p < 2000 * MICRO_G))
    assert np.abs(np.gradient(bias, temperature, axis=0)).max() < 30 * MICRO_G
    voltage = 0.75 + 0.01 * (temperature - 25.0)
    alpha, beta = np.array(model.config.bias_alpha), np.array(model.config.bias_beta)
    npt.assert_allclose(bias[:, 1], alpha[1, 0] * np.exp(beta[1, 0] * voltage)
                        + alpha[1, 1] * np.exp(beta[1, 1] * voltage), rtol=1e-12)


def test_polynomial_bias_and_scale_factor():
    config = ThermalConfig(bias_model='polynomial',
                           bias_poly=((1e-3, 2e-5, 0.0), (0.0, 0.0, 0.0), (1e-4, 0.0, 1e-7)),
                           sf_tc_ppm_per_c=(100.0, 50.0, 0.0),
                           sf_tc2_ppm_per_c2=(0.0, 0.0, 0.5))
    model = ThermalModel(config, np.random.default_rng(0))
    bias = model.zero_bias(np.array([25.0, 35.0]))
    npt.assert_allclose(bias, [[1e-3, 0.0, 1e-4], [1.2e-3, 0.0, 1e-4 + 1e-5]], rtol=1e-12)
    npt.assert_allclose(model.scale_factor_error(-15.0), [-4e-3, -2e-3, 8e-4], rtol=1e-12)


def test_hysteresis_splits_heating_and_cooling():
    amplitude = 20 * MICRO_G
    config = ThermalConfig(cycle_period_s=200.0, sensor_tau_s=2.0, hysteresis_c=2.0,
                           hysteresis_m_s2=(amplitude, 0.0, 0.0), tsensor_noise_v=0.0)
    model = ThermalModel(config, np.random.default_rng(0))
    chunk = model.run(40000, 0.01)
    hysteresis_free = model.zero_bias(chunk.sensor_c)
    split = chunk.bias[:, 0] - hysteresis_free[:, 0]
    heating = np.gradient(chunk.sensor_c) > 1e-3
    cooling = np.gradient(chunk.sensor_c) < -1e-3
    # mid-range, 55 degC = 27 hysteresis_c away from the turning points
    middle = (np.abs(chunk.sensor_c - 15.0) < 10.0) & (chunk.time > 50.0)
    npt.assert_allclose(split[heating & middle], amplitude, rtol=1e-6)
    npt.assert_allclose(split[cooling & middle], -amplitude, rtol=1e-6)
    npt.assert_array_equal(chunk.bias[:, 1], hysteresis_free[:, 1])


def test_time_is_exact_across_dt_change():
    model = ThermalModel(ThermalConfig(), np.random.default_rng(0))
    model.run(1000, 1e-3)
    chunk = model.run(10, 0.5)
    npt.assert_allclose(chunk.time, 1.0 + 0.5 * np.arange(10), rtol=1e-15)
    assert model.time == pytest.approx(6.0)


@pytest.mark.parametrize('kwargs, name', [
    ({'ambient_c': float('nan')}, 'ambient_c'), ({'sensor_tau_s': 0.0}, 'sensor_tau_s'),
    ({'ambient_profile': 'arctic'}, 'ambient_profile'), ({'adc_bits': 4}, 'adc_bits'),
    ({'bias_alpha': ((1.0, 2.0),)}, 'bias_alpha'), ({'cycle_dwell_fraction': 1.0},
                                                    'cycle_dwell_fraction'),
    ({'tsensor_noise_v': -1e-3}, 'tsensor_noise_v'), ({'cycle_low_c': 80.0}, 'cycle_low_c'),
    ({'sf_tc_ppm_per_c': (1.0, float('inf'), 0.0)}, 'sf_tc_ppm_per_c'),
    ({'initial_sensor_c': float('nan')}, 'initial_sensor_c'),
    ({'bias_poly': ((1.0, 2.0), (1.0,), (0.0,))}, 'bias_poly'),
])
def test_config_validation(kwargs, name):
    with pytest.raises(ValueError, match=name):
        ThermalConfig(**kwargs)


def test_run_and_constructor_validation():
    model = ThermalModel(ThermalConfig(), np.random.default_rng(0))
    for n, dt, name in ((-1, 1e-3, 'n'), (10, 0.0, 'dt'), (10, float('nan'), 'dt')):
        with pytest.raises(ValueError, match=name):
            model.run(n, dt)
    with pytest.raises(ValueError, match='rng'):
        ThermalModel(ThermalConfig(), 42)
    assert model.run(0, 1e-3).bias.shape == (0, 3)


@pytest.mark.parametrize('tau_s, tau_p', [(2.0, 0.5), (1.0, 3.0)])
def test_probe_lags_the_body_like_two_first_order_stages(tau_s, tau_p):
    config = ThermalConfig(ambient_profile='constant', ambient_c=30.0, initial_sensor_c=-10.0,
                           sensor_tau_s=tau_s, probe_tau_s=tau_p, tsensor_noise_v=0.0)
    model = ThermalModel(config, np.random.default_rng(0))
    chunk = model.run(10000, 1e-3)
    t = chunk.time
    body = 30.0 - 40.0 * np.exp(-t / tau_s)
    probe = 30.0 - 40.0 * (tau_s * np.exp(-t / tau_s) - tau_p * np.exp(-t / tau_p)) / (
        tau_s - tau_p)
    npt.assert_allclose(chunk.sensor_c, body, rtol=0, atol=1e-10)
    # First-order hold of a curved input: O(dt^2), 5e-7 degC here.
    npt.assert_allclose(chunk.v_temp_true, 0.75 + 0.01 * (probe - 25.0), rtol=0, atol=1e-7)
    npt.assert_array_equal(chunk.v_temp, np.rint(chunk.v_temp_true / config.adc_lsb_v)
                           * config.adc_lsb_v)
    # The zero bias follows the body (proof mass), not the lagging probe.
    npt.assert_allclose(chunk.bias, model.zero_bias(chunk.sensor_c), rtol=1e-13, atol=0)
    alpha, beta = np.array(config.bias_alpha), np.array(config.bias_beta)
    v_body = 0.75 + 0.01 * (body - 25.0)
    npt.assert_allclose(chunk.bias[:, 2], alpha[2, 0] * np.exp(beta[2, 0] * v_body)
                        + alpha[2, 1] * np.exp(beta[2, 1] * v_body), rtol=1e-9)
    npt.assert_allclose(chunk.scale_factor_error[:, 0], 80e-6 * (body - 25.0), atol=1e-13)


# -- a unit is a draw (issue 14) ---------------------------------------------------------

def _unit_curves(unit):
    grid = np.linspace(-40.0, 70.0, 221)
    return grid, unit.zero_bias(grid), unit.scale_factor_error(grid)


def test_the_same_seed_is_the_same_unit_and_two_seeds_differ():
    from qfa_ros.model.drawn_unit import draw_unit
    assert draw_unit(7) == draw_unit(7)
    a, b = draw_unit(7), draw_unit(8)
    assert np.all(np.abs(np.subtract(a.turn_on_bias, b.turn_on_bias)) > 1e-6)
    _, bias_a, sf_a = _unit_curves(a)
    _, bias_b, sf_b = _unit_curves(b)
    # different thermal curves, not only different offsets
    assert np.all(np.ptp(bias_a - bias_b, axis=0) > 10 * MICRO_G)
    assert np.all(np.ptp(sf_a - sf_b, axis=0) > 100e-6)
    with pytest.raises(ValueError, match='seed'):
        draw_unit(-1)


def test_drawn_units_stay_within_the_datasheet_spreads():
    from qfa_ros.model.drawn_unit import draw_unit
    g = STANDARD_GRAVITY
    slopes, turn_on = [], []
    for seed in range(30):
        unit = draw_unit(seed)
        grid, bias, sf = _unit_curves(unit)
        npt.assert_allclose(unit.zero_bias(25.0), unit.turn_on_bias, atol=1e-12)
        turn_on.append(unit.turn_on_bias)
        slopes.append(np.abs(np.gradient(bias, grid, axis=0)).max(axis=0))
        assert np.all(np.abs(np.gradient(sf, grid, axis=0)).max(axis=0) < 180e-6)
        k2 = np.abs(unit.k2) * g ** 2 / MICRO_G
        assert np.all((k2 >= 10.0) & (k2 <= 30.0))
        assert np.abs(unit.misalignment).max() <= 1e-3
        assert np.all(np.abs(unit.bias_aging_per_year) <= 160 * MICRO_G)
        assert np.all(np.abs(unit.sf_aging_ppm_per_year) <= 310)
        assert np.all(np.asarray(unit.hysteresis_m_s2) <= 3 * MICRO_G)
    turn_on, slopes = np.array(turn_on), np.array(slopes)
    assert np.all(np.abs(turn_on) < 4e-3 * g)
    assert np.all(slopes < 30 * MICRO_G)
    # a spread, not one shape: slopes and turn-on biases vary widely over 30 units
    assert slopes.max() / slopes.min() > 2 and np.ptp(turn_on) > 2e-3 * g


def test_a_units_config_reproduces_its_curves_and_ages():
    from qfa_ros.model.drawn_unit import draw_unit
    from qfa_ros.model.triad_config import TriadConfig
    unit = draw_unit(3)
    base = TriadConfig(thermal=ThermalConfig(ambient_profile='constant', ambient_c=10.0))
    triad = unit.triad(base, rng=0)
    assert triad.thermal.config.ambient_c == 10.0           # the ambient is kept
    model = ThermalModel(triad.thermal.config, np.random.default_rng(0))
    npt.assert_allclose(model.zero_bias(np.array([-20.0, 25.0, 60.0])),
                    unit.zero_bias(np.array([-20.0, 25.0, 60.0])), atol=1e-15)
    npt.assert_allclose(model.scale_factor_error(np.array([0.0, 50.0])),
                    unit.scale_factor_error(np.array([0.0, 50.0])), atol=1e-15)
    npt.assert_allclose(triad.config.misalignment, unit.misalignment)
    # bias aging: a year of aged time gives the yearly rate; continuous across a change
    # of the time acceleration
    triad.drift.set_time_acceleration(3.15576e7)
    npt.assert_allclose(triad.drift.bias_at(1.0), unit.bias_aging_per_year, rtol=1e-9)
    assert triad.drift.rate[0, triad.drift.components.index('b')] != 0.0


def test_units_draw_their_own_component_coefficients_from_their_own_stream():
    # Issue 28: the I_ref and forward-chain temperature coefficients are per unit (the
    # estimators measure unknowns), drawn from their own stream: no other draw moved.
    from qfa_ros.model.drawn_unit import draw_unit, FORWARD_TC_COMPONENTS, UnitSpread
    from qfa_ros.model.error_profiles import ErrorProfile
    from qfa_ros.model.triad import QfaTriad
    from qfa_ros.model.triad_config import TriadConfig
    units = [draw_unit(seed) for seed in range(200)]
    i_ref = np.array([unit.i_ref_tc_ppm_per_c for unit in units])
    forward = np.array([unit.forward_tc_ppm_per_c for unit in units])
    assert np.all((i_ref >= 0.0) & (i_ref <= 60.0))
    # 200 units x 3 axes per coefficient, each the type's mean plus sigma times a normal
    # clipped at +-3: the mean of the 600 is normal around the type's with standard error
    # sigma sqrt(m2 / 600), their mean square deviation around sigma^2 m2 with sigma^2
    # sqrt((m4 - m2^2) / 600) (m2 = 0.995, m4 = 2.89: the clipped normal's moments).
    # Bounds at a false failure of 1e-6 per test over the 8 checks (z 5.3,
    # test/statistics_helpers.py): I_ref's mean within 2.1 ppm/degC, its sigma -16/+13 %.
    spread = UnitSpread()
    m2, m4 = clipped_normal_moments(spread.tc_clip_sigmas)
    z = normal_bound(8)
    means = (spread.i_ref_tc_mean_ppm_per_c, *spread.forward_tc_mean_ppm_per_c)
    sigmas = (spread.i_ref_tc_sigma_ppm_per_c, *spread.forward_tc_sigma_ppm_per_c)
    draws = (i_ref, *np.moveaxis(forward, 1, 0))
    for values, mean, sigma in zip(draws, means, sigmas):
        n = values.size
        assert abs(values.mean() - mean) < z * sigma * np.sqrt(m2 / n), (mean, values.mean())
        spread_ratio = np.mean((values - mean) ** 2) / sigma ** 2
        assert abs(spread_ratio - m2) < z * np.sqrt((m4 - m2 ** 2) / n), (sigma, spread_ratio)
    # Seed 7's other draws are those of the draw before these were added (its turn-on bias
    # and K2, recorded from that version).
    unit = draw_unit(7)
    npt.assert_allclose(unit.turn_on_bias, (-0.01215409209511419, 0.0029759159819227133,
                                            -0.009705406379406237), rtol=1e-12)
    # The profile switches the sources, the unit sets their size.
    triad = QfaTriad(TriadConfig(), rng=0)
    unit.install_error_profile(triad, ErrorProfile())
    drift = triad.drift
    npt.assert_allclose(drift.temperature_coefficient[:, drift.components.index('i_ref')],
                        np.multiply(unit.i_ref_tc_ppm_per_c, 1e-6))
    for component, row in zip(FORWARD_TC_COMPONENTS, unit.forward_tc_ppm_per_c):
        npt.assert_allclose(drift.temperature_coefficient[:, drift.components.index(component)],
                            np.multiply(row, 1e-6))
    ideal = QfaTriad(TriadConfig(), rng=0)
    unit.install_error_profile(ideal, ErrorProfile.ideal())
    assert not ideal.drift.temperature_coefficient.any()
