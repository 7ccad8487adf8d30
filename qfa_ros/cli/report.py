"""
``qfa-report BAG... [--out DIR]``: draw PNG figures from traces and scenario bags.

``qfa-report imu-yaml CONFIG|BAG``: write an ``imu.yaml`` (:mod:`qfa_ros.cli.imu_yaml`).
``qfa-report recover PATH...``: finish what a killed node left (:mod:`qfa_ros.cli.recover`).
Both need only the node's packages (``make run``).
"""

import argparse
from pathlib import Path
import sys

from qfa_ros.cli.extras import needs_tools
from qfa_ros.cli.interrupt import stops_quietly


@stops_quietly('qfa-report')
@needs_tools('qfa-report')
def main(argv=None):
    """Run the report command line; return the exit status."""
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] == ['imu-yaml']:
        from qfa_ros.cli.imu_yaml import main as imu_yaml
        return imu_yaml(args[1:])
    if args[:1] == ['recover']:
        from qfa_ros.cli.recover import main as recover
        return recover(args[1:])
    parser = argparse.ArgumentParser(
        prog='qfa-report',
        description='Plot qfa_ros estimation traces and qfa-sim scenario bags as PNG figures '
                    '(forward/feedback gain, static output, temperature compensation).',
        epilog='Also: `qfa-report imu-yaml CONFIG|BAG` (noise figures for VIO/INS) and '
               '`qfa-report recover PATH...` (finish the recordings and traces a killed '
               'node left unfinished).')
    parser.add_argument('bags', nargs='+', metavar='BAG',
                        help='trace .mcap files, scenario bags, or directories of them; '
                             'files given together are combined')
    parser.add_argument('--out', metavar='DIR',
                        help='output directory (default: <first BAG name>_report)')
    args = parser.parse_args(args)
    missing = [bag for bag in args.bags if not Path(bag).exists()]
    if missing:
        print(f'qfa-report: no such file: {", ".join(missing)}', file=sys.stderr)
        return 1
    out_dir = Path(args.out or f'{Path(args.bags[0]).stem}_report')
    # Imported here: matplotlib is one of the tools `make run` does not install.
    from qfa_ros.report.figures import report

    try:
        written = report(args.bags, out_dir)
    except (OSError, ValueError) as error:
        print(f'qfa-report: {error}', file=sys.stderr)
        return 1
    if not written:
        print('qfa-report: nothing to plot (no trace tables, IMU stream or temperature '
              'points found)', file=sys.stderr)
        return 1
    for path in written:
        print(path)
    return 0


if __name__ == '__main__':
    sys.exit(main())
