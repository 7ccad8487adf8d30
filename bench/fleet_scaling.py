"""Fleet study cost and scaling: 1 versus 2 local Dask workers, side by side.

Run: ``.venv/bin/python bench/fleet_scaling.py [--units 40] [--repeats 3]
[--study bench/studies/monthly_1y.yaml]``. Runs the study's first ``--units`` units
with one worker, then two, ``--repeats`` times interleaved, each into a fresh
directory; checks that the two tables are identical; prints the median wall times,
the speed-up, the CPU cost per unit and per simulated sensor-second, and what a
10 000-unit, 5-year monthly study costs in CPU hours by that measured cost.
"""

import argparse
from dataclasses import replace
from pathlib import Path
import statistics
import tempfile
import time

import numpy as np

from qfa_ros.fleet.runner import run_study
from qfa_ros.fleet.study import Study


def sensor_seconds(study, table):
    """Return the simulated sensor time of ``table``'s units [s]."""
    schedule = np.asarray(table.column('schedule_s')).sum()
    # Reference capture, start-up and the bias windows are not in schedule_s.
    units = study.units
    capture = study.schedule_settings()
    feedback = capture.reference_feedback
    forward = capture.forward
    capture_s = (len(forward.sequence()) * (forward.settle_s + forward.average_s)
                 + len(feedback.sequence()) * (feedback.settle_s + feedback.average_s))
    overhead = units * (0.2 + capture_s) + table.num_rows * (0.1 + 2 * 0.5)
    return schedule + overhead


def main():
    """Measure, interleaved, and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--study', default=str(Path(__file__).with_name('studies')
                                               / 'monthly_1y.yaml'))
    parser.add_argument('--units', type=int, default=40)
    parser.add_argument('--repeats', type=int, default=3)
    args = parser.parse_args()
    study = replace(Study.load(args.study), units=args.units, batch_units=2)
    walls = {1: [], 2: []}
    tables = {}
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(args.repeats):
            for workers in (1, 2):
                out = Path(scratch) / f'r{repeat}_w{workers}.parquet'
                start = time.perf_counter()
                tables[workers] = run_study(study, out, workers=workers, progress=False,
                                            log=lambda line: None)
                walls[workers].append(time.perf_counter() - start)
                print(f'repeat {repeat} workers {workers}: {walls[workers][-1]:.1f} s',
                      flush=True)
    identical = tables[1].equals(tables[2])
    one, two = statistics.median(walls[1]), statistics.median(walls[2])
    per_unit = one / study.units
    sensor = sensor_seconds(study, tables[1])
    cpu_per_sensor_s = one / sensor
    five_year = replace(study, horizon_years=5.0, units=10000)
    sensor_5y = sensor * (10000 / study.units) * (1 + five_year.calibrations) \
        / (1 + study.calibrations)
    print()
    print('| measure | value |')
    print('|---|---|')
    print(f'| units x calibrations | {study.units} x {study.calibrations} |')
    print(f'| wall, 1 worker (median of {args.repeats}) | {one:.1f} s |')
    print(f'| wall, 2 workers (median of {args.repeats}) | {two:.1f} s |')
    print(f'| speed-up 2 vs 1 | {one / two:.2f}x |')
    print(f'| tables identical | {identical} |')
    print(f'| CPU per unit (1 worker) | {per_unit:.2f} s |')
    print(f'| CPU per simulated sensor-second | {1e3 * cpu_per_sensor_s:.2f} ms |')
    print(f'| 2000 units x 1 year on 2 workers (extrapolated) | '
          f'{2000 * per_unit / (one / two) / 60:.0f} min |')
    print(f'| 10 000 units x 5 years monthly (extrapolated) | '
          f'{sensor_5y * cpu_per_sensor_s / 3600:.0f} CPU hours |')


if __name__ == '__main__':
    main()
