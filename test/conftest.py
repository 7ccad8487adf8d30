"""Suite-wide options: ``--busy-cores N`` keeps N cores busy for the whole session.

The header also names the ROS domain range of the node tests (``QFA_TEST_DOMAINS``,
default 1-100; ``node_helpers.domain_id``).

The suite runs on up to two pytest-xdist workers, one test file at a time each
(``pytest.ini``: ``-n auto --maxprocesses 2 --dist loadfile``; ``-n 0`` runs it in one
process); each worker gets its own share of the domain range.

A shared CI machine is often busy. ``--busy-cores 1`` (or ``QFA_TEST_BUSY_CORES=1``)
starts one pure-Python busy loop per core in its own process before the first test and
kills it at the end of the session (the controller does, not each xdist worker), so that
the timing and DDS tests can be checked under that load on any machine.
"""

import os
import subprocess
import sys

import pytest

_BUSY_LOOPS = []


def pytest_addoption(parser):
    parser.addoption(
        '--busy-cores', type=int, default=None, metavar='N',
        help='keep N cores busy with busy-loop processes during the session '
             '(default: $QFA_TEST_BUSY_CORES or 0)')


def busy_cores(config):
    """Return the number of busy loops asked for by option or environment."""
    value = config.getoption('busy_cores')
    if value is None:
        value = int(os.environ.get('QFA_TEST_BUSY_CORES', '0') or 0)
    if value < 0:
        raise ValueError(f'--busy-cores must be >= 0, not {value}')
    return value


def pytest_configure(config):
    text = os.environ.get('QFA_TEST_DOMAINS', '1-100')
    try:
        low, high = (int(part) for part in text.split('-'))
    except ValueError:
        low, high = 1, 0
    if not 0 <= low <= high <= 232:
        raise pytest.UsageError(f'QFA_TEST_DOMAINS must be LOW-HIGH with 0 <= LOW <= HIGH '
                                f'<= 232 (ROS domain ids), not {text!r}')
    if hasattr(config, 'workerinput'):
        return  # a pytest-xdist worker: the controller keeps the cores busy for the run
    for _ in range(busy_cores(config)):
        _BUSY_LOOPS.append(subprocess.Popen(
            [sys.executable, '-c', 'while True: pass'],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))


def pytest_report_header(config):
    # The node tests' domains (node_helpers.domain_id): two runs on one host need two ranges.
    lines = [f'ROS domains: {os.environ.get("QFA_TEST_DOMAINS", "1-100")} '
             '(QFA_TEST_DOMAINS=LOW-HIGH; give each concurrent test run its own range)']
    if _BUSY_LOOPS:
        pids = ', '.join(str(p.pid) for p in _BUSY_LOOPS)
        lines.append(f'busy cores: {len(_BUSY_LOOPS)} (busy-loop processes {pids})')
    return lines


def pytest_unconfigure(config):
    while _BUSY_LOOPS:
        process = _BUSY_LOOPS.pop()
        process.kill()
        process.wait()
