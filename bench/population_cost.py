"""
CPU cost per unit of the two population studies of issue 28, and the time 200 units take.

Runs a few units of each study in this process (the functions a fleet worker runs:
:func:`qfa_ros.fleet.unit.simulate_batch`) and reports the process time per unit and the
projection for the study's size on one worker::

    nice -n 10 python bench/population_cost.py --units 2
"""

import argparse
from pathlib import Path
import time

import numpy as np

from qfa_ros.fleet.study import Study
from qfa_ros.fleet.unit import simulate_batch

STUDIES = Path(__file__).resolve().parent / 'studies'


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--units', type=int, default=2, help='units measured per study')
    parser.add_argument('studies', nargs='*', default=['temperature_200.yaml',
                                                       'self_calibration_200.yaml'])
    args = parser.parse_args()
    print('| study | units measured | CPU per unit [s] (each) | projected CPU for the '
          'study [min] |')
    print('|---|---|---|---|')
    for name in args.studies:
        study = Study.load(STUDIES / name)
        each = []
        for index in range(args.units):
            started = time.process_time()
            simulate_batch(study, index, index + 1)
            each.append(time.process_time() - started)
        mean = float(np.mean(each))
        cells = ', '.join(f'{v:.1f}' for v in each)
        print(f'| {name} | {args.units} | {mean:.1f} ({cells}) | '
              f'{mean * study.units / 60:.0f} ({study.units} units) |', flush=True)


if __name__ == '__main__':
    main()
