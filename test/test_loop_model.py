"""Acceptance tests of the digital closed-loop QFA model (issue: foundation)."""

import math

import numpy as np
from numpy.testing import assert_allclose
import pytest

from qfa_ros.allan import allan_deviation
from qfa_ros.design import LinearLoop
from qfa_ros.hardware import AxisHardware, STANDARD_GRAVITY
from qfa_ros.model import FLAG_OVER_RANGE, QfaTriad, TriadConfig
from qfa_ros.noise import MICRO_G, NoiseConfig
from qfa_ros.profiles import SineProfile, StaticProfile, StepProfile

G = STANDARD_GRAVITY
QUIET = NoiseConfig.off()


def quiet_triad(profile=None, **config):
    """Return a noise-free triad (the loop's own quantization remains)."""
    return QfaTriad(TriadConfig(noise=QUIET, **config), rng=0, profile=profile)


def settled_mean(triad, seconds, discard=0.2):
    """Run, drop the first ``discard`` seconds and return the mean output [m/s^2]."""
    triad.run_for(discard)
    return triad.run_for(seconds).accel.mean(axis=0)


@pytest.mark.parametrize('roll, pitch', [(0.0, 0.0), (0.3, -0.2), (math.pi, 0.0), (1.2, 0.7)])
@pytest.mark.parametrize('bias_ug, k2_ug', [((0, 0, 0), (0, 0, 0)),
                                            ((120.0, -80.0, 40.0), (15.0, 25.0, -10.0))])
def test_static_output_equals_input_plus_model_terms(roll, pitch, bias_ug, k2_ug):
    profile = StaticProfile.orientation(roll, pitch)
    config = TriadConfig.from_datasheet(bias_ug=bias_ug, k2_ug_per_g2=k2_ug, noise=QUIET)
    triad = QfaTriad(config, rng=0, profile=profile)
    mean = settled_mean(triad, 1.0)
    f = np.asarray(profile.specific_force)
    expected = np.asarray(config.bias) + f + np.asarray(config.k2) * f * f
    # 1 ppm of the scale factor on the 1 g input, with a floor of 0.5 ug on a ~0 g axis.
    assert_allclose(mean, expected, rtol=1e-6, atol=0.5 * MICRO_G)


@pytest.mark.parametrize('component', ['k_vi', 'v_da2_ref', 'b', 'l_coil'])
@pytest.mark.parametrize('ppm', [200.0, -200.0, 1000.0])
def test_feedback_step_changes_scale_by_its_inverse(component, ppm):
    triad = quiet_triad()
    before = settled_mean(triad, 1.0)[2]
    for axis in range(3):
        triad.drift.set_step(axis, component, ppm * 1e-6)
    after = settled_mean(triad, 1.0)[2]
    change_ppm = (after / before - 1.0) * 1e6
    assert_allclose(change_ppm, -ppm / (1.0 + ppm * 1e-6), atol=1.0)


def lock_in(triad, frequency, amplitude, cycles=20, settle_cycles=5):
    """Return the complex response output/input of axis z at ``frequency``."""
    rate = triad.config.sample_rate_hz
    settle = int(round(settle_cycles / frequency * rate))
    triad.run(settle)
    n = int(round(cycles / frequency * rate))
    out = triad.run(n)
    t = out.stamps_ns * 1e-9
    reference = np.exp(-2j * np.pi * frequency * t)
    response = 2 * np.mean((out.accel[:, 2] - out.accel[:, 2].mean()) * reference)
    # The input sin(w t) has the phasor -j; its step k is held over [t_k, t_k + dt) while
    # stamps mark the end of the step, so the input phase is taken at the step start.
    phasor = -1j * amplitude * np.exp(-2j * np.pi * frequency / triad.config.loop_rate_hz)
    return response / phasor


@pytest.mark.parametrize('frequency', [2.0, 20.0, 80.0, 150.0, 220.0, 300.0])
def test_frequency_response_matches_linearized_model(frequency):
    amplitude = 2 * G
    profile = SineProfile(frequency, amplitude=(0.0, 0.0, amplitude))
    triad = quiet_triad(profile, sample_rate_hz=10000.0)
    measured = lock_in(triad, frequency, amplitude)
    model = LinearLoop(triad.config.hardware, triad.axes[2].controller,
                       triad.config.loop_rate_hz).closed_loop(np.array([frequency]))[0]
    assert abs(20 * np.log10(abs(measured) / abs(model))) < 0.5
    assert abs(np.degrees(np.angle(measured / model))) < 3.0


def test_linearized_design_meets_bandwidth_and_margins():
    triad = quiet_triad()
    crossover, phase_margin, gain_margin, bandwidth = LinearLoop(
        triad.config.hardware, triad.axes[0].controller, triad.config.loop_rate_hz).margins()
    assert bandwidth >= 300.0
    assert phase_margin >= 45.0
    assert gain_margin >= 6.0
    assert_allclose(crossover, triad.config.crossover_hz, rtol=0.01)


@pytest.mark.parametrize('ppm', [2000.0, -2000.0])
def test_forward_step_keeps_output_and_moves_bandwidth_as_predicted(ppm):
    triad = quiet_triad()
    before = settled_mean(triad, 1.0)[2]
    for axis in range(3):
        triad.drift.set_step(axis, 'k_amp', ppm * 1e-6)
    after = settled_mean(triad, 1.0)[2]
    assert_allclose((after / before - 1.0) * 1e6, 0.0, atol=1.0)

    # Bandwidth: measured response near the corner, nominal vs drifted loop.
    hw = AxisHardware()
    nominal = LinearLoop(hw, triad.axes[2].controller, 10000.0)
    corner = nominal.margins()[3]
    drifted_gains = triad.axes[2].gains
    drifted = LinearLoop(hw, triad.axes[2].controller, 10000.0, gains=drifted_gains)
    predicted = abs(drifted.closed_loop(np.array([corner]))[0]) \
        / abs(nominal.closed_loop(np.array([corner]))[0]) - 1.0
    amplitude = 1 * G
    responses = []
    for delta in (0.0, ppm * 1e-6):
        sim = quiet_triad(SineProfile(corner, amplitude=(0.0, 0.0, amplitude)),
                          sample_rate_hz=10000.0)
        sim.drift.set_step(2, 'k_amp', delta)
        responses.append(abs(lock_in(sim, corner, amplitude, cycles=60)))
    measured = responses[1] / responses[0] - 1.0
    assert abs(predicted) > 2e-4  # the corner does move measurably
    assert_allclose(measured, predicted, rtol=0.1)
    bandwidth_shift = drifted.margins()[3] - corner
    assert np.sign(bandwidth_shift) == np.sign(ppm)


def test_open_loop_output_is_linear_in_n_fpga():
    triad = quiet_triad()
    triad.run_for(0.1)
    for axis in range(3):
        triad.set_open_loop(axis, True)
    base = triad.config.hardware.n_fpga
    words = base + 400 * np.arange(8)
    levels = []
    for word in words:
        for axis in range(3):
            triad.set_n_fpga(axis, int(word))
        triad.run_for(0.02)
        out = triad.run_for(0.05)
        assert not out.valid.any()
        levels.append(out.counts[:, 2].mean())
    slope, intercept = np.polyfit(words, levels, 1)
    residual = np.asarray(levels) - (slope * words + intercept)
    gain = triad.axes[2].controller.gain
    assert np.max(np.abs(residual)) <= 0.5 * gain + 1.0  # one ADC code through k(D(z))
    assert abs(intercept) <= 0.5 * gain * len(words)
    gains = triad.axes[2].gains
    assert_allclose(slope, gain * gains.open_loop_counts_per_fpga, rtol=1e-4)


def test_reference_current_shifts_output_by_eq_26():
    triad = quiet_triad()
    off = triad.run_for(0.5)
    off = triad.run_for(1.0).counts[:, 2].mean()
    triad.set_reference_current(2, True)
    triad.run_for(0.2)
    on = triad.run_for(1.0).counts[:, 2].mean()
    gains = triad.axes[2].gains
    assert_allclose(on - off, -gains.i_ref / gains.k_da2_vi, atol=1.0)
    assert_allclose(on - off, -71739, rtol=1e-3)  # seed 1 Table 4 scale


def test_reclosing_the_loop_recovers_without_lasting_error():
    triad = quiet_triad()
    before = settled_mean(triad, 0.5)
    triad.set_open_loop(2, True)
    triad.run_for(0.2)
    triad.set_open_loop(2, False)
    out = triad.run_for(1.0)
    settle = int(triad.config.settle_time * triad.config.sample_rate_hz)
    assert not out.valid[:settle, 2].any() and out.valid[settle:, 2].all()
    assert_allclose(out.accel[settle:, 2].mean(), before[2], atol=2 * MICRO_G)
    # After the settle window, no sample strays beyond the 1 g step response's scale.
    assert np.max(np.abs(out.accel[settle:, 2] - before[2])) < 0.01 * G


def test_allan_deviation_at_one_second_matches_white_noise():
    density = 20.0 * MICRO_G
    config = TriadConfig(noise=NoiseConfig(noise_density=density, bias_instability=0.0))
    out = QfaTriad(config, rng=11).run_for(300.0, chunk_samples=10000)
    for axis in range(3):
        taus, adev = allan_deviation(out.accel[:, axis], 1e-3, taus=[1.0])
        assert_allclose(adev[0], density, rtol=0.1)


def test_allan_floor_matches_bias_instability():
    floor = 10.0 * MICRO_G
    config = TriadConfig(noise=NoiseConfig(noise_density=1.0 * MICRO_G, bias_instability=floor))
    out = QfaTriad(config, rng=5).run_for(2000.0, chunk_samples=10000)
    for axis in range(3):
        taus, adev = allan_deviation(out.accel[:, axis], 1e-3)
        window = (taus >= 1.0) & (taus <= 200.0)
        assert floor / 1.5 <= adev[window].min() <= floor * 1.5
        assert adev[window].max() <= floor * 1.5 * 1.5


def test_over_range_input_is_flagged_and_recovers():
    profile = StepProfile(times=(0.0, 0.3, 0.8), levels=((0, 0, G), (0, 0, 100 * G), (0, 0, G)))
    triad = quiet_triad(profile)
    out = triad.run_for(2.0)
    assert np.all(np.isfinite(out.accel))
    during = (out.stamps_ns > 0.32e9) & (out.stamps_ns < 0.8e9)
    assert np.all(out.saturated[during, 2])
    assert np.all(out.flags[during, 2] & FLAG_OVER_RANGE)
    limit = triad.config.hardware.da2_full_scale
    assert np.all(np.abs(out.counts[:, 2]) <= limit)
    tail = out.stamps_ns > 1.3e9
    assert not out.saturated[tail].any()
    assert_allclose(out.accel[tail, 2].mean(), G, rtol=1e-6)


def test_same_seed_same_output_and_chunking_is_invisible():
    one = QfaTriad(TriadConfig(), rng=42).run(3000)
    again = QfaTriad(TriadConfig(), rng=42).run(3000)
    assert np.array_equal(one.accel, again.accel)
    chunks = QfaTriad(TriadConfig(), rng=42)
    parts = [chunks.run(n) for n in (1, 999, 17, 1983)]
    for field in ('stamps_ns', 'accel', 'counts', 'flags'):
        assert np.array_equal(np.concatenate([getattr(p, field) for p in parts]),
                              getattr(one, field))
    other = QfaTriad(TriadConfig(), rng=43).run(3000)
    assert not np.array_equal(one.accel, other.accel)


def test_stamps_are_evenly_spaced_integer_nanoseconds():
    triad = QfaTriad(TriadConfig(sample_rate_hz=2000.0), rng=1)
    stamps = np.concatenate([triad.run(n).stamps_ns for n in (1, 7, 333, 1000)])
    assert stamps.dtype == np.int64
    assert np.all(np.diff(stamps) == 500_000)
    assert stamps[0] == 500_000


@pytest.mark.parametrize('kwargs, name', [
    ({'loop_rate_hz': 0.0}, 'loop_rate_hz'),
    ({'loop_rate_hz': -10000.0}, 'loop_rate_hz'),
    ({'sample_rate_hz': 0.0}, 'sample_rate_hz'),
    ({'sample_rate_hz': float('nan')}, 'sample_rate_hz'),
    ({'sample_rate_hz': 3000.0}, 'integer multiple'),
    ({'bias': (0.0, float('nan'), 0.0)}, 'bias'),
    ({'misalignment': ((0.0, 0.0), (0.0, 0.0))}, 'misalignment'),
])
def test_invalid_triad_settings_raise_value_error(kwargs, name):
    with pytest.raises(ValueError, match=name):
        TriadConfig(**kwargs)


@pytest.mark.parametrize('kwargs, name', [
    ({'n_ad_bits': 40}, 'n_ad_bits'),
    ({'n_da2_bits': 7}, 'n_da2_bits'),
    ({'n_da1_bits': 12.5}, 'n_da1_bits'),
    ({'damping': float('nan')}, 'damping'),
    ({'sense_resistor': -58.0}, 'sense_resistor'),
    ({'damping_ratio': 0.5}, 'damping_ratio'),
])
def test_invalid_hardware_raises_value_error(kwargs, name):
    with pytest.raises(ValueError, match=name):
        AxisHardware(**kwargs)


@pytest.mark.parametrize('kwargs, name', [
    ({'noise_density': -1.0}, 'noise_density'),
    ({'adc_noise': float('inf')}, 'adc_noise'),
    ({'correlation_times': ()}, 'correlation_times'),
])
def test_invalid_noise_raises_value_error(kwargs, name):
    with pytest.raises(ValueError, match=name):
        NoiseConfig(**kwargs)


def test_run_rejects_bad_input():
    triad = quiet_triad()
    with pytest.raises(ValueError, match='specific_force'):
        triad.run(10, specific_force=np.full((10, 3), np.nan))
    with pytest.raises(ValueError, match='specific_force'):
        triad.run(10, specific_force=np.zeros((11, 3)))
    with pytest.raises(ValueError, match='n_fpga'):
        triad.set_n_fpga(0, 2 ** 20)
    with pytest.raises(ValueError, match='controller gain'):
        triad.set_controller_gain(0, float('nan'))


def test_misalignment_couples_axes_as_configured():
    misalignment = ((0.0, 1e-3, -2e-3), (5e-4, 0.0, 1e-3), (-1e-3, 2e-3, 0.0))
    profile = StaticProfile.orientation(0.4, -0.3)
    triad = QfaTriad(TriadConfig(noise=QUIET, misalignment=misalignment), rng=0,
                     profile=profile)
    mean = settled_mean(triad, 1.0)
    expected = (np.eye(3) + np.asarray(misalignment)) @ np.asarray(profile.specific_force)
    assert_allclose(mean, expected, rtol=1e-6, atol=0.5 * MICRO_G)
