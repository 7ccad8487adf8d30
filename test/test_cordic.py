"""Tests of the fixed-point hyperbolic CORDIC exponential (Liu, Li and Shen, eq. 4-9)."""

import math

import numpy as np
import numpy.testing as npt
import pytest

from qfa_ros.calibration.cordic import (
    CordicExp,
    hyperbolic_gain,
    K_HYPERBOLIC,
    repeated_iterations,
)


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


# --- against an independent hardware model and math.exp ----------------------------------

def _register(value, bits, signed=True):
    """Return ``value`` after checking that it fits a register of ``bits`` bits."""
    low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    assert low <= value <= high, f'{value} overflows a {bits}-bit register'
    return value


class HardwareExp:
    """Liu, Li and Shen, eq. 4-9 as a datapath of fixed-width registers, written from the paper.

    Widths: input ``N + M + 1`` (signed), first product ``N + 2M + G + 3`` (signed),
    ``Q`` ``N + 2``, fraction ``W`` and ``theta0`` ``W`` (unsigned), CORDIC ``x`` ``W + 2``
    (unsigned) and angle ``W + 2`` (signed), ``W = M + G``.
    """

    def __init__(self, m_bits, n_bits, guard_bits):
        self.m, self.n, self.w = m_bits, n_bits, m_bits + guard_bits
        self.g = guard_bits
        self.inv_ln2 = round(2 ** self.w / math.log(2))
        self.ln2 = round(math.log(2) * 2 ** self.w)
        self.shifts = []
        for i in range(1, self.w + 2):
            self.shifts += [i, i] if i in (4, 13, 40) else [i]
        gain = math.prod(math.sqrt(1 - 2.0 ** (-2 * i)) for i in self.shifts)
        self.angles = [round(math.atanh(2.0 ** -i) * 2 ** self.w) for i in self.shifts]
        self.x1 = round(2 ** self.w / gain)

    def __call__(self, z_q):
        m, n, w = self.m, self.n, self.w
        z_q = _register(z_q, n + m + 1)
        product = _register(z_q * self.inv_ln2, n + 2 * m + self.g + 3)
        q = _register(product >> (m + w), n + 2)
        fraction = _register((product >> m) % (1 << w), w, signed=False)
        theta = _register((fraction * self.ln2) >> w, w, signed=False)
        x = _register(self.x1, w + 2, signed=False)
        for shift, angle in zip(self.shifts, self.angles):
            direction = 1 if theta >= 0 else -1
            x = _register(x + direction * (x >> shift), w + 2, signed=False)
            theta = _register(theta - direction * angle, w + 2)
        return x, q


HARDWARE_CONFIGS = [(16, 6, 0), (16, 6, 4), (16, 2, 4), (12, 16, 4), (20, 8, 4), (24, 6, 4),
                    (24, 9, 4), (27, 0, 4)]


@pytest.mark.parametrize('m_bits, n_bits, guard_bits', HARDWARE_CONFIGS)
def test_bit_exact_with_a_fixed_width_hardware_model(m_bits, n_bits, guard_bits):
    cordic = CordicExp(m_bits=m_bits, n_bits=n_bits, guard_bits=guard_bits)
    hardware = HardwareExp(m_bits, n_bits, guard_bits)
    assert (cordic.inv_ln2_q, cordic.ln2_q, cordic.x_start) == (
        hardware.inv_ln2, hardware.ln2, hardware.x1)
    assert list(cordic.shift_indices) == hardware.shifts
    rng = np.random.default_rng(m_bits + n_bits)
    z_q = _test_inputs(cordic, rng, 1500)
    z_q = np.concatenate([z_q[:1500], z_q[-7:], rng.choice(z_q[1500:-7], 500)])
    expected = [hardware(int(z)) for z in z_q]
    scalar = [cordic.exp_parts(int(z)) for z in z_q]
    assert all(type(a) is int and type(b) is int for a, b in scalar)  # pure integers
    assert scalar == expected
    mantissa, q = cordic.exp_parts_array(z_q)
    assert list(zip(mantissa.tolist(), q.tolist())) == expected


def _log_relative_error(cordic, z_q):
    """Return |result / e^z - 1| computed in the log domain (no float64 overflow)."""
    mantissa, q = cordic.exp_parts_array(z_q)
    log_ratio = (np.log(mantissa.astype(float)) + (q - cordic.work_bits) * math.log(2)
                 - z_q / cordic.scale)
    return np.abs(np.expm1(log_ratio))


@pytest.mark.parametrize('m_bits, guard_bits', [(12, 4), (16, 0), (16, 4), (20, 4), (24, 4)])
def test_documented_error_budget_holds_up_to_extreme_q(m_bits, guard_bits):
    rng = np.random.default_rng(m_bits)
    for n_bits in range(0, 17):
        try:
            cordic = CordicExp(m_bits=m_bits, n_bits=n_bits, guard_bits=guard_bits)
        except ValueError:
            continue  # the first multiplier would exceed 64 bits
        z_q = _test_inputs(cordic, rng, 20000)
        assert _log_relative_error(cordic, z_q).max() <= cordic.relative_error_bound, n_bits


@pytest.mark.parametrize('m_bits, n_values, target', [
    (16, range(0, 9), 2e-4),   # issue target 0.02 % (Liu, Li and Shen: 0.019 %)
    (24, range(0, 10), 2e-6),  # every N the 64-bit multiplier allows at M = 24
])
def test_accuracy_targets_hold_for_every_allowed_range(m_bits, n_values, target):
    for n_bits in n_values:
        cordic = CordicExp(m_bits=m_bits, n_bits=n_bits)
        assert cordic.relative_error_bound <= target, n_bits
        z_q = _test_inputs(cordic, np.random.default_rng(n_bits), 20000)
        assert _log_relative_error(cordic, z_q).max() <= target, n_bits
    assert CordicExp(m_bits=16, n_bits=16).relative_error_bound > 0.01  # documented limit


@pytest.mark.parametrize('m_bits, n_bits, target', [(16, 6, 2e-4), (16, 8, 2e-4),
                                                     (24, 6, 2e-6), (24, 9, 2e-6)])
def test_edges_against_math_exp(m_bits, n_bits, target):
    cordic = CordicExp(m_bits=m_bits, n_bits=n_bits)
    words = [cordic.z_min_q, cordic.z_min_q + 1, -(1 << m_bits), -1, 0, 1, 1 << m_bits,
             cordic.z_max_q - 1, cordic.z_max_q]
    # Both sides of every Q boundary k ln 2 within the range, negative and positive.
    for k in (-int(2 ** n_bits / math.log(2)), -1, 1, int((2 ** n_bits - 1) / math.log(2))):
        boundary = math.floor(k * math.log(2) * cordic.scale)
        words += [boundary, boundary + 1]
    for z_q in words:
        mantissa, q = cordic.exp_parts(z_q)
        value = math.ldexp(mantissa, q - cordic.work_bits)
        assert abs(value / math.exp(z_q / cordic.scale) - 1) <= target, z_q
        # Q is floor(z / ln 2), or its neighbour right at a boundary (theta0 ~ 0 or ln 2).
        assert abs(math.floor(z_q / cordic.scale / math.log(2)) - q) <= 1, z_q


@pytest.mark.parametrize('output_bits', [40, 63])
def test_exp_fixed_is_never_a_wrong_number(output_bits):
    """Over the whole M = 16 input range: a close integer, or an error / saturation."""
    cordic = CordicExp(m_bits=16, n_bits=6, output_bits=output_bits)
    z_q = np.arange(cordic.z_min_q, cordic.z_max_q + 1, dtype=np.int64)
    limit = 2 ** output_bits - 1
    words = cordic.exp_fixed_array(z_q, saturate=True)
    exact = np.exp(z_q / cordic.scale) * cordic.scale
    saturated = words == limit
    # Saturation exactly where the result does not fit (up to the CORDIC error).
    assert np.all(exact[saturated] >= limit * (1 - cordic.relative_error_bound))
    fits = ~saturated
    error = np.abs(words[fits] - exact[fits])
    assert np.all(error <= cordic.relative_error_bound * exact[fits] + 1)
    first = int(np.argmax(saturated))
    assert np.all(saturated[first:]) and not np.any(saturated[:first])
    with pytest.raises(ValueError, match='output word'):
        cordic.exp_fixed_array(z_q[first:first + 1])
    with pytest.raises(ValueError, match='output word'):
        cordic.exp_fixed(int(z_q[first]))
    around = [int(z) for z in z_q[max(first - 50, 0):first]]
    assert [cordic.exp_fixed(z) for z in around] == words[max(first - 50, 0):first].tolist()
    assert cordic.exp_fixed(int(z_q[first]), saturate=True) == limit


def test_float_convenience_overflow_is_an_error():
    cordic = CordicExp(m_bits=16, n_bits=10)
    assert cordic.exp(-1000.0) == 0.0  # underflows like math.exp
    assert cordic.exp(709.0) == pytest.approx(math.exp(709.0), rel=cordic.relative_error_bound)
    with pytest.raises(OverflowError, match='float64'):
        cordic.exp(710.0)
    with pytest.raises(OverflowError):
        cordic.exp(np.array([0.0, 800.0]))
