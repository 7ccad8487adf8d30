r"""
Zero-bias temperature model fitting and its fixed-point compensator (seed 2).

The zero bias is modelled as ``y = alpha1 e^(beta1 V) + alpha2 e^(beta2 V)`` (seed eq. 1)
with ``V`` the on-board temperature-sensor voltage [V] and ``y`` the zero output (any
unit: V, m/s^2, counts; the alphas carry it, the betas are in 1/V).  It is fitted by
the seed's alternating iteration and compared with 3rd/4th-order polynomials (seed
Tables 1-2); the compensator evaluates it on the fixed-point CORDIC path. The fits,
their comparison and the compensator built from them are one cohesive thing: the
compensator's ROM is the fit's coefficients in fixed point, so they live together.
"""

import dataclasses
from dataclasses import dataclass, field
import math
import time

import numpy as np

from qfa_ros.calibration.cordic import CordicExp

_START_GRID = np.linspace(-6.0, 6.0, 25)
"""Scaled exponents ``beta * half_range`` tried for the automatic start values."""

_LM_MAX_TRIALS = 12


# -- shared helpers ---------------------------------------------------------------------


def _as_data(v, y, min_points):
    v = np.asarray(v, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if v.shape != y.shape:
        raise ValueError(f'v_temp and v_out must have the same length, got {v.size}, {y.size}')
    if v.size < min_points:
        raise ValueError(f'at least {min_points} points are needed, got {v.size}')
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(y))):
        raise ValueError('v_temp and v_out must be finite')
    if np.ptp(v) <= 0:
        raise ValueError('v_temp must not be constant')
    return v, y


def _goodness(y, prediction):
    residual = y - prediction
    sse = float(residual @ residual)
    sst = float(((y - y.mean()) ** 2).sum())
    r_squared = 1.0 - sse / sst if sst > 0 else (1.0 if sse == 0 else 0.0)
    return math.sqrt(sse / y.size), r_squared


class _Scaling:
    """Map ``V`` to ``u = (V - center) / half_range`` in [-1, 1] and ``y`` to unit rms."""

    def __init__(self, v, y):
        self.center = 0.5 * (v.max() + v.min())
        self.half_range = 0.5 * (v.max() - v.min())
        self.y_scale = float(np.sqrt(np.mean(y ** 2))) or 1.0
        self.u = (v - self.center) / self.half_range
        self.y = y / self.y_scale

    def to_physical(self, alpha_scaled, s):
        """Return (alpha, beta) of the unscaled model from scaled ones (exact)."""
        beta = np.asarray(s) / self.half_range
        alpha = np.asarray(alpha_scaled) * self.y_scale * np.exp(-beta * self.center)
        return alpha, beta

    def to_scaled(self, beta):
        return np.asarray(beta, dtype=float) * self.half_range


def _basis(u, s):
    return np.exp(np.outer(u, s))


def _solve_alpha(u, y, s, baseline=False):
    basis = _basis(u, s)
    if baseline:
        basis = np.column_stack([basis, np.ones_like(u), u])
    alpha = np.linalg.lstsq(basis, y, rcond=None)[0]
    residual = y - basis @ alpha
    return alpha, residual, basis


def cancellation_bits(basis, alpha):
    """
    Return how many bits the fit's terms cancel by over its points.

    ``log2(largest |term| / largest |sum|)``, each exponential and the linear baseline
    being one term: a fixed-point evaluation of the sum loses these bits.

    Parameters
    ----------
    basis : ndarray, shape (n, 2) or (n, 4)
        The exponentials at the points, then (with a baseline) the columns ``1`` and ``V``.
    alpha : ndarray, shape (2,) or (4,)
        The coefficients of the columns.
    """
    terms = basis[:, :2] * alpha[None, :2]
    if basis.shape[1] > 2:
        terms = np.column_stack([terms, basis[:, 2:] @ alpha[2:]])
    sum_peak = float(np.abs(terms.sum(axis=1)).max())
    term_peak = float(np.abs(terms).max())
    return math.log2(term_peak / sum_peak) if sum_peak > 0 else math.inf


def _grid_start(u, y, baseline=False, max_cancellation_bits=None):
    """Return the scaled exponent pair of a small grid with the lowest projected SSE."""
    if baseline or max_cancellation_bits is not None:
        best, pair = math.inf, None
        for i in range(_START_GRID.size):
            for j in range(i + 1, _START_GRID.size):
                s = _START_GRID[[i, j]]
                alpha, residual, basis = _solve_alpha(u, y, s, baseline)
                if max_cancellation_bits is not None \
                        and cancellation_bits(basis, alpha) > max_cancellation_bits:
                    continue
                if residual @ residual < best:
                    best, pair = float(residual @ residual), s
        if pair is None:
            raise ValueError('no start exponents fit within max_cancellation_bits='
                             f'{max_cancellation_bits}')
        return np.array(pair)
    exps = np.exp(np.outer(_START_GRID, u))
    gram = exps @ exps.T
    rhs = exps @ y
    i, j = np.triu_indices(_START_GRID.size, k=1)
    g11, g22, g12 = gram[i, i], gram[j, j], gram[i, j]
    det = g11 * g22 - g12 ** 2
    usable = det > 1e-10 * g11 * g22
    # SSE = y.y - b^T G^-1 b for the 2x2 normal equations of every pair
    explained = (g22 * rhs[i] ** 2 - 2 * g12 * rhs[i] * rhs[j] + g11 * rhs[j] ** 2)
    explained = np.where(usable, explained / np.where(usable, det, 1.0), -np.inf)
    best = int(np.argmax(explained))
    return np.array([_START_GRID[i[best]], _START_GRID[j[best]]])


_MAX_SCALED_BETA = 8.0
_MIN_SCALED_SEPARATION = 0.5
_SECOND_TERM_F = 10.0
"""The F statistic a fit's second exponential must exceed to be kept.

``F = ((SSE1 - SSE2) / 2) / (SSE2 / (n - p))``, the MSE reduction the pair's two more
parameters buy against its residual (``p`` parameters of the pair fit, ``n`` points):
two parameters fitted to noise alone give ``F`` above 10 in about one fit of 10 000
(``F(2, 50)``). Data one exponential explains (plus the baseline) leave the pair
unidentifiable: every ``(beta2, alpha2)`` along a flat valley fits, and the alternation
stops wherever the rounding of the linear algebra leaves it -- the second term vanishing
with ``beta2`` at the grid's edge, or two near-equal exponents whose cancelling alphas
cost the fixed-point words bits (seen for ``1e-3 e^(2V)``: from 0 to 7.4 cancelled bits
with the OpenBLAS kernel). Such data get the single exponential (``alpha2 = 0``), the
same on every machine."""

_SSE_RESOLUTION = 1e-20
"""SSE differences below this many times the points are rounding (``y`` at unit rms)."""


def _second_term_needed(sse_single, sse_pair, points, parameters):
    """Whether the pair's SSE is significantly below the single exponential's (F test)."""
    gain = sse_single - sse_pair
    if gain <= _SSE_RESOLUTION * points:
        return False
    if points <= parameters or sse_pair <= 0.0:
        return True
    return gain / 2.0 > _SECOND_TERM_F * sse_pair / (points - parameters)


def _well_separated(s):
    """Return True for scaled exponents a fixed-point datapath can evaluate.

    Near-equal exponents with a baseline reproduce a polynomial by two huge, cancelling
    alphas: the float fit barely improves while the fixed-point words lose every bit.
    """
    return bool(np.all(np.abs(s) <= _MAX_SCALED_BETA)
                and (len(s) < 2 or abs(s[0] - s[1]) >= _MIN_SCALED_SEPARATION))


def _sorted_fit(alpha, beta):
    order = np.argsort(beta)
    return alpha[order], beta[order]


# -- double exponential ---------------------------------------------------------------


@dataclass(frozen=True)
class DoubleExpFit:
    r"""
    Fitted double-exponential zero-bias model ``y = a1 e^(b1 V) + a2 e^(b2 V)``.

    Attributes
    ----------
    alpha1, alpha2 : float
        Linear coefficients, in the unit of the fitted output.
    beta1, beta2 : float
        Exponents [1/V], ``beta1 <= beta2``.
    rmse : float
        Root-mean-square residual, in the unit of the output.
    r_squared : float
        Coefficient of determination ``1 - SSE/SST``.
    iterations : int
        Alternations (or function evaluations for the reference fit).
    converged : bool
        Whether the stopping rule was met before ``max_iter``.
    mse_history : tuple of float
        Mean-square error after every alternation, in the output unit squared (not
        persisted by :meth:`TemperatureCalibration.to_dict`, not compared by ``==``).
    offset, slope : float
        Linear baseline ``offset + slope V`` added to the two exponentials (0 for the
        seed's pure model; see ``baseline`` of :func:`fit_double_exponential`).
    """

    alpha1: float
    alpha2: float
    beta1: float
    beta2: float
    rmse: float
    r_squared: float
    iterations: int
    converged: bool
    mse_history: tuple = field(default=(), repr=False, compare=False)
    offset: float = 0.0
    slope: float = 0.0

    @property
    def alpha(self):
        """Return ``(alpha1, alpha2)``."""
        return self.alpha1, self.alpha2

    @property
    def beta(self):
        """Return ``(beta1, beta2)``."""
        return self.beta1, self.beta2

    def evaluate(self, v):
        """Return the model at the temperature-sensor voltage(s) ``v`` [V] (float)."""
        v = np.asarray(v, dtype=float)
        return (self.alpha1 * np.exp(self.beta1 * v) + self.alpha2 * np.exp(self.beta2 * v)
                + self.offset + self.slope * v)


def _make_fit(v, y, alpha, beta, iterations, converged, history, line=(0.0, 0.0)):
    alpha, beta = _sorted_fit(np.asarray(alpha, float), np.asarray(beta, float))
    fit = DoubleExpFit(float(alpha[0]), float(alpha[1]), float(beta[0]), float(beta[1]),
                       0.0, 0.0, int(iterations), bool(converged), tuple(history),
                       float(line[0]), float(line[1]))
    rmse, r_squared = _goodness(y, fit.evaluate(v))
    return dataclasses.replace(fit, rmse=rmse, r_squared=r_squared)


def _start_exponents(scaling, beta0, baseline=False, max_cancellation_bits=None):
    if beta0 is None:
        return _grid_start(scaling.u, scaling.y, baseline, max_cancellation_bits)
    beta0 = np.asarray(beta0, dtype=float)
    if beta0.shape != (2,) or not np.all(np.isfinite(beta0)):
        raise ValueError(f'beta0 must be two finite exponents [1/V], got {beta0!r}')
    return scaling.to_scaled(beta0)


def _single_start(u, y, baseline):
    """Return the scaled exponent of the grid with the lowest projected SSE, as an array."""
    sse = [float(r @ r) for r in (_solve_alpha(u, y, np.array([g]), baseline)[1]
                                  for g in _START_GRID)]
    return np.array([_START_GRID[int(np.argmin(sse))]])


def _refine(u, y, s, baseline, tol, max_iter, max_cancellation_bits=None):
    """
    Refine the scaled exponents ``s`` (one or two) by the seed's alternation.

    With the exponents fixed, the alphas by linear least squares; then a
    Levenberg-Marquardt step on the exponents only, the alphas projected out (Kaufman's
    variable-projection Jacobian ``(I - P) dPhi/dbeta alpha``), accepted only if the MSE
    after re-solving the alphas does not increase, the exponents stay evaluable
    (:func:`_well_separated`) and, if bounded, the cancellation within the bound.

    :returns: ``(s, alpha, mse, iterations, converged, history)`` on the scaled problem.
    """
    count = len(s)
    alpha, residual, basis = _solve_alpha(u, y, s, baseline)
    mse = float(residual @ residual) / u.size
    history = [mse]
    damping = 1e-3
    converged = False
    iterations = 0
    for iterations in range(1, max_iter + 1):
        derivative = basis[:, :count] * u[:, None] * alpha[None, :count]
        # Kaufman: project the derivative onto the complement of span(basis)
        coefficients = np.linalg.lstsq(basis, derivative, rcond=None)[0]
        jacobian = derivative - basis @ coefficients
        normal = jacobian.T @ jacobian
        gradient = jacobian.T @ residual
        accepted = False
        for _ in range(_LM_MAX_TRIALS):
            damped = normal + damping * np.diag(np.diag(normal) + 1e-300)
            try:
                step = np.linalg.solve(damped, gradient)
            except np.linalg.LinAlgError:
                damping *= 10.0
                continue
            s_new = s + step
            alpha_new, residual_new, basis_new = _solve_alpha(u, y, s_new, baseline)
            mse_new = float(residual_new @ residual_new) / u.size
            if np.all(np.isfinite(s_new)) and mse_new <= mse and (
                    not baseline or _well_separated(s_new)) and (
                    max_cancellation_bits is None
                    or cancellation_bits(basis_new, alpha_new) <= max_cancellation_bits):
                accepted = True
                break
            damping *= 10.0
        if not accepted:
            # no descent direction left: the MSE is stationary at this bound
            converged = True
            break
        change = mse - mse_new
        s, alpha, residual, basis, mse = s_new, alpha_new, residual_new, basis_new, mse_new
        history.append(mse)
        damping = max(damping / 10.0, 1e-12)
        if change <= tol * mse + 1e-300:
            converged = True
            break
    return s, alpha, mse, iterations, converged, history


def fit_double_exponential(v_temp, v_out, beta0=None, tol=1e-12, max_iter=200,
                           baseline=False, max_cancellation_bits=None):
    r"""
    Fit ``v_out = a1 e^(b1 v_temp) + a2 e^(b2 v_temp)`` by alternating iteration.

    Seed 2 steps: (1) start exponents; (2) with the betas fixed, the alphas by linear
    least squares; (3) a nonlinear update of the betas only; (4) the mean-square error;
    (5) repeat until its relative change is at most ``tol``.  Step 3 is a
    Levenberg-Marquardt step on the betas with the alphas projected out (Kaufman's
    variable-projection Jacobian ``(I - P) dPhi/dbeta alpha``), accepted only if the
    MSE after re-solving the alphas decreases.  The problem is solved on
    ``u = (V - center)/half_range`` and unit-rms ``y`` and mapped back exactly.
    Data a single exponential explains as well (:data:`_SECOND_TERM_F`) get it,
    ``alpha2 = 0``: the pair is not identifiable there, and where the alternation stops
    would depend on the machine's rounding.

    Parameters
    ----------
    v_temp, v_out : array_like
        Temperature-sensor voltage [V] and zero output (any unit), same length >= 5.
    beta0 : pair of float, optional
        Start exponents [1/V]; default from a 25 x 25 grid of the projected SSE.
    tol : float
        Bound on the relative MSE change between alternations.
    max_iter : int
        Maximum number of alternations.
    baseline : bool
        Add a linear baseline ``offset + slope V`` to the linear step (two more columns
        beside the exponentials, still solved by linear least squares): a unit's curve is
        not always the double exponential's own shape (a polynomial trend under a
        curvature), and without it the fit drifts into near-equal betas with huge
        cancelling alphas that no fixed-point datapath can evaluate.
    max_cancellation_bits : float, optional
        Constrain the fit to terms that cancel by at most this many bits
        (:func:`cancellation_bits`): the start is the best admissible grid pair and a step
        that leaves the bound is refused. ``ValueError`` if no grid pair is admissible.

    Returns
    -------
    DoubleExpFit
    """
    if not (math.isfinite(tol) and tol > 0):
        raise ValueError(f'tol must be finite and > 0, got {tol!r}')
    if max_cancellation_bits is not None and not (
            isinstance(max_cancellation_bits, (int, float))
            and math.isfinite(max_cancellation_bits) and max_cancellation_bits >= 0):
        raise ValueError('max_cancellation_bits must be a finite number >= 0, got '
                         f'{max_cancellation_bits!r}')
    if isinstance(max_iter, bool) or not isinstance(max_iter, int) or max_iter < 1:
        raise ValueError(f'max_iter must be an integer >= 1, got {max_iter!r}')
    v, y = _as_data(v_temp, v_out, 5)
    scaling = _Scaling(v, y)
    u, ys = scaling.u, scaling.y
    s = _start_exponents(scaling, beta0, baseline, max_cancellation_bits)
    s, alpha, mse, iterations, converged, history = _refine(
        u, ys, s, baseline, tol, max_iter, max_cancellation_bits)
    if max_cancellation_bits is None and beta0 is None:
        single = _refine(u, ys, _single_start(u, ys, baseline), baseline, tol, max_iter)
        parameters = 4 + (2 if baseline else 0)
        if not _second_term_needed(single[2] * u.size, mse * u.size, u.size, parameters):
            s1, alpha1, mse, iterations, converged, history = single
            # The second term vanishes; its exponent is the first's (no new range).
            s = np.array([s1[0], s1[0]])
            alpha = np.concatenate([alpha1[:1], [0.0], alpha1[1:]])
    history = [value * scaling.y_scale ** 2 for value in history]
    alpha_phys, beta_phys = scaling.to_physical(alpha[:2], s)
    line = (0.0, 0.0)
    if baseline:
        # c0 + c1 u with u = (V - center) / half_range, in the unit-rms output
        c0, c1 = alpha[2] * scaling.y_scale, alpha[3] * scaling.y_scale
        line = (c0 - c1 * scaling.center / scaling.half_range, c1 / scaling.half_range)
    return _make_fit(v, y, alpha_phys, beta_phys, iterations, converged, history, line)


def fit_double_exponential_reference(v_temp, v_out, beta0=None):
    """Fit the double exponential with ``scipy.optimize.least_squares`` on all 4 parameters."""
    # Imported here: scipy.optimize takes a quarter of a second to import, and the node
    # and the simulator load this module without ever calling the reference fit.
    from scipy.optimize import least_squares

    v, y = _as_data(v_temp, v_out, 5)
    scaling = _Scaling(v, y)
    u, ys = scaling.u, scaling.y
    s0 = _start_exponents(scaling, beta0)
    alpha0 = _solve_alpha(u, ys, s0)[0]

    def residual(params):
        return params[0] * np.exp(params[2] * u) + params[1] * np.exp(params[3] * u) - ys

    def jacobian(params):
        e1, e2 = np.exp(params[2] * u), np.exp(params[3] * u)
        return np.column_stack([e1, e2, params[0] * u * e1, params[1] * u * e2])

    result = least_squares(residual, np.concatenate([alpha0, s0]), jac=jacobian,
                           method='lm', xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=20000)
    alpha_phys, beta_phys = scaling.to_physical(result.x[:2], result.x[2:])
    mse = float(np.mean(result.fun ** 2)) * scaling.y_scale ** 2
    return _make_fit(v, y, alpha_phys, beta_phys, result.nfev, result.status > 0, [mse])


# -- polynomial -----------------------------------------------------------------------


@dataclass(frozen=True)
class PolynomialFit:
    """
    Least-squares polynomial ``y = sum c_k v^k`` (seed Tables 1-2 comparison).

    Attributes
    ----------
    coefficients : tuple of float
        Coefficients in ``v`` [V], highest power first (``numpy.polyval`` order).
    rmse, r_squared : float
        Root-mean-square residual (output unit) and coefficient of determination.
    order : int
        Polynomial order.
    center, half_range : float
        Scaling ``u = (v - center) / half_range`` used for a well-conditioned solve.
    scaled_coefficients : tuple of float
        Coefficients in ``u``, highest power first (what :meth:`evaluate` uses).
    """

    coefficients: tuple
    rmse: float
    r_squared: float
    order: int
    center: float
    half_range: float
    scaled_coefficients: tuple

    def evaluate(self, v):
        """Return the polynomial at ``v`` [V]."""
        u = (np.asarray(v, dtype=float) - self.center) / self.half_range
        return np.polyval(self.scaled_coefficients, u)


def fit_polynomial(v, y, order):
    """Fit a polynomial of ``order`` by least squares on scaled ``v``; return PolynomialFit."""
    if isinstance(order, bool) or not isinstance(order, int) or not 0 <= order <= 10:
        raise ValueError(f'order must be an integer in [0, 10], got {order!r}')
    v, y = _as_data(v, y, order + 1)
    center = 0.5 * (v.max() + v.min())
    half_range = 0.5 * (v.max() - v.min())
    u = (v - center) / half_range
    scaled = np.linalg.lstsq(np.vander(u, order + 1), y, rcond=None)[0]
    # expand p(u) with u = (v - c)/h into powers of v
    raw = np.poly1d(0.0)
    for power, coefficient in enumerate(scaled[::-1]):
        raw = raw + coefficient * np.poly1d([1.0 / half_range, -center / half_range]) ** power
    raw_coefficients = np.concatenate([np.zeros(order + 1 - raw.coeffs.size), raw.coeffs])
    prediction = np.polyval(scaled, u)
    rmse, r_squared = _goodness(y, prediction)
    return PolynomialFit(tuple(float(c) for c in raw_coefficients), rmse, r_squared, order,
                         float(center), float(half_range), tuple(float(c) for c in scaled))


# -- fixed-point compensator ------------------------------------------------------------


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
            if not math.isfinite(getattr(fit, name)):
                raise ValueError(f'fit.{name} must be finite')
        self.fit = fit
        v_low, v_high = (float(x) for x in v_range)
        if not (math.isfinite(v_low) and math.isfinite(v_high) and v_low < v_high):
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
        needed = 0
        while not all(-(1 << (needed + self.m_bits)) <= z < (1 << (needed + self.m_bits))
                      for z in z_extremes):
            needed += 1
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
                product = np.int64(mantissa) * np.asarray(factor, dtype=np.int64)
                total += product << shift if shift >= 0 else product >> -shift
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


# -- calibration pipeline ---------------------------------------------------------------


def bin_by_temperature(v_temp, values, n_bins=100, min_count=1):
    """Return ``(v_mean, value_mean, count)`` of equal-width V_temp bins with data."""
    v, y = _as_data(v_temp, values, 2)
    if isinstance(n_bins, bool) or not isinstance(n_bins, int) or n_bins < 1:
        raise ValueError(f'n_bins must be an integer >= 1, got {n_bins!r}')
    edges = np.linspace(v.min(), v.max(), n_bins + 1)
    index = np.clip(np.searchsorted(edges, v, side='right') - 1, 0, n_bins - 1)
    count = np.bincount(index, minlength=n_bins)
    v_sum = np.bincount(index, weights=v, minlength=n_bins)
    y_sum = np.bincount(index, weights=y, minlength=n_bins)
    keep = count >= max(1, min_count)
    return v_sum[keep] / count[keep], y_sum[keep] / count[keep], count[keep]


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
        3rd/4th-order comparison fits on the same bins (seed Tables 1-2).
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


def max_m_bits(guard_bits):
    """Return the most fraction bits the 63-bit datapath holds with ``guard_bits``."""
    return (63 - guard_bits - 4) // 2


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
        span = float(v_bins.max() - v_bins.min())
        low = float(v_bins.min()) - 0.25 * span
        # a unipolar temperature ADC never reads below 0 V
        v_range = (max(low, 0.0) if v_bins.min() >= 0 else low,
                   float(v_bins.max()) + 0.25 * span)
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
    # Terms that cancel by c bits cost the fixed-point output c bits: beyond the guard
    # bits, widen the words by what the cancellation takes (within the 63-bit datapath).
    widen = max(0, math.ceil(min(cancellation, 64.0)) - guard_bits)
    bits = min(max_m_bits(guard_bits), m_bits + widen)
    while True:
        try:
            compensator = DoubleExpCompensator(fit, m_bits=bits, guard_bits=guard_bits,
                                               v_range=v_range)
            break
        except ValueError:
            # The widened words overflow a multiplier of this fit's datapath: fewer.
            if bits <= m_bits:
                raise
            bits -= 1
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


# -- multi-position compensation (bias and scale factor per axis) ------------------------


def _matrix(value, name):
    array = np.asarray(value, dtype=float)
    if array.shape != (3, 3) or not np.all(np.isfinite(array)):
        raise ValueError(f'{name} must be a finite 3x3 matrix')
    return array


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
        self.misalignment = _matrix(misalignment, 'misalignment')
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
        axes = ('x', 'y', 'z')
        return {'format': 'multiposition/1',
                'bias': {a: c.to_dict() for a, c in zip(axes, self.bias)},
                'scale': {a: c.to_dict() for a, c in zip(axes, self.scale)},
                'misalignment': self.misalignment.tolist(), 'k2': self.k2.tolist()}

    @classmethod
    def from_dict(cls, data):
        """Rebuild from :meth:`to_dict` output; ValueError on a malformed record."""
        axes = ('x', 'y', 'z')
        try:
            if data.get('format') != 'multiposition/1':
                raise ValueError('temperature record: unknown format (run calibrate_temperature '
                                 'again)')
            return cls([TemperatureCalibration.from_dict(data['bias'][a]) for a in axes],
                       [TemperatureCalibration.from_dict(data['scale'][a]) for a in axes],
                       data['misalignment'], data['k2'])
        except (KeyError, TypeError, AttributeError) as error:
            raise ValueError(f'invalid temperature record: {error!r}') from error
