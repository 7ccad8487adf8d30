"""
Tolerances of the seeded statistical tests, from the estimators' sampling distributions.

A statistical test runs over several seeds and allows itself a false-failure
probability of :data:`FALSE_FAILURE` in all, split evenly over its checks (Bonferroni):
each bound below is the two-sided quantile at ``FALSE_FAILURE / checks``. A planted
defect of the size the test names (a noise density x1.2, a bias doubled) lies far
outside it.
"""

import math
from statistics import NormalDist

FALSE_FAILURE = 1e-6
"""Probability that a correct model fails one test, whatever its seeds."""


def normal_bound(checks, probability=FALSE_FAILURE):
    """Return z with P(|Z| > z) = probability / checks for a standard normal Z."""
    return NormalDist().inv_cdf(1.0 - probability / checks / 2.0)


def variance_ratio_bounds(edf, checks, probability=FALSE_FAILURE):
    """
    Return (low, high) of an estimated over a true variance with ``edf`` degrees of freedom.

    The estimate is ``chi2(edf) / edf`` times the truth: the bounds are its quantiles at
    ``probability / checks / 2`` on each side.
    """
    from scipy.stats import chi2
    tail = probability / checks / 2.0
    return float(chi2.ppf(tail, edf) / edf), float(chi2.isf(tail, edf) / edf)


def assert_variance_ratios(ratios, edf, checks):
    """
    Check estimated over true variances, each and pooled, against their chi-square bounds.

    ``ratios`` has one row per estimate (a seed and axis) and one column per ``edf``
    entry (a tau); every estimate is checked with its column's ``edf``, the column mean
    with ``edf`` times the rows. ``checks`` is the number of checks the test makes in all.
    """
    import numpy as np
    ratios = np.asarray(ratios, dtype=float).reshape(len(ratios), -1)
    for column, dof in zip(ratios.T, np.broadcast_to(edf, ratios.shape[1:])):
        low, high = variance_ratio_bounds(dof, checks)
        assert np.all((low < column) & (column < high)), (dof, low, high, column)
        low, high = variance_ratio_bounds(dof * len(column), checks)
        assert low < column.mean() < high, (dof, low, high, column.mean())


def allan_edf_white(samples, m):
    """Return Greenhall's equivalent degrees of freedom of an overlapping AVAR, white FM."""
    import allantools
    return float(allantools.edf_greenhall(alpha=0, d=2, m=int(m), N=int(samples),
                                          overlapping=True))


def allan_edf_flicker(samples, m):
    """Return Greenhall's equivalent degrees of freedom of an overlapping AVAR, flicker FM."""
    import allantools
    return float(allantools.edf_greenhall(alpha=-1, d=2, m=int(m), N=int(samples),
                                          overlapping=True))


def mean_sd(values):
    """Return (mean, its standard error) of a sample."""
    n = len(values)
    mean = math.fsum(values) / n
    variance = math.fsum((v - mean) ** 2 for v in values) / (n - 1)
    return mean, math.sqrt(variance / n)


def t_bound(df, checks, probability=FALSE_FAILURE):
    """Return t with P(|T| > t) = probability / checks for Student's T with ``df``."""
    from scipy.stats import t
    return float(t.isf(probability / checks / 2.0, df))


def clipped_normal_moments(c):
    """Return E[X^2] and E[X^4] of a standard normal clipped to [-c, c]."""
    normal = NormalDist()
    inside, density, tail = 2.0 * normal.cdf(c) - 1.0, normal.pdf(c), 1.0 - normal.cdf(c)
    second = inside - 2.0 * c * density + 2.0 * c ** 2 * tail
    fourth = 3.0 * inside - 2.0 * (c ** 3 + 3.0 * c) * density + 2.0 * c ** 4 * tail
    return second, fourth
