"""``qfa-replay BAG``: publish a rosbag2 MCAP bag with its original timing and QoS."""

import argparse
import math
import signal
import sys

from qfa_ros.bag.reader import BagError
from qfa_ros.cli.interrupt import stops_quietly
from qfa_ros.model.checks import is_finite
from qfa_ros.ros.fastdds import use_shipped_fastdds_profile
from qfa_ros.ros.replay import BagReplayer, EXIT_NO_SUBSCRIBERS, ReplaySummary


def build_parser():
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='qfa-replay',
        description='Publish a rosbag2 MCAP bag over ROS 2 with its original timing and QoS '
                    '(ros2 bag play without the ROS 2 CLI).')
    parser.add_argument('bag', help='bag directory (metadata.yaml + .mcap) or .mcap file')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='playback speed factor (default 1)')
    parser.add_argument('--loop', action='store_true', help='repeat until interrupted')
    parser.add_argument('--topics', nargs='+', metavar='TOPIC',
                        help='play only these topics')
    parser.add_argument('--clock', nargs='?', type=float, const=100.0, default=None,
                        metavar='HZ',
                        help='also publish /clock with the bag time, at HZ in wall time '
                             '(default 100; 0: before every message)')
    parser.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                        help='start this many bag seconds after the first message')
    parser.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                        help='start only once N subscriptions in total match the played '
                             'topics (default 0: do not wait)')
    parser.add_argument('--domain-ready-timeout', type=float, default=30.0, metavar='S',
                        help='give up waiting for subscribers after S seconds (exit status '
                             f'{EXIT_NO_SUBSCRIBERS}; default 30)')
    return parser


@stops_quietly('qfa-replay')
def main(argv=None):
    """Run the replay command line; return the exit status."""
    args = build_parser().parse_args(argv)
    if not args.rate > 0:
        print('qfa-replay: --rate must be positive', file=sys.stderr)
        return 2
    if not (is_finite(args.start_offset) and args.start_offset >= 0) or (
            args.clock is not None and not (is_finite(args.clock) and args.clock >= 0)):
        print('qfa-replay: --start-offset and --clock must be finite and not negative',
              file=sys.stderr)
        return 2
    if math.isnan(args.domain_ready_timeout):
        print('qfa-replay: --domain-ready-timeout must be a number of seconds, got nan',
              file=sys.stderr)
        return 2
    use_shipped_fastdds_profile()
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    # Our own handlers stop playback between messages, so the summary still prints.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = rclpy.create_node('qfa_replay')
        try:
            replayer = BagReplayer(args.bag, node, rate=args.rate, topics=args.topics,
                                   clock=args.clock is not None,
                                   clock_hz=args.clock if args.clock is not None else 100.0,
                                   loop=args.loop, start_offset=args.start_offset)
        except BagError as error:
            print(f'qfa-replay: {error}', file=sys.stderr)
            return 1
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, lambda *_: replayer.stop())
        if not replayer.publishers:
            print('qfa-replay: nothing to play', file=sys.stderr)
            print(ReplaySummary(skipped=replayer.skipped).format(), file=sys.stderr)
            return 1
        if args.wait_for_subscribers > 0:
            print(f'qfa-replay: waiting for {args.wait_for_subscribers} subscription(s)',
                  flush=True)
            if not replayer.wait_for_subscribers(args.wait_for_subscribers,
                                                 args.domain_ready_timeout):
                if replayer.stopped:
                    return 0
                print(f'qfa-replay: {replayer.subscription_count()} of '
                      f'{args.wait_for_subscribers} subscription(s) matched after '
                      f'{args.domain_ready_timeout:g} s; not playing', file=sys.stderr)
                return EXIT_NO_SUBSCRIBERS
        print(f'qfa-replay: playing {args.bag}', flush=True)
        summary = replayer.run()
        if not replayer.flush():
            print('qfa-replay: some reliable subscribers did not acknowledge the last '
                  'messages', file=sys.stderr)
        print(summary.format(replayer.source.topics), flush=True)
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
