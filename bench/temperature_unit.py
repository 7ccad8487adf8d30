"""
Re-run one unit of a temperature study, optionally with schedule overrides (failure analysis).

Prints the unit's row (worst zero drift and scale factor per axis, the probe lag) and per
axis the bias fit's cancellation bits
(:class:`qfa_ros.calibration.thermal_compensation.TemperatureCalibration`:
how many bits the fixed-point compensator loses to cancelling terms)::

    nice -n 10 python bench/temperature_unit.py bench/studies/temperature_reduced_200.yaml 42
    nice -n 10 python bench/temperature_unit.py bench/studies/temperature_reduced_200.yaml 42 \
        --set m_bits=24
"""

import argparse
from dataclasses import replace
from unittest import mock

from qfa_ros.calibration import temperature
from qfa_ros.fleet import temperature_unit
from qfa_ros.fleet.study import Study
from qfa_ros.model.triad import AXES


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('study')
    parser.add_argument('unit', type=int)
    parser.add_argument('--set', action='append', default=[], metavar='FIELD=VALUE',
                        help='TemperatureSettings override (integer values)')
    args = parser.parse_args()
    study = Study.load(args.study)
    overrides = {k: int(v) for k, v in (item.split('=', 1) for item in args.set)}
    study = replace(study, temperature={**study.temperature, **overrides})
    results = []
    calibrate = temperature.temperature_calibration

    def keep(*a, **k):
        out = yield from calibrate(*a, **k)
        results.append(out[0])
        return out

    with mock.patch.object(temperature_unit, 'temperature_calibration', keep):
        row, = temperature_unit.simulate_temperature_unit(study, args.unit)
    bits = [c.cancellation_bits for c in results[0].compensation.bias]
    print(f'study {study.name}, unit {args.unit} (unit.seed {row["unit_seed"]}), overrides '
          f'{overrides or "none"}; probe lag true {row["probe_tau_s"]:.2f} s, estimated '
          f'{row["probe_lag_s"]:.2f} s')
    for axis, b in zip(AXES, bits):
        print(f'{axis}: worst zero drift {row[f"zd_max_ug_{axis}"]:.1f} ug, scale factor p2p '
              f'{row[f"sf_p2p_ppm_{axis}"]:.1f} / max {row[f"sf_max_ppm_{axis}"]:.1f} ppm; bias '
              f'fit cancellation {b:.1f} bits')


if __name__ == '__main__':
    main()
