"""Tests of the fixed-point hyperbolic CORDIC exponential (seed 2, eq. 4-9)."""

import math

import numpy as np
import numpy.testing as npt
import pytest

from qfa_ros.cordic import CordicExp, hyperbolic_gain, K_HYPERBOLIC, repeated_iterations


def _relative_error(cordic, z_q):
    mantissa, q = cordic.exp_parts_array(z_q)
    value = np.ldexp(mantissa.astype(float), (q - cordic.work_bits).astype(np.int32))
    return np.abs(value / np.exp(z_q / cordic.scale) - 1.0)


def _test_inputs(cordic, rng, count):
    """Return random words plus the edges and the words around every Q boundary."""
    boundaries = np.round(np.arange(-2 ** cordic.n_bits / math.log(2),
                                    2 ** cordic.n_bits / math.log(2) + 1)
                          * math.log(2) * cordic.scale).astype(np.int64)
    near = (boundaries[:, None] + np.arange(-2, 3)[None, :]).ravel()
    words = np.concatenate([rng.integers(cordic.z_min_q, cordic.z_max_q + 1, count), near,
                            [cordic.z_min_q, cordic.z_min_q + 1, -1, 0, 1,
                             cordic.z_max_q - 1, cordic.z_max_q]])
    return words[(words >= cordic.z_min_q) & (words <= cordic.z_max_q)]


def test_gain_matches_seed_constant():
    assert hyperbolic_gain(repeated_iterations(60)) == pytest.approx(K_HYPERBOLIC, abs=1e-12)


def test_repeated_indices_follow_3k_plus_1():
    indices = repeated_iterations(45)
    for repeated in (4, 13, 40):
        assert indices.count(repeated) == 2
    assert sum(indices.count(i) for i in range(1, 46)) == 45 + 3


def test_seed_datapath_constants():
    cordic = CordicExp(m_bits=16, n_bits=6, guard_bits=0)
    assert cordic.inv_ln2_q == round(2 ** 16 / math.log(2)) == 94548
    assert cordic.ln2_q == round(math.log(2) * 2 ** 16) == 45426
    assert cordic.atanh_table[0] == round(math.atanh(0.5) * 2 ** 16)


@pytest.mark.parametrize('m_bits, n_bits', [(16, 4), (16, 6)])
def test_exhaustive_relative_error_m16(m_bits, n_bits):
    cordic = CordicExp(m_bits=m_bits, n_bits=n_bits)
    z_q = np.arange(cordic.z_min_q, cordic.z_max_q + 1, dtype=np.int64)
    assert _relative_error(cordic, z_q).max() <= 2e-4


@pytest.mark.parametrize('seed', [0, 1])
@pytest.mark.parametrize('m_bits, n_bits, bound', [(24, 6, 2e-6), (24, 3, 2e-6), (20, 8, 2e-5)])
def test_sampled_relative_error(seed, m_bits, n_bits, bound):
    cordic = CordicExp(m_bits=m_bits, n_bits=n_bits)
    z_q = _test_inputs(cordic, np.random.default_rng(seed), 100_000)
    assert _relative_error(cordic, z_q).max() <= bound


def test_extreme_q_keeps_relative_error():
    cordic = CordicExp(m_bits=16, n_bits=6)
    _, q = cordic.exp_parts(cordic.z_min_q)
    assert q == math.floor(-64 / math.log(2))
    assert cordic.exp(-64.0) == pytest.approx(math.exp(-64.0), rel=2e-4)
    assert cordic.exp(64.0 - 2 ** -16) == pytest.approx(math.exp(64.0 - 2 ** -16), rel=2e-4)


@pytest.mark.parametrize('seed', [3, 4])
def test_scalar_and_vector_paths_bit_exact(seed):
    cordic = CordicExp(m_bits=16, n_bits=6)
    z_q = _test_inputs(cordic, np.random.default_rng(seed), 300)[::7]
    mantissa, q = cordic.exp_parts_array(z_q)
    scalar = [cordic.exp_parts(int(z)) for z in z_q]
    assert [(int(a), int(b)) for a, b in zip(mantissa, q)] == scalar
    small = z_q[z_q < 30 * cordic.scale]
    npt.assert_array_equal(cordic.exp_fixed_array(small),
                           [cordic.exp_fixed(int(z)) for z in small])


def test_range_reduction():
    cordic = CordicExp(m_bits=16, n_bits=6)
    for z in (-63.2, -1.0, -1e-4, 0.0, 0.3, 0.6931, 5.5, 63.9):
        q, theta = cordic.reduce(round(z * cordic.scale))
        assert 0 <= theta < cordic.ln2_q
        assert q * math.log(2) + theta / 2 ** cordic.work_bits == pytest.approx(z, abs=1e-4)


@pytest.mark.parametrize('z', [-11.0, -3.3, 0.0, 0.5, 7.25, 30.0])
def test_exp_fixed_is_truncated_output_word(z):
    cordic = CordicExp(m_bits=16, n_bits=6)
    z_q = round(z * cordic.scale)
    exact = math.exp(z_q / cordic.scale) * cordic.scale
    assert abs(cordic.exp_fixed(z_q) - exact) <= 1e-4 * exact + 1


def test_output_overflow_raises_or_saturates():
    cordic = CordicExp(m_bits=16, n_bits=6, output_bits=40)
    big = round(20.0 * cordic.scale)  # e^20 * 2^16 is about 2^44.9
    with pytest.raises(ValueError, match='output word'):
        cordic.exp_fixed(big)
    with pytest.raises(ValueError, match='output word'):
        cordic.exp_fixed_array(np.array([0, big]))
    assert cordic.exp_fixed(big, saturate=True) == 2 ** 40 - 1
    npt.assert_array_equal(cordic.exp_fixed_array(np.array([big]), saturate=True), [2 ** 40 - 1])
    assert cordic.exp_fixed(round(16.0 * cordic.scale)) < 2 ** 40


@pytest.mark.parametrize('z_q', [-(2 ** 22) - 1, 2 ** 22, 10 ** 12])
def test_out_of_range_input_raises(z_q):
    cordic = CordicExp(m_bits=16, n_bits=6)
    with pytest.raises(ValueError, match='input range'):
        cordic.exp_fixed(z_q)
    with pytest.raises(ValueError, match='input range'):
        cordic.exp_parts_array(np.array([0, z_q]))
    with pytest.raises(ValueError, match='input range'):
        cordic.exp(z_q / cordic.scale)


def test_float_input_word_rejected():
    cordic = CordicExp()
    with pytest.raises(ValueError, match='z_q'):
        cordic.exp_fixed(1.5)
    with pytest.raises(ValueError, match='z_q'):
        cordic.exp_parts_array(np.array([1.5]))
    with pytest.raises(ValueError, match='finite'):
        cordic.exp(float('nan'))


def test_float_convenience_vectorized():
    cordic = CordicExp(m_bits=20, n_bits=4)
    z = np.linspace(-15.9, 15.9, 1001)
    npt.assert_allclose(cordic.exp(z), np.exp(z), rtol=2e-5)
    assert isinstance(cordic.exp(0.25), float)


@pytest.mark.parametrize('kwargs, name', [
    ({'m_bits': 3}, 'm_bits'), ({'m_bits': 16.0}, 'm_bits'), ({'n_bits': -1}, 'n_bits'),
    ({'guard_bits': -1}, 'guard_bits'), ({'iterations': 2}, 'iterations'),
    ({'output_bits': 64}, 'output_bits'), ({'m_bits': 30, 'n_bits': 6}, 'm_bits=30'),
    ({'m_bits': 20, 'n_bits': 0, 'guard_bits': 12}, 'exceeds 31'),
])
def test_constructor_validation(kwargs, name):
    with pytest.raises(ValueError, match=name):
        CordicExp(**kwargs)
