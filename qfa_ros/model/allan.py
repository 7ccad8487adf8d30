"""Overlapping Allan deviation (IEEE 952/1293)."""

import numpy as np


def allan_deviation(samples, sample_period, taus=None):
    """
    Return (taus [s], overlapping Allan deviation) of a rate-like series.

    ``sigma^2(tau) = 1 / (2 (N - 2m + 1)) sum (ybar_{k+m} - ybar_k)^2`` over all
    overlapping averages ``ybar`` of ``m = tau / sample_period`` samples, computed
    from the cumulative sum. ``taus`` default to about 10 per decade up to N/9.
    """
    y = np.asarray(samples, dtype=float)
    if y.ndim != 1 or len(y) < 3:
        raise ValueError('samples must be a 1-D series of at least 3 values')
    if not sample_period > 0:
        raise ValueError(f'sample_period must be positive, got {sample_period!r}')
    n = len(y)
    if taus is None:
        m = np.unique(np.logspace(0, np.log10(max(1, n // 9)), 60).astype(int))
    else:
        m = np.unique(np.round(np.asarray(taus) / sample_period).astype(int))
        m = m[(m >= 1) & (2 * m < n)]
    cumulative = np.concatenate(([0.0], np.cumsum(y - y.mean())))
    deviation = np.empty(len(m))
    for j, size in enumerate(m):
        means = (cumulative[size:] - cumulative[:-size]) / size
        diff = means[size:] - means[:-size]
        deviation[j] = np.sqrt(0.5 * np.mean(diff * diff))
    return m * sample_period, deviation
