"""
Temperature calibration of one axis and the triad's compensation built from it (Liu, Li and Shen).

:func:`calibrate_zero_bias` bins a temperature cycle by V_temp, fits the double exponential
and the comparison polynomials (:mod:`qfa_ros.calibration.tempfit`) and builds the
fixed-point compensator (:mod:`qfa_ros.calibration.fixed_point_compensator`): a
:class:`TemperatureCalibration`, the ROM contents of one axis. :class:`ThermalCompensation`
applies the bias and scale-factor calibrations of three axes and the tumble's constant
terms to the triad's output.
"""

from dataclasses import dataclass
import math
import time

import numpy as np

from qfa_ros.calibration.fixed_point_compensator import DoubleExpCompensator, max_m_bits
from qfa_ros.calibration.tempfit import (
    bin_by_temperature,
    cancellation_bits,
    DoubleExpFit,
    fit_double_exponential,
    fit_polynomial,
    PolynomialFit,
)
from qfa_ros.model.triad import AXES


def _poly_to_dict(poly):
    return {'order': poly.order, 'coefficients': list(poly.coefficients), 'rmse': poly.rmse,
            'r_squared': poly.r_squared, 'center': poly.center,
            'half_range': poly.half_range,
            'scaled_coefficients': list(poly.scaled_coefficients)}


def _poly_from_dict(data):
    return PolynomialFit(tuple(data['coefficients']), float(data['rmse']),
                         float(data['r_squared']), int(data['order']), float(data['center']),
                         float(data['half_range']), tuple(data['scaled_coefficients']))


@dataclass(frozen=True)
class TemperatureCalibration:
    """
    Result of a zero-bias temperature calibration of one axis (the ROM contents).

    Attributes
    ----------
    fit : DoubleExpFit
        Double-exponential model of the binned zero output vs V_temp.
    poly3, poly4 : PolynomialFit
        3rd/4th-order comparison fits on the same bins (Liu, Li and Shen, Tables 1-2).
    m_bits, n_bits, guard_bits, output_frac_bits : int
        Fixed-point format of the compensator.
    v_range : tuple of float
        Temperature-sensor voltages the compensator accepts [V].
    n_points : int
        Number of V_temp bins the fits used.
    p2p_before, p2p_after : float
        Peak-to-peak of the binned zero output before and after the fixed-point
        compensation (output unit).
    p2p_after_poly4 : float
        Same after subtracting the 4th-order polynomial (float), for comparison.
    max_fixed_error : float
        Largest ``|fixed - float|`` of the compensator on the bins (output unit).
    fit_seconds : float
        Wall time of the double-exponential fit.
    cancellation_bits : float
        ``log2(max |larger term| / max |sum|)`` over the bins: bits the two terms lose by
        cancelling.  Near ``m_bits`` the fixed-point output is meaningless; large values
        flag a degenerate fit (``beta1 ~ beta2``, huge opposite alphas), i.e. data a
        double exponential does not describe (e.g. an S-shaped curve).
    """

    fit: DoubleExpFit
    poly3: PolynomialFit
    poly4: PolynomialFit
    m_bits: int
    n_bits: int
    guard_bits: int
    output_frac_bits: int
    v_range: tuple
    n_points: int
    p2p_before: float
    p2p_after: float
    p2p_after_poly4: float
    max_fixed_error: float
    fit_seconds: float = 0.0
    cancellation_bits: float = 0.0

    @property
    def reduction(self):
        """Return ``p2p_before / p2p_after`` (inf if the residual is flat)."""
        return self.p2p_before / self.p2p_after if self.p2p_after > 0 else math.inf

    def compensator(self):
        """Return the fixed-point compensator described by this calibration."""
        return DoubleExpCompensator(self.fit, m_bits=self.m_bits, n_bits=self.n_bits,
                                    guard_bits=self.guard_bits, v_range=self.v_range,
                                    output_frac_bits=self.output_frac_bits)

    def to_dict(self):
        """Return a JSON-serializable dict (floats round-trip exactly through json)."""
        fit = self.fit
        return {
            'model': 'double_exponential',
            'alpha': [fit.alpha1, fit.alpha2], 'beta': [fit.beta1, fit.beta2],
            'line': [fit.offset, fit.slope],
            'fit': {'rmse': fit.rmse, 'r_squared': fit.r_squared,
                    'iterations': fit.iterations, 'converged': fit.converged},
            'm_bits': self.m_bits, 'n_bits': self.n_bits, 'guard_bits': self.guard_bits,
            'output_frac_bits': self.output_frac_bits, 'v_range': list(self.v_range),
            'rom': self.compensator().rom(),
            'poly3': _poly_to_dict(self.poly3), 'poly4': _poly_to_dict(self.poly4),
            'n_points': self.n_points, 'p2p_before': self.p2p_before,
            'p2p_after': self.p2p_after, 'p2p_after_poly4': self.p2p_after_poly4,
            'max_fixed_error': self.max_fixed_error, 'fit_seconds': self.fit_seconds,
            'cancellation_bits': self.cancellation_bits,
        }

    @classmethod
    def from_dict(cls, data):
        """Rebuild from :meth:`to_dict` output; ValueError if the ROM words disagree."""
        try:
            fit_info = data['fit']
            fit = DoubleExpFit(float(data['alpha'][0]), float(data['alpha'][1]),
                               float(data['beta'][0]), float(data['beta'][1]),
                               float(fit_info['rmse']), float(fit_info['r_squared']),
                               int(fit_info['iterations']), bool(fit_info['converged']),
                               offset=float(data.get('line', (0.0, 0.0))[0]),
                               slope=float(data.get('line', (0.0, 0.0))[1]))
            calibration = cls(fit, _poly_from_dict(data['poly3']),
                              _poly_from_dict(data['poly4']), int(data['m_bits']),
                              int(data['n_bits']), int(data['guard_bits']),
                              int(data['output_frac_bits']), tuple(data['v_range']),
                              int(data['n_points']), float(data['p2p_before']),
                              float(data['p2p_after']), float(data['p2p_after_poly4']),
                              float(data['max_fixed_error']),
                              float(data.get('fit_seconds', 0.0)),
                              float(data.get('cancellation_bits', 0.0)))
        except (KeyError, IndexError, TypeError) as error:
            raise ValueError(f'invalid temperature calibration record: {error!r}') from error
        if 'rom' in data and data['rom'] != calibration.compensator().rom():
            raise ValueError('rom words do not match the stored coefficients')
        return calibration


def _fit_cancellation(fit, v):
    """Return the bits the terms of ``fit`` cancel by at the voltages ``v`` [V]."""
    basis = np.column_stack([np.exp(np.outer(v, fit.beta)), np.ones_like(v), v])
    return cancellation_bits(basis, np.array([*fit.alpha, fit.offset, fit.slope]))


def calibrate_zero_bias(v_temp, zero_output, m_bits=16, n_bins=100, min_count=1,
                        v_range=None, guard_bits=4, baseline=False):
    """
    Calibrate the zero-bias temperature model of one axis from a temperature cycle.

    The samples are averaged in ``n_bins`` equal-width V_temp bins (this removes the
    white noise and the time order), the double exponential is fitted by
    :func:`fit_double_exponential` on the bin means, the 3rd/4th-order polynomials on
    the same points, and the fixed-point compensator is built and applied to the bins.

    Parameters
    ----------
    v_temp : array_like
        Measured temperature-sensor voltage [V] per sample.
    zero_output : array_like
        Zero output of the axis per sample (any unit, e.g. m/s^2).
    m_bits : int
        Fixed-point fraction bits of the compensator: at least these; a fit whose terms
        cancel by more than ``guard_bits`` gets the bits the cancellation takes on top
        (up to :func:`max_m_bits`), so a degenerate fit keeps its precision; a fit
        cancelling by more than those words can absorb is refitted with
        ``max_cancellation_bits`` at that bound (:func:`fit_double_exponential`).
    n_bins, min_count : int
        Number of V_temp bins and the least samples a bin needs to be used.
    v_range : pair of float, optional
        Voltages the compensator accepts; default the data span widened by 25 % of
        itself on each side (not below 0 V if the data are all >= 0).
    guard_bits : int
        CORDIC guard bits.
    baseline : bool
        Fit the double exponential with a linear baseline (:func:`fit_double_exponential`).

    Returns
    -------
    TemperatureCalibration
    """
    v_bins, y_bins, _ = bin_by_temperature(v_temp, zero_output, n_bins, min_count)
    if v_bins.size < 5:
        raise ValueError(f'only {v_bins.size} V_temp bins hold data; at least 5 are needed')
    started = time.perf_counter()
    fit = fit_double_exponential(v_bins, y_bins, baseline=baseline)
    fit_seconds = time.perf_counter() - started
    poly3 = fit_polynomial(v_bins, y_bins, 3)
    poly4 = fit_polynomial(v_bins, y_bins, 4)
    if v_range is None:
        v_range = _widened_span(v_bins)
    cancellation = _fit_cancellation(fit, v_bins)
    # The most the widened words below can absorb; a fit cancelling more is refitted
    # under that bound (a slightly worse float fit the fixed-point datapath evaluates
    # exactly beats a better one it cannot).
    budget = max_m_bits(guard_bits) - m_bits + guard_bits
    if cancellation > budget:
        try:
            constrained = fit_double_exponential(v_bins, y_bins, baseline=baseline,
                                                 max_cancellation_bits=budget)
        except ValueError:
            constrained = None
        if constrained is not None:
            fit, cancellation = constrained, _fit_cancellation(constrained, v_bins)
        fit_seconds = time.perf_counter() - started
    compensator = _widened_compensator(fit, cancellation, m_bits, guard_bits, v_range)
    fixed = compensator.evaluate_fixed(v_bins)
    return TemperatureCalibration(
        fit=fit, poly3=poly3, poly4=poly4, m_bits=compensator.m_bits,
        n_bits=compensator.n_bits, guard_bits=compensator.guard_bits,
        output_frac_bits=compensator.output_frac_bits, v_range=compensator.v_range,
        n_points=int(v_bins.size), p2p_before=float(np.ptp(y_bins)),
        p2p_after=float(np.ptp(y_bins - fixed)),
        p2p_after_poly4=float(np.ptp(y_bins - poly4.evaluate(v_bins))),
        max_fixed_error=float(np.max(np.abs(fixed - fit.evaluate(v_bins)))),
        fit_seconds=fit_seconds, cancellation_bits=float(max(cancellation, 0.0)))


def _widened_span(v_bins):
    """Return the span of ``v_bins`` [V] widened by 25 % of itself on each side."""
    span = float(v_bins.max() - v_bins.min())
    low = float(v_bins.min()) - 0.25 * span
    # a unipolar temperature ADC never reads below 0 V
    return (max(low, 0.0) if v_bins.min() >= 0 else low, float(v_bins.max()) + 0.25 * span)


def _widened_compensator(fit, cancellation, m_bits, guard_bits, v_range):
    """
    Return the compensator of ``fit``, its words widened by what its terms cancel.

    Terms that cancel by c bits cost the fixed-point output c bits: beyond the guard bits,
    the words are widened by what the cancellation takes, within the 63-bit datapath, and
    narrowed again (not below ``m_bits``) where they overflow a multiplier of this fit's.

    Raises
    ------
    ValueError
        Not even ``m_bits`` fraction bits fit the datapath.
    """
    widen = max(0, math.ceil(min(cancellation, 64.0)) - guard_bits)
    bits = min(max_m_bits(guard_bits), m_bits + widen)
    while True:
        try:
            return DoubleExpCompensator(fit, m_bits=bits, guard_bits=guard_bits,
                                        v_range=v_range)
        except ValueError:
            # The widened words overflow a multiplier of this fit's datapath: fewer.
            if bits <= m_bits:
                raise
            bits -= 1


# -- multi-position compensation (bias and scale factor per axis) ------------------------


class ThermalCompensation:
    r"""
    Output compensation of a triad from a multi-position temperature calibration.

    Per axis ``i``, with ``V`` the measured temperature-sensor voltage:
    ``y'_i = (y_i - b_i(V)) (1 + c_i(V))`` where ``b_i`` is the zero bias and
    ``c_i = 1/(1 + s_i) - 1`` the scale-factor correction, both evaluated on the
    fixed-point CORDIC path (:class:`DoubleExpCompensator`); then the constant terms the
    tumble measured: ``a = (I + M)^-1 y'`` (misalignment) and ``a_i - k2_i a_i^2``.

    Parameters
    ----------
    bias, scale : list of TemperatureCalibration
        Zero-bias [m/s^2] and scale-factor-correction [1] calibrations per axis.
    misalignment : array_like
        3x3 cross-coupling ``M`` (the diagonal is the scale factor's: zero here).
    k2 : array_like
        Second-order coefficient per axis [1/(m/s^2)].
    """

    def __init__(self, bias, scale, misalignment=np.zeros((3, 3)), k2=(0.0, 0.0, 0.0)):
        if len(bias) != 3 or len(scale) != 3:
            raise ValueError('bias and scale need one calibration per axis')
        self.bias = list(bias)
        self.scale = list(scale)
        self.misalignment = np.asarray(misalignment, dtype=float)
        if self.misalignment.shape != (3, 3) or not np.all(np.isfinite(self.misalignment)):
            raise ValueError('misalignment must be a finite 3x3 matrix')
        self.k2 = np.asarray(k2, dtype=float)
        if self.k2.shape != (3,) or not np.all(np.isfinite(self.k2)):
            raise ValueError('k2 must be 3 finite numbers')
        self._bias = [c.compensator() for c in self.bias]
        self._scale = [c.compensator() for c in self.scale]
        self._inverse = np.linalg.inv(np.eye(3) + self.misalignment)

    def apply(self, accel, v_temp):
        """Return the compensated output (n, 3) [m/s^2] of ``accel`` at ``v_temp`` [V]."""
        out = np.empty_like(accel)
        for i in range(3):
            out[:, i] = (accel[:, i] - self._bias[i].evaluate_fixed(v_temp, clip=True)) * (
                1.0 + self._scale[i].evaluate_fixed(v_temp, clip=True))
        out = out @ self._inverse.T
        return out - self.k2 * out * out

    def to_dict(self):
        """Return the JSON-serializable ROM record (``state.temperature``)."""
        return {'format': 'multiposition/1',
                'bias': {a: c.to_dict() for a, c in zip(AXES, self.bias)},
                'scale': {a: c.to_dict() for a, c in zip(AXES, self.scale)},
                'misalignment': self.misalignment.tolist(), 'k2': self.k2.tolist()}

    @classmethod
    def from_dict(cls, data):
        """Rebuild from :meth:`to_dict` output; ValueError on a malformed record."""
        try:
            if data.get('format') != 'multiposition/1':
                raise ValueError('temperature record: unknown format (run calibrate_temperature '
                                 'again)')
            return cls([TemperatureCalibration.from_dict(data['bias'][a]) for a in AXES],
                       [TemperatureCalibration.from_dict(data['scale'][a]) for a in AXES],
                       data['misalignment'], data['k2'])
        except (KeyError, TypeError, AttributeError) as error:
            raise ValueError(f'invalid temperature record: {error!r}') from error
