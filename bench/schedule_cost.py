"""
CPU cost of the longest schedule call the parameter ranges allow (docs/security.md).

Runs the default sensor's temperature schedule and a fast self-calibration offline (the
generators the node drives), measures CPU time per second of sensor time and per model
loop step, and scales it to the worst cases of ``qfa_ros.ros.parameter_table``::

    python bench/schedule_cost.py            # about 15 s of CPU
    python bench/schedule_cost.py --short    # about 3 s: proves the script works
    python bench/schedule_cost.py --largest  # the largest calls the ranges allow, run

``--largest`` runs ``capture_reference`` and then ``calibrate_temperature`` at the largest
settings every parameter range allows (``bounds.LARGEST_*``, the values of
``test_trust_boundary.py::test_the_largest_schedules_the_ranges_allow_run``) on the default
sensor, and checks that each ends within its documented bound (``SCHEDULE_WORST_S``,
``CHAMBER_WORST_S``) and the loop-step budget; the suite runs the estimation call with the
same words but short averaging, this both calls at their largest (the chamber program 6.2e7
loop steps at the default limits, ~30 CPU-s). Its result:
``bench/results/schedule_cost.md``.
"""

import argparse
import sys
import time

from qfa_ros.calibration.estimation import capture_reference, self_calibrate
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.temperature import temperature_calibration, temperature_schedule
from qfa_ros.model.triad import QfaTriad
from qfa_ros.ros.bounds import (
    CHAMBER_WORST_S,
    FEEDBACK_WORST_S,
    FORWARD_WORST_S,
    LARGEST_CHAMBER,
    LARGEST_FEEDBACK,
    LARGEST_FORWARD,
    MAX_SCHEDULE_LOOP_STEPS,
    SCHEDULE_WORST_S,
)
from qfa_ros.ros.model_settings import (
    feedback_settings,
    forward_settings,
    input_profile,
    make_triad,
    temperature_settings,
    triad_config,
)
from qfa_ros.ros.parameter_table import PARAMETERS


def measure(make, values):
    """Run one schedule offline; return (CPU seconds, sensor seconds)."""
    triad = QfaTriad(triad_config(values), rng=values['seed'], profile=input_profile(values))
    state = CalibrationState()
    run_schedule(triad, capture_reference(triad, state, forward_settings(values),
                                          feedback_settings(values)))
    started_cpu, started_sensor = time.process_time(), triad.time
    run_schedule(triad, make(triad, state, values))
    return time.process_time() - started_cpu, triad.time - started_sensor


def largest():
    """Run the largest estimation and chamber calls the ranges allow; return the exit status."""
    values = {spec.name: spec.default for spec in PARAMETERS}
    values.update({'temperature_calibration.period_s': LARGEST_CHAMBER.period_s,
                   'temperature_calibration.cycles': LARGEST_CHAMBER.cycles})
    triad = make_triad(values, input_profile(values))
    state = CalibrationState()
    rows, problems = [], []
    for kind, make, bound_s in (
            ('capture_reference', lambda: capture_reference(triad, state, LARGEST_FORWARD,
                                                            LARGEST_FEEDBACK),
             FORWARD_WORST_S + FEEDBACK_WORST_S),
            ('calibrate_temperature', lambda: temperature_calibration(triad, state,
                                                                      LARGEST_CHAMBER),
             CHAMBER_WORST_S)):
        started_cpu, started_sensor = time.process_time(), triad.time
        run_schedule(triad, make(), chunk_samples=100_000)
        cpu_s, sensor_s = time.process_time() - started_cpu, triad.time - started_sensor
        steps = sensor_s * values['loop_rate_hz']
        rows.append((kind, sensor_s, bound_s, steps, cpu_s))
        # The chamber program's plateaus alone take period_s; the bound adds its soaks.
        floor_s = LARGEST_CHAMBER.period_s if kind == 'calibrate_temperature' else 0.0
        if not floor_s < sensor_s <= bound_s + 0.01 or steps > MAX_SCHEDULE_LOOP_STEPS:
            problems.append(f'{kind}: {sensor_s:.1f} s of sensor time, {steps:.3g} loop steps')
    print('| call at its largest settings | sensor time [s] | documented bound [s] | loop steps '
          '| CPU [s] |')
    print('|---|---:|---:|---:|---:|')
    for kind, sensor_s, bound_s, steps, cpu_s in rows:
        print(f'| {kind} | {sensor_s:.1f} | {bound_s:.0f} | {steps:.3g} | {cpu_s:.1f} |')
    print(f'loop-step budget {MAX_SCHEDULE_LOOP_STEPS:.3g}; '
          + ('every call within its bound' if not problems else '; '.join(problems)))
    return 1 if problems else 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--short', action='store_true', help='a 600 s chamber cycle only')
    parser.add_argument('--largest', action='store_true',
                        help='run the largest calls the ranges allow against their bounds')
    args = parser.parse_args()
    if args.largest:
        sys.exit(largest())
    values = {spec.name: spec.default for spec in PARAMETERS}
    values['temperature_calibration.period_s'] = 600.0 if args.short else 3600.0
    loop_rate = values['loop_rate_hz']
    rows = []
    for kind, make, worst_s in (
            ('self_calibrate', lambda t, s, v: self_calibrate(
                t, s, forward_settings(v), feedback_settings(v)), SCHEDULE_WORST_S),
            ('temperature', lambda t, s, v: temperature_schedule(
                t, s, temperature_settings(v)), CHAMBER_WORST_S)):
        cpu_s, sensor_s = measure(make, values)
        per_step_us = cpu_s / (sensor_s * loop_rate) * 1e6
        rows.append((kind, sensor_s, cpu_s, per_step_us, worst_s,
                     worst_s * cpu_s / sensor_s))
    print(f'loop_rate_hz {loop_rate:g}; budget {MAX_SCHEDULE_LOOP_STEPS:.3g} loop steps a call')
    print('| call | sensor time [s] | CPU [s] | CPU per loop step [us] | worst sensor time [s] '
          '| worst CPU [s] |')
    print('|---|---|---|---|---|---|')
    for kind, sensor_s, cpu_s, per_step_us, worst_s, worst_cpu_s in rows:
        print(f'| {kind} | {sensor_s:.1f} | {cpu_s:.2f} | {per_step_us:.3f} | {worst_s:.0f} '
              f'| {worst_cpu_s:.0f} |')
    worst_step_us = max(row[3] for row in rows)
    print(f'any call at the budget: <= {MAX_SCHEDULE_LOOP_STEPS * worst_step_us * 1e-6:.0f} s '
          'of CPU at the slower rate per loop step')


if __name__ == '__main__':
    main()
