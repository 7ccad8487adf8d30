"""Sensor noise: velocity random walk, bias instability, ADC noise (drawn in the kernel)."""

from dataclasses import dataclass
import math
from types import SimpleNamespace

import numpy as np

from qfa_ros.model import checks, random_streams
from qfa_ros.model.constants import MICRO_G


@dataclass(frozen=True)
class NoiseConfig:
    """
    Noise of one axis, in SI units.

    Attributes
    ----------
    noise_density : float
        White acceleration noise N [(m/s^2)/sqrt(Hz)], the velocity random walk: its
        Allan deviation at tau = 1 s is N (IEEE 1293 convention), i.e. a one-sided power
        spectral density ``2 N^2``, so its rms in a band ``[0, B]`` is ``N sqrt(2 B)``.
        Default 1.5 ug/sqrt(Hz): 6.7 ug rms in 0-10 Hz, inside the "< 7 ug rms in
        0-10 Hz" of the navigation-grade QFA class the docs cite (Honeywell QA-2000/QA-3000
        class datasheets); 2 ug/sqrt(Hz) would be 8.9 ug rms.
    bias_instability : float
        Flicker floor of the Allan deviation [m/s^2], modelled as a sum of
        first-order Gauss-Markov processes with one correlation time per decade of
        ``correlation_times``, scaled so that the floor of their Allan deviation
        equals this value.
    correlation_times : tuple of float
        Correlation times of the Gauss-Markov processes [s]. Default 60 s ... 60 000 s:
        the floor from about a minute to hours, the time scales a bias stability is
        quoted over (Ran et al. 2019, Table 2: 50 ug bias stability); below a few seconds the
        stream is white (ADEV(1 s) = 1.04 N, see :func:`allan_deviation_model`), so the
        published per-sample covariance describes it. Chosen, not from a source.
    adc_noise : float
        White noise at the ADC input, standard deviation [count].
    random_walk : float
        Bias random walk K [(m/s^2)/sqrt(s) = m/s^3/sqrt(Hz)]: a bias ``b' = K w(t)``
        (``w`` unit white noise), Kalibr's ``accelerometer_random_walk``; its Allan
        deviation is ``K sqrt(tau / 3)``. Default 0: the sensor's own bias wanders as the
        Gauss-Markov sum above; an emulated ``imu.yaml`` (:mod:`qfa_ros.model.noise_figures`)
        sets this instead.
    """

    noise_density: float = 1.5 * MICRO_G
    bias_instability: float = 3.0 * MICRO_G
    correlation_times: tuple = (60.0, 600.0, 6000.0, 60000.0)
    adc_noise: float = 4.0
    random_walk: float = 0.0

    def __post_init__(self):
        for name in ('noise_density', 'bias_instability', 'adc_noise', 'random_walk'):
            checks.non_negative(name, getattr(self, name))
        checks.positive_times('correlation_times', self.correlation_times)

    @classmethod
    def off(cls):
        """Return a configuration with every noise source switched off."""
        return cls(noise_density=0.0, bias_instability=0.0, adc_noise=0.0)


def gauss_markov_allan_variance(tau, variance, correlation_time):
    """
    Return the Allan variance of a first-order Gauss-Markov process.

    For the autocovariance ``R(u) = q^2 exp(-|u|/T)``::

        sigma^2(tau) = q^2 T^2 / tau^2 (2 tau / T - 3 + 4 e^(-tau/T) - e^(-2 tau/T))
    """
    ratio = np.asarray(tau, dtype=float) / correlation_time
    return variance / ratio ** 2 * (2 * ratio - 3 + 4 * np.exp(-ratio) - np.exp(-2 * ratio))


def flicker_component_variance(config):
    """Return the variance per Gauss-Markov component that sets the configured floor."""
    if config.bias_instability == 0:
        return 0.0
    times = np.asarray(config.correlation_times)
    tau = np.logspace(math.log10(times.min()) - 1, math.log10(times.max()) + 1, 400)
    unit = sum(gauss_markov_allan_variance(tau, 1.0, t) for t in times)
    # The floor is the Allan deviation's flat region: its maximum between the first and
    # last correlation time (the sum ripples slightly across the decades).
    inside = (tau >= times.min()) & (tau <= times.max() * 2)
    floor = math.sqrt(unit[inside].mean())
    return (config.bias_instability / floor) ** 2


class NoiseSource:
    """
    Noise of ``n_axes`` independent axes, drawn inside the compiled loop kernel.

    White acceleration noise per loop step ``w ~ N(0, N^2 f_loop)``; the bias
    instability processes advance at the sample rate, ``b[k] = phi b[k-1] + v[k]``,
    ``phi = exp(-dt/T)``, ``v ~ N(0, q^2 (1 - phi^2))``, and are held over each
    decimation block; a bias random walk ``K`` is one more such process, with ``phi = 1``
    and ``v ~ N(0, K^2 dt)``, started at zero; ADC noise ``n ~ N(0, sigma_adc^2)`` per
    loop step [count].
    Every random number of axis ``i`` comes from ``streams[i]``, the child
    ``'triad.noise'`` ``i`` of ``rng`` (:mod:`qfa_ros.model.random_streams`):
    :func:`qfa_ros.model.kernel.run_axis` draws them in a fixed order,
    so the output depends on the seed only, not on the chunk lengths or on which thread
    runs which axis. This object holds the parameters and the Gauss-Markov states.

    Attributes
    ----------
    streams : list of numpy.random.Generator
        One stream per axis.
    white_std : float
        Standard deviation of ``w`` per loop step [m/s^2].
    adc_std : float
        Standard deviation of ``n`` per loop step [count].
    gm_block : int
        Samples per Gauss-Markov step.
    phi, drive_std : float64[k]
        ``phi`` and ``q sqrt(1 - phi^2)`` [m/s^2] per Gauss-Markov component and step,
        then ``1`` and ``K sqrt(dt)`` of the random walk (``k = 0`` without either).
    bias_state : float64[n_axes, k]
        Gauss-Markov states [m/s^2], started in their stationary distribution; the
        random walk's, at zero.
    """

    def __init__(self, config, n_axes, loop_rate_hz, sample_rate_hz, rng):
        self.config = config
        self.n_axes = n_axes
        self.decimation = int(round(loop_rate_hz / sample_rate_hz))
        self.streams = [random_streams.generator(rng, 'triad.noise', axis)
                        for axis in range(n_axes)]
        self.white_std = config.noise_density * math.sqrt(loop_rate_hz)
        self.adc_std = float(config.adc_noise)
        # The bias instability steps once per block of samples (a tenth of the shortest
        # correlation time, at most GAUSS_MARKOV_BLOCK_S) and holds: its Allan deviation
        # is unchanged from the block on, where the white noise dwarfs it, and it costs
        # 1/block of its random numbers (bench/results/sim_limit.md).
        self.gm_block = max(1, int(min(GAUSS_MARKOV_BLOCK_S,
                                       0.1 * min(config.correlation_times)) * sample_rate_hz))
        if config.random_walk > 0 and config.bias_instability == 0:
            # A random walk alone (an emulated imu.yaml) steps every sample, Kalibr's
            # discrete model exactly: one normal a sample (bench/results/sim_limit.md).
            self.gm_block = 1
        dt = self.gm_block / sample_rate_hz
        if config.bias_instability > 0:
            self.phi = np.exp(-dt / np.asarray(config.correlation_times, dtype=float))
            variance = flicker_component_variance(config)
            self.drive_std = np.sqrt(variance * (1.0 - self.phi ** 2))
            self.bias_state = np.array([stream.standard_normal(len(self.phi))
                                        for stream in self.streams]) * math.sqrt(variance)
        else:
            self.phi = np.zeros(0)
            self.drive_std = np.zeros(0)
            self.bias_state = np.zeros((n_axes, 0))
        if config.random_walk > 0:
            # The walk's step comes after the Gauss-Markov ones in each stream (the
            # kernel's order), so a sensor without a walk draws what it always drew.
            self.phi = np.append(self.phi, 1.0)
            self.drive_std = np.append(self.drive_std, config.random_walk * math.sqrt(dt))
            self.bias_state = np.hstack([self.bias_state, np.zeros((n_axes, 1))])


GAUSS_MARKOV_BLOCK_S = 0.1
"""Longest hold of the bias-instability processes between their steps [s]."""
ADC_QUANTIZATION_VARIANCE = 1.0 / 12.0
"""Variance of the ADC's rounding to a code [count^2] (dithered by the ADC noise)."""


def acceleration_variance(config, sample_rate_hz, white_share=1.0, adc_gain=0.0):
    """
    Return the variance of one published sample per axis [(m/s^2)^2] (REP-145 covariance).

    The variance of the noise that is white at the published rate: the white
    acceleration noise ``N^2 f_s`` times ``white_share`` (the loop's and decimator's
    noise-equivalent bandwidth over ``f_s / 2``; 1 for an ideal averaging of ``f_s``)
    plus the ADC noise and the ADC's rounding, ``(sigma_adc^2 + 1/12) adc_gain^2``.
    :func:`qfa_ros.model.design.published_acceleration_variance` supplies both factors
    from the designed loop. The bias instability is not in it: correlated over a minute to
    hours, it is a bias a filter estimates (its Allan floor is ``bias_instability``),
    not noise of one sample; its stationary variance is
    ``len(correlation_times) * flicker_component_variance(config)``.

    Parameters
    ----------
    config : NoiseConfig
        The noise.
    sample_rate_hz : float
        Published rate f_s [Hz].
    white_share : float
        Per-sample variance of unit-density white input over ``f_s`` [1].
    adc_gain : float
        Standard deviation of a published sample per count of white ADC noise
        [(m/s^2)/count].
    """
    if not sample_rate_hz > 0 or not white_share > 0 or not adc_gain >= 0:
        raise ValueError('sample_rate_hz and white_share must be positive, adc_gain >= 0')
    adc = (config.adc_noise ** 2 + ADC_QUANTIZATION_VARIANCE) * adc_gain ** 2
    return white_share * config.noise_density ** 2 * sample_rate_hz + adc


def allan_deviation_model(config, tau):
    """
    Return the Allan deviation the noise model implies at ``tau`` [s] [m/s^2].

    ``sigma^2(tau) = N^2 / tau + sum_j AVAR_GM(tau; q^2, T_j) + K^2 tau / 3``.
    """
    return float(model_allan_deviation(config.noise_density, config.bias_instability,
                                       config.correlation_times,
                                       checks.positive('tau', tau), config.random_walk))


def model_allan_deviation(noise_density, bias_instability, correlation_times, taus,
                          rate_random_walk=0.0, quantization=0.0):
    """
    Return the Allan deviation of white noise, a Gauss-Markov sum and a random walk.

    ``sigma^2 = 3 Q^2 / tau^2 + N^2 / tau + sum_j AVAR_GM(tau; q^2, T_j) + K^2 tau / 3``
    with ``q^2`` the component variance that puts the flicker floor at
    ``bias_instability`` (:func:`flicker_component_variance`), ``Q`` the angle (or
    velocity) quantization.
    """
    taus = np.asarray(taus, dtype=float)
    if not np.all(np.isfinite(taus) & (taus > 0)):
        raise ValueError(f'taus must be finite and > 0 [s], got {taus!r}')
    variance = flicker_component_variance(SimpleNamespace(
        bias_instability=bias_instability, correlation_times=tuple(correlation_times)))
    flicker = sum(gauss_markov_allan_variance(taus, variance, t) for t in correlation_times) \
        if variance else 0.0
    return np.sqrt(3.0 * quantization ** 2 / taus ** 2 + noise_density ** 2 / taus + flicker
                   + rate_random_walk ** 2 * taus / 3.0)
