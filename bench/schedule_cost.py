"""
CPU cost of the longest schedule call the parameter ranges allow (docs/security.md).

Runs the default sensor's temperature schedule and a fast self-calibration offline (the
generators the node drives), measures CPU time per second of sensor time and per model
loop step, and scales it to the worst cases of ``qfa_ros.ros.parameter_table``::

    python bench/schedule_cost.py            # about 15 s of CPU
    python bench/schedule_cost.py --short    # about 3 s: proves the script works
"""

import argparse
import time

from qfa_ros.calibration.estimation import capture_reference, self_calibrate
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.temperature import temperature_schedule
from qfa_ros.model.triad import QfaTriad
from qfa_ros.ros.bounds import CHAMBER_WORST_S, MAX_SCHEDULE_LOOP_STEPS, SCHEDULE_WORST_S
from qfa_ros.ros.model_settings import (
    feedback_settings,
    forward_settings,
    input_profile,
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--short', action='store_true', help='a 600 s chamber cycle only')
    args = parser.parse_args()
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
