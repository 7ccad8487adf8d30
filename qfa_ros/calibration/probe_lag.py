"""
How far the on-board temperature reading lags the proof mass, from the tumble records.

The errors follow the proof mass's temperature; the on-board sensor reads it with the
probe's lag (a second or two). :func:`estimate_probe_lag` finds the lag that makes one
fit of every tumble block (:func:`global_fit`) fit best; the multi-position temperature
calibration (:mod:`qfa_ros.calibration.temperature`) moves every reading by it before
its fits. Only what the sensor can know is used: block means of the output and the
reading, and the known fixture positions.
"""

import numpy as np
from numpy.polynomial.chebyshev import chebvander

MAX_PROBE_LAG_S = 4.0
"""Longest lag of the on-board temperature reading behind the proof mass the fit looks for
[s] (twice the datasheet-like 0.5-2 s of :mod:`qfa_ros.model.drawn_unit`)."""
PROBE_LAG_STEP_S = 0.05
"""Resolution of the lag search [s]."""


def reading_rate(times_s, v, width=3):
    """
    Return the rate of the on-board reading at every block [V/s], smoothed over a tumble.

    Central differences of the block means against their end times, then a running mean
    over a tumble's worth of blocks (the reading's quantization and noise would otherwise
    dominate the derivative on a plateau).
    """
    if len(v) < 3:
        return np.zeros(len(v))
    rate = np.gradient(v, times_s)
    width = min(width, len(v))
    kernel = np.ones(width) / width
    padded = np.pad(rate, (width // 2, width - 1 - width // 2), mode='edge')
    return np.convolve(padded, kernel, mode='valid')


def global_fit(v, force, output):
    """Return misalignment, K2 and the residual sum of squares of the all-block fit."""
    centre, half = 0.5 * (v.max() + v.min()), max(0.5 * np.ptp(v), 1e-9)
    u = (v - centre) / half
    misalignment = np.zeros((3, 3))
    k2 = np.zeros(3)
    rss = 0.0
    for i in range(3):
        others = [j for j in range(3) if j != i]
        design = np.column_stack([chebvander(u, 6), chebvander(u, 4) * force[:, i:i + 1],
                                  force[:, others], force[:, i] ** 2])
        target = output[:, i] - force[:, i]
        coefficients = np.linalg.lstsq(design, target, rcond=None)[0]
        misalignment[i, others] = coefficients[-3:-1]
        k2[i] = coefficients[-1]
        rss += float(np.sum((target - design @ coefficients) ** 2))
    return misalignment, k2, rss


def estimate_probe_lag(v, rate, force, output, max_lag_s=MAX_PROBE_LAG_S,
                       step_s=PROBE_LAG_STEP_S):
    """
    Estimate how far the on-board reading lags the proof mass from the blocks [s].

    The errors follow the proof mass's temperature; the reading follows it with the
    probe's lag ``tau``, so the mass is at ``V + tau dV/dt`` of the reading. While the
    chamber moves, heating and cooling blocks at one reading disagree by twice the slope
    of the curves times ``tau dV/dt``; the ``tau`` whose corrected reading makes the
    all-block fit (bias, scale factor, misalignment, K2) fit best is the lag. On
    plateaus the rate is zero and the correction vanishes.
    """
    def best(lags):
        rss = [global_fit(v + lag * rate, force, output)[2] for lag in lags]
        return round(float(lags[int(np.argmin(rss))]), 6)

    # Coarse, then fine around the coarse minimum (the residual is smooth in the lag).
    coarse_step = 5.0 * step_s
    lag = best(np.arange(0.0, max_lag_s + 0.5 * coarse_step, coarse_step))
    fine = np.arange(max(0.0, lag - coarse_step), min(max_lag_s, lag + coarse_step)
                     + 0.5 * step_s, step_s)
    return best(fine)
