"""``qfa-node`` (``ros2 run qfa_ros qfa_node``): run the emulated IMU until SIGINT/SIGTERM."""

import os
import re
import signal
import sys
import warnings

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.logging import get_logger
from rclpy.signals import SignalHandlerOptions

from qfa_ros.ros.fastdds import use_shipped_fastdds_profile

NODE_NAME = 'qfa_node'
EXIT_MIDDLEWARE = 1
"""Exit status when the middleware cannot start (DDS Security, arguments, ...)."""
EXIT_PARAMETERS = 2
"""Exit status of an invalid start configuration."""

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

    :returns: ``(secured, problem)``: whether security is asked for, and why the node
        must not start (or None).
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

    :param stage: What failed, e.g. ``'rclpy.init'``.
    :param error: The exception, or a message.
    :param secured: Whether DDS Security was asked for (``ROS_SECURITY_ENABLE``).
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


def init_rclpy(args, secured):
    """
    Initialise rclpy; return None, or the exit status after a one-line report.

    Every start-up error of the middleware (``RCLError``: arguments, parameters file,
    DDS Security, ...) ends here or in :func:`create_node`, never in a traceback.
    """
    try:
        # Our own handlers (main) only set a flag: a signal never interrupts a write.
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except rclpy_implementation.RCLError as error:
        return startup_failure('rclpy.init', error, secured)
    return None


def create_node(secured):
    """Create the node; return ``(node, None)`` or ``(None, status)`` after a one-line report."""
    # Imported only now: the model takes seconds to load, a middleware refusal does not.
    from qfa_ros.ros.node import QfaNode
    try:
        with warnings.catch_warnings():
            # rclpy warns about the half-made rosout publisher of a node that failed.
            warnings.simplefilter('ignore', RuntimeWarning)
            return QfaNode(NODE_NAME), None
    except (rclpy_implementation.RCLError, ValueError) as error:
        return None, startup_failure('creating the node', error, secured)


def main(args=None):
    """Run the node until SIGINT or SIGTERM; return the exit status."""
    use_shipped_fastdds_profile()
    secured, problem = require_security()
    if problem:
        return startup_failure('checking the environment', problem, secured)
    status = init_rclpy(args, secured)
    if status is not None:
        return status
    # After rclpy.init, which would put back the handlers it found.
    stop = []
    previous = {number: signal.signal(number, lambda signum, frame: stop.append(signum))
                for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        node, status = create_node(secured)
        if node is None:
            return status
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            while not stop and rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:
            pass
        finally:
            node.close()
            executor.shutdown()
            node.destroy_node()
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
