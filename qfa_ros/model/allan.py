"""Overlapping Allan deviation (IEEE 952/1293), in the conventions of allantools ``oadev``."""

import math

from numba import njit
import numpy as np

from qfa_ros.model import checks


def octave_factors(n):
    """
    Return the octave averaging factors ``m = 1, 2, 4, ...`` usable on ``n`` samples.

    As allantools' ``taus='octave'``: powers of two up to the length of the phase
    series (``n + 1``), keeping those with at least two second differences
    (``n + 1 - 2 m >= 2``).
    """
    if n < 3:
        return np.zeros(0, dtype=np.int64)
    m = 2 ** np.arange(int(math.floor(math.log2(n + 1))) + 1, dtype=np.int64)
    return m[n + 1 - 2 * m >= 2]


def allan_deviation(samples, sample_period, taus='octave'):
    r"""
    Return (taus [s], overlapping Allan deviation) of a rate-like series.

    With the phase ``x_0 = 0``, ``x_k = sum_{i<k} (y_i - mean(y))`` (``N + 1`` points
    for ``N`` samples)::

        sigma^2(m tau0) = sum_{k=0}^{N-2m} (x_{k+2m} - 2 x_{k+m} + x_k)^2
                          / (2 m^2 (N + 1 - 2m))

    which is ``1 / (2 (N - 2m + 1)) sum (ybar_{k+m} - ybar_k)^2`` over all overlapping
    averages ``ybar`` of ``m`` samples: allantools' ``oadev(y, rate, data_type='freq')``
    (NIST SP 1065 eq. 11). One pass over the phase per factor, compiled.

    Parameters
    ----------
    samples : array_like, shape (N,)
        Series sampled every ``sample_period``, in its own unit (the deviation has it).
    sample_period : float
        ``tau0`` [s].
    taus : 'octave' or array_like
        ``'octave'`` (default, also None): ``tau = 2^k tau0`` (:func:`octave_factors`); otherwise
        averaging times [s], rounded to multiples of ``tau0``; factors with fewer than
        two second differences are dropped, duplicates merged.
    """
    y = np.asarray(samples, dtype=float)
    if y.ndim != 1 or len(y) < 3:
        raise ValueError('samples must be a 1-D series of at least 3 values')
    phase = np.empty(len(y) + 1)
    phase[0] = 0.0
    np.cumsum(y - y.mean(), out=phase[1:])
    return allan_deviation_of_phase(phase, sample_period, taus)


def allan_deviation_of_phase(phase, sample_period, taus='octave'):
    """
    Return (taus [s], overlapping Allan deviation) from the phase of a series.

    ``phase`` is ``x_0 = 0, x_k = sum_{i<k} (y_i - c)`` (``N + 1`` values) for any
    constant ``c`` near the mean of ``y`` (the second differences cancel it; the mean
    itself gives :func:`allan_deviation` exactly): a long run can accumulate it chunk
    by chunk instead of keeping ``y``. ``taus`` as in :func:`allan_deviation`.
    """
    phase = np.ascontiguousarray(phase, dtype=float)
    n = len(phase) - 1
    if phase.ndim != 1 or n < 3:
        raise ValueError('phase must be a 1-D series of at least 4 values')
    sample_period = checks.positive('sample_period', sample_period)
    if taus is None:
        taus = 'octave'
    if isinstance(taus, str):
        if taus != 'octave':
            raise ValueError(f"taus must be 'octave' or averaging times, got {taus!r}")
        m = octave_factors(n)
    else:
        taus = np.asarray(taus, dtype=float)
        if not np.all(np.isfinite(taus)):
            raise ValueError(f'taus must be finite averaging times [s], got {taus!r}')
        m = np.unique(np.round(taus / sample_period)).astype(np.int64)
        m = m[(m >= 1) & (n + 1 - 2 * m >= 2)]
    deviation = np.empty(len(m))
    _overlapping_adev(phase, m, deviation)
    return m * sample_period, deviation


_BLOCK = 8192
"""Phase points per cache block: factors up to it share one pass over the phase."""


# reassoc lets LLVM vectorize the sum (order of additions only; checked against allantools).
@njit(cache=True, nogil=True, fastmath={'reassoc'})
def _overlapping_adev(phase, factors, out):
    # out[j]: overlapping Allan deviation at factor m = factors[j] from the phase series.
    # Factors up to _BLOCK are summed block by block of k, so the phase a block needs
    # (k .. k + _BLOCK + 2 m) is read from memory once for all of them, not once each.
    n = phase.shape[0]
    totals = np.zeros(factors.shape[0])
    for start in range(0, n, _BLOCK):
        for j in range(factors.shape[0]):
            m = factors[j]
            if m > _BLOCK:
                continue
            stop = min(start + _BLOCK, n - 2 * m)
            total = 0.0
            for k in range(start, stop):
                d = phase[k + 2 * m] - 2.0 * phase[k + m] + phase[k]
                total += d * d
            totals[j] += total
    for j in range(factors.shape[0]):
        m = factors[j]
        if m > _BLOCK:
            total = 0.0
            for k in range(n - 2 * m):
                d = phase[k + 2 * m] - 2.0 * phase[k + m] + phase[k]
                total += d * d
            totals[j] = total
        out[j] = math.sqrt(totals[j] / (2.0 * (n - 2 * m))) / m
