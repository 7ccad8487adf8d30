"""Ran et al.'s experiment as a distribution, and the Monte Carlo of the residual scale error.

Run: ``.venv/bin/python bench/estimation_accuracy.py [--trials 50] [--draws 100] [--seed 0]``.

Part 1: ``--trials`` seeds of Ran et al. 2019, §IV-A (each a fresh sensor in the paper's room:
wander within 3 degC, warm-up; see ``qfa_ros.calibration.experiments.PaperRoom``): mean
and standard deviation of both estimates, the static errors and the restrained error
beside the paper's six trials.

Part 2: the residual scale-factor error after self-calibration [ppm], truth measured with
a known input (``measure_scale``), for the paper's and the improved schedule, drifts of
+-200 ppm (the paper), +-100 ppm (a year) and +-1000 ppm, with and without k_t drift,
thermal model on with room wander. Each row is a fleet study (``qfa_ros.fleet``) run
through the same path as ``qfa-fleet`` (Dask, every core, Parquet): ``--draws`` units,
one self-calibration a year after the reference capture, aging uniform within the span
(k_t: +-50 ppm and the magnet's temperature coefficient, or neither). Prints Markdown
tables; ``--keep DIR`` keeps the Parquet files (and resumes from them).
"""

import argparse
import logging
import os
from pathlib import Path
import tempfile
import time

import numpy as np

from qfa_ros.calibration.experiments import paper_experiment
from qfa_ros.fleet.runner import run_study
from qfa_ros.fleet.study import SPANS_PPM, Study
from qfa_ros.fleet.summary import residual_metrics

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
    print(f'| quantity ({trials} seeds) | mean | σ | σ of the mean | Ran et al. 2019 (6 trials) |')
    print('|---|---|---|---|---|')
    for name, v in values.items():
        paper = PAPER.get(name)
        cell = '' if paper is None else f'{paper[0]}' + (
            f' (σ {paper[1]})' if paper[1] is not None else '')
        print(f'| {name} | {v.mean():.2f} | {v.std(ddof=1):.2f} | '
              f'{v.std(ddof=1) / np.sqrt(len(v)):.2f} | {cell} |')


def residual_table(draws, seed, keep, workers):
    """Print the residual after self-calibration for every schedule, k_t case and span."""
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=workers or os.cpu_count(), threads_per_worker=1,
                      dashboard_address=':0', silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        _residual_rows(draws, seed, keep, client)


def _residual_rows(draws, seed, keep, client):
    print('| ' + ' | '.join(COLUMNS) + ' |')
    print('|' + '---|' * len(COLUMNS))
    for schedule in ('paper', 'improved'):
        for torquer_drift in (False, True):
            for span in SPANS_PPM.values():
                study = Study.one_calibration(schedule, span, torquer_drift, draws, seed)
                table = run_study(study, Path(keep) / f'{study.name}.parquet',
                                  client=client, log=lambda line: None)
                metrics = {'schedule': schedule, 'k_t drift': 'yes' if torquer_drift else 'no',
                           'drift span ppm': span, **residual_metrics(table)}
                cells = [f'{metrics[c]:.2f}' if isinstance(metrics[c], float) else metrics[c]
                         for c in COLUMNS]
                print('| ' + ' | '.join(cells) + ' |', flush=True)


def main():
    """Run both parts."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--trials', type=int, default=50)
    parser.add_argument('--draws', type=int, default=100)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--workers', type=int, default=None,
                        help='Dask workers (default: every core)')
    parser.add_argument('--keep', metavar='DIR', default=None,
                        help="keep the studies' Parquet files here (and resume from them)")
    args = parser.parse_args()
    start = time.perf_counter()
    paper_distribution(args.trials, args.seed)
    print()
    if args.keep:
        residual_table(args.draws, args.seed, args.keep, args.workers)
    else:
        with tempfile.TemporaryDirectory() as keep:
            residual_table(args.draws, args.seed, keep, args.workers)
    print(f'\n{args.draws} units x 3 axes per row, seed {args.seed}; '
          f'wall {time.perf_counter() - start:.0f} s')


if __name__ == '__main__':
    main()
