"""
Test that estimators see no truth, and the claims of docs/calibration.md.

The I_ref coefficient, the paper distribution and the residual scale error (issue 13).
Reduced sizes; tolerances from the quantities' own standard errors.
"""

import ast
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.testing import assert_allclose
import pytest

from qfa_ros.calibration.chamber import ChamberBench, idle
from qfa_ros.calibration.estimation import capture_reference, feedback_schedule, FeedbackSettings
from qfa_ros.calibration.experiments import (
    ErrorProfile,
    measure_scale,
    paper_experiment,
)
from qfa_ros.calibration.reference_tc import reference_tc_schedule
from qfa_ros.calibration.schedule import run_schedule, SensorPort, SensorSamples
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.temperature import temperature_calibration, TemperatureSettings
from qfa_ros.model.drawn_unit import draw_unit
from qfa_ros.model.noise import NoiseConfig
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig

ROOT = Path(__file__).resolve().parents[1]
# Every estimator that reads the sensor: estimation.py the gain schedules, reference_tc.py
# the I_ref coefficient against gravity and the I_ref steps at the temperature plateaus,
# gyro_bias.py the gyro bias at rest.
ESTIMATORS = tuple(ROOT / 'qfa_ros' / 'calibration' / name
                   for name in ('estimation.py', 'reference_tc.py', 'gyro_bias.py'))
# Names through which a model truth could be read: the true input and body temperature,
# the drift and thermal state, the noise configuration, the error profile, the model.
FORBIDDEN = {'truth', 'temperature', 'drift', 'thermal', 'noise', 'config', 'gains',
             'axes', 'profile', '_triad', 'scale', 'sample_index'}
FORBIDDEN_NAMES = {'_triad', 'ErrorProfile', 'NoiseConfig', 'ThermalConfig', 'QfaTriad',
                   'triad'}
# qfa_ros.model.constants holds constants only (PPM, MICRO_G, ...; test_units keeps it so);
# qfa_ros.model.checks only the checks of a caller's numbers (no model state).
ALLOWED_IMPORTS = {'dataclasses', 'math', 'numpy', 'qfa_ros.calibration.schedule',
                   'qfa_ros.calibration.estimation', 'qfa_ros.model.triad',
                   'qfa_ros.model.earth', 'qfa_ros.model.constants', 'qfa_ros.model.checks'}


def truth_reads(path):
    """Return the forbidden attribute reads, names and imports of an estimator module."""
    tree = ast.parse(Path(path).read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr in FORBIDDEN:
            found.append(f'line {node.lineno}: .{node.attr}')
        elif isinstance(node, ast.Name) and node.id in FORBIDDEN_NAMES:
            found.append(f'line {node.lineno}: {node.id}')
        elif isinstance(node, ast.ImportFrom) and node.module not in ALLOWED_IMPORTS:
            found.append(f'line {node.lineno}: from {node.module}')
        elif isinstance(node, ast.ImportFrom) and node.module == 'qfa_ros.model.triad' \
                and {a.name for a in node.names} - {'AXES', 'FLAG_ADC_CLIPPED'}:
            found.append(f'line {node.lineno}: from qfa_ros.model.triad beyond constants')
        elif isinstance(node, ast.Import):
            found += [f'line {node.lineno}: import {a.name}' for a in node.names
                      if a.name not in ALLOWED_IMPORTS]
    return found


@pytest.mark.parametrize('path', ESTIMATORS, ids=lambda p: p.name)
def test_estimation_sees_no_truth(path):
    # Static audit: the estimators touch the sensor through SensorPort only.
    assert truth_reads(path) == []


@pytest.mark.parametrize('path, honest, violation', [
    # The deliberate violation of the issue: the old co-regression read the true body
    # temperature and the profile's coefficient.
    (ESTIMATORS[0], 'reading = float(np.mean(readings))',
     'reading = port._triad.temperature  # violation'),
    # The I_ref steps at the temperature plateaus, likewise.
    (ESTIMATORS[1], "'reading_c': float(np.mean(readings))",
     "'reading_c': port._triad.temperature,  # violation"),
], ids=['feedback', 'plateau_step'])
def test_audit_catches_an_estimator_reading_the_truth(tmp_path, path, honest, violation):
    source = path.read_text().replace(honest, violation, 1)
    assert 'violation' in source
    scratch = tmp_path / 'estimation.py'
    scratch.write_text(source)
    assert any('_triad' in hit for hit in truth_reads(scratch))
    assert any('.temperature' in hit for hit in truth_reads(scratch))


def test_port_hands_the_estimator_no_truth():
    triad = QfaTriad(TriadConfig(), rng=0)
    port = SensorPort(triad)
    samples = port.view(triad.run(5))
    assert isinstance(samples, SensorSamples)
    for name in ('truth', 'temperature', 'drift', 'thermal', 'config', 'axes'):
        assert not hasattr(samples, name) and not hasattr(port, name), name
    with pytest.raises(AttributeError):
        port.extra = 1   # __slots__: nothing can be smuggled in


def test_reference_tc_schedule_measures_the_coefficient_against_gravity():
    # c = a_Iref + a_kt - e (I_ref +30, magnet +10, k_VI -5 ppm/degC, lumped scale
    # factor e = 80 / 100 / 60 ppm/degC); k_VI cancels. Noise off but ADC dither.
    config = TriadConfig(thermal=ThermalConfig(ambient_profile='room'),
                         noise=NoiseConfig(noise_density=0.0, bias_instability=0.0))
    triad = QfaTriad(config, rng=1)
    for axis in range(3):
        for name, tc in (('i_ref', 30.0), ('b', 10.0), ('k_vi', -5.0)):
            triad.drift.set_temperature_coefficient(axis, name, tc)
    state = CalibrationState()
    result = run_schedule(triad, reference_tc_schedule(triad, ChamberBench(triad), state))
    assert_allclose(result.estimate_ppm, [-40.0, -60.0, -20.0], atol=0.2)
    assert_allclose(state.reference_tc_ppm, result.estimate_ppm)
    restored = CalibrationState.from_dict(state.to_dict())
    assert restored.reference_tc_ppm == state.reference_tc_ppm
    legacy = state.to_dict()
    del legacy['reference_tc_ppm']
    assert CalibrationState.from_dict(legacy).reference_tc_ppm == []


def test_temperature_calibration_measures_the_iref_coefficient_it_corrects_with():
    # Reduced like test_temperature_calibration (2 kHz loop, 100 Hz output, body 60 s,
    # a 720 s chamber program): the paper profile on drawn unit 11, with the unit's own
    # I_ref coefficients (drawn around +30 ppm/degC; the estimator does not read them).
    # The step in counts, -I_ref / (k_VI k_DA), moves with the I_ref source only (not
    # with the magnet, the forward chain nor the unit's scale-factor curve).
    unit = draw_unit(11)
    unit = replace(unit, probe_tau_s=unit.probe_tau_s * 60.0 / 300.0)
    config = TriadConfig(thermal=ThermalConfig(ambient_profile='constant', sensor_tau_s=60.0),
                         loop_rate_hz=2000.0, sample_rate_hz=100.0, crossover_hz=100.0)
    triad = unit.triad(config, rng=11)
    unit.install_error_profile(triad, ErrorProfile())
    truth = np.asarray(unit.i_ref_tc_ppm_per_c)
    assert np.ptp(truth) > 5.0     # three different unknowns, not the type figure
    state = CalibrationState()
    switching = FeedbackSettings(cycles=4, settle_s=0.3, average_s=0.3, order='chopped')
    run_schedule(triad, capture_reference(triad, state, feedback=switching))
    settings = TemperatureSettings(period_s=720.0, block_s=2.0, bins=40, reference_steps=True)
    chamber, steps = run_schedule(triad, temperature_calibration(triad, state, settings))
    assert chamber.applied and steps.kind == 'reference_tc' and steps.applied
    assert len(steps.points['temperature_c']) == len(settings.plateaus(25.0))
    assert np.ptp(steps.points['temperature_c']) > 80.0    # on-board readings, -40..70
    # Within 3 standard errors plus 0.15 ppm/degC: the on-board reading lags the body
    # while a plateau still settles, which the residual scatter does not show.
    assert np.all(steps.std_error_ppm < 0.2)
    assert np.all(np.abs(steps.estimate_ppm - truth) <= 3 * steps.std_error_ppm + 0.15), \
        (steps.estimate_ppm, steps.std_error_ppm)
    assert state.reference_tc_ppm == steps.estimate_ppm.tolist()
    # 10 degC above the reference, no drift applied: uncorrected, the feedback schedule
    # takes I_ref's -10 c0 ppm for a drift; corrected, it sees none.
    triad.thermal.set_ambient(ambient_profile='constant', ambient_c=35.0)
    idle(triad, 360.0)   # six body time constants
    triad.run_for(0.5)
    plain, corrected = (run_schedule(triad, feedback_schedule(
        triad, state, replace(switching, temperature_correction=on), apply=False))
        for on in (False, True))
    assert np.all(np.abs(plain.estimate_ppm + 10.0 * truth) < 30.0), plain.estimate_ppm
    assert np.all(np.abs(corrected.estimate_ppm) <= 3 * corrected.std_error_ppm + 1.0), \
        (corrected.estimate_ppm, corrected.std_error_ppm)


def test_measure_scale_sees_an_injected_feedback_drift():
    triad = QfaTriad(TriadConfig(), rng=2)
    before = measure_scale(triad)
    for axis in range(3):
        triad.drift.set_step(axis, 'k_vi', 100e-6)
    after = measure_scale(triad)
    # N = K0 a / (k_t k_VI k_DA): k_VI +100 ppm shrinks the output scale by 100 ppm.
    assert_allclose((after / before - 1) * 1e6, (1 / 1.0001 - 1) * 1e6, atol=0.3)


def test_improved_schedule_meets_the_acceptance_on_paper_size_drifts():
    # docs/calibration.md: improved schedule, no oracle, +-200 ppm, thermal on with room
    # wander, k_t stable: residual <= 5 ppm mean, <= 10 ppm p95. 3 draws x 3 axes here;
    # the population (30 x 3: mean 3.08 ppm, per-axis sigma 1.6 ppm, p95 5.8 ppm) is
    # bench/estimation_accuracy.py's (bench/results/estimation_accuracy.md). With 9 axes
    # the mean's standard error is ~0.53 ppm: a drawn mean + 2 se past 6 ppm is 3.5 sigma
    # from the population's (a false failure ~2e-4; 4 draws: 4 sigma, 3e-5), while a
    # +3 ppm bias fails with probability 0.985 (as with 4 draws) and the paper schedule's
    # 52 ppm always. Seed 11: 2.65 ppm, se 0.51 ppm, p95 4.5 ppm.
    # The same fleet study path as bench/estimation_accuracy.py and qfa-fleet.
    # The fleet layer needs pyarrow, which the library floor (.venv-jazzy) has not.
    pa = pytest.importorskip('pyarrow', reason='the fleet studies need pyarrow (numpy 2): '
                             'not on the library floor')
    from qfa_ros.fleet.self_calibration_unit import simulate_batch
    from qfa_ros.fleet.study import Study
    from qfa_ros.fleet.summary import residual_metrics
    study = Study.one_calibration('improved', 200.0, torquer_drift=False, units=3, seed=11)
    rows = simulate_batch(study, 0, study.units)
    metrics = residual_metrics(pa.Table.from_pylist(rows))
    assert metrics['residual mean ppm'] + 2 * metrics['residual mean se ppm'] <= 6.0
    assert metrics['residual p95 ppm'] <= 12.0
    assert metrics['error before mean ppm'] > 40.0   # there was an error to remove
    assert np.std([row['body_c'] for row in rows]) > 0.2  # the room did move


def test_paper_experiment_is_a_distribution_near_the_paper():
    # docs/calibration.md: 50 seeds. Here 10: mean forward estimate within 3 standard errors of the
    # paper's -180.5 ppm; its scatter from the physics, within a factor 2 (plus the
    # sampling error of a 10-sample sigma) of the paper's 3.9 ppm; feedback near +218.
    trials = paper_experiment(seed=0, trials=10, static_s=2.0)
    forward = np.array([t.forward_estimate_ppm for t in trials])
    feedback = np.array([t.feedback_estimate_ppm for t in trials])
    se = forward.std(ddof=1) / np.sqrt(len(forward))
    assert abs(forward.mean() + 180.5) < 3 * se + 2.0
    assert 3.9 / 2 / 1.5 < forward.std(ddof=1) < 3.9 * 2 * 1.5
    assert abs(feedback.mean() - 218.15) < 3 * feedback.std(ddof=1) / np.sqrt(10) + 5.0


def test_paper_experiment_without_error_sources_is_nearly_exact():
    trials = paper_experiment(seed=0, trials=2, profile=ErrorProfile.ideal(), static_s=2.0)
    for t in trials:
        assert abs(t.forward_estimate_ppm + 200.0) < 0.2
        # The two 10 s segments see white noise and flicker: within 4 standard errors.
        assert abs(t.feedback_estimate_ppm - 200.0) < 4 * t.feedback_std_error_ppm
        assert abs(t.scale_error_after_ppm) < 4 * t.feedback_std_error_ppm
