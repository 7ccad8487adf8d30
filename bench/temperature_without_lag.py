"""
Run a temperature study with the probe-lag correction off (does the correction cost yield).

Runs the first ``--units`` units of a temperature study in this process (the function a
fleet worker runs, :func:`qfa_ros.fleet.unit.simulate_batch`) with
``qfa_ros.calibration.temperature.estimate_probe_lag`` forced to 0 (the fit before issue
28), writes them to ``--out`` and prints the fleet summary; compare with the study's own
results by ``bench/population_compare.py``::

    nice -n 10 python bench/temperature_without_lag.py STUDY.yaml --units 100 --out X.parquet
"""

import argparse
import time
from unittest import mock

import pyarrow as pa
import pyarrow.parquet as pq

from qfa_ros.calibration import temperature
from qfa_ros.fleet.study import Study
from qfa_ros.fleet.summary import format_summary
from qfa_ros.fleet.unit import simulate_batch


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('study')
    parser.add_argument('--units', type=int, default=100)
    parser.add_argument('--out', required=True)
    args = parser.parse_args()
    study = Study.load(args.study)
    started = time.process_time()
    rows = []
    with mock.patch.object(temperature, 'estimate_probe_lag', return_value=0.0):
        for index in range(min(args.units, study.units)):
            rows.extend(simulate_batch(study, index, index + 1))
            table = pa.Table.from_pylist(rows)
            pq.write_table(table, args.out)
    print(f'{study.name}, lag correction off, units 0..{len(rows) - 1}; CPU '
          f'{time.process_time() - started:.0f} s\n')
    print(format_summary(table))


if __name__ == '__main__':
    main()
