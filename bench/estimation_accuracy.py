"""Seed 1's experiment as a distribution, and the Monte Carlo of the residual scale error.

Run: ``.venv/bin/python bench/estimation_accuracy.py [--trials 50] [--draws 100] [--seed 0]``.

Part 1: ``--trials`` seeds of seed 1 §IV-A (each a fresh sensor in the paper's room:
wander within 3 degC, warm-up; see ``qfa_ros.calibration.experiments.PaperRoom``): mean
and standard deviation of both estimates, the static errors and the restrained error
beside the paper's six trials.

Part 2: the residual scale-factor error after self-calibration [ppm], truth measured with
a known input (``measure_scale``), for the paper's and the improved schedule, drifts of
+-200 ppm (the paper), +-100 ppm (a year) and +-1000 ppm, with and without k_t drift,
thermal model on with room wander (``monte_carlo``). Prints Markdown tables.
"""

import argparse
import time

import numpy as np

from qfa_ros.calibration.experiments import (
    IMPROVED_SCHEDULE,
    monte_carlo,
    paper_experiment,
    PAPER_SCHEDULE,
    SCENARIOS,
)

PAPER = {'forward_estimate_ppm': (-180.53, 3.9), 'feedback_estimate_ppm': (218.15, None),
         'drifted_error_ug': (193.0, None), 'compensated_error_ug': (24.0, None),
         'restrained_percent': (87.56, None)}
COLUMNS = ('schedule', 'k_t drift', 'drift span ppm', 'error before mean ppm',
           'residual mean ppm', 'residual mean se ppm', 'residual p95 ppm', 'residual max ppm',
           'sensor time s')


def paper_distribution(trials, seed):
    """Print the paper experiment over ``trials`` seeds beside the paper."""
    results = paper_experiment(seed=seed, trials=trials, progress=True)
    values = {name: np.array([getattr(t, name) for t in results]) for name in (
        'forward_estimate_ppm', 'feedback_estimate_ppm', 'scale_error_after_ppm')}
    values['drifted_error_ug'] = np.array([abs(t.drifted_error_ug) for t in results])
    values['compensated_error_ug'] = np.array([abs(t.compensated_error_ug) for t in results])
    values['restrained_percent'] = 100 * (1 - values['compensated_error_ug']
                                          / values['drifted_error_ug'])
    print(f'| quantity ({trials} seeds) | mean | σ | σ of the mean | seed 1 (6 trials) |')
    print('|---|---|---|---|---|')
    for name, v in values.items():
        paper = PAPER.get(name)
        cell = '' if paper is None else f'{paper[0]}' + (
            f' (σ {paper[1]})' if paper[1] is not None else '')
        print(f'| {name} | {v.mean():.2f} | {v.std(ddof=1):.2f} | '
              f'{v.std(ddof=1) / np.sqrt(len(v)):.2f} | {cell} |')


def main():
    """Run both parts."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--trials', type=int, default=50)
    parser.add_argument('--draws', type=int, default=100)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    start = time.perf_counter()
    paper_distribution(args.trials, args.seed)
    print()
    print('| ' + ' | '.join(COLUMNS) + ' |')
    print('|' + '---|' * len(COLUMNS))
    for schedule in (PAPER_SCHEDULE, IMPROVED_SCHEDULE):
        for torquer_drift in (False, True):
            for span in SCENARIOS.values():
                metrics = monte_carlo(schedule, draws=args.draws, seed=args.seed,
                                      torquer_drift=torquer_drift, span_ppm=span,
                                      progress=True).metrics()
                cells = [f'{metrics[c]:.2f}' if isinstance(metrics[c], float) else metrics[c]
                         for c in COLUMNS]
                print('| ' + ' | '.join(cells) + ' |', flush=True)
    print(f'\n{args.draws} draws x 3 axes per row, seed {args.seed}; '
          f'wall {time.perf_counter() - start:.0f} s')


if __name__ == '__main__':
    main()
