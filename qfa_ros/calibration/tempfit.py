r"""
Zero-bias temperature model fitting (Liu, Li and Shen): the double exponential and its comparisons.

The zero bias is modelled as ``y = alpha1 e^(beta1 V) + alpha2 e^(beta2 V)`` (eq. 1)
with ``V`` the on-board temperature-sensor voltage [V] and ``y`` the zero output (any
unit: V, m/s^2, counts; the alphas carry it, the betas are in 1/V).  It is fitted by
their alternating iteration and compared with 3rd/4th-order polynomials (their
Tables 1-2). :mod:`qfa_ros.calibration.fixed_point_compensator` evaluates a fit on the
fixed-point CORDIC path; :mod:`qfa_ros.calibration.thermal_compensation` bins a
temperature cycle, fits it and builds the compensation.
"""

import dataclasses
from dataclasses import dataclass, field
import math

import numpy as np

from qfa_ros.model.checks import is_finite

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


def _solve_alpha(u, y, s, baseline=False):
    basis = np.exp(np.outer(u, s))
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
(``F(2, 50)``). Data one exponential explains leave the pair unidentifiable, split
wherever the BLAS kernel's rounding leaves it (``bench/results/tempfit_second_term.md``);
such data get the single exponential (``alpha2 = 0``), the same on every machine."""

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
        paper's pure model; see ``baseline`` of :func:`fit_double_exponential`).
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
    order = np.argsort(beta)
    alpha, beta = np.asarray(alpha, float)[order], np.asarray(beta, float)[order]
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
    return beta0 * scaling.half_range


def _single_start(u, y, baseline):
    """Return the scaled exponent of the grid with the lowest projected SSE, as an array."""
    sse = [float(r @ r) for r in (_solve_alpha(u, y, np.array([g]), baseline)[1]
                                  for g in _START_GRID)]
    return np.array([_START_GRID[int(np.argmin(sse))]])


def _refine(u, y, s, baseline, tol, max_iter, max_cancellation_bits=None):
    """
    Refine the scaled exponents ``s`` (one or two) by Liu, Li and Shen's alternation.

    With the exponents fixed, the alphas by linear least squares; then a
    Levenberg-Marquardt step on the exponents only, the alphas projected out (Kaufman's
    variable-projection Jacobian ``(I - P) dPhi/dbeta alpha``), accepted only if the MSE
    after re-solving the alphas does not increase, the exponents stay evaluable
    (:func:`_well_separated`) and, if bounded, the cancellation within the bound.

    Returns
    -------
    tuple
        ``(s, alpha, mse, iterations, converged, history)`` on the scaled problem.
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

    Liu, Li and Shen's steps: (1) start exponents; (2) with the betas fixed, the alphas by linear
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
    if not (is_finite(tol) and tol > 0):
        raise ValueError(f'tol must be finite and > 0, got {tol!r}')
    if max_cancellation_bits is not None and not (
            is_finite(max_cancellation_bits, types=(int, float)) and max_cancellation_bits >= 0):
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
    Least-squares polynomial ``y = sum c_k v^k`` (Liu, Li and Shen's Tables 1-2 comparison).

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
    """
    Fit a polynomial of ``order`` by least squares on scaled ``v``; return PolynomialFit.

    :meth:`numpy.polynomial.Polynomial.fit` maps the data's span onto [-1, 1] (the
    scaled coefficients) and :meth:`~numpy.polynomial.Polynomial.convert` gives the
    coefficients in ``v``.
    """
    if isinstance(order, bool) or not isinstance(order, int) or not 0 <= order <= 10:
        raise ValueError(f'order must be an integer in [0, 10], got {order!r}')
    v, y = _as_data(v, y, order + 1)
    series = np.polynomial.Polynomial.fit(v, y, order)
    low, high = series.domain
    scaled, raw = (tuple(float(c) for c in np.pad(s.coef, (0, order + 1 - s.coef.size))[::-1])
                   for s in (series, series.convert()))
    rmse, r_squared = _goodness(y, series(v))
    return PolynomialFit(raw, rmse, r_squared, order, float(0.5 * (high + low)),
                         float(0.5 * (high - low)), scaled)


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
