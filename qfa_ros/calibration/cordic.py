r"""
Fixed-point hyperbolic CORDIC exponential with an extended input range (Liu, Li and Shen, eq. 4-9).

The datapath is modelled bit for bit with Python integers (scalar path) and ``int64``
(vectorized path: numpy for the range reduction, a numba loop for the rotations); both
give identical words.  Every right shift is an arithmetic shift, i.e. it truncates
towards minus infinity, as a hardware shifter does.

Datapath (``M`` = ``m_bits``, ``N`` = ``n_bits``, ``G`` = ``guard_bits``, ``W = M + G``):

1. input word ``z_q = z * 2^M``, signed, ``N + M + 1`` bits, ``z`` in ``[-2^N, 2^N)``;
2. first multiplier (eq. 8): ``A = z_q * C_INV_LN2`` with
   ``C_INV_LN2 = round(2^W / ln 2)`` (``W + 1`` bits), so ``A = z / ln 2 * 2^(M + W)``
   in ``N + 2M + G + 2`` bits plus sign; ``Q = A >> (M + W)`` is the integer part
   (floor), ``F = A[M + W - 1 : M]`` the first ``W`` fraction bits (the paper's ``decimal_M``);
3. second multiplier (eq. 9): ``theta0_q = (F * C_LN2) >> W`` with
   ``C_LN2 = round(ln 2 * 2^W)``, so ``theta0 = theta0_q / 2^W`` lies in ``[0, ln 2)``,
   inside the convergence range of the hyperbolic CORDIC (about 1.118);
4. hyperbolic CORDIC in rotation mode on ``W``-fraction-bit registers, shift indices
   ``1 .. iterations`` with 4, 13, 40, ... executed twice, ``X_1 = Y_1 = round(2^W / K)``
   where ``K`` is the gain product of exactly the iterations executed (it tends to
   ``K_h = 0.8281593609602``) and the angle table ``round(atanh(2^-i) * 2^W)``.  With
   ``X_1 = Y_1`` the two registers stay equal, ``X_n = Y_n = e^theta0 * 2^W`` (eq. 5),
   so a single register is carried;
5. range extension (eq. 6): ``e^z = 2^Q * e^theta0``.

``guard_bits`` widens the internal words beyond the input/output scale ``2^M``.  With
``guard_bits = 0`` the datapath is the paper's (constants quantized to ``M`` bits); the
error of ``C_INV_LN2`` is then multiplied by ``|z|`` and reaches about 0.031 % at
``M = 16``, ``|z| = 64``, which is why the default carries 4 guard bits.

Accuracy
--------
The relative error of ``mantissa * 2^(Q - W)`` grows with the input range, because the
rounding of ``C_INV_LN2`` (half an LSB of ``2^W``) is multiplied by ``|z| < 2^N``; the
second multiplier, the truncations, the angle table and the shifts add a few LSBs of
``2^-W`` per iteration.  :attr:`CordicExp.relative_error_bound` is that error budget,
``expm1((2^N ln 2 / 2 + 3 n + 4) 2^-W)`` with ``n`` executed iterations, checked
against ``math.exp`` over the whole input range in the tests.  With the default 4
guard bits the error is below 0.02 % at ``M = 16`` for ``N <= 8`` (2.3e-5 at
``N = 6``) and below 2e-6 at ``M = 24`` for every ``N`` the 64-bit multiplier allows;
at ``M = 16``, ``N = 16`` it is 1.7 %.  Choose ``N`` no larger than the inputs need
(:class:`qfa_ros.calibration.fixed_point_compensator.DoubleExpCompensator` picks the smallest).

Output formats
--------------
* :meth:`CordicExp.exp_parts` returns the pair ``(mantissa, Q)`` with
  ``e^z ~= mantissa * 2^(Q - W)``, ``mantissa`` in about ``[2^W, 2^(W + 1))``: a
  floating-point result whose relative error is bounded over the whole input range,
  including very negative ``z`` (large negative ``Q``).  Hardware consumers (e.g. a
  coefficient multiplier) use this pair and shift once, at the end.
* :meth:`CordicExp.exp_fixed` returns ``e^z * 2^M`` as an integer in an unsigned output
  word of ``output_bits`` bits: the mantissa shifted by ``Q + M - W`` (truncated).  Its
  error is the mantissa's relative error plus at most one output LSB, so its *relative*
  error grows as ``e^z * 2^M`` approaches 1.  A result that would not fit the output word
  raises :class:`ValueError` (or saturates to ``2^output_bits - 1`` with
  ``saturate=True``); it is never wrapped.
"""

import math

import numba
import numpy as np

K_HYPERBOLIC = 0.8281593609602
"""Gain of the hyperbolic CORDIC with the repeated iterations 4, 13, 40, ... (limit)."""

_INT64_BITS = 63


def repeated_iterations(max_index):
    """Return the hyperbolic shift indices 1..max_index with 4, 13, 40, ... repeated."""
    indices = []
    repeat = 4
    for i in range(1, max_index + 1):
        indices.append(i)
        if i == repeat:
            indices.append(i)
            repeat = 3 * repeat + 1
    return tuple(indices)


def hyperbolic_gain(indices):
    """Return the CORDIC gain product of sqrt(1 - 2^(-2 i)) over ``indices``."""
    return math.prod(math.sqrt(1.0 - 4.0 ** (-i)) for i in indices)


@numba.njit(cache=True, nogil=True)
def _rotate(theta, x_start, shifts, angles):
    """Run the single-register hyperbolic CORDIC over every start angle (int64)."""
    x_out = np.empty_like(theta)
    for k in range(theta.shape[0]):
        x = x_start
        angle_left = theta[k]
        for j in range(shifts.shape[0]):
            if angle_left >= 0:
                x += x >> shifts[j]
                angle_left -= angles[j]
            else:
                x -= x >> shifts[j]
                angle_left += angles[j]
        x_out[k] = x
    return x_out


def _check_int(name, value, low, high):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f'{name} must be an integer, got {value!r}')
    if not low <= value <= high:
        raise ValueError(f'{name} must be in [{low}, {high}], got {value!r}')
    return int(value)


class CordicExp:
    r"""
    Fixed-point ``e^z`` by hyperbolic CORDIC with Liu, Li and Shen's range extension.

    ``e^z = 2^Q * e^theta0`` with ``z = Q ln 2 + theta0``, ``Q`` integer and
    ``theta0`` in ``[0, ln 2)`` obtained from two multipliers on ``z * 2^M`` (eq.
    7-9); ``e^theta0`` by hyperbolic CORDIC (eq. 4-5).  See the module
    docstring for the word widths and the rounding of every constant.

    Parameters
    ----------
    m_bits : int
        ``M``: fraction bits of the input and output words (scale ``2^M``), 4..30.
    n_bits : int
        ``N``: the input range is ``[-2^N, 2^N)``, 0..16.
    iterations : int or None
        Highest CORDIC shift index (repeats of 4, 13, 40 are added); default
        ``M + guard_bits + 1``, beyond which a shift yields nothing.
    guard_bits : int
        Extra fraction bits of the internal words beyond ``M`` (0 = seed datapath).
    output_bits : int
        Width of the unsigned output word of :meth:`exp_fixed`, at most 63 so that it
        fits ``numpy.int64``.

    Raises
    ------
    ValueError
        If a parameter is out of range, the first multiplier's product
        (``N + 2M + guard_bits + 3`` bits with sign) would not fit 64 bits, or
        ``W = M + guard_bits`` exceeds 31 (second multiplier, ``2W`` bits).
    """

    def __init__(self, m_bits=16, n_bits=6, iterations=None, guard_bits=4, output_bits=63):
        self.m_bits = _check_int('m_bits', m_bits, 4, 30)
        self.n_bits = _check_int('n_bits', n_bits, 0, 16)
        self.guard_bits = _check_int('guard_bits', guard_bits, 0, 16)
        self.output_bits = _check_int('output_bits', output_bits, 1, _INT64_BITS)
        self.work_bits = self.m_bits + self.guard_bits
        product_bits = self.n_bits + 2 * self.m_bits + self.guard_bits + 3
        if product_bits > 64:
            raise ValueError(
                f'm_bits={self.m_bits}, n_bits={self.n_bits}, guard_bits={self.guard_bits} '
                f'need a {product_bits}-bit first multiplier; at most 64 is supported')
        if self.work_bits > 31:
            raise ValueError(f'm_bits + guard_bits = {self.work_bits} exceeds 31: the second '
                             'multiplier (2W bits) would not fit 64 bits')
        if iterations is None:
            iterations = self.work_bits + 1
        self.iterations = _check_int('iterations', iterations, 4, 62)
        self.shift_indices = repeated_iterations(self.iterations)
        self.gain = hyperbolic_gain(self.shift_indices)
        w = self.work_bits
        self.inv_ln2_q = round(2 ** w / math.log(2.0))
        self.ln2_q = round(math.log(2.0) * 2 ** w)
        self.atanh_table = tuple(round(math.atanh(2.0 ** -i) * 2 ** w)
                                 for i in self.shift_indices)
        self.x_start = round(2 ** w / self.gain)
        self.z_min_q = -(1 << (self.n_bits + self.m_bits))
        self.z_max_q = (1 << (self.n_bits + self.m_bits)) - 1
        self._atanh_array = np.array(self.atanh_table, dtype=np.int64)
        self._shift_array = np.array(self.shift_indices, dtype=np.int64)

    def __repr__(self):
        return (f'CordicExp(m_bits={self.m_bits}, n_bits={self.n_bits}, '
                f'iterations={self.iterations}, guard_bits={self.guard_bits}, '
                f'output_bits={self.output_bits})')

    @property
    def scale(self):
        """Return the fixed-point scale ``2^M`` of the input and output words."""
        return 1 << self.m_bits

    @property
    def relative_error_bound(self):
        """Return the error budget of :meth:`exp_parts` over the whole input range.

        ``expm1((2^N ln 2 / 2 + 3 n + 4) 2^-W)``, ``n`` the executed iterations: the
        constant ``C_INV_LN2`` is off by at most half an LSB, i.e. ``|z| ln 2 2^-(W+1)``
        in the exponent, and every other rounding or truncation costs at most about
        ``2^-W`` per stage (see the module docstring).
        """
        budget = (2 ** self.n_bits * math.log(2) / 2 + 3 * len(self.shift_indices) + 4)
        return math.expm1(budget * 2.0 ** -self.work_bits)

    # -- scalar path (Python integers) ---------------------------------------------------

    def _check_input(self, z_q):
        if isinstance(z_q, bool) or not isinstance(z_q, (int, np.integer)):
            raise ValueError(f'z_q must be an integer (z * 2^M), got {z_q!r}')
        z_q = int(z_q)
        if not self.z_min_q <= z_q <= self.z_max_q:
            raise ValueError(
                f'z_q={z_q} is outside the CORDIC input range [-2^{self.n_bits}, '
                f'2^{self.n_bits}) * 2^{self.m_bits}')
        return z_q

    def reduce(self, z_q):
        """Return ``(Q, theta0_q)`` with ``z ~= Q ln 2 + theta0_q / 2^W`` (eq. 8-9)."""
        z_q = self._check_input(z_q)
        w = self.work_bits
        product = z_q * self.inv_ln2_q
        q = product >> (self.m_bits + w)
        fraction = (product >> self.m_bits) & ((1 << w) - 1)
        return q, (fraction * self.ln2_q) >> w

    def exp_parts(self, z_q):
        """Return ``(mantissa, Q)`` with ``e^z ~= mantissa * 2^(Q - W)``, W = M + guard."""
        q, theta = self.reduce(z_q)
        x = self.x_start
        for shift, angle in zip(self.shift_indices, self.atanh_table):
            if theta >= 0:
                x += x >> shift
                theta -= angle
            else:
                x -= x >> shift
                theta += angle
        return x, q

    def exp_fixed(self, z_q, saturate=False):
        """Return ``e^z * 2^M`` as an integer for the input word ``z_q = z * 2^M``."""
        mantissa, q = self.exp_parts(z_q)
        shift = q + self.m_bits - self.work_bits
        limit = (1 << self.output_bits) - 1
        if shift >= 0:
            if mantissa > limit >> shift:
                if saturate:
                    return limit
                raise ValueError(
                    f'e^z * 2^{self.m_bits} for z_q={z_q} does not fit the '
                    f'{self.output_bits}-bit output word')
            return mantissa << shift
        return mantissa >> -shift

    # -- vectorized path (numpy int64, bit-identical to the scalar path) -----------------

    def _check_input_array(self, z_q):
        z_q = np.asarray(z_q)
        if not np.issubdtype(z_q.dtype, np.integer):
            raise ValueError(f'z_q must be an integer array (z * 2^M), got dtype {z_q.dtype}')
        z_q = z_q.astype(np.int64)
        if z_q.size and (z_q.min() < self.z_min_q or z_q.max() > self.z_max_q):
            raise ValueError(
                f'z_q has values outside the CORDIC input range [-2^{self.n_bits}, '
                f'2^{self.n_bits}) * 2^{self.m_bits}')
        return z_q

    def exp_parts_array(self, z_q):
        """Return int64 arrays ``(mantissa, Q)`` for an integer array ``z_q``."""
        z_q = self._check_input_array(z_q)
        w = self.work_bits
        product = z_q * np.int64(self.inv_ln2_q)
        q = product >> np.int64(self.m_bits + w)
        fraction = (product >> np.int64(self.m_bits)) & np.int64((1 << w) - 1)
        theta = (fraction * np.int64(self.ln2_q)) >> np.int64(w)
        x = _rotate(theta.ravel(), np.int64(self.x_start), self._shift_array,
                    self._atanh_array)
        return x.reshape(z_q.shape), q

    def exp_fixed_array(self, z_q, saturate=False):
        """Return ``e^z * 2^M`` as an int64 array for an integer array ``z_q``."""
        mantissa, q = self.exp_parts_array(z_q)
        shift = q + np.int64(self.m_bits - self.work_bits)
        left = np.clip(shift, 0, _INT64_BITS)
        right = np.clip(-shift, 0, _INT64_BITS)
        limit = np.int64((1 << self.output_bits) - 1)
        overflow = mantissa > (limit >> left)
        if np.any(overflow) and not saturate:
            raise ValueError(
                f'e^z * 2^{self.m_bits} does not fit the {self.output_bits}-bit output '
                f'word for {int(np.count_nonzero(overflow))} input(s)')
        result = np.where(shift >= 0, np.where(overflow, 0, mantissa) << left,
                          mantissa >> right)
        return np.where(overflow, limit, result)

    # -- float convenience ---------------------------------------------------------------

    def quantize(self, z):
        """Return the input word ``round(z * 2^M)`` (int64 array or int), range-checked."""
        z_array = np.asarray(z, dtype=float)
        if not np.all(np.isfinite(z_array)):
            raise ValueError('z must be finite')
        z_q = np.rint(z_array * self.scale).astype(np.int64)
        self._check_input_array(z_q)
        return int(z_q) if z_q.ndim == 0 else z_q

    def exp(self, z):
        """Return ``e^z`` (float or array) computed on the fixed-point path.

        Like ``math.exp``, a result beyond the float64 range raises ``OverflowError``
        (``z`` above about 709.78; possible for ``N >= 10``) and one below it underflows
        to a subnormal or 0.
        """
        z_q = self.quantize(z)
        mantissa, q = self.exp_parts_array(np.atleast_1d(z_q))
        with np.errstate(over='ignore'):
            value = np.ldexp(mantissa.astype(float), (q - self.work_bits).astype(np.int32))
        if not np.all(np.isfinite(value)):
            raise OverflowError(f'e^z overflows float64 for z up to '
                                f'{np.max(np.atleast_1d(z_q)) / self.scale:g}')
        return float(value[0]) if np.ndim(z_q) == 0 else value
