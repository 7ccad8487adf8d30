"""
Measure the I_ref temperature coefficient the temperature calibration finds, and its use.

Run from the repository root::

    .venv/bin/python bench/reference_tc.py > bench/results/reference_tc.md

Per unit: the node's default sensor (``qfa_ros.ros.parameter_table`` defaults with ``seed`` =
the unit: drawn unit, ``sensor.error_profile: paper`` with the unit's own I_ref
coefficient, drawn around +30 ppm/degC, 10 kHz
loop, the default ``temperature_calibration.*``) captures its references, runs the
temperature calibration with the I_ref steps at every plateau (what
``~/calibrate_temperature`` runs), then soaks 10 degC above the reference (constant
ambient, six body time constants) and runs the feedback schedule (chopped, 16 cycles,
not applied) without and with the temperature correction. No drift is applied, so the
right feedback estimate is zero. ``--short``: the reduced scenario of
``test_temperature_calibration_measures_the_iref_coefficient_it_corrects_with`` (2 kHz
loop, 100 Hz, body 60 s, a 720 s chamber program), to prove the script works quickly.
"""

import argparse
import dataclasses
from pathlib import Path
import sys
import time

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from qfa_ros.calibration.chamber import idle  # noqa: E402
from qfa_ros.calibration.estimation import (  # noqa: E402
    capture_reference,
    feedback_schedule,
    FeedbackSettings,
)
from qfa_ros.calibration.schedule import run_schedule  # noqa: E402
from qfa_ros.calibration.state import CalibrationState  # noqa: E402
from qfa_ros.calibration.temperature import (  # noqa: E402
    temperature_calibration,
    TemperatureSettings,
)
from qfa_ros.model.drawn_unit import draw_unit  # noqa: E402
from qfa_ros.model.error_profiles import ErrorProfile  # noqa: E402
from qfa_ros.model.thermal import ThermalConfig  # noqa: E402
from qfa_ros.model.triad_config import TriadConfig  # noqa: E402
from qfa_ros.ros.model_settings import make_triad, temperature_settings
from qfa_ros.ros.parameter_table import PARAMETERS


def short_unit(seed):
    """Return the reduced sensor of the test, its settings and switching."""
    unit = draw_unit(seed)
    unit = dataclasses.replace(unit, probe_tau_s=unit.probe_tau_s * 60.0 / 300.0)
    config = TriadConfig(thermal=ThermalConfig(ambient_profile='constant', sensor_tau_s=60.0),
                         loop_rate_hz=2000.0, sample_rate_hz=100.0, crossover_hz=100.0)
    triad = unit.triad(config, rng=seed)
    unit.install_error_profile(triad, ErrorProfile())
    return (triad, TemperatureSettings(period_s=720.0, block_s=2.0, bins=40,
                                       reference_steps=True),
            FeedbackSettings(cycles=4, settle_s=0.3, average_s=0.3, order='chopped'), 60.0)


def node_unit(seed):
    """Return the node's default sensor of ``seed``, its settings and switching."""
    values = {spec.name: spec.default for spec in PARAMETERS}
    values['seed'] = seed
    triad = make_triad(values)
    return (triad, temperature_settings(values),
            FeedbackSettings(cycles=16, settle_s=0.02, average_s=0.28, order='chopped'),
            values['thermal.sensor_tau_s'])


def run_unit(seed, short):
    """Return the coefficient, its SE and the feedback estimates of unit ``seed``."""
    triad, settings, switching, tau = (short_unit if short else node_unit)(seed)
    state = CalibrationState()
    run_schedule(triad, capture_reference(triad, state, feedback=switching))
    reference_c = float(triad.thermal.sensor_c)
    _, steps = run_schedule(triad, temperature_calibration(triad, state, settings))
    triad.thermal.set_ambient(ambient_profile='constant', ambient_c=reference_c + 10.0)
    idle(triad, 6 * tau)
    triad.run_for(0.5)
    estimates = []
    for on in (False, True):
        result = run_schedule(triad, feedback_schedule(
            triad, state, dataclasses.replace(switching, temperature_correction=on),
            apply=False))
        estimates.append((result.estimate_ppm, result.std_error_ppm))
    truth = draw_unit(seed).i_ref_tc_ppm_per_c
    return steps.estimate_ppm, steps.std_error_ppm, estimates, truth


def main(argv=None):
    """Print the Markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--units', type=int, default=3, help='units (seeds 11, 12, ...)')
    parser.add_argument('--short', action='store_true', help='the reduced test scenario')
    args = parser.parse_args(argv)
    started = time.perf_counter()
    rows = []
    for seed in tqdm(range(11, 11 + args.units), desc='units', disable=None,
                     file=sys.stderr):
        rows.append((seed, *run_unit(seed, args.short)))
    scenario = 'reduced (the test)' if args.short else "the node's default sensor"
    print(f'# I_ref temperature coefficient from the temperature calibration ({scenario})\n')
    print(f'Command: `python bench/reference_tc.py{" --short" if args.short else ""} '
          f"--units {args.units}`; each unit's own I_ref coefficient c0 (drawn: "
          'qfa_ros.model.drawn_unit, the estimator does not read it); feedback estimates 10 degC '
          'above the reference, no drift applied (right answer 0).\n')
    print('| unit | axis | true c0 [ppm/degC] | measured c [ppm/degC] | (c - c0) / SE | '
          'feedback, uncorrected [ppm] | feedback, corrected [ppm] |')
    print('|---|---|---|---|---|---|---|')
    deviations = []
    for seed, tc, se, ((plain, plain_se), (corr, corr_se)), truth in rows:
        for axis, name in enumerate('xyz'):
            deviations.append((tc[axis] - truth[axis]) / se[axis])
            print(f'| {seed} | {name} | {truth[axis]:+.3f} | '
                  f'{tc[axis]:+.3f} ± {se[axis]:.3f} | {deviations[-1]:+.2f} | '
                  f'{plain[axis]:+.1f} ± {plain_se[axis]:.1f} | '
                  f'{corr[axis]:+.1f} ± {corr_se[axis]:.1f} |')
    corrected = np.array([c for *_, (_, (c, _)), _ in rows]).ravel()
    print(f'\nrms of (c - c0) / SE: {np.sqrt(np.mean(np.square(deviations))):.2f}; corrected '
          f'feedback estimates: mean {corrected.mean():+.2f} ppm, rms '
          f'{np.sqrt(np.mean(corrected ** 2)):.2f} ppm; {time.perf_counter() - started:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
