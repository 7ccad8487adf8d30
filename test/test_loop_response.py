"""
Test the loop's margins, bandwidth and step response measured on the simulated loop.

The figures are measured on the compiled kernel (integer PID, ZOH pendulum, quantization,
default noise) by loop breaking and a square wave (:mod:`qfa_ros.model.loop_response`), and
compared with the linearized design and with the figures docs/model.md quotes. Tolerances:
four standard errors of the measurement (spread over the chirp periods / step edges) plus
the bin interpolation bound.
"""

from pathlib import Path

import numpy as np
import pytest

from qfa_ros.model.design import LinearLoop
from qfa_ros.model.loop_response import design_step, measure_loop, measure_step, step_figures
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig

ROOT = Path(__file__).resolve().parents[1]
# Measured figures docs/model.md and the README's table quote (bench/loop_response.py).
DOCUMENTED = {'crossover_hz': 300.0, 'phase_margin_deg': 58.86, 'gain_margin_db': 12.24,
              'bandwidth_hz': 600.0, 'overshoot': 0.1105, 'rise_time_s': 0.53e-3,
              'settling_time_s': 8.8e-3}


@pytest.fixture(scope='module')
def loop():
    config = TriadConfig()
    controller = QfaTriad(config, rng=0).axes[0].controller
    design = LinearLoop(config.hardware, controller, config.loop_rate_hz).margins()
    return config, controller, design, measure_loop(config, rng=7).margins()


def test_measured_margins_match_the_design_and_meet_the_requirements(loop):
    config, _, (crossover, phase_margin, gain_margin, bandwidth), measured = loop
    # The crossover the design targets, the margins and bandwidth it predicts.
    assert abs(measured.crossover_hz - config.crossover_hz) < 4 * measured.crossover_se_hz + 0.1
    assert abs(measured.crossover_hz - crossover) < 4 * measured.crossover_se_hz + 0.1
    assert abs(measured.phase_margin_deg - phase_margin) < 4 * measured.phase_margin_se_deg
    assert abs(measured.gain_margin_db - gain_margin) < 4 * measured.gain_margin_se_db + 0.01
    assert abs(measured.bandwidth_hz - bandwidth) < 4 * measured.bandwidth_se_hz + 0.1
    # The requirements: PM >= 45 deg, GM >= 6 dB, bandwidth >= 300 Hz.
    assert measured.phase_margin_deg - 4 * measured.phase_margin_se_deg >= 45.0
    assert measured.gain_margin_db - 4 * measured.gain_margin_se_db >= 6.0
    assert measured.bandwidth_hz >= 300.0
    # The uncertainties are those of a real measurement, not zero.
    assert 0 < measured.phase_margin_se_deg < 0.5
    assert 0 < measured.crossover_se_hz < 1.0


def test_measured_step_response_matches_the_design(loop):
    config, controller, _, _ = loop
    step = measure_step(config, rng=8)
    design = design_step(config, controller, len(step.time_s))
    overshoot, rise, settling = step_figures(design, step.settle_band, config.loop_rate_hz)
    assert abs(step.overshoot - overshoot) < 4 * step.overshoot_se + 1e-3
    # Rise time to one loop step (its resolution). The settling time is where the slow
    # tail leaves the 2 % band: its resolution is one step plus 4 standard errors of the
    # response there over the tail's slope.
    step_s = 1.0 / config.loop_rate_hz
    assert abs(step.rise_time_s - rise) < step_s
    k = int(round(settling * config.loop_rate_hz))
    slope = abs(design[k] - design[k - 1]) / step_s
    settle_tol = 1.5 * step_s + 4 * step.response_se[k] / slope
    assert abs(step.settling_time_s - settling) < settle_tol
    np.testing.assert_allclose(step.response, design, atol=5e-3)
    # The documented figures.
    assert abs(step.overshoot - DOCUMENTED['overshoot']) < 4 * step.overshoot_se + 1e-3
    assert abs(step.rise_time_s - DOCUMENTED['rise_time_s']) < step_s
    assert abs(step.settling_time_s - DOCUMENTED['settling_time_s']) < settle_tol


def test_docs_quote_the_measured_figures(loop):
    _, _, _, measured = loop
    text = (ROOT / 'docs' / 'model.md').read_text()
    assert abs(measured.crossover_hz - DOCUMENTED['crossover_hz']) \
        < 4 * measured.crossover_se_hz + 0.1
    assert abs(measured.phase_margin_deg - DOCUMENTED['phase_margin_deg']) \
        < 4 * measured.phase_margin_se_deg + 0.01
    assert abs(measured.gain_margin_db - DOCUMENTED['gain_margin_db']) \
        < 4 * measured.gain_margin_se_db + 0.01
    assert abs(measured.bandwidth_hz - DOCUMENTED['bandwidth_hz']) \
        < 4 * measured.bandwidth_se_hz + 0.5
    assert f"{DOCUMENTED['phase_margin_deg']:.2f}°" in text
    assert f"{DOCUMENTED['overshoot'] * 100:.2f} %" in text
    assert 'bench/loop_response.py' in text


def test_a_doubled_controller_gain_is_measured():
    # The measurement follows the loop that runs: k(D(z)) doubled moves the crossover to
    # about 577 Hz and the phase margin to about 38 deg, as the linearized model predicts.
    config = TriadConfig()
    controller = QfaTriad(config, rng=0).axes[0].controller.with_gain(
        2 * QfaTriad(config, rng=0).axes[0].controller.gain)
    measured = measure_loop(config, rng=9, controller=controller, periods=4).margins()
    crossover, phase_margin, _, _ = LinearLoop(config.hardware, controller,
                                               config.loop_rate_hz).margins()
    assert abs(measured.phase_margin_deg - phase_margin) < 4 * measured.phase_margin_se_deg
    assert abs(measured.crossover_hz - crossover) < 4 * measured.crossover_se_hz + 0.1
    assert measured.phase_margin_deg < 45.0


def test_bad_measurement_settings_raise_value_error():
    config = TriadConfig()
    with pytest.raises(ValueError, match='band_hz'):
        measure_loop(config, band_hz=(10.0, 6000.0))
    with pytest.raises(ValueError, match='periods'):
        measure_loop(config, periods=1)
    with pytest.raises(ValueError, match='saturated'):
        measure_loop(config, amplitude=100 * 9.81, periods=2)
    with pytest.raises(ValueError, match='settle_band'):
        measure_step(config, settle_band=1.5)
