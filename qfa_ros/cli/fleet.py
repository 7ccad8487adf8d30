"""``qfa-fleet STUDY.yaml``: run a fleet study on Dask and summarize it."""

import argparse
from multiprocessing import resource_tracker
from pathlib import Path
import signal
import sys

from qfa_ros.cli.extras import needs_tools
from qfa_ros.cli.interrupt import INTERRUPTED_STATUS, stops_quietly


def build_parser():
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='qfa-fleet',
        description='Monte Carlo over units, schedules and years: units drawn per seed, '
                    'aged and self-calibrated, scored against the truth (Dask, Parquet).')
    parser.add_argument('study', help='study file (YAML; see qfa_ros.fleet.study)')
    parser.add_argument('--out', metavar='FILE.parquet',
                        help='results (default: STUDY.parquet beside the study file); '
                             'finished batches are kept in FILE.parquet.parts to resume')
    where = parser.add_mutually_exclusive_group()
    where.add_argument('--workers', type=int, metavar='N',
                       help='worker processes of the local cluster (default: every core)')
    where.add_argument('--scheduler', metavar='tcp://HOST:PORT',
                       help='run on an existing Dask cluster instead')
    parser.add_argument('--figures', metavar='DIR', help='also write PNG figures to DIR')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    return parser


@stops_quietly('qfa-fleet')
@needs_tools('qfa-fleet')
def main(argv=None):
    """Run the fleet command line; return the exit status (130: stopped by Ctrl-C)."""
    args = build_parser().parse_args(argv)
    # Ctrl-C must reach this thread: the threads the imports and Dask start from here on
    # inherit a blocked SIGINT; run_study unblocks it here once its workers are up
    # (fleet.runner.workers_shielded_from_sigint), the finally at the latest. The
    # resource tracker of multiprocessing unblocks SIGINT in the thread that first
    # starts it (and so in every thread that one starts): it is started here, before.
    resource_tracker.ensure_running()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        return run(args)
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def run(args):
    """Run the study of the parsed ``args``; return the exit status."""
    # Imported here (model, numba, Dask: seconds) so that even an early Ctrl-C is one line.
    from qfa_ros.fleet.runner import parts_directory, run_study
    from qfa_ros.fleet.study import Study, StudyError
    from qfa_ros.fleet.summary import draw_figures, format_summary

    if args.workers is not None and args.workers < 1:
        print('qfa-fleet: --workers must be at least 1', file=sys.stderr)
        return 2
    try:
        study = Study.load(args.study)
    except StudyError as error:
        print(f'qfa-fleet: {args.study}: {error}', file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path(args.study).with_suffix('.parquet')
    try:
        table = run_study(study, out, workers=args.workers, scheduler=args.scheduler,
                          progress=not args.no_progress and sys.stderr.isatty())
    except StudyError as error:
        print(f'qfa-fleet: {error}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        parts = parts_directory(out)
        kept = len(list(parts.glob('batch-*.parquet')))
        print(f'qfa-fleet: interrupted; {kept} of {len(study.batches)} batches kept in '
              f'{parts}: the same command resumes', file=sys.stderr, flush=True)
        return INTERRUPTED_STATUS
    except OSError as error:
        print(f'qfa-fleet: {error}', file=sys.stderr)
        return 1
    print(format_summary(table))
    if args.figures:
        for path in draw_figures(table, Path(args.figures), study.name):
            print(path)
    return 0


if __name__ == '__main__':
    sys.exit(main())
