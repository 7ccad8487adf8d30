"""Time the test suite as CI runs it: wall per test file and in total, and its collection.

Run: ``.venv/bin/python bench/suite_time.py --rev HEAD --label after`` (prints Markdown).

Each ``--rev`` is exported with ``git archive`` into a fresh temporary tree (no
``__pycache__``, so every numba kernel compiles as on a fresh CI checkout) and its suite
runs there with ``nice -n 10 python -m pytest -p no:cacheprovider --durations=60
--junitxml=...`` (``PYTHONPATH`` the exported tree). Per file: the sum of its tests'
setup, call and teardown (pytest's JUnit ``time``; with xdist workers these overlap); the
suite's CPU time is that of every process the run waited for; the collection is the wall time of
``pytest --collect-only -q`` in the same tree. The load average before and after is
printed: the machine is shared, so compare runs made under a similar load.
"""

import argparse
import collections
import os
from pathlib import Path
import resource
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree

REPO = Path(__file__).resolve().parents[1]


def export(rev, directory):
    """Write the tree of ``rev`` into ``directory`` (no untracked files, no caches)."""
    archive = subprocess.run(['git', '-C', str(REPO), 'archive', rev], check=True,
                             capture_output=True).stdout
    subprocess.run(['tar', '-x', '-C', str(directory)], input=archive, check=True)


def load():
    return ' '.join(Path('/proc/loadavg').read_text().split()[:3])


def run_suite(tree, extra, junit, log):
    """Run the suite in ``tree``; return (wall s, CPU s of every process waited for, status)."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    command = ['nice', '-n', '10', sys.executable, '-m', 'pytest', '-p', 'no:cacheprovider',
               '--durations=60', f'--junitxml={junit}', *extra]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.monotonic()
    with open(log, 'w') as stream:
        status = subprocess.run(command, cwd=tree, env=env, stdout=stream,
                                stderr=subprocess.STDOUT).returncode
    wall = time.monotonic() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, status


def collection_time(tree):
    env = dict(os.environ, PYTHONPATH=str(tree))
    started = time.monotonic()
    subprocess.run(['nice', '-n', '10', sys.executable, '-m', 'pytest', '-p',
                    'no:cacheprovider', '--collect-only', '-q'], cwd=tree, env=env,
                   check=True, stdout=subprocess.DEVNULL)
    return time.monotonic() - started


def per_file(junit):
    """Return ``{test file: seconds}`` and the test counts from a JUnit XML report."""
    seconds = collections.Counter()
    outcomes = collections.Counter()
    for case in ElementTree.parse(junit).getroot().iter('testcase'):
        name = case.get('classname', '').split('.')[-1] + '.py'
        seconds[name] += float(case.get('time', 0.0))
        kinds = {child.tag for child in case}
        outcomes['failed' if kinds & {'failure', 'error'} else
                 'skipped' if 'skipped' in kinds else 'passed'] += 1
    return seconds, outcomes


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--rev', default='HEAD', help='git revision to time')
    parser.add_argument('--label', default=None)
    parser.add_argument('--keep', type=Path, default=None,
                        help='directory for the pytest log and JUnit report')
    parser.add_argument('pytest_args', nargs='*',
                        help='more pytest arguments (after --), e.g. -- -n 0')
    args = parser.parse_args()
    label = args.label or args.rev
    keep = args.keep or Path(tempfile.mkdtemp(prefix='suite_time_'))
    keep.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix='suite_tree_') as tree:
        tree = Path(tree)
        export(args.rev, tree)
        load_before = load()
        collect = collection_time(tree)
        junit = keep / f'{label}.xml'
        wall, cpu, status = run_suite(tree, args.pytest_args, junit, keep / f'{label}.log')
        load_after = load()
    seconds, outcomes = per_file(junit)
    print(f'## {label} ({args.rev}, {time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())})\n')
    print(f'load average before {load_before}, after {load_after}; exit status {status}; '
          f'{dict(outcomes)}; log {keep / (label + ".log")}\n')
    print('| file | s |\n|---|---|')
    for name, value in seconds.most_common():
        print(f'| {name} | {value:.1f} |')
    print(f'| sum of tests | {sum(seconds.values()):.1f} |')
    print(f'| collection (`--collect-only`, separate run) | {collect:.1f} |')
    print(f'| **suite wall** | **{wall:.1f}** |')
    print(f'| suite CPU (user + sys of the processes waited for) | {cpu:.1f} |')


if __name__ == '__main__':
    main()
