"""
``qfa-report recover PATH...``: make what a killed node left unfinished readable.

``PATH`` is a flight-recorder bag directory, a trace ``.mcap.part``, or a directory
holding them (``recorder.directory``, ``trace_dir``, ``output_dir``). Every ``.part`` is
finished in place into a standard MCAP file holding every complete chunk, and a bag's
``metadata.yaml`` is rewritten listing every file (:mod:`qfa_ros.bag.recovery`); what a
live node is recording into right now is left alone. Idempotent: a second run finds
nothing to recover. Needs only the node's packages (``make run``).
"""

import argparse
import sys

from qfa_ros.bag.recovery import recover

OK, FAILED, USAGE = 0, 1, 2


def main(argv=None):
    """Run ``qfa-report recover``; return the exit status (1 if anything is unreadable)."""
    parser = argparse.ArgumentParser(
        prog='qfa-report recover',
        description='Finish the recordings and traces a killed node left unfinished '
                    '(NAME.mcap.part, an out-of-date metadata.yaml), so that rosbags, the '
                    'mcap readers and Foxglove open them; what a running node records into '
                    'is left alone.')
    parser.add_argument('paths', nargs='+', metavar='PATH',
                        help='bag directory, trace .mcap.part, or a directory of them '
                             '(e.g. ~/.ros/qfa_ros)')
    args = parser.parse_args(argv)
    status = OK
    for path in args.paths:
        try:
            results = recover(path)
        except OSError as error:
            print(f'qfa-report recover: {path}: {error.strerror or error}', file=sys.stderr)
            status = FAILED
            continue
        said = [result for result in results if result.status != 'nothing to recover']
        for result in said:
            print(result.describe())
            if result.status == 'failed' or any(f.status == 'failed' for f in result.files):
                status = FAILED
        if not said:
            print(f'{path}: nothing to recover (complete bag directories: {len(results)})')
    return status
