"""Measure how fast short-lived participants match a long-running one, per Fast DDS profile.

A long-running participant publishes ``std_msgs/String`` at 200 Hz (its own process,
the profile under test). This process then creates and destroys ``--trials``
participants one after another, each with a best-effort subscription, and records the
time from ``rclpy.init`` of the new context to its first message (start-up match). Every
``--publisher-every``-th trial is reversed: the short-lived participant publishes and
the long-running one must see it (the node starting while a subscriber waits). At the
end the long-running participant must still be discoverable and streaming (churn).

Run: ``.venv/bin/python bench/discovery.py [--profile FILE|default] [--trials 100]
[--busy]``; ``--busy`` keeps one core loaded (a spinning process) meanwhile. Prints one
Markdown table row. Fast DDS reads the profile once per process, so each profile needs
its own run.
"""

import argparse
import multiprocessing
import os
from pathlib import Path
import statistics
import sys
import time

ROOT = Path(__file__).resolve().parents[1]
TOPIC = 'discovery_probe'
BACK_TOPIC = 'discovery_back'


def _spin_forever():
    while True:
        pass


def _long_runner(domain, ready, stop, seen_back):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node('long_runner', context=context)
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    publisher = node.create_publisher(String, TOPIC, qos)
    node.create_timer(0.005, lambda: publisher.publish(String(data='x')))
    node.create_subscription(String, BACK_TOPIC,
                             lambda message: seen_back.put(message.data), qos)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    ready.set()
    while not stop.is_set():
        executor.spin_once(timeout_sec=0.05)
    rclpy.try_shutdown(context=context)


def _trial(domain, index, reverse, seen_back, timeout):
    """Return the seconds until the new participant matched (None: timed out)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    start = time.monotonic()
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        node = rclpy.create_node(f'short_{index}', context=context)
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
        got = []
        if reverse:
            publisher = node.create_publisher(String, BACK_TOPIC, qos)
        else:
            node.create_subscription(String, TOPIC, got.append, qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        tag = f'{index}'
        while time.monotonic() - start < timeout:
            if reverse:
                publisher.publish(String(data=tag))
                try:
                    while seen_back.get(timeout=0.005) != tag:
                        pass
                    return time.monotonic() - start
                except Exception:
                    pass
            else:
                executor.spin_once(timeout_sec=0.005)
                if got:
                    return time.monotonic() - start
        return None
    finally:
        rclpy.try_shutdown(context=context)


def main(argv=None):
    """Run the trials and print a Markdown row."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--profile', default=str(ROOT / 'config' / 'fastdds_discovery.xml'),
                        help="Fast DDS XML profile, or 'default' for none")
    parser.add_argument('--trials', type=int, default=100)
    parser.add_argument('--publisher-every', type=int, default=4)
    parser.add_argument('--domain', type=int, default=int(os.environ.get('ROS_DOMAIN_ID', 90)))
    parser.add_argument('--timeout', type=float, default=10.0)
    parser.add_argument('--busy', action='store_true', help='keep one core loaded')
    args = parser.parse_args(argv)
    if args.profile == 'default':
        os.environ.pop('FASTDDS_DEFAULT_PROFILES_FILE', None)
    else:
        os.environ['FASTDDS_DEFAULT_PROFILES_FILE'] = args.profile
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    spawn = multiprocessing.get_context('spawn')
    ready, stop, seen_back = spawn.Event(), spawn.Event(), spawn.Queue()
    busy = spawn.Process(target=_spin_forever, daemon=True) if args.busy else None
    if busy:
        busy.start()
    runner = spawn.Process(target=_long_runner, args=(args.domain, ready, stop, seen_back))
    runner.start()
    ready.wait(30)
    forward, backward, misses = [], [], 0
    try:
        from tqdm import tqdm
        trials = tqdm(range(args.trials), file=sys.stderr, disable=not sys.stderr.isatty())
    except ImportError:
        trials = range(args.trials)
    try:
        for index in trials:
            reverse = args.publisher_every and index % args.publisher_every == 1
            seconds = _trial(args.domain, index, reverse, seen_back, args.timeout)
            if seconds is None:
                misses += 1
            else:
                (backward if reverse else forward).append(seconds)
        final = _trial(args.domain, args.trials, False, seen_back, args.timeout)
    finally:
        stop.set()
        runner.join(20)
        if runner.is_alive():
            runner.kill()
        if busy:
            busy.kill()

    def describe(values):
        if not values:
            return '-'
        late = sum(v > 1.0 for v in values)
        return (f'median {statistics.median(values):.2f} s, max {max(values):.2f} s, '
                f'{late}/{len(values)} > 1 s')

    name = 'default' if args.profile == 'default' else Path(args.profile).name
    after = 'no match' if final is None else f'{final:.2f} s'
    print(f'| {name} | {args.trials} | {"yes" if args.busy else "no"} | {describe(forward)} '
          f'| {describe(backward)} | {misses} | {after} |')
    return 0 if final is not None else 1


if __name__ == '__main__':
    sys.exit(main())
