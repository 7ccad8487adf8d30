"""Tests of the double-exponential fit, polynomial fits, compensator and calibration."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import numpy.testing as npt
import pytest
from statistics_helpers import normal_bound, variance_ratio_bounds

from qfa_ros.calibration.fixed_point_compensator import DoubleExpCompensator
from qfa_ros.calibration.tempfit import (
    DoubleExpFit,
    fit_double_exponential,
    fit_double_exponential_reference,
    fit_polynomial,
)
from qfa_ros.calibration.thermal_compensation import calibrate_zero_bias, TemperatureCalibration

# (alpha1, beta1, alpha2, beta2): TMP36-range voltages, m/s^2 and V-scale outputs
COEFFICIENT_SETS = [
    (7.8e-4, 2.0, 8.8e-3, -0.6),
    (-1.2e-3, 1.5, -2.5e-3, -1.2),
    (0.02, -3.0, 0.5, 0.4),
]


def _model(v, a1, b1, a2, b2):
    return a1 * np.exp(b1 * v) + a2 * np.exp(b2 * v)


def _synthetic(coefficients, seed, noise_fraction, n=400):
    rng = np.random.default_rng(seed)
    v = np.sort(rng.uniform(0.1, 1.2, n))
    clean = _model(v, *coefficients)
    return v, clean + noise_fraction * np.ptp(clean) * rng.standard_normal(n)


@pytest.mark.parametrize('coefficients', COEFFICIENT_SETS)
def test_noise_free_data_recovers_coefficients(coefficients):
    v, y = _synthetic(coefficients, 0, 0.0)
    fit = fit_double_exponential(v, y)
    a1, b1, a2, b2 = coefficients
    expected = sorted([(b1, a1), (b2, a2)])
    npt.assert_allclose([fit.beta1, fit.beta2], [expected[0][0], expected[1][0]], rtol=1e-6)
    npt.assert_allclose([fit.alpha1, fit.alpha2], [expected[0][1], expected[1][1]], rtol=1e-6)
    assert fit.converged
    assert fit.r_squared == pytest.approx(1.0, abs=1e-12)


def _jacobian(v, a1, b1, a2, b2):
    e1, e2 = np.exp(b1 * v), np.exp(b2 * v)
    return np.column_stack([e1, a1 * v * e1, e2, a2 * v * e2])


def _standard_errors(v, sigma, a1, b1, a2, b2):
    """Return the asymptotic standard errors of (a1, b1, a2, b2): sigma^2 (J^T J)^-1."""
    jacobian = _jacobian(v, a1, b1, a2, b2)
    return sigma * np.sqrt(np.diag(np.linalg.inv(jacobian.T @ jacobian)))


@pytest.mark.parametrize('coefficients', COEFFICIENT_SETS)
def test_noisy_data_recovers_curve_and_noise_level(coefficients):
    # Seeds 1-4, 400 points each. Least squares with four parameters: n rmse^2 / sigma^2
    # is chi2(n - 4); the fitted curve's error at v_i is normal with standard deviation
    # sigma sqrt(h_i) (h: the hat matrix's diagonal, from the Jacobian at the truth).
    # Bounds at a false failure of 1e-6 per test, half for the 4 rmse checks, half for
    # the 4 x 400 points (test/statistics_helpers.py): rmse within -18 %/+19 %, the curve
    # within 6.3 sigma sqrt(h_i) (0.6 sigma at most, against 4 sigma before).
    noise_fraction, n, seeds = 1e-3, 400, range(1, 5)
    low, high = variance_ratio_bounds(n - 4, 2 * len(seeds))
    z = normal_bound(2 * len(seeds) * n)
    for seed in seeds:
        v, y = _synthetic(coefficients, seed, noise_fraction, n)
        fit = fit_double_exponential(v, y)
        clean = _model(v, *coefficients)
        sigma = noise_fraction * np.ptp(clean)
        assert low < n * fit.rmse ** 2 / (n - 4) / sigma ** 2 < high, (seed, fit.rmse / sigma)
        leverage = np.sum(np.linalg.qr(_jacobian(v, *coefficients))[0] ** 2, axis=1)
        deviation = np.abs(fit.evaluate(v) - clean) / (sigma * np.sqrt(leverage))
        assert np.all(deviation < z), (seed, deviation.max())


@pytest.mark.parametrize('coefficients', COEFFICIENT_SETS)
def test_noisy_data_recovers_coefficients_within_their_standard_errors(coefficients):
    # Seeds 1-8: each fitted parameter's error over its asymptotic standard error is
    # standard normal, and their mean over the seeds is normal with sigma 1 / sqrt(8);
    # bounds at a false failure of 1e-6 per test over the 8 x 4 + 4 checks (z 5.6,
    # test/statistics_helpers.py).
    noise_fraction, seeds = 1e-3, range(1, 9)
    a1, b1, a2, b2 = coefficients
    (b_low, a_low), (b_high, a_high) = sorted([(b1, a1), (b2, a2)])
    truth = np.array([a_low, b_low, a_high, b_high])
    z = normal_bound(len(seeds) * 4 + 4)
    scores = []
    for seed in seeds:
        v, y = _synthetic(coefficients, seed, noise_fraction)
        sigma = noise_fraction * np.ptp(_model(v, *coefficients))
        fit = fit_double_exponential(v, y)
        assert fit.converged
        found = np.array([fit.alpha1, fit.beta1, fit.alpha2, fit.beta2])
        scores.append((found - truth) / _standard_errors(v, sigma, *truth))
    scores = np.array(scores)
    assert np.all(np.abs(scores) < z), scores
    assert np.all(np.abs(scores.mean(axis=0)) < z / np.sqrt(len(seeds))), scores.mean(axis=0)


@pytest.mark.parametrize('seed', [4, 5])
@pytest.mark.parametrize('coefficients', COEFFICIENT_SETS)
def test_alternating_iteration_matches_scipy_reference(coefficients, seed):
    v, y = _synthetic(coefficients, seed, 3e-3)
    fit = fit_double_exponential(v, y)
    reference = fit_double_exponential_reference(v, y)
    assert fit.converged and reference.converged
    assert fit.rmse == pytest.approx(reference.rmse, rel=1e-8)
    assert fit.r_squared == pytest.approx(reference.r_squared, rel=1e-10)
    # Same minimum: the parameters agree far inside their statistical uncertainty.
    sigma = reference.rmse
    errors = _standard_errors(v, sigma, reference.alpha1, reference.beta1, reference.alpha2,
                              reference.beta2)
    found = np.array([fit.alpha1, fit.beta1, fit.alpha2, fit.beta2])
    expected = np.array([reference.alpha1, reference.beta1, reference.alpha2, reference.beta2])
    assert np.all(np.abs(found - expected) <= 1e-4 * errors), (found - expected) / errors
    npt.assert_allclose(found, expected, rtol=1e-5)
    npt.assert_allclose(fit.evaluate(v), reference.evaluate(v), atol=1e-6 * np.ptp(y))


@pytest.mark.parametrize('beta0', [(0.5, -0.5), (4.0, -4.0), (-2.0, 1.0), (2.5, 1.0),
                                   (1.0, 0.5), (-1.0, -2.0)])
def test_start_values_do_not_change_the_result(beta0):
    v, y = _synthetic(COEFFICIENT_SETS[0], 11, 1e-3)
    automatic = fit_double_exponential(v, y)
    started = fit_double_exponential(v, y, beta0=beta0)
    assert started.converged
    assert started.rmse == pytest.approx(automatic.rmse, rel=1e-8)
    npt.assert_allclose([started.beta1, started.beta2], [automatic.beta1, automatic.beta2],
                        rtol=1e-4)


def test_bad_start_can_end_at_the_coalesced_stationary_point_like_scipy():
    """Known limit of a given start: beta1 = beta2 is a stationary point of the SSE.

    The automatic (grid) start avoids it; from (3, 2) both the alternating iteration
    and scipy stop there, with opposite, cancelling alphas.
    """
    v, y = _synthetic(COEFFICIENT_SETS[0], 11, 1e-3)
    stuck = fit_double_exponential(v, y, beta0=(3.0, 2.0))
    reference = fit_double_exponential_reference(v, y, beta0=(3.0, 2.0))
    assert stuck.rmse == pytest.approx(reference.rmse, rel=1e-8)
    assert abs(stuck.beta2 - stuck.beta1) < 1e-4 and stuck.alpha1 * stuck.alpha2 < 0
    assert stuck.rmse > 100 * fit_double_exponential(v, y).rmse


def test_mse_history_decreases_and_start_value_accepted():
    v, y = _synthetic(COEFFICIENT_SETS[0], 6, 1e-3)
    fit = fit_double_exponential(v, y, beta0=(1.0, -1.0))
    history = np.array(fit.mse_history)
    assert np.all(np.diff(history) <= 0)
    assert history[-1] == pytest.approx(fit.rmse ** 2, rel=1e-9)
    limited = fit_double_exponential(v, y, beta0=(5.0, -5.0), max_iter=1)
    assert limited.iterations == 1 and not limited.converged


@pytest.mark.parametrize('kwargs, message', [
    ({'v_temp': [0.1, 0.2], 'v_out': [1.0, 2.0]}, 'at least'),
    ({'v_temp': np.linspace(0, 1, 9), 'v_out': np.ones(8)}, 'same length'),
    ({'v_temp': np.r_[np.linspace(0, 1, 9), np.nan], 'v_out': np.ones(10)}, 'finite'),
    ({'v_temp': np.ones(10), 'v_out': np.arange(10.0)}, 'constant'),
    ({'v_temp': np.linspace(0, 1, 9), 'v_out': np.ones(9), 'tol': 0.0}, 'tol'),
    ({'v_temp': np.linspace(0, 1, 9), 'v_out': np.ones(9), 'max_iter': 0}, 'max_iter'),
    ({'v_temp': np.linspace(0, 1, 9), 'v_out': np.ones(9), 'beta0': (1.0,)}, 'beta0'),
])
def test_fit_input_validation(kwargs, message):
    with pytest.raises(ValueError, match=message):
        fit_double_exponential(**kwargs)


@pytest.mark.parametrize('order', [3, 4])
@pytest.mark.parametrize('seed', [7, 8])
def test_polynomial_fit_matches_numpy_polyfit(order, seed):
    v, y = _synthetic(COEFFICIENT_SETS[0], seed, 2e-3)
    fit = fit_polynomial(v, y, order)
    expected = np.polyfit(v, y, order)
    npt.assert_allclose(fit.coefficients, expected, rtol=1e-7, atol=1e-12 * np.abs(y).max())
    residual = y - np.polyval(expected, v)
    assert fit.rmse == pytest.approx(math.sqrt(np.mean(residual ** 2)), rel=1e-8)
    r_squared = 1 - np.sum(residual ** 2) / np.sum((y - y.mean()) ** 2)
    assert fit.r_squared == pytest.approx(r_squared, rel=1e-10)
    npt.assert_allclose(fit.evaluate(v), np.polyval(expected, v), rtol=1e-9)


def test_polynomial_of_degree_four_is_exact_and_order_validated():
    v = np.linspace(0.1, 1.2, 50)
    coefficients = [0.3, -1.0, 0.2, 0.05, -0.01]
    fit = fit_polynomial(v, np.polyval(coefficients, v), 4)
    npt.assert_allclose(fit.coefficients, coefficients, rtol=1e-9)
    with pytest.raises(ValueError, match='order'):
        fit_polynomial(v, v, -1)


def test_double_exponential_beats_poly3_on_double_exponential_data():
    v, y = _synthetic(COEFFICIENT_SETS[2], 9, 2e-5)
    assert fit_double_exponential(v, y).rmse < 0.5 * fit_polynomial(v, y, 3).rmse


def _fit(a1=7.8e-4, b1=2.0, a2=8.8e-3, b2=-0.6):
    return DoubleExpFit(a1, a2, b1, b2, 0.0, 1.0, 0, True)


@pytest.mark.parametrize('m_bits, bound', [(16, 2e-4), (24, 2e-6)])
@pytest.mark.parametrize('fit', [_fit(), _fit(-0.02, -3.0, 0.5, 0.4)])
def test_compensator_fixed_matches_float_reference(fit, m_bits, bound):
    compensator = DoubleExpCompensator(fit, m_bits=m_bits, v_range=(0.0, 2.5))
    v = np.random.default_rng(10).uniform(0.0, 2.5, 20000)
    reference = compensator.evaluate_reference(v)
    scale = np.abs(fit.alpha1 * np.exp(fit.beta1 * v)) + np.abs(fit.alpha2 * np.exp(fit.beta2 * v))
    error = np.abs(compensator.evaluate_fixed(v) - reference)
    assert np.all(error <= bound * scale + 2 * compensator.output_lsb)


def test_compensator_vector_path_bit_exact_with_scalar():
    compensator = DoubleExpCompensator(_fit(-0.02, -3.0, 0.5, 0.4), m_bits=16)
    words = compensator.quantize_v(np.random.default_rng(11).uniform(0.0, 2.5, 300))
    npt.assert_array_equal(compensator.evaluate_fixed_q(words),
                           [compensator.evaluate_fixed_scalar(w) for w in words])


def test_compensator_chooses_smallest_n_bits():
    fit = _fit(b1=9.0)  # beta*V reaches 22.5 on 0..2.5 V: N = 5
    compensator = DoubleExpCompensator(fit, v_range=(0.0, 2.5))
    assert compensator.n_bits == 5
    with pytest.raises(ValueError, match='n_bits'):
        DoubleExpCompensator(fit, n_bits=4, v_range=(0.0, 2.5))


def test_compensator_range_checks():
    compensator = DoubleExpCompensator(_fit(), v_range=(0.0, 1.5))
    with pytest.raises(ValueError, match='v_range'):
        compensator.evaluate_fixed([1.6])
    clipped = compensator.evaluate_fixed([1.6], clip=True)
    npt.assert_array_equal(clipped, compensator.evaluate_fixed([1.5]))
    with pytest.raises(ValueError, match='v_range'):
        DoubleExpCompensator(_fit(), v_range=(1.0, 1.0))
    with pytest.raises(ValueError, match='fit'):
        DoubleExpCompensator((1.0, 2.0))


def _cycle_data(seed, n=20000):
    rng = np.random.default_rng(seed)
    phase = np.linspace(0.0, 2.0, n)
    v = 0.65 + 0.55 * np.sin(2 * np.pi * phase) + 2e-4 * rng.standard_normal(n)
    bias = _model(v, 7.8e-4, 2.0, 8.8e-3, -0.6)
    return v, bias + 5e-5 * rng.standard_normal(n), bias


@pytest.mark.parametrize('seed', [12, 13])
def test_calibration_reduces_peak_to_peak(seed):
    v, output, _ = _cycle_data(seed)
    calibration = calibrate_zero_bias(v, output, m_bits=16)
    assert calibration.fit.converged
    assert calibration.reduction >= 30
    dense = _model(np.linspace(0.1, 1.2, 1001), 7.8e-4, 2.0, 8.8e-3, -0.6)
    assert calibration.p2p_before == pytest.approx(np.ptp(dense), rel=0.05)
    assert calibration.max_fixed_error < 1e-6
    assert calibration.poly4.rmse <= calibration.poly3.rmse
    assert calibration.cancellation_bits < 2


def test_calibration_flags_degenerate_fit_of_s_curve():
    temperature = np.linspace(-40.0, 70.0, 2000) - 25.0
    v = 0.75 + 0.01 * temperature
    s_curve = 1e-4 * temperature + 5e-7 * temperature ** 2 - 1.5e-8 * temperature ** 3
    calibration = calibrate_zero_bias(v, s_curve)
    assert calibration.fit.r_squared < 0.99
    assert calibration.poly3.r_squared == pytest.approx(1.0, abs=1e-9)
    assert calibration.cancellation_bits > 8


def test_calibration_json_round_trip_and_rom_check():
    v, output, _ = _cycle_data(14)
    calibration = calibrate_zero_bias(v, output)
    record = json.loads(json.dumps(calibration.to_dict()))
    restored = TemperatureCalibration.from_dict(record)
    assert restored == calibration
    words = restored.compensator().evaluate_fixed_q(restored.compensator().quantize_v(v[:100]))
    npt.assert_array_equal(words, calibration.compensator().evaluate_fixed_q(
        calibration.compensator().quantize_v(v[:100])))
    record['rom']['beta_q'][0] += 1
    with pytest.raises(ValueError, match='rom'):
        TemperatureCalibration.from_dict(record)
    with pytest.raises(ValueError, match='invalid'):
        TemperatureCalibration.from_dict({'alpha': [1.0]})


# -- linear baseline (issue 14: curves that are not the double exponential's shape) --------

def _mixed_curve():
    v = np.linspace(0.1, 1.2, 80)
    t = (v - 0.75) / 0.01
    x = t / 55.0
    # an exponential under a cubic trend: what a drawn unit looks like (model/drawn_unit.py)
    return v, 1e-3 * (0.4 * np.exp(2.5 * (v - 0.75)) + 0.8 * x - 0.3 * x ** 2 + 0.15 * x ** 3)


def test_baseline_fits_a_curve_the_pure_model_cannot():
    v, y = _mixed_curve()
    pure = calibrate_zero_bias(v, y, n_bins=80)
    lined = calibrate_zero_bias(v, y, n_bins=80, baseline=True)
    assert lined.p2p_after < 0.01 * pure.p2p_before
    assert lined.p2p_after < 0.2 * pure.p2p_after
    assert lined.cancellation_bits < 8          # the fixed-point words keep their bits
    fit = lined.fit
    npt.assert_allclose(fit.evaluate(v), fit.alpha1 * np.exp(fit.beta1 * v)
                        + fit.alpha2 * np.exp(fit.beta2 * v) + fit.offset + fit.slope * v)


def test_baseline_compensator_is_bit_exact_with_its_scalar_reference_and_round_trips():
    v, y = _mixed_curve()
    calibration = calibrate_zero_bias(v, y, n_bins=80, baseline=True)
    compensator = calibration.compensator()
    assert 'line_mantissa' in compensator.rom()
    words = compensator.quantize_v(v)
    assert [compensator.evaluate_fixed_scalar(w) for w in words] == \
        compensator.evaluate_fixed_q(words).tolist()
    npt.assert_allclose(compensator.evaluate_fixed(v), calibration.fit.evaluate(v),
                        atol=1e-3 * np.ptp(y))
    restored = TemperatureCalibration.from_dict(json.loads(json.dumps(calibration.to_dict())))
    assert restored.compensator().rom() == compensator.rom()
    assert restored.fit.offset == calibration.fit.offset


def test_a_cancelling_fit_gets_the_fraction_bits_it_loses():
    # Issue 28: a double exponential whose terms cancel (an S-shaped curve outside the
    # family) lost those bits in the 16-bit compensator: the population study's failures
    # (tens to thousands of ug). The compensator now widens its words by the cancellation
    # beyond the guard bits.
    from qfa_ros.calibration.fixed_point_compensator import DoubleExpCompensator
    from qfa_ros.calibration.thermal_compensation import calibrate_zero_bias
    v = np.linspace(0.35, 1.2, 2000)
    y = 1e-3 * ((v - 0.75) / 0.45) ** 3
    calibration = calibrate_zero_bias(v, y, m_bits=16, n_bins=60, baseline=True)
    assert calibration.cancellation_bits > 6.0
    assert calibration.m_bits == 16 + math.ceil(calibration.cancellation_bits) - 4
    narrow = DoubleExpCompensator(calibration.fit, m_bits=16, guard_bits=4,
                                  v_range=calibration.v_range)
    v_bins = np.linspace(0.36, 1.19, 50)
    exact = calibration.fit.evaluate(v_bins)
    wide_error = np.abs(calibration.compensator().evaluate_fixed(v_bins) - exact).max()
    narrow_error = np.abs(narrow.evaluate_fixed(v_bins) - exact).max()
    assert wide_error < narrow_error / 8
    # A well-conditioned fit keeps the requested bits.
    plain = calibrate_zero_bias(v, 1e-3 * np.exp(2.0 * v), m_bits=16, n_bins=60)
    assert plain.cancellation_bits < 4 and plain.m_bits == 16


ONE_EXPONENTIAL_FIT = """
import json
import numpy as np
from qfa_ros.calibration.thermal_compensation import calibrate_zero_bias
v = np.linspace(0.35, 1.2, 2000)
calibration = calibrate_zero_bias(v, 1e-3 * np.exp(2.0 * v), m_bits=16, n_bins=60)
fit = calibration.fit
print(json.dumps([fit.alpha1, fit.alpha2, fit.beta1, fit.beta2, calibration.cancellation_bits,
                  calibration.m_bits]))
"""


def test_data_one_exponential_explains_get_it_whatever_the_blas_kernel():
    # The pair is unidentifiable there: the alternation stopped where the rounding of
    # each OpenBLAS kernel left it (beta2 at the grid's edge, or near-equal exponents with
    # cancelling alphas: 7.4 cancelled bits were seen beside numpy 1.26). The fit is now
    # the single exponential, alpha2 = 0, on every kernel.
    fits = {}
    for core in ('Prescott', 'Sandybridge', 'Haswell'):
        result = subprocess.run([sys.executable, '-c', ONE_EXPONENTIAL_FIT], text=True,
                                env=dict(os.environ, OPENBLAS_CORETYPE=core),
                                capture_output=True, timeout=120, check=True)
        fits[core] = json.loads(result.stdout)
    for core, (alpha1, alpha2, beta1, beta2, cancelled, m_bits) in fits.items():
        assert alpha2 == 0.0 and beta1 == beta2, (core, fits[core])
        assert alpha1 == pytest.approx(1e-3, rel=1e-4) and beta1 == pytest.approx(2.0, rel=1e-6)
        assert cancelled == 0.0 and m_bits == 16
    reference = fits['Prescott']
    assert all(fit == pytest.approx(reference, rel=1e-12) for fit in fits.values()), fits


def test_a_fit_cancelling_beyond_any_word_is_refitted_within_the_words():
    # Population unit 63 y: a bias fit whose terms cancelled by 29.7 bits, beyond the
    # widest words (27 fraction bits), compensated garbage (2321 ug). The calibration now
    # refits such an axis with the cancellation bounded by what the words absorb.
    from qfa_ros.calibration.fixed_point_compensator import max_m_bits
    from qfa_ros.calibration.tempfit import cancellation_bits
    v = np.linspace(0.35, 1.2, 2000)
    y = 1e-3 * ((v - 0.75) / 0.45) ** 3
    v_bins = np.linspace(0.36, 1.19, 50)
    free = fit_double_exponential(v_bins, 1e-3 * ((v_bins - 0.75) / 0.45) ** 3, baseline=True)
    m_bits = max_m_bits(4) - 2          # words that absorb 2 + 4 guard bits only
    budget = max_m_bits(4) - m_bits + 4
    basis = np.column_stack([np.exp(np.outer(v_bins, free.beta)), np.ones_like(v_bins),
                             v_bins])
    assert cancellation_bits(basis, np.array([*free.alpha, free.offset, free.slope])) > budget
    calibration = calibrate_zero_bias(v, y, m_bits=m_bits, n_bins=60, baseline=True)
    assert calibration.cancellation_bits <= budget
    exact = calibration.fit.evaluate(v_bins)
    # What the words hold is what the fit says, to the output's last bits...
    npt.assert_allclose(calibration.compensator().evaluate_fixed(v_bins), exact,
                        atol=1e-6 * np.ptp(y))
    # ...and the constrained fit still takes the curve out (2 % of its p2p left).
    assert calibration.p2p_after < 0.02 * calibration.p2p_before


def test_a_constrained_fit_keeps_its_bound_and_validates_it():
    from qfa_ros.calibration.tempfit import cancellation_bits
    v = np.linspace(0.35, 1.2, 60)
    y = 1e-3 * ((v - 0.75) / 0.45) ** 3
    for bound in (2.0, 5.0, 8.0):
        fit = fit_double_exponential(v, y, baseline=True, max_cancellation_bits=bound)
        basis = np.column_stack([np.exp(np.outer(v, fit.beta)), np.ones_like(v), v])
        assert cancellation_bits(basis, np.array([*fit.alpha, fit.offset, fit.slope])) \
            <= bound + 1e-9
    for bad in (-1.0, math.nan, 'five'):
        with pytest.raises(ValueError, match='max_cancellation_bits'):
            fit_double_exponential(v, y, max_cancellation_bits=bad)
