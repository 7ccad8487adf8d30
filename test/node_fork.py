"""
Start node processes by fork from a warmed server instead of a fresh interpreter.

A node started as ``python -m qfa_ros.cli.node`` spends ~1.2-2 CPU-s before its first
sample, most of it the same in every start: the interpreter, rclpy and the node's
modules imported, numba's one-time set-up at the first kernel call. The suite starts
about forty nodes. :class:`ForkedProcess` forks each from a :mod:`multiprocessing` fork server
(one per test process) that did that work once when it started: importing this module
imports the node and calls a kernel, and nothing else (no rclpy context, no DDS
participant, no thread), so the fork is safe. The child then runs the node's own
``main`` with its own environment, arguments, working directory and log, as the
command line would: its own process, its own DDS participant, signals and exit status
as with ``subprocess``.

What is about the start itself (``ros2 run``, ``make run``, launch files, the other
distribution's venv, an environment of the test's own, ``--version``) starts the real
command: :class:`node_helpers.NodeProcess` forks only with its defaults, and only under
pytest (a bench measures the node as its users start it).
"""

import functools
import multiprocessing
from multiprocessing import forkserver
import os
from pathlib import Path
import signal
import subprocess
import sys
from unittest import mock

SERVER_ENV = 'QFA_TEST_NODE_FORK_SERVER'
"""Set for the fork server's start only: its import of this module does the warm-up."""


def warm_up():
    """Do what every node start would do, once, in the fork server."""
    try:
        from qfa_ros.cli import node as command  # noqa: F401 (inherited by the forks)
        from qfa_ros.ros import lifecycle_node, node  # noqa: F401 (inherited by the forks)
        from qfa_ros.ros.model_settings import make_triad
        from qfa_ros.ros.parameter_table import PARAMETERS
        make_triad({spec.name: spec.default for spec in PARAMETERS}).run(10)
    except Exception:  # noqa: BLE001 (a broken node fails in the child, with its message)
        pass


if os.environ.pop(SERVER_ENV, None):
    warm_up()

HERE = Path(__file__).resolve().parent


@functools.cache
def context():
    """Return the fork-server context, its server started with this module preloaded."""
    forkserver.set_forkserver_preload([__name__])
    # The server process imports this module by name and the node from this tree
    # (Python 3.11's fork server does not take the parent's sys.path).
    path = os.pathsep.join(filter(None, [str(HERE), str(HERE.parent),
                                         os.environ.get('PYTHONPATH')]))
    with mock.patch.dict(os.environ, {'PYTHONPATH': path, SERVER_ENV: '1'}):
        forkserver.ensure_running()
    return multiprocessing.get_context('forkserver')


def run_node(argv, env, cwd, log_path, managed):
    """Run the node's ``main`` with this environment, directory, log and arguments."""
    os.environ.clear()
    os.environ.update(env)
    os.chdir(cwd)
    descriptor = os.open(log_path, os.O_WRONLY | os.O_APPEND)
    os.dup2(descriptor, 1)
    os.dup2(descriptor, 2)
    os.close(descriptor)
    sys.stdout.reconfigure(line_buffering=True, write_through=True)
    sys.argv = list(argv)
    from qfa_ros.cli.node import main
    sys.exit(main(managed=managed))


class ForkedProcess:
    """A forked node seen through the part of :class:`subprocess.Popen` the tests use."""

    def __init__(self, argv, env, cwd, log_path, managed):
        self.args = argv
        self._process = context().Process(
            target=run_node, args=(argv, env, str(cwd), str(log_path), managed),
            name=Path(log_path).stem, daemon=True)
        self._process.start()
        self.pid = self._process.pid

    def poll(self):
        return self._process.exitcode

    def wait(self, timeout=None):
        self._process.join(timeout)
        if self._process.exitcode is None:
            raise subprocess.TimeoutExpired(self.args, timeout)
        return self._process.exitcode

    def send_signal(self, signum):
        if self._process.exitcode is None:
            try:
                os.kill(self.pid, signum)
            except ProcessLookupError:  # ended meanwhile
                pass

    def kill(self):
        self.send_signal(signal.SIGKILL)
