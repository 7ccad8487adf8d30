"""
``qfa_node`` (``ros2 run qfa_ros qfa_node``): run the emulated IMU until SIGINT/SIGTERM.

SIGINT and SIGTERM stop the process within a few seconds in every case
(:func:`shut_down`): the node's own writes (calibration state, flight recording) finish
first; a middleware teardown that hangs is then abandoned with :data:`EXIT_HARD` and a
log line saying so.
"""

import faulthandler
import os
import signal
import socket
import sys
import threading

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from qfa_ros.ros.fastdds import use_shipped_fastdds_profile
from qfa_ros.ros.node import QfaNode

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

CLOSE_TIMEOUT_S = 2.0
"""How long the node may take to stop its sensor thread before the writes go ahead anyway."""

MIDDLEWARE_TIMEOUT_S = 2.0
"""How long the middleware teardown may take before the process exits without it."""

SPIN_EXIT_TIMEOUT_S = 2.0
"""How long the spin loop may take to notice a stop signal (a callback hung in DDS)."""

EXIT_INVALID_PARAMETERS = 2

EXIT_HARD = 3
"""Exit status when the process had to exit without the middleware teardown."""


def main(args=None):
    """Run the node until SIGINT or SIGTERM; exit with the status (2: invalid parameters)."""
    use_shipped_fastdds_profile()
    signals = StopSignals()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = QfaNode()
    except ValueError as error:
        # Through the ROS logger: the console (stderr) and the node's log file.
        rclpy.logging.get_logger('qfa_node').fatal(f'invalid parameters: {error}')
        rclpy.try_shutdown()
        return EXIT_INVALID_PARAMETERS
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    signals.watch(node)
    try:
        while not signals.stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    signals.stopping.set()
    status = shut_down(node, executor)
    # Skip the interpreter's finalization: nothing is left to write, and under `ros2
    # launch` with two units it was seen to hang after a complete teardown (until the
    # launcher's SIGTERM). Standard streams are flushed first.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


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
        self._reader, self._writer = socket.socketpair()
        self._writer.setblocking(False)
        for signum in STOP_SIGNALS:
            signal.signal(signum, lambda signum, frame: self.stop.set())
        signal.set_wakeup_fd(self._writer.fileno(), warn_on_full_buffer=False)
        threading.Thread(target=self._wait, name='qfa_signals', daemon=True).start()

    def watch(self, node):
        """Close ``node`` if the main thread cannot."""
        self._node = node

    def _wait(self):
        while True:
            data = self._reader.recv(1)
            if not data or data[0] in STOP_SIGNALS:
                break
        self.stop.set()
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

    :param node: The :class:`QfaNode`.
    :param executor: The executor spinning it.
    :return: 0 (a hung teardown ends the process instead of returning).
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
