"""
What finding its own ROS libraries costs ``qfa_node`` at start (qfa_ros.cli.own_libraries).

Run: ``.venv/bin/python bench/foreign_start.py [--repeat 15] [--other .venv-jazzy]``.

* The check every start pays: :func:`own_environment` on this process's environment
  (its own, nothing to change), median of many calls, and the import of the module.
* The re-execution a start from another environment pays: the wall time of ``qfa_node
  --version`` (which exits right after the imports the check precedes) started from its
  own environment and from the other venv's (its library path and bootstrap guard, as a
  launcher of that venv hands them down), alternating, medians side by side.

Prints a Markdown table, with the load average beside it.
"""

import argparse
import json
import os
from pathlib import Path
import statistics
import subprocess
import sys
import time

from qfa_ros.cli.own_libraries import own_environment, own_library_directories

ROOT = Path(__file__).resolve().parents[1]


def check_us(repeat=2000):
    """Return the median time of the check on this (own) environment [us]."""
    own = own_library_directories()
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        assert own_environment(os.environ, own) is None
        times.append(time.perf_counter() - started)
    return statistics.median(times) * 1e6


def import_ms():
    """Return the wall time of ``import qfa_ros.cli.own_libraries`` in a fresh process [ms]."""
    code = ('import time; t = time.perf_counter(); import qfa_ros.cli.own_libraries; '
            'print(time.perf_counter() - t)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout
    return float(out) * 1e3


def other_environment(other_python):
    """Return the environment a process of the other venv hands down (after its bootstrap)."""
    code = 'import os, json; print(json.dumps(dict(os.environ)))'
    clean = {k: v for k, v in os.environ.items()
             if k not in ('LD_LIBRARY_PATH', '_ROS_WHEELS_BOOTSTRAP_COMPLETE',
                          'NUMBA_CACHE_DIR')}
    return json.loads(subprocess.run([str(other_python), '-c', code], env=clean,
                                     capture_output=True, text=True, check=True).stdout)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeat', type=int, default=15)
    parser.add_argument('--other', default=str(ROOT / '.venv-jazzy'),
                        help='the other ROS-wheels venv (default .venv-jazzy)')
    args = parser.parse_args(argv)
    program = str(Path(sys.prefix) / 'bin' / 'qfa_node')
    foreign = other_environment(Path(args.other) / 'bin' / 'python')
    own = dict(os.environ)
    times = {'own environment': [], 'from the other venv (re-executed)': []}
    for _ in range(args.repeat):
        for case, env in zip(times, (own, foreign)):
            started = time.perf_counter()
            result = subprocess.run([program, '--version'], env=env, capture_output=True,
                                    text=True, check=True)
            times[case].append(time.perf_counter() - started)
            assert result.stdout.startswith('qfa_node '), result.stdout
    load = os.getloadavg()
    print(f'load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; {args.repeat} runs each, '
          f'alternating; {sys.prefix}')
    print()
    print('| what | median | min |')
    print('|---|---|---|')
    print(f'| the check, own environment (in process) | {check_us():.1f} us | |')
    imports = [import_ms() for _ in range(5)]
    print(f'| import of qfa_ros.cli.own_libraries (fresh process) | '
          f'{statistics.median(imports):.1f} ms | {min(imports):.1f} ms |')
    for case, values in times.items():
        print(f'| `qfa_node --version`, {case} | {statistics.median(values) * 1e3:.0f} ms | '
              f'{min(values) * 1e3:.0f} ms |')
    difference = (statistics.median(times['from the other venv (re-executed)'])
                  - statistics.median(times['own environment']))
    print(f'| re-execution (difference of the medians) | {difference * 1e3:.0f} ms | |')


if __name__ == '__main__':
    main()
