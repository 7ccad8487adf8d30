"""
Unit 218566 on the node's sensor: temperature calibration, eight attitudes (issue 28).

The node's default sensor (``qfa_ros.ros.parameter_table`` defaults: drawn unit, paper error
profile, 10 kHz loop) with ``unit.seed: 218566``, ``sample_rate_hz: 200`` and
``thermal.sensor_tau_s: 8`` (the body follows the chamber within seconds, as the node was
tried), a constant ambient; ``calibrate_temperature``'s schedule (the default
``temperature_calibration.*``), then the compensated errors in eight attitudes at -27, 8,
41 and 64 degC (off the 10 degC grid; :func:`qfa_ros.calibration.verification.verify_attitudes`).
Twice: the calibration as it is (the reading's lag behind the proof mass estimated and
removed) and with the lag correction off (``estimate_probe_lag`` forced to 0, the fit
before issue 28)::

    nice -n 10 python bench/unit_218566.py > bench/results/unit_218566.md
"""

import contextlib
import time
from unittest import mock

import numpy as np

from qfa_ros.calibration import temperature
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.verification import verify_attitudes
from qfa_ros.model.unit import draw_unit
from qfa_ros.model.units import MICRO_G
from qfa_ros.ros.model_settings import make_triad, temperature_settings
from qfa_ros.ros.parameter_table import PARAMETERS

SEED = 218566


def run(correct_lag):
    """Calibrate and verify the unit; return (result, verification, CPU seconds)."""
    values = {spec.name: spec.default for spec in PARAMETERS}
    values.update({'unit.seed': SEED, 'sample_rate_hz': 200.0, 'thermal.sensor_tau_s': 8.0,
                   'thermal.ambient_profile': 'constant'})
    triad = make_triad(values)
    started = time.process_time()
    patch = contextlib.nullcontext() if correct_lag else \
        mock.patch.object(temperature, 'estimate_probe_lag', return_value=0.0)
    with patch:
        result = run_schedule(triad, temperature.temperature_calibration(
            triad, CalibrationState(), temperature_settings(values)))[0]
    verification = verify_attitudes(triad, soak_s=80.0)
    return result, verification, time.process_time() - started


def main():
    print('# Unit 218566: temperature calibration verified in eight attitudes (issue 28)\n')
    print('Command: `nice -n 10 python bench/unit_218566.py`. Node defaults, `unit.seed: '
          '218566`, `sample_rate_hz: 200`, `thermal.sensor_tau_s: 8`, constant ambient; '
          f'true probe lag {draw_unit(SEED).probe_tau_s:.2f} s. Zero-drift p2p over -27, 8, '
          "41, 64 degC per attitude [ug] x/y/z; scale factor of each axis's +-g pair, "
          'largest |error| and p2p over the temperatures [ppm]. Limits 30 ug, 20 ppm.\n')
    for correct in (False, True):
        result, verification, cpu = run(correct)
        label = 'lag correction on (this version)' if correct else \
            'lag correction off (the fit before issue 28)'
        print(f'## {label}: estimated lag {result.probe_lag_s:.2f} s, CPU {cpu:.0f} s\n')
        print('| attitude | zero drift p2p x / y / z [ug] |')
        print('|---|---|')
        for name, p2p in zip(verification.names, verification.zero_drift_p2p / MICRO_G):
            print(f'| {name} | ' + ' / '.join(f'{v:.1f}' for v in p2p) + ' |')
        worst = np.max(verification.zero_drift_p2p, axis=0) / MICRO_G
        print(f'\nworst zero drift x/y/z {worst[0]:.1f} / {worst[1]:.1f} / {worst[2]:.1f} ug; '
              'scale factor max |error| x/y/z ' + ' / '.join(
                  f'{v:.1f}' for v in verification.scale_max * 1e6) + ' ppm, p2p ' + ' / '.join(
                  f'{v:.1f}' for v in verification.scale_p2p * 1e6) + ' ppm\n')


if __name__ == '__main__':
    main()
