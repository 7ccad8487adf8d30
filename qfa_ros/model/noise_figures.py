r"""
Noise figures in the conventions of VIO/INS tools (Kalibr, OpenVINS, allan_variance_ros).

Kalibr's ``imu.yaml`` (its wiki, "IMU Noise Model") takes per sensor two continuous-time
densities, and OpenVINS the same two (``NoiseManager``: white noise [m/s^2/sqrt(Hz)],
random walk [m/s^3/sqrt(Hz)]):

* ``*_noise_density`` ``sigma``: the white noise ``n`` on the output,
  ``E[n(t1) n(t2)] = sigma^2 delta(t1 - t2)``, sampled as ``sigma / sqrt(dt)`` per sample
  (behind an ideal decimation filter); the Allan deviation of white noise is
  ``sigma / sqrt(tau)``, so ``sigma = sigma(tau) sqrt(tau)`` where the white noise rules;
* ``*_random_walk`` ``sigma_b``: the bias as Brownian motion, ``b' = sigma_b w(t)``,
  ``b[k] = b[k-1] + sigma_b sqrt(dt) w[k]``; Allan deviation ``sigma_b sqrt(tau / 3)``.

**From a configuration** (:func:`config_figures`) the figures are the model's, exactly,
read off no curve and no fit range:

* white: the acceleration white noise ``N`` the model injects. The loop (unity gain below
  its bandwidth, 600 Hz) and the averaging decimator shape it only where an Allan
  deviation no longer looks (``sigma(tau) sqrt(tau)`` is 4.9 % above ``N`` at 10 ms from
  the loop's peaking, 0.9 % at 0.1 s: ``bench/imu_yaml.py``); the ADC noise leaves the loop as
  white *phase* noise (slope -1, the integrator), with a white floor
  ``|G_ADC(0)| sigma_adc / sqrt(f_loop)`` (:func:`loop_white_floor`, 2.4e-9 m/s^2/sqrt(Hz)
  for the defaults) added in quadrature. The gyros: their angle random walk.
* random walk: the driving density of the bias processes. A first-order Gauss-Markov bias
  of variance ``q^2`` and correlation time ``T`` is ``b' = -b / T + w`` with ``w`` of
  density ``q sqrt(2 / T)``: Kalibr's Brownian motion plus a pull-back. Over a window
  ``D`` its increments have the variance ``2 q^2 (1 - exp(-D/T))``, the random walk's
  ``(2 q^2 / T) D`` while ``D << T`` and less beyond: the figure is exact for a filter's
  short windows and an upper bound (never optimistic) for long ones. A sum of such
  processes drives with ``sqrt(sum_j 2 q_j^2 / T_j)`` (:func:`drive_density`); a true
  random walk (the gyros' rate random walk, an emulated ``imu.yaml``) adds in quadrature.
  The fit allan_variance_ros makes instead reads a +1/2 line through a curve without one
  (these sensors' bias instability is a Gauss-Markov sum), so its figure moves with the
  fit range (2x for the accelerometers, 7x for the gyros between 60 and 1000 s).
* zero where the model has none (``sensor.error_profile: ideal``: the loop's quantization
  stays, deterministic, no white noise).

Temperature-driven bias and scale changes are not in the figures, as Kalibr's model
leaves them out (its wiki: a model of a sensor "at constant temperature").

**From a recording** (:func:`measured_figures`): allan_variance_ros's estimator
(``scripts/analysis.py``): the slope -1/2 line (log-log least squares, slope fixed) through
the points at tau < 10 s read at tau = 1 s, the slope +1/2 line through every point read at
tau = 3 s, the worst axis. Its curve is sampled on the linear grid tau = 0.1, 0.2, ...
999.9 s; here on a log grid, each point weighted by the linear grid's density there
(proportional to tau): the same fit. The white-noise density at short tau
(:data:`SHORT_TAUS`) is measured beside it.

:func:`emulated_config` makes the sensor of a Kalibr ``imu.yaml``: its densities and random
walks in place of the configured noise processes, the QFA loop and everything else kept.
"""

from dataclasses import dataclass, replace
import math
from types import SimpleNamespace

import numpy as np

from qfa_ros.model import checks
from qfa_ros.model.allan import allan_deviation
from qfa_ros.model.constants import DEG_PER_HOUR, DEG_PER_ROOT_HOUR, MICRO_G
from qfa_ros.model.design import designed_loop
from qfa_ros.model.noise import (
    ADC_QUANTIZATION_VARIANCE,
    flicker_component_variance,
    model_allan_deviation,
)

MIN_TAU = 0.1
"""Shortest averaging time of the fits [s] (allan_variance_ros's grid)."""
MAX_TAU = 1000.0
"""Longest averaging time of the fits [s] (allan_variance_ros's grid: 999.9 s)."""
WHITE_LIMIT = 10.0
"""The white-noise line is fitted to tau < this [s]."""
POINTS_PER_DECADE = 40
SHORT_TAUS = (0.1, 1.0)
"""Averaging times [s] of the white-noise density of a recording: past most of the loop's
and the decimator's shaping (0.9 % at 0.1 s), short of the bias processes' correlation times,
where ``sigma(tau)^2 tau = N^2 + (K^2 / 3) tau^2`` (:func:`white_density`)."""
KEYS = ('accelerometer_noise_density', 'accelerometer_random_walk',
        'gyroscope_noise_density', 'gyroscope_random_walk')
"""Kalibr's noise keys, in its order."""
LIMITS = {'accelerometer_noise_density': 10000.0 * MICRO_G,
          'accelerometer_random_walk': 0.1,
          'gyroscope_noise_density': 100.0 * DEG_PER_ROOT_HOUR,
          'gyroscope_random_walk': 1000.0 * DEG_PER_HOUR / 60.0}
"""Largest figure an emulated sensor takes (SI): the node's ``noise.*`` and ``gyro.*``
bounds (10 000 ug/sqrt(Hz), 100 deg/sqrt(h), 1000 deg/h/sqrt(h)); 0.1 m/s^3/sqrt(Hz) is
30 times the EuRoC (ADIS16448) figure."""


@dataclass(frozen=True)
class ImuNoiseFigures:
    """
    The four noise figures of a Kalibr ``imu.yaml`` (SI units, see the module docstring).

    Attributes
    ----------
    accelerometer_noise_density : float
        [m/s^2/sqrt(Hz)]
    accelerometer_random_walk : float
        [m/s^3/sqrt(Hz)]
    gyroscope_noise_density : float
        [rad/s/sqrt(Hz)]
    gyroscope_random_walk : float
        [rad/s^2/sqrt(Hz)]
    """

    accelerometer_noise_density: float
    accelerometer_random_walk: float
    gyroscope_noise_density: float
    gyroscope_random_walk: float

    def __post_init__(self):
        for key in KEYS:
            value = getattr(self, key)
            if not checks.is_finite(value, bool_ok=False, types=(int, float)) \
                    or not 0 <= value <= LIMITS[key]:
                raise ValueError(f'{key} must be a number in [0, {LIMITS[key]:.3g}]')

    def as_dict(self):
        """Return the figures by their Kalibr keys."""
        return {key: float(getattr(self, key)) for key in KEYS}


def drive_density(bias_instability, correlation_times):
    """
    Return the driving density of a Gauss-Markov sum [unit/sqrt(s)], 0 without one.

    ``sqrt(sum_j 2 q^2 / T_j)`` with ``q^2`` the component variance that puts the Allan
    floor at ``bias_instability`` (:func:`qfa_ros.model.noise.flicker_component_variance`).
    """
    variance = flicker_component_variance(SimpleNamespace(
        bias_instability=bias_instability, correlation_times=tuple(correlation_times)))
    return math.sqrt(sum(2.0 * variance / t for t in correlation_times))


def loop_white_floor(config):
    """
    Return the white density the ADC noise leaves in the output [m/s^2/sqrt(Hz)].

    ``sqrt(sigma_adc^2 + 1/12) |G_ADC(f -> 0)| / sqrt(f_loop)``, ``G_ADC`` the published
    output per ADC code through the designed loop
    (:meth:`qfa_ros.model.design.LinearLoop.adc_response`, read at 1e-6 of the loop
    rate); the ADC's rounding counts only when the ADC noise dithers it. 0 without ADC
    noise.
    """
    adc = config.noise.adc_noise
    if adc == 0:
        return 0.0
    gain = abs(designed_loop(config).adc_response(np.array([1e-6 * config.loop_rate_hz]))[0])
    return math.sqrt((adc ** 2 + ADC_QUANTIZATION_VARIANCE) / config.loop_rate_hz) * gain


def config_figures(config):
    """
    Return the :class:`ImuNoiseFigures` a TriadConfig's noise model implies (module doc).

    Without gyros (``config.gyro`` None) the gyroscope figures are 0.
    """
    noise = config.noise
    accel_white = math.hypot(noise.noise_density, loop_white_floor(config))
    accel_walk = math.hypot(noise.random_walk,
                            drive_density(noise.bias_instability, noise.correlation_times))
    gyro = config.gyro
    gyro_white = gyro_walk = 0.0
    if gyro is not None:
        gyro_white = gyro.arw
        gyro_walk = math.hypot(gyro.rate_random_walk,
                               drive_density(gyro.bias_instability, gyro.correlation_times))
    return ImuNoiseFigures(accel_white, accel_walk, gyro_white, gyro_walk)


def emulated_config(config, figures):
    """
    Return ``config`` with the noise of ``figures`` (an :class:`ImuNoiseFigures`).

    The accelerometers get the white noise that, with the loop's own floor
    (:func:`loop_white_floor`), publishes the density of ``figures``, and the random walk
    as a bias random walk, no Gauss-Markov sum; the gyros (when ``config`` has them) the
    angle random walk and rate random walk, no Gauss-Markov sum. Everything else (the
    loop, its ADC noise, the unit's errors, the gyros' quantization) stays:
    ``config_figures(emulated_config(config, f)) == f`` within rounding.

    Raises
    ------
    ValueError
        The accelerometer density is below the loop's own floor.
    """
    floor = loop_white_floor(config)
    density = figures.accelerometer_noise_density
    if density < floor:
        raise ValueError(f'accelerometer_noise_density is below the white noise the QFA '
                         f"loop's ADC leaves ({floor:.3g} m/s^2/sqrt(Hz))")
    noise = replace(config.noise, noise_density=math.sqrt(density ** 2 - floor ** 2),
                    bias_instability=0.0, random_walk=figures.accelerometer_random_walk)
    gyro = config.gyro
    if gyro is not None:
        gyro = gyro.with_errors(arw=figures.gyroscope_noise_density, bias_instability=0.0,
                                rate_random_walk=figures.gyroscope_random_walk)
    return replace(config, noise=noise, gyro=gyro)


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
    Return the relative 1-sigma uncertainty bound of a fit through (taus, counts) points.

    Each point's log deviation scatters by about ``1 / sqrt(2 (K - 1))`` with ``K`` the
    independent averages at its tau (``counts``: record length / tau); a fit is a
    weighted mean of the points (weights tau), and the bound takes their errors as fully
    correlated (the weighted mean of the scatters), which no real curve exceeds.
    """
    taus, counts = np.asarray(taus, dtype=float), np.asarray(counts, dtype=float)
    scatter = 1.0 / np.sqrt(2.0 * np.maximum(counts - 1.0, 1.0))
    return float(np.average(scatter, weights=taus))


def model_fit_figures(config, max_tau=MAX_TAU):
    """
    Return what allan_variance_ros's fit reads off a TriadConfig's model Allan deviation.

    A dict by Kalibr key (gyroscope keys with gyros only): the fit of
    :func:`fit_like_allan_variance_ros` over 0.1 .. ``max_tau`` s of the curve of
    :func:`model_allan_deviation` (the loop's floor left out): what a recording of the
    sensor should give back over that range, not the sensor's figures
    (:func:`config_figures`).
    """
    taus = tau_grid(max_tau)
    noise = config.noise
    accel = model_allan_deviation(noise.noise_density, noise.bias_instability,
                                  noise.correlation_times, taus, noise.random_walk)
    figures = dict(zip(KEYS[:2], fit_like_allan_variance_ros(taus, accel)))
    gyro = config.gyro
    if gyro is not None:
        rate = model_allan_deviation(gyro.arw, gyro.bias_instability, gyro.correlation_times,
                                     taus, gyro.rate_random_walk, gyro.quantization)
        figures.update(zip(KEYS[2:], fit_like_allan_variance_ros(taus, rate)))
    return figures


def white_density(taus, adev):
    """
    Return the white-noise density ``N`` read off an Allan deviation at short tau.

    ``sigma(tau)^2 tau = N^2 + (K^2 / 3) tau^2``: white noise and the random walk the bias
    processes make over times short of their correlation (and a true random walk), fitted
    by least squares in ``tau^2``, each point weighted by the inverse of its variance
    (``~ (sigma^2 tau)^2 tau``, the independent averages going as ``1 / tau``).
    ``sigma(tau) sqrt(tau)`` of the white noise alone, where it has no bias in it.
    """
    taus, adev = np.asarray(taus, dtype=float), np.asarray(adev, dtype=float)
    y = adev ** 2 * taus
    if not np.all(y > 0):
        return 0.0
    weights = 1.0 / (y ** 2 * taus)
    design = np.stack([np.ones_like(taus), taus ** 2], axis=1) * np.sqrt(weights)[:, None]
    (white, _), *_ = np.linalg.lstsq(design, y * np.sqrt(weights), rcond=None)
    return math.sqrt(max(white, 0.0))


@dataclass(frozen=True)
class MeasuredFigures:
    """
    What a recorded static stream gives (:func:`measured_figures`).

    Attributes
    ----------
    fit : dict
        allan_variance_ros's figures by Kalibr key (the worst axis's).
    fit_uncertainty : dict
        Their relative 1-sigma bounds (:func:`fit_uncertainty`).
    white : dict
        The white-noise density at :data:`SHORT_TAUS` by noise-density key (the worst
        axis's, :func:`white_density`).
    white_uncertainty : dict
        Its relative 1-sigma bound.
    max_tau : float
        Longest averaging time of the fits [s].
    """

    fit: dict
    fit_uncertainty: dict
    white: dict
    white_uncertainty: dict
    max_tau: float


def measured_figures(accel, rate, sample_period, max_tau=MAX_TAU):
    """
    Return the :class:`MeasuredFigures` of a recorded static stream.

    ``accel`` and ``rate`` (n, 3) (``rate`` None: no gyros): the overlapping Allan
    deviation of each axis on :func:`tau_grid` up to ``max_tau`` and a tenth of the record
    (at least ten independent averages at the longest tau), each read by
    :func:`fit_like_allan_variance_ros`; the figure is the worst axis's, as
    allan_variance_ros writes it. The white density likewise from :data:`SHORT_TAUS`.
    """
    accel = np.asarray(accel, dtype=float)
    duration = len(accel) * sample_period
    max_tau = min(max_tau, duration / 10.0)
    taus = tau_grid(max_tau)
    short = np.logspace(*np.log10(SHORT_TAUS), 9)
    fit, fit_bound, white, white_bound = {}, {}, {}, {}
    sensors = [('accelerometer', accel)]
    if rate is not None:
        sensors.append(('gyroscope', np.asarray(rate, dtype=float)))
    for name, data in sensors:
        fits, densities = [], []
        for axis in range(data.shape[1]):
            used, adev = allan_deviation(data[:, axis], sample_period, taus)
            fits.append(fit_like_allan_variance_ros(used, adev))
            near, adev = allan_deviation(data[:, axis], sample_period, short)
            densities.append(white_density(near, adev))
        fit[f'{name}_noise_density'], fit[f'{name}_random_walk'] = np.max(fits, axis=0)
        white_taus, walk_taus = used[used < WHITE_LIMIT], used
        fit_bound[f'{name}_noise_density'] = fit_uncertainty(white_taus,
                                                             duration / white_taus)
        fit_bound[f'{name}_random_walk'] = fit_uncertainty(walk_taus, duration / walk_taus)
        white[f'{name}_noise_density'] = float(max(densities))
        white_bound[f'{name}_noise_density'] = fit_uncertainty(near, duration / near)
    return MeasuredFigures(fit, fit_bound, white, white_bound, max_tau)
