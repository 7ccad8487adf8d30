"""
Test that the published covariance, the noise defaults and the stream agree.

The node publishes ``linear_acceleration_covariance`` = the per-sample variance of the
noise that is white at the published rate, through the loop and the averaging decimator
(:func:`qfa_ros.model.design.published_acceleration_variance`). An Allan analysis of the
stream (allantools) must read, at tau = 1 s, the white noise that covariance implies.
Seeded, 5 seeds x 12 s x 3 axes (x 120 s for ADEV(1 s)); tolerances from the estimates' own
standard errors / confidence intervals (test/statistics_helpers.py).
"""

import math

import allantools
import numpy as np
import pytest
from scipy import signal
from statistics_helpers import allan_edf_white, mean_sd, t_bound, variance_ratio_bounds

from qfa_ros.model.allan import allan_deviation
from qfa_ros.model.constants import MICRO_G
from qfa_ros.model.design import design_controller, LinearLoop, published_acceleration_variance
from qfa_ros.model.noise import allan_deviation_model, model_allan_deviation, NoiseConfig
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig

SECONDS = 60.0


def stream(config, seed, seconds=SECONDS):
    """Return a static stream [m/s^2] of ``seconds`` per axis, (n, 3)."""
    return QfaTriad(config, rng=seed).run_for(seconds).accel


def white_share(config):
    controller = design_controller(config.hardware, config.loop_rate_hz, config.crossover_hz,
                                   config.integrator_ratio, config.lead_pole_ratio)
    return LinearLoop(config.hardware, controller, config.loop_rate_hz).noise_shares(
        config.decimation)[0]


def allan_ratio(config, accel):
    """Return (ratio, its 1-sigma) of the stream's ADEV(1 s) to the covariance's."""
    rate = config.sample_rate_hz
    adev = np.array([allantools.oadev(accel[:, axis], rate=rate, data_type='freq',
                                      taus=[1.0])[1][0] for axis in range(3)])
    # Greenhall's equivalent degrees of freedom, white frequency noise (alpha 0), per axis;
    # three independent axes pooled in the Allan variance.
    edf = 3 * allantools.edf_greenhall(alpha=0, d=2, m=int(rate), N=len(accel),
                                       overlapping=True)
    measured = math.sqrt(np.mean(adev ** 2))
    implied = math.sqrt(published_acceleration_variance(config)
                        / (white_share(config) * rate * 1.0))
    return measured / implied, measured / implied / math.sqrt(2 * edf), measured


def test_published_covariance_is_the_per_sample_variance_of_the_stream():
    # 5 seeds x 12 s x 3 axes. Each second's variance (its mean removed: the bias
    # instability, correlated over a minute and more, is a bias, not per-sample noise;
    # the covariance leaves it out by definition) over the published one: per seed the
    # mean of 36 within Student's t(35) of their standard error, all 180 within
    # t(179); a false failure of 1e-6 per test over the 6 checks (t 6.5 and 5.4).
    config = TriadConfig()
    rate = int(config.sample_rate_hz)
    published = published_acceleration_variance(config)
    seeds = range(4, 9)
    checks = len(seeds) + 1
    pooled = []
    for seed in seeds:
        per_block = stream(config, seed, 12.0).reshape(-1, rate, 3).var(axis=1, ddof=1)
        ratio, se = mean_sd((per_block / published).ravel())
        assert abs(ratio - 1.0) < t_bound(per_block.size - 1, checks) * se, (seed, ratio, se)
        pooled.extend((per_block / published).ravel())
    ratio, se = mean_sd(pooled)
    assert abs(ratio - 1.0) < t_bound(len(pooled) - 1, checks) * se, (ratio, se)
    assert 0 < se < 0.02


def test_allan_deviation_at_one_second_matches_the_published_covariance():
    # The noise model's ADEV(1 s) over the white noise the covariance implies at the
    # output's noise-equivalent bandwidth: 0.9-1.1 (the bias instability adds 4 % at 1 s).
    config = TriadConfig()
    rate = config.sample_rate_hz
    implied = math.sqrt(published_acceleration_variance(config) / (white_share(config) * rate))
    model = allan_deviation_model(config.noise, 1.0)
    assert 0.9 < model / implied < 1.1
    # The streams read the model: 5 seeds x 120 s x 3 axes. Each AVAR(1 s) over the
    # model's is chi2(edf)/edf, edf = 110: the smaller of Greenhall's for white FM (178)
    # and for random-walk FM (110; the Gauss-Markov bias instability, 8 % of AVAR(1 s),
    # acts as one at 1 s), so conservative; the 15 pooled, edf 15 x 110. Bounds at a
    # false failure of 1e-6 per test over the 16 checks (test/statistics_helpers.py):
    # pooled 0.82-1.20 (ADEV -9 %/+10 %), each 0.43-1.91.
    seeds, seconds = range(5, 10), 120.0
    samples = int(seconds * rate)
    edf = min(allan_edf_white(samples, rate),
              allantools.edf_greenhall(alpha=-2, d=2, m=int(rate), N=samples, overlapping=True))
    checks = 3 * len(seeds) + 1
    ratios = []
    for seed in seeds:
        accel = stream(config, seed, seconds)
        for axis in range(3):
            adev = allantools.oadev(accel[:, axis], rate=rate, data_type='freq', taus=[1.0])[1]
            ratios.append((adev[0] / model) ** 2)
    low, high = variance_ratio_bounds(edf, checks)
    assert np.all((low < np.array(ratios)) & (np.array(ratios) < high)), (low, high, ratios)
    low, high = variance_ratio_bounds(edf * len(ratios), checks)
    assert low < np.mean(ratios) < high, (low, high, np.mean(ratios))


@pytest.mark.parametrize('tau', [0, 0.0, -1.0, float('nan'), float('inf')])
def test_the_model_allan_deviation_refuses_an_averaging_time_that_is_none(tau):
    # sigma(tau) has N^2 / tau: at 0 it is no number (inf with a warning before the refusal).
    with pytest.raises(ValueError, match='tau'):
        allan_deviation_model(NoiseConfig(), tau)
    with pytest.raises(ValueError, match='taus'):
        model_allan_deviation(1e-5, 1e-6, (1.0,), [1.0, tau])


@pytest.mark.parametrize('period, taus, name', [
    (float('inf'), 'octave', 'sample_period'),
    (None, 'octave', 'sample_period'),
    ('x', 'octave', 'sample_period'),
    (0.0, 'octave', 'sample_period'),
    (1.0, [2.0, float('nan')], 'taus'),
    (1.0, [float('inf')], 'taus'),
])
def test_the_measured_allan_deviation_refuses_a_period_or_tau_that_is_none(period, taus, name):
    # Before: an infinite period gave infinite taus, None a TypeError, a NaN tau was dropped.
    with pytest.raises(ValueError, match=name):
        allan_deviation(np.arange(100.0) % 7, period, taus)


def test_the_old_flicker_shape_breaks_the_allan_ratio():
    # The bias-instability floor starting at 0.1 s (the previous default) dominates
    # ADEV(1 s): the stream's is far above what the per-sample covariance implies.
    config = TriadConfig(noise=NoiseConfig(correlation_times=(0.1, 1.0, 10.0, 100.0, 1000.0)))
    ratio, sigma, _ = allan_ratio(config, stream(config, 5))
    assert ratio - 3 * sigma > 1.5


def test_default_noise_is_below_7_ug_rms_in_0_to_10_hz():
    # The navigation-grade QFA figure the docs cite: < 7 ug rms in 0-10 Hz. White part:
    # one-sided density sqrt(2) N, rms N sqrt(2 x 10 Hz); the stream in 0.1-10 Hz
    # (Welch, 10 s segments; the bias instability adds its share above 0.1 Hz).
    config = TriadConfig()
    assert config.noise.noise_density * math.sqrt(2 * 10.0) < 7.0 * MICRO_G
    accel = stream(config, 6)
    freq, psd = signal.welch(accel - accel.mean(axis=0), fs=config.sample_rate_hz,
                             nperseg=int(10 * config.sample_rate_hz), axis=0)
    band = (freq > 0) & (freq <= 10.0)
    rms = math.sqrt(psd[band].mean(axis=1).sum() * (freq[1] - freq[0]))
    assert rms < 7.0 * MICRO_G
    # and it is the white noise: within 5 % of N sqrt(2 x 9.9 Hz).
    assert abs(rms / (config.noise.noise_density * math.sqrt(2 * 9.9)) - 1.0) < 0.05
