"""``qfa-node`` (``ros2 run qfa_ros qfa_node``): run the emulated IMU until SIGINT/SIGTERM."""

import signal
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from qfa_ros.ros.fastdds import use_shipped_fastdds_profile
from qfa_ros.ros.node import QfaNode


def main(args=None):
    """Run the node until SIGINT or SIGTERM; return the exit status."""
    use_shipped_fastdds_profile()
    # Our own handlers only set a flag, so that a signal never interrupts a state-file
    # or recorder write half way: the spin loop below ends and the node closes cleanly.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = []
    previous = {number: signal.signal(number, lambda signum, frame: stop.append(signum))
                for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            node = QfaNode()
        except ValueError as error:
            print(f'qfa_node: invalid parameters: {error}', file=sys.stderr)
            return 2
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
