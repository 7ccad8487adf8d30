"""Suite-wide options: ``--busy-cores N`` keeps N cores busy for the whole session.

The header also names the ROS domain range of the node tests (``QFA_TEST_DOMAINS``,
default 1-100; ``node_helpers.domain_id``).

Every numba kernel is compiled into its cache once at the start of the session
(``kernel_warmup.py``, two processes beside the workers' collection); each test process
waits for that before its first test.

The suite runs on up to two pytest-xdist workers, one test file at a time each
(``pytest.ini``: ``-n auto --maxprocesses 2 --dist loadfile``; ``-n 0`` runs it in one
process), the longest files first (:data:`LONGEST_FIRST`); each worker gets its own share
of the domain range.

A shared CI machine is often busy. ``--busy-cores 1`` (or ``QFA_TEST_BUSY_CORES=1``)
starts one pure-Python busy loop per core in its own process before the first test and
kills it at the end of the session (the controller does, not each xdist worker), so that
the timing and DDS tests can be checked under that load on any machine; the busy cores
are not given xdist workers (:func:`pytest_xdist_auto_num_workers`).
"""

import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile

from kernel_warmup import PARTS, wait_for_warmup
import pytest

_BUSY_LOOPS = []
_WARMUP = []
WARMUP_ENV = 'QFA_TEST_WARMUP_DIR'
"""Where the kernel warm-up's done files go (set by the controller, read by the workers)."""
WARMUP_PIDS_ENV = 'QFA_TEST_WARMUP_PIDS'
"""The warm-up processes: a worker stops waiting for one that ended without its file."""


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
    # The numba kernels compiled once into their cache, while the workers collect.
    directory = tempfile.mkdtemp(prefix='qfa_kernel_warmup_')
    os.environ[WARMUP_ENV] = directory
    script = Path(__file__).with_name('kernel_warmup.py')
    for part in PARTS:
        _WARMUP.append(subprocess.Popen(
            [sys.executable, str(script), part, str(Path(directory) / f'{part}.done')],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    os.environ[WARMUP_PIDS_ENV] = ' '.join(str(process.pid) for process in _WARMUP)


def pytest_xdist_auto_num_workers(config):
    """Use the cores that ``--busy-cores`` leaves free (at least one; pytest.ini caps at 2).

    Two workers on two cores already give each timing test one busy core beside it, the
    load the suite is checked under; a busy loop on top would make it two.
    """
    return max(1, (os.cpu_count() or 1) - busy_cores(config))


LONGEST_FIRST = (
    'test_node_services.py', 'test_soak.py', 'test_node_lifecycle.py', 'test_managed_node.py',
    'test_node_fuzz.py', 'test_fleet.py', 'test_ins.py', 'test_node_progress.py',
    'test_crash_recording.py', 'test_node_gyro_bias.py', 'test_estimation_truth.py',
    'test_distributions.py', 'test_launch.py', 'test_bags.py', 'test_replay.py',
    'test_recorder.py', 'test_report.py',
    'test_node_stream.py', 'test_node_delivery.py', 'test_imu_yaml.py', 'test_node_ins.py',
    'test_node_security.py', 'test_trust_boundary.py', 'test_node_truth.py', 'test_retention.py',
    'test_temperature_calibration.py', 'test_loop_model.py', 'test_recovery.py',
    'test_tempfit.py', 'test_docs.py')
"""The files that take longest, longest first (bench/results/suite_time.md): started first,
so that no worker is left alone with one at the end (``--no-loadscope-reorder`` keeps this
order). A stale list costs time, never a test."""


def pytest_collection_modifyitems(session, config, items):
    rank = {name: index for index, name in enumerate(LONGEST_FIRST)}
    # A stable sort: the tests of one file stay in the order written.
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture(scope='session', autouse=True)
def compiled_kernels():
    """Wait for the kernel warm-up of the session (kernel_warmup.py) before the first test."""
    directory = os.environ.get(WARMUP_ENV)
    if directory:
        wait_for_warmup(directory, [int(pid) for pid in os.environ[WARMUP_PIDS_ENV].split()])


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
    while _WARMUP:
        process = _WARMUP.pop()
        process.kill()
        process.wait()
    if os.environ.get(WARMUP_ENV) and not hasattr(config, 'workerinput'):
        shutil.rmtree(os.environ.pop(WARMUP_ENV), ignore_errors=True)
        os.environ.pop(WARMUP_PIDS_ENV, None)
