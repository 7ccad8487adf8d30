"""Monte Carlo accuracy of the paper's estimation schedule and the improved one.

Run: ``.venv/bin/python bench/estimation_accuracy.py [--draws 200] [--seed 0]``.
Each draw: a fresh sensor, references captured, then forward and feedback drifts
uniform in [-1000, +1000] ppm on all three axes at once, the room moved within
+-1.5 degC (the paper's error profile acts), optionally an unobservable k_t drift.
Prints a Markdown table (see ``qfa_ros.calibration.experiments.monte_carlo``).
"""

import argparse
import time

from qfa_ros.calibration.experiments import IMPROVED_SCHEDULE, monte_carlo, PAPER_SCHEDULE

COLUMNS = ('schedule', 'k_t drift', 'forward mean error ppm', 'forward p95 error ppm',
           'forward estimated %', 'feedback mean error ppm', 'feedback p95 error ppm',
           'feedback estimated %', 'output error restrained %', 'sensor time s')


def main():
    """Run the Monte Carlo for both schedules, with and without k_t drift."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--draws', type=int, default=200)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    print('| ' + ' | '.join(COLUMNS) + ' |')
    print('|' + '---|' * len(COLUMNS))
    start = time.perf_counter()
    for schedule in (PAPER_SCHEDULE, IMPROVED_SCHEDULE):
        for torquer_drift in (False, True):
            metrics = monte_carlo(schedule, draws=args.draws, seed=args.seed,
                                  torquer_drift=torquer_drift).metrics()
            cells = [f'{metrics[c]:.2f}' if isinstance(metrics[c], float) else metrics[c]
                     for c in COLUMNS]
            print('| ' + ' | '.join(cells) + ' |', flush=True)
    print(f'\n{args.draws} draws x 3 axes per row, seed {args.seed}; '
          f'wall {time.perf_counter() - start:.0f} s')


if __name__ == '__main__':
    main()
