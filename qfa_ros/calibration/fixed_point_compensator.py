r"""
Fixed-point evaluation of a double-exponential fit: the compensation ROM's datapath.

The datapath of Liu, Li and Shen.

The words :class:`DoubleExpCompensator` stores are the fit's coefficients in fixed point
(:func:`qfa_ros.calibration.tempfit.fit_double_exponential`); ``e^z`` is
:class:`qfa_ros.calibration.cordic.CordicExp`.
"""

import math

import numpy as np

from qfa_ros.calibration.cordic import CordicExp
from qfa_ros.calibration.tempfit import DoubleExpFit
from qfa_ros.model.checks import is_finite


def _float_word(value, m_bits):
    """Return ``(mantissa, exponent)``: ``value ~= mantissa * 2^exponent``, M+1-bit mantissa."""
    if value == 0:
        return 0, 0
    exponent = math.frexp(value)[1] - 1 - m_bits
    mantissa = round(value / 2.0 ** exponent)
    if abs(mantissa) >= 1 << (m_bits + 1):
        mantissa //= 2
        exponent += 1
    return int(mantissa), int(exponent)


def _shift(value, shift):
    return value << shift if shift >= 0 else value >> -shift


class DoubleExpCompensator:
    r"""
    Fixed-point evaluation of ``a1 e^(b1 V) + a2 e^(b2 V)`` for the compensation ROM.

    Integer datapath per term ``k`` (``M`` = ``m_bits``, ``W = M + guard_bits``):

    * ``V_q = round(V * 2^M)`` (the temperature word, ``M`` fraction bits);
    * ``beta_q = round(beta * 2^M)``; ``z_q = (beta_q * V_q) >> M`` (truncated product);
    * ``(mantissa, Q) = CordicExp(M, N).exp_parts(z_q)``, ``e^z ~= mantissa 2^(Q - W)``;
    * ``alpha ~= alpha_mantissa * 2^alpha_exponent`` with an ``M + 1``-bit signed
      mantissa (a block-floating ROM word, so small alphas keep ``M`` significant bits);
    * ``term = (alpha_mantissa * mantissa)`` shifted by
      ``alpha_exponent + Q - W + F`` (arithmetic, truncating) into the output word with
      ``F`` = ``output_frac_bits`` fraction bits; the two terms are added.

    The output is in the unit of the fitted zero output (e.g. m/s^2); its LSB is
    ``2^-F``.

    Parameters
    ----------
    fit : DoubleExpFit
        The model to evaluate.
    m_bits : int
        ``M``, fraction bits of the temperature, exponent and CORDIC words.
    n_bits : int or None
        ``N``, CORDIC input range ``[-2^N, 2^N)``; default: the smallest that holds
        ``beta * V`` over ``v_range``.
    guard_bits : int
        Guard bits of the CORDIC (see :class:`qfa_ros.calibration.cordic.CordicExp`).
    v_range : pair of float
        Accepted temperature-sensor voltages [V] (default: the ADC span 0..2.5 V of
        the default thermal model).
    output_frac_bits : int or None
        ``F``; default ``M + guard_bits`` minus the bit length of the larger term's
        peak over ``v_range``, i.e. ``W`` significant bits for the largest value.
    """

    def __init__(self, fit, m_bits=16, n_bits=None, guard_bits=4, v_range=(0.0, 2.5),
                 output_frac_bits=None):
        if not isinstance(fit, DoubleExpFit):
            raise ValueError(f'fit must be a DoubleExpFit, got {type(fit).__name__}')
        for name in ('alpha1', 'alpha2', 'beta1', 'beta2', 'offset', 'slope'):
            if not is_finite(getattr(fit, name)):
                raise ValueError(f'fit.{name} must be finite')
        self.fit = fit
        v_low, v_high = (float(x) for x in v_range)
        if not (is_finite(v_low) and is_finite(v_high) and v_low < v_high):
            raise ValueError(f'v_range must be finite with low < high, got {v_range!r}')
        self.v_range = (v_low, v_high)
        # CordicExp validates m_bits/guard_bits; probe with n_bits=0 first
        probe = CordicExp(m_bits=m_bits, n_bits=0, guard_bits=guard_bits)
        self.m_bits, self.guard_bits = probe.m_bits, probe.guard_bits
        if 2 * self.m_bits + self.guard_bits + 4 > 63:
            raise ValueError(f'm_bits={m_bits} with guard_bits={guard_bits} overflows the '
                             '64-bit coefficient multiplier')
        scale = 1 << self.m_bits
        self.v_q_range = (int(np.rint(v_low * scale)), int(np.rint(v_high * scale)))
        self.beta_q = tuple(round(b * scale) for b in fit.beta)
        self.alpha_words = tuple(_float_word(a, self.m_bits) for a in fit.alpha)
        self.line_words = (_float_word(fit.offset, self.m_bits),
                           _float_word(fit.slope, self.m_bits))
        z_extremes = [(b * v) >> self.m_bits for b in self.beta_q for v in self.v_q_range]
        # the least N with -2^(N + M) <= z < 2^(N + M) for every z: max(z, ~z) < 2^(N + M)
        needed = max(0, *(max(z, ~z).bit_length() - self.m_bits for z in z_extremes))
        if n_bits is None:
            n_bits = needed
        elif isinstance(n_bits, int) and not isinstance(n_bits, bool) and n_bits < needed:
            raise ValueError(f'n_bits={n_bits} is too small: beta*V over v_range needs '
                             f'n_bits >= {needed}')
        self.cordic = CordicExp(m_bits=self.m_bits, n_bits=n_bits, guard_bits=guard_bits)
        self.n_bits = self.cordic.n_bits
        peak = max([abs(a) * math.exp(b * v) for a, b in zip(fit.alpha, fit.beta)
                    for v in self.v_range]
                   + [abs(fit.offset)] + [abs(fit.slope * v) for v in self.v_range])
        if output_frac_bits is None:
            output_frac_bits = (self.m_bits + self.guard_bits
                                - (math.frexp(peak)[1] if peak > 0 else 0))
        if (isinstance(output_frac_bits, bool) or not isinstance(output_frac_bits, int)
                or not -64 <= output_frac_bits <= 64):
            raise ValueError(f'output_frac_bits must be an integer in [-64, 64], '
                             f'got {output_frac_bits!r}')
        self.output_frac_bits = output_frac_bits
        if peak * 2.0 ** output_frac_bits >= 2.0 ** 61:
            raise ValueError(f'output_frac_bits={output_frac_bits} overflows the output word')

    @property
    def output_lsb(self):
        """Return the output LSB ``2^-F`` in the unit of the fitted output."""
        return 2.0 ** -self.output_frac_bits

    def rom(self):
        """Return the integer ROM words (what a hardware implementation stores)."""
        rom = {'m_bits': self.m_bits, 'n_bits': self.n_bits, 'guard_bits': self.guard_bits,
               'output_frac_bits': self.output_frac_bits, 'beta_q': list(self.beta_q),
               'alpha_mantissa': [w[0] for w in self.alpha_words],
               'alpha_exponent': [w[1] for w in self.alpha_words]}
        if any(w[0] for w in self.line_words):
            rom['line_mantissa'] = [w[0] for w in self.line_words]
            rom['line_exponent'] = [w[1] for w in self.line_words]
        return rom

    def _line_q(self, v_q):
        """Return the baseline ``offset + slope V`` as output words (integer datapath)."""
        (offset_mantissa, offset_exponent), (slope_mantissa, slope_exponent) = self.line_words
        terms = ((offset_mantissa, offset_exponent + self.output_frac_bits, 1),
                 (slope_mantissa, slope_exponent - self.m_bits + self.output_frac_bits, v_q))
        return terms

    def quantize_v(self, v_temp, clip=False):
        """Return ``round(V * 2^M)`` as int64; out-of-range V raises unless ``clip``."""
        v = np.asarray(v_temp, dtype=float)
        if not np.all(np.isfinite(v)):
            raise ValueError('v_temp must be finite')
        v_q = np.rint(v * (1 << self.m_bits)).astype(np.int64)
        low, high = self.v_q_range
        if clip:
            return np.clip(v_q, low, high)
        if v_q.size and (v_q.min() < low or v_q.max() > high):
            raise ValueError(f'v_temp outside v_range {self.v_range} of the compensator')
        return v_q

    def evaluate_fixed_q(self, v_q):
        """Return the compensation word (int64, LSB ``2^-F``) for temperature words ``v_q``."""
        v_q = np.asarray(v_q, dtype=np.int64)
        low, high = self.v_q_range
        if v_q.size and (v_q.min() < low or v_q.max() > high):
            raise ValueError('v_q outside the compensator range')
        total = np.zeros(v_q.shape, dtype=np.int64)
        work = self.cordic.work_bits
        for beta_q, (alpha_mantissa, alpha_exponent) in zip(self.beta_q, self.alpha_words):
            z_q = (np.int64(beta_q) * v_q) >> np.int64(self.m_bits)
            mantissa, q = self.cordic.exp_parts_array(z_q)
            product = np.int64(alpha_mantissa) * mantissa
            shift = q + np.int64(alpha_exponent - work + self.output_frac_bits)
            left = np.clip(shift, 0, 62)
            right = np.clip(-shift, 0, 63)
            total += np.where(shift >= 0, product << left, product >> right)
        for mantissa, shift, factor in self._line_q(v_q):
            if mantissa:
                total += _shift(np.int64(mantissa) * np.asarray(factor, dtype=np.int64), shift)
        return total

    def evaluate_fixed_scalar(self, v_q):
        """Return the compensation word for one temperature word (Python-int reference)."""
        v_q = int(v_q)
        if not self.v_q_range[0] <= v_q <= self.v_q_range[1]:
            raise ValueError('v_q outside the compensator range')
        total = 0
        for beta_q, (alpha_mantissa, alpha_exponent) in zip(self.beta_q, self.alpha_words):
            mantissa, q = self.cordic.exp_parts((beta_q * v_q) >> self.m_bits)
            total += _shift(alpha_mantissa * mantissa,
                            q + alpha_exponent - self.cordic.work_bits + self.output_frac_bits)
        for mantissa, shift, factor in self._line_q(v_q):
            total += _shift(mantissa * factor, shift)
        return total

    def evaluate_fixed(self, v_temp, clip=False):
        """Return the compensation value(s) at ``v_temp`` [V] from the fixed-point path."""
        words = self.evaluate_fixed_q(self.quantize_v(v_temp, clip=clip))
        return words.astype(float) * self.output_lsb

    def evaluate_reference(self, v_temp):
        """Return the floating-point model at ``v_temp`` [V], the fixed path's yardstick."""
        return self.fit.evaluate(v_temp)


def max_m_bits(guard_bits):
    """Return the most fraction bits the 63-bit datapath holds with ``guard_bits``."""
    return (63 - guard_bits - 4) // 2
