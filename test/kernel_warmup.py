"""
Compile every numba kernel into its on-disk cache once, before the tests need them.

``python test/kernel_warmup.py PART DONE_FILE`` runs one part and then writes its exit
status to ``DONE_FILE``. The suite's controller (``conftest.py``) starts both parts side
by side at the start of the session; each test process waits for them before its first
test (:func:`wait_for_warmup`), so that on a fresh checkout the kernels are compiled
once, not by each pytest-xdist worker and each node or ``qfa-sim`` subprocess that
happened to start before another had written the cache (the trajectory kernels alone
take ~14 CPU-s). ``make setup``, and so ``make test``, runs the ``trajectory`` part once
after installing, so that a fresh clone's first session finds them compiled. Nothing here
is a test: a failed warm-up only means the tests compile the kernels themselves, and fail
there if a kernel is broken.

Parts, about equal in compile time, together the 22 host-CPU signatures the suite
compiles (listed from the cache index after a full run):

- ``trajectory``: a trajectory's sample means (the ``trajectory_means`` kernels, ~12 s);
- ``static``: static runs of the accelerometers with their Allan summary and of the full
  IMU (loop, gyros, thermal), and the CORDIC (~6 s).
"""

import os
from pathlib import Path
import sys
import time

PARTS = ('trajectory', 'static')


def run(part):
    """Run the workload of ``part``, which calls each of its kernels once."""
    if part == 'trajectory':
        import numpy as np

        from qfa_ros.model import motion_scripts
        drive = motion_scripts.vehicle_drive()
        drive.sample_means(0.0, 1e-3, 2000)
        drive.sample_means(100.0, 1e-2, 100)
        drive.kinematics(np.array([0.0, 1.0]))
        return 0
    import numpy as np

    from qfa_ros.calibration.cordic import CordicExp
    from qfa_ros.cli.sim import main
    status = main(['static', '--duration', '1'])
    status |= main(['trajectory', '--motion', 'static', '--duration', '60', '--rate', '100'])
    CordicExp(m_bits=16, n_bits=8).exp_parts_array(np.arange(5))
    return status


def done_files(directory):
    """Return the done file of each part in ``directory``."""
    return [Path(directory) / f'{part}.done' for part in PARTS]


def running(pid):
    """Return whether process ``pid`` is running (not gone, not a zombie)."""
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != 'Z'


def wait_for_warmup(directory, pids, timeout_s=300.0):
    """
    Wait until each part has written its done file or ended without one (it crashed).

    Give up after ``timeout_s``; return whether every part wrote its done file.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        done = [path.exists() for path in done_files(directory)]
        if all(done) or not any(running(pid) for pid in pids):
            return all(path.exists() for path in done_files(directory))
        time.sleep(0.1)
    return False


if __name__ == '__main__':
    name, done = sys.argv[1], Path(sys.argv[2])
    status = 1
    try:
        with open(os.devnull, 'w') as quiet:
            sys.stdout = quiet  # the summaries are not wanted
            status = run(name)
    finally:
        sys.stdout = sys.__stdout__
        temporary = done.with_suffix('.tmp')
        temporary.write_text(f'{status}\n')
        temporary.rename(done)
