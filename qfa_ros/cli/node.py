"""
``qfa_node`` (``ros2 run qfa_ros qfa_node``): run the emulated IMU until SIGINT/SIGTERM.

``qfa_lifecycle_node`` runs its managed variant (REP-2004 lifecycle; ``ros2 lifecycle set
/qfa_node configure`` ...), which a stop signal takes through its ``shutdown`` transition.

SIGINT and SIGTERM stop the process within a few seconds in every case
(:func:`shut_down`): the node's own writes (calibration state, flight recording) finish
first; a middleware teardown that hangs is then abandoned with :data:`EXIT_HARD` and a
log line saying so. Start-up failures (DDS Security asked for but unavailable, bad
arguments or parameters) end in one line through the ROS logger and a non-zero status.
"""

import faulthandler
import gc
import os
import re
import signal
import socket
import sys
import threading
import warnings

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.logging import get_logger
from rclpy.signals import SignalHandlerOptions

from qfa_ros import VERSION
from qfa_ros.ros.distro import ros_distribution
from qfa_ros.ros.fastdds import use_shipped_fastdds_profile

NODE_NAME = 'qfa_node'
EXIT_MIDDLEWARE = 1
"""Exit status when the middleware cannot start (DDS Security, arguments, ...)."""
EXIT_PARAMETERS = 2
"""Exit status of an invalid start configuration."""

SWITCH_INTERVAL_S = 0.00005
"""Python's GIL switch interval while the node runs [s]. A thread waiting for the GIL waits
this long before it asks the holder to drop it, and a busy thread that drops the GIL
briefly (numba kernels, ctypes) mostly takes it back first; so this is about how long a
batch holds the pacer up (the default 5 ms would hold it that long; see docs/node.md)."""

SECURITY_HINT = ('DDS Security (SROS2) needs a ROS 2 installation whose Fast DDS was built '
                 'with security; the Kilted pip wheels are not')


def require_security(environ=None):
    """
    Make ``ROS_SECURITY_ENABLE=true`` mean secured or not at all; call before ``rclpy.init``.

    With security asked for, the ``Permissive`` strategy would start the node without
    any security when the enclave is missing; the strategy is forced to ``Enforce``, so
    that the node either runs secured or fails to start (then :func:`startup_failure`
    says why in one line). rcl enables security only for exactly ``true``: another
    spelling of yes (``True``, ``1``) would start the node open, so it is refused.

    Returns
    -------
    tuple
        ``(secured, problem)``: whether security is asked for, and why the node must not
        start (or None).
    """
    environ = os.environ if environ is None else environ
    value = environ.get('ROS_SECURITY_ENABLE', '')
    if value.strip().lower() in ('true', '1', 'yes', 'on') and value != 'true':
        return True, (f'ROS_SECURITY_ENABLE={value!r}: rcl enables DDS Security only for '
                      f'exactly true and would start this node unsecured')
    if value != 'true':
        return False, None
    environ['ROS_SECURITY_STRATEGY'] = 'Enforce'
    return True, None


def one_line(error):
    """Return an rcl error message as one line, without the C source locations."""
    text = re.sub(r',? at /\S+:\d+', '', str(error))
    return ' '.join(text.split())


def startup_failure(stage, error, secured):
    """
    Report a start-up failure as one line (stderr via the ROS logger); return the status.

    Parameters
    ----------
    stage : str
        What failed, e.g. ``'rclpy.init'``.
    error : BaseException or str
        The exception, or a message.
    secured : bool
        Whether DDS Security was asked for (``ROS_SECURITY_ENABLE``).
    """
    reason = one_line(error)
    if isinstance(error, ValueError):
        status = EXIT_PARAMETERS
        line = f'invalid parameters: {reason}'
    elif secured:
        status = EXIT_MIDDLEWARE
        detail = ('error not set' in reason and 'check ROS_SECURITY_KEYSTORE and the '
                  'enclave; ') or ''
        line = (f'cannot start with DDS Security asked for (ROS_SECURITY_ENABLE): {stage} '
                f'failed ({reason}); {detail}{SECURITY_HINT}; the node never runs unsecured '
                f'when security is asked for (ROS_SECURITY_STRATEGY Permissive is treated as '
                f'Enforce)')
    else:
        status = EXIT_MIDDLEWARE
        line = f'cannot start: {stage} failed: {reason}'
    try:
        # The ROS logger writes to stderr and, once rcl logging is up, to the log file.
        get_logger(NODE_NAME).fatal(line)
    except Exception:
        print(f'{NODE_NAME}: {line}', file=sys.stderr)
    return status


class ProcessTuning:
    """
    The interpreter settings of a process that runs one node; its sensor thread applies them.

    Both are process-wide, so the entry point asks for them (:func:`create_node`) and a
    node created inside another program (a test, a launch composition) does without.
    """

    def warmed(self):
        """
        Freeze the start-up objects out of the garbage collector (before the grid starts).

        rclpy, numba and the model leave ~1.4e5 long-lived objects: a full collection walks
        them all holding the GIL (~90 ms, every sample of it late), and one comes whenever
        enough new objects survive (the recorder's). Frozen, they are left out of every
        collection; the process runs one node, so they live as long as it. Only the young
        generations are collected first: a full collection would walk them all too, before
        the first sample, and find no more garbage.
        """
        gc.collect(1)
        gc.freeze()

    def streaming(self):
        """Shorten the GIL switch interval to :data:`SWITCH_INTERVAL_S` (first batch done)."""
        sys.setswitchinterval(SWITCH_INTERVAL_S)

    def released(self):
        """
        Reclaim a unit the managed node removed (``cleanup``), frozen objects and all.

        The frozen objects go back to the collector and a full collection runs at once:
        the removed unit's collaborators reference each other, and :meth:`warmed` collects
        only the young generations before it freezes again, so without it every removed
        unit stayed, frozen, for good (``bench/results/lifecycle_cycles.md``).
        Nothing is published meanwhile; it takes about as long as the collection
        :meth:`warmed` avoids (~0.1 s).
        """
        gc.unfreeze()
        gc.collect()


def create_node(secured, managed=False):
    """Create the node; return ``(node, None)`` or ``(None, status)`` after a one-line report."""
    # Imported only now: the model takes seconds to load, a middleware refusal does not.
    if managed:
        from qfa_ros.ros.lifecycle_node import QfaLifecycleNode as NodeClass
    else:
        from qfa_ros.ros.node import QfaNode as NodeClass
    try:
        with warnings.catch_warnings():
            # rclpy warns about the half-made rosout publisher of a node that failed.
            warnings.simplefilter('ignore', RuntimeWarning)
            return NodeClass(NODE_NAME, process_tuning=ProcessTuning()), None
    except (rclpy_implementation.RCLError, ValueError) as error:
        return None, startup_failure('creating the node', error, secured)

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

CLOSE_TIMEOUT_S = 2.0
"""How long the node may take to stop its sensor thread before the writes go ahead anyway."""

MIDDLEWARE_TIMEOUT_S = 2.0
"""How long the middleware teardown may take before the process exits without it."""

SPIN_EXIT_TIMEOUT_S = 2.0
"""How long the spin loop may take to notice a stop signal (a callback hung in DDS)."""

SPIN_TIMEOUT_S = 1.0
"""Longest wait of the spin loop when nothing happens [s]: a stop signal wakes it at once
(a guard condition), and each wake-up of an idle executor costs about 1.4 ms of CPU."""

EXIT_HARD = 3
"""Exit status when the process had to exit without the middleware teardown."""


def version_line():
    """Return what ``qfa_node --version`` prints: the release and the ROS 2 distribution."""
    return f'{NODE_NAME} {VERSION} (qfa_ros; ROS 2 {ros_distribution() or "unknown"})'


def main(args=None, managed=False):
    """
    Run the node until SIGINT or SIGTERM; exit with the status (2: invalid parameters).

    ``--version`` (before any ``--ros-args``) prints :func:`version_line` and exits.

    Parameters
    ----------
    managed : bool
        Run the managed (lifecycle) node, which starts unconfigured.
    """
    own_args = list(sys.argv if args is None else args)
    if '--ros-args' in own_args:
        own_args = own_args[:own_args.index('--ros-args')]
    if '--version' in own_args:
        print(version_line())
        return 0
    use_shipped_fastdds_profile()
    secured, problem = require_security()
    if problem:
        return startup_failure('checking the environment', problem, secured)
    try:
        # Every start-up error of the middleware (RCLError: arguments, parameters file, DDS
        # Security, ...) ends here or in create_node, never in a traceback. Our own
        # handlers (StopSignals) only set a flag: a signal never interrupts a write.
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except rclpy_implementation.RCLError as error:
        return startup_failure('rclpy.init', error, secured)
    # After rclpy.init: the stop signals are ours from here on.
    signals = StopSignals()
    node, status = create_node(secured, managed)
    if node is None:
        rclpy.try_shutdown()
        return status
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    signals.watch(node)
    try:
        while not signals.stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
    except ExternalShutdownException:
        pass
    signals.stopping.set()
    if managed:
        node.finalize()
    status = shut_down(node, executor)
    # Skip the interpreter's finalization: nothing is left to write, and under `ros2
    # launch` with two units it was seen to hang after a complete teardown (until the
    # launcher's SIGTERM). Standard streams are flushed first.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


def lifecycle_main(args=None):
    """``qfa_lifecycle_node``: run the managed node (unconfigured until told) as :func:`main`."""
    return main(args, managed=True)


class StopSignals:
    """
    See SIGINT and SIGTERM from a thread of their own and make sure the process ends.

    Any thread may receive a signal (numpy's and Fast DDS's threads too); Python's C-level
    handler writes its number to a wakeup socket (``signal.set_wakeup_fd``), which this
    class's thread reads, so it learns of the signal even while the main thread is stuck
    in a middleware call. The first signal sets :attr:`stop`, which ends the spin loop;
    the Python-level handlers do nothing else, so a signal never interrupts a state-file
    or recorder write half way. If the main thread has not started :func:`shut_down`
    within :data:`SPIN_EXIT_TIMEOUT_S` (a callback hung in the middleware), this thread
    closes the node itself (state, recording) and exits with :data:`EXIT_HARD`.
    """

    def __init__(self):
        self.stop = threading.Event()
        self.stopping = threading.Event()
        self._node = None
        self._wake = None
        self._reader, self._writer = socket.socketpair()
        self._writer.setblocking(False)
        for signum in STOP_SIGNALS:
            signal.signal(signum, lambda signum, frame: self.stop.set())
        signal.set_wakeup_fd(self._writer.fileno(), warn_on_full_buffer=False)
        threading.Thread(target=self._wait, name='qfa_signals', daemon=True).start()

    def watch(self, node):
        """Close ``node`` if the main thread cannot; wake its executor on a stop signal."""
        self._wake = node.create_guard_condition(lambda: None)
        self._node = node
        if self.stop.is_set():
            self._wake.trigger()

    def _wait(self):
        while True:
            data = self._reader.recv(1)
            if not data or data[0] in STOP_SIGNALS:
                break
        self.stop.set()
        if self._wake is not None:
            self._wake.trigger()
        # The last resort, in C: fires even if a hung call holds the interpreter lock.
        faulthandler.dump_traceback_later(
            SPIN_EXIT_TIMEOUT_S + CLOSE_TIMEOUT_S + MIDDLEWARE_TIMEOUT_S + 2.0, exit=True)
        if self.stopping.wait(SPIN_EXIT_TIMEOUT_S) or self._node is None:
            return
        print('[qfa_node] stop signal: the executor is stuck; closing the node from the '
              'signal thread and exiting hard', file=sys.stderr, flush=True)
        self._node.close(timeout_s=CLOSE_TIMEOUT_S)
        os._exit(EXIT_HARD)


def shut_down(node, executor, close_timeout_s=CLOSE_TIMEOUT_S,
              middleware_timeout_s=MIDDLEWARE_TIMEOUT_S):
    """
    Stop ``node`` within a few seconds whatever the middleware does; return the exit status.

    First the node's own work ends: its sensor thread stops (at most ``close_timeout_s``),
    the calibration state is saved and the flight recording finished. Only then is the
    middleware torn down (executor, node, context). Should that hang (a deadlocked DDS
    thread holding a lock that ``rcl_publisher_fini`` needs), the process says so and
    exits with :data:`EXIT_HARD` after ``middleware_timeout_s``: nothing is left to write.
    A C-level watchdog (``faulthandler``, exit status 1, every thread's stack on stderr)
    backs the Python one in case the hung call holds the interpreter lock.

    Parameters
    ----------
    node : QfaNode
        The :class:`QfaNode`.
    executor : rclpy.executors.Executor
        The executor spinning it.

    Returns
    -------
    int
        0 (a hung teardown ends the process instead of returning).
    """
    node.close(timeout_s=close_timeout_s)
    node.get_logger().info('calibration state and recording closed; stopping the middleware')
    teardown_done = threading.Event()

    def exit_hard():
        if not teardown_done.wait(middleware_timeout_s):
            # Not the ROS logger: it may be what hangs.
            print(f'[qfa_node] middleware shutdown hung for {middleware_timeout_s:g} s; '
                  'calibration state and recording were closed before; exiting hard',
                  file=sys.stderr, flush=True)
            os._exit(EXIT_HARD)

    threading.Thread(target=exit_hard, name='qfa_exit_watchdog', daemon=True).start()
    faulthandler.dump_traceback_later(middleware_timeout_s + 1.0, exit=True)
    try:
        executor.shutdown(timeout_sec=middleware_timeout_s)
        node.destroy_node()
        rclpy.try_shutdown()
    finally:
        teardown_done.set()
        faulthandler.cancel_dump_traceback_later()
    return 0


if __name__ == '__main__':
    sys.exit(main())
