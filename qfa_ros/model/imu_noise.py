r"""
Noise figures in the conventions of VIO/INS tools (Kalibr, OpenVINS, allan_variance_ros).

``imu.yaml`` takes per sensor a white-noise density (``*_noise_density``: the continuous
white noise, ``sigma_discrete = density * sqrt(update_rate)``; the Allan deviation at
tau = 1 s of white noise) and a random walk (``*_random_walk``: the bias's driving noise
density; the Allan deviation at tau = 3 s of a random walk). allan_variance_ros
(``scripts/analysis.py``) reads them off the Allan deviation curve with two fixed-slope
least-squares lines in log-log: slope -1/2 through the points at tau < 10 s, read at
tau = 1 s; slope +1/2 through every point, read at tau = 3 s. Its curve is sampled on the
linear grid tau = 0.1, 0.2, ... 999.9 s; here the curve is sampled on a log grid and each
point weighted by the linear grid's density there (proportional to tau), the same fit.

:func:`fit_like_allan_variance_ros` is that estimator; :func:`model_allan_deviation` the
curve the noise configuration implies (accelerometers: :mod:`qfa_ros.model.noise`;
gyros: :mod:`qfa_ros.model.gyro`), so the configuration and a recording are read the
same way and can be compared. The sensors here have no true random walk in the
accelerometers (their bias instability is a sum of Gauss-Markov processes): the "random
walk" of such a fit is a property of the fit over the tau range, not of the sensor, which
is why the range (``max_tau``) must match.
"""

import math
from types import SimpleNamespace

import numpy as np

from qfa_ros.model.allan import allan_deviation
from qfa_ros.model.noise import flicker_component_variance, gauss_markov_allan_variance

MIN_TAU = 0.1
"""Shortest averaging time of the fits [s] (allan_variance_ros's grid)."""
MAX_TAU = 1000.0
"""Longest averaging time of the fits [s] (allan_variance_ros's grid: 999.9 s)."""
WHITE_LIMIT = 10.0
"""The white-noise line is fitted to tau < this [s]."""
POINTS_PER_DECADE = 40


def tau_grid(max_tau=MAX_TAU):
    """Return the log-spaced averaging times [s] from :data:`MIN_TAU` to ``max_tau``."""
    if not max_tau > MIN_TAU:
        raise ValueError(f'max_tau must exceed {MIN_TAU} s, got {max_tau!r}')
    count = int(math.ceil(math.log10(max_tau / MIN_TAU) * POINTS_PER_DECADE)) + 1
    return np.logspace(math.log10(MIN_TAU), math.log10(max_tau), count)


def _fixed_slope_line(taus, adev, slope, at, weights):
    """Return the fixed-slope log-log least-squares line through (taus, adev) at ``at``."""
    intercept = np.average(np.log(adev) - slope * np.log(taus), weights=weights)
    return float(math.exp(intercept + slope * math.log(at)))


def fit_like_allan_variance_ros(taus, adev):
    """
    Return (noise density, random walk) read off an Allan deviation curve.

    White noise: the slope -1/2 line through the points at tau < 10 s, at tau = 1 s;
    random walk: the slope +1/2 line through every point, at tau = 3 s; points weighted
    by tau (allan_variance_ros's linear grid). Units: those of ``adev`` per sqrt(Hz)
    and per sqrt(Hz) s^-1.
    """
    taus, adev = np.asarray(taus, dtype=float), np.asarray(adev, dtype=float)
    if np.all(adev == 0):
        return 0.0, 0.0  # a noiseless sensor (sensor.error_profile ideal)
    keep = np.isfinite(adev) & (adev > 0)
    taus, adev = taus[keep], adev[keep]
    white = taus < WHITE_LIMIT
    if white.sum() < 2:
        raise ValueError('the Allan deviation needs points below 10 s')
    density = _fixed_slope_line(taus[white], adev[white], -0.5, 1.0, taus[white])
    walk = _fixed_slope_line(taus, adev, 0.5, 3.0, taus)
    return density, walk


def fit_uncertainty(taus, counts):
    """
    Return the relative 1-sigma uncertainty bounds of the two fits (white, walk).

    Each point's log deviation scatters by about ``1 / sqrt(2 (K - 1))`` with ``K`` the
    independent averages at its tau (``counts``: record length / tau); the fits are
    weighted means of the points, and the bound takes their errors as fully correlated
    (the weighted mean of the scatters), which no real curve exceeds.
    """
    taus, counts = np.asarray(taus, dtype=float), np.asarray(counts, dtype=float)
    scatter = 1.0 / np.sqrt(2.0 * np.maximum(counts - 1.0, 1.0))
    white = taus < WHITE_LIMIT
    return (float(np.average(scatter[white], weights=taus[white])),
            float(np.average(scatter, weights=taus)))


def model_allan_deviation(noise_density, bias_instability, correlation_times, taus,
                          rate_random_walk=0.0, quantization=0.0):
    """
    Return the Allan deviation of white noise, a Gauss-Markov sum and a random walk.

    ``sigma^2 = 3 Q^2 / tau^2 + N^2 / tau + sum_j AVAR_GM(tau; q^2, T_j) + K^2 tau / 3``
    with ``q^2`` the component variance that puts the flicker floor at
    ``bias_instability`` (:func:`qfa_ros.model.noise.flicker_component_variance`), ``Q``
    the angle (or velocity) quantization.
    """
    taus = np.asarray(taus, dtype=float)
    variance = flicker_component_variance(SimpleNamespace(
        bias_instability=bias_instability, correlation_times=tuple(correlation_times)))
    flicker = sum(gauss_markov_allan_variance(taus, variance, t) for t in correlation_times) \
        if variance else 0.0
    return np.sqrt(3.0 * quantization ** 2 / taus ** 2 + noise_density ** 2 / taus + flicker
                   + rate_random_walk ** 2 * taus / 3.0)


def implied_figures(config, max_tau=MAX_TAU):
    """
    Return the ``imu.yaml`` figures a TriadConfig implies, read as allan_variance_ros does.

    A dict of ``accelerometer_noise_density``, ``accelerometer_random_walk`` and, with
    gyros, ``gyroscope_noise_density``, ``gyroscope_random_walk`` (SI units).
    """
    taus = tau_grid(max_tau)
    noise = config.noise
    accel = model_allan_deviation(noise.noise_density, noise.bias_instability,
                                  noise.correlation_times, taus)
    figures = dict(zip(('accelerometer_noise_density', 'accelerometer_random_walk'),
                       fit_like_allan_variance_ros(taus, accel)))
    gyro = config.gyro
    if gyro is not None:
        rate = model_allan_deviation(gyro.arw, gyro.bias_instability, gyro.correlation_times,
                                     taus, gyro.rate_random_walk, gyro.quantization)
        figures.update(zip(('gyroscope_noise_density', 'gyroscope_random_walk'),
                           fit_like_allan_variance_ros(taus, rate)))
    return figures


def measured_figures(accel, rate, sample_period, max_tau=MAX_TAU):
    """
    Return (figures, uncertainty, max_tau) of a recorded static stream.

    ``accel`` and ``rate`` (n, 3) (``rate`` None: no gyros): the overlapping Allan
    deviation of each axis on :func:`tau_grid` up to ``max_tau`` and a tenth of the record
    (at least ten independent averages at the longest tau), each read by
    :func:`fit_like_allan_variance_ros`; the figure is the worst axis's, as
    allan_variance_ros writes it. ``uncertainty`` holds the relative 1-sigma bounds of
    :func:`fit_uncertainty` under the same names; ``max_tau`` the range used.
    """
    accel = np.asarray(accel, dtype=float)
    duration = len(accel) * sample_period
    max_tau = min(max_tau, duration / 10.0)
    taus = tau_grid(max_tau)
    figures, uncertainty = {}, {}
    sensors = [('accelerometer', accel)]
    if rate is not None:
        sensors.append(('gyroscope', np.asarray(rate, dtype=float)))
    for name, data in sensors:
        fits = []
        for axis in range(data.shape[1]):
            used, adev = allan_deviation(data[:, axis], sample_period, taus)
            fits.append(fit_like_allan_variance_ros(used, adev))
        white, walk = np.max(fits, axis=0)
        figures[f'{name}_noise_density'], figures[f'{name}_random_walk'] = white, walk
        bounds = fit_uncertainty(used, duration / used)
        uncertainty[f'{name}_noise_density'], uncertainty[f'{name}_random_walk'] = bounds
    return figures, uncertainty, max_tau
