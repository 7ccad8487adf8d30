"""Replay a rosbag2 MCAP bag over ROS 2 with its original timing and QoS.

``qfa-replay BAG`` is ``ros2 bag play`` for machines without the ROS 2 CLI: it
reads a bag directory (``metadata.yaml`` plus ``.mcap`` files) or a bare
``.mcap`` file with the ``mcap`` package and publishes every message's CDR bytes
unchanged with rclpy. Message ``i`` is due at ``start + (t_i - t_0) / rate`` on
the monotonic clock, where ``t`` is the log time, so lateness never accumulates.
Each topic is offered with the QoS it was recorded with (``offered_qos_profiles``).
Topics of a type this Python cannot import, or not CDR encoded, are skipped with a
warning.
"""

import argparse
import dataclasses
import heapq
import importlib
from pathlib import Path
import signal
import sys
import threading
import time

from mcap.exceptions import McapError
from mcap.reader import make_reader
import yaml

from qfa_ros.fastdds import use_shipped_fastdds_profile

__all__ = [
    'BagReplayer',
    'BagSource',
    'BagTopic',
    'ReplaySummary',
    'import_message_type',
    'main',
    'qos_from_offers',
]

CLOCK_TOPIC = '/clock'
# Longest single sleep, so that a stop request (signal or another thread) is seen soon.
_SLEEP_SLICE_S = 0.05
# The publisher side sees a match as soon as it discovers the subscription; the
# subscription side may learn of the publisher a moment later and drop what arrives
# before that (best-effort topics are never repaired), so playback starts this long
# after the wanted subscriptions are matched.
MATCH_SETTLE_S = 0.2
# rmw_fastrtps publishes asynchronously: a best-effort sample handed over just before
# the process exits may still sit in the writer's queue, and nothing acknowledges it.
FLUSH_LINGER_S = 0.1
# A sleep wakes 0.1 ms late typically but up to several ms late on a loaded or
# virtualized host; the last stretch before a due time is polled instead.
SPIN_S = 0.001
# rosbag2's default when a bag records no QoS for a topic.
_DEFAULT_DEPTH = 10
EXIT_NO_SUBSCRIBERS = 3


class BagError(RuntimeError):
    """The bag cannot be read: missing, not MCAP, or malformed."""


# --- reading ------------------------------------------------------------------------------

@dataclasses.dataclass
class BagTopic:
    """
    One recorded topic.

    Attributes
    ----------
    name : str
        Topic name as recorded.
    msgtype : str
        Type name like ``'sensor_msgs/msg/Imu'``.
    encoding : str
        MCAP message encoding; only ``'cdr'`` can be published.
    offered_qos : list of dict
        The recorded publishers' QoS profiles as rosbag2 stores them (may be empty).
    """

    name: str
    msgtype: str
    encoding: str = 'cdr'
    offered_qos: list = dataclasses.field(default_factory=list)


def _parse_offers(value):
    """Return rosbag2 ``offered_qos_profiles`` (YAML text or already a list) as a list."""
    if value is None or value == '':
        return []
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value)
        except yaml.YAMLError:
            return []
    if isinstance(value, dict):
        value = [value]
    return [offer for offer in value or [] if isinstance(offer, dict)]


def _canonical_type(name):
    parts = [part for part in name.split('/') if part]
    if len(parts) == 2:
        parts.insert(1, 'msg')
    return '/'.join(parts)


class BagSource:
    """
    The messages of a rosbag2 MCAP bag, merged across its files in log-time order.

    Parameters
    ----------
    path : str or os.PathLike
        A bag directory (rosbag2 ``metadata.yaml`` naming its ``.mcap`` files, or
        just ``.mcap`` files) or a single ``.mcap`` file.

    Attributes
    ----------
    files : list of pathlib.Path
        The MCAP files in playback order.
    topics : dict of str to BagTopic
        Every recorded topic by name.
    warnings : list of str
        What could not be used (conflicting channel types, ...).
    """

    def __init__(self, path):
        self.path = Path(path)
        self.warnings = []
        metadata_topics = {}
        if self.path.is_dir():
            self.files, metadata_topics = self._directory_files(self.path)
        elif self.path.is_file():
            self.files = [self.path]
        else:
            raise BagError(f'no bag at {self.path}')
        self.topics = {}
        for file in self.files:
            for channel, schema_name in self._channels(file):
                self._add_channel(channel, schema_name, metadata_topics.get(channel.topic))

    @staticmethod
    def _directory_files(directory):
        metadata_file = directory / 'metadata.yaml'
        if not metadata_file.exists():
            files = sorted(directory.glob('*.mcap'))
            if not files:
                raise BagError(f'{directory} has neither metadata.yaml nor .mcap files')
            return files, {}
        try:
            info = yaml.safe_load(metadata_file.read_text())['rosbag2_bagfile_information']
        except (OSError, yaml.YAMLError, KeyError, TypeError) as error:
            raise BagError(f'{metadata_file}: not rosbag2 metadata ({error})') from error
        storage = info.get('storage_identifier', 'mcap')
        if storage != 'mcap':
            raise BagError(f'{directory}: storage {storage!r} is not supported, only mcap '
                           '(convert with `ros2 bag convert` or rosbags-convert)')
        files = [directory / name for name in info.get('relative_file_paths') or []]
        missing = [str(file) for file in files if not file.exists()]
        if missing or not files:
            raise BagError(f'{directory}: bag files missing: {", ".join(missing) or "none"}')
        topics = {}
        for entry in info.get('topics_with_message_count') or []:
            meta = entry.get('topic_metadata') or {}
            if 'name' in meta:
                topics[meta['name']] = meta
        return files, topics

    def _channels(self, file):
        """Yield ``(channel, schema name)`` of every channel in ``file``."""
        try:
            with open(file, 'rb') as stream:
                reader = make_reader(stream)
                summary = reader.get_summary()
                if summary is not None:
                    for channel in summary.channels.values():
                        schema = summary.schemas.get(channel.schema_id)
                        yield channel, schema.name if schema else ''
                    return
                # No summary (an interrupted recording): learn the channels by reading it.
                seen = set()
                for schema, channel, _ in reader.iter_messages(log_time_order=False):
                    if channel.id not in seen:
                        seen.add(channel.id)
                        yield channel, schema.name if schema else ''
        except (OSError, McapError, ValueError) as error:
            raise BagError(f'{file}: cannot read MCAP ({error})') from error

    def _add_channel(self, channel, schema_name, metadata):
        msgtype = _canonical_type(schema_name or (metadata or {}).get('type', ''))
        offers = _parse_offers(channel.metadata.get('offered_qos_profiles'))
        if not offers and metadata:
            offers = _parse_offers(metadata.get('offered_qos_profiles'))
        known = self.topics.get(channel.topic)
        if known is None:
            self.topics[channel.topic] = BagTopic(channel.topic, msgtype,
                                                  channel.message_encoding, offers)
        elif known.msgtype != msgtype:
            self.warnings.append(f'{channel.topic}: recorded as both {known.msgtype} and '
                                 f'{msgtype}; playing {known.msgtype} only')
        else:
            known.offered_qos.extend(offer for offer in offers
                                     if offer not in known.offered_qos)

    def messages(self, topics=None, start_ns=None):
        """
        Yield ``(topic, log_time_ns, cdr_bytes)`` in log-time order.

        Parameters
        ----------
        topics : collection of str, optional
            Only these topics (default all).
        start_ns : int, optional
            Skip messages logged before this time.
        """
        topics = None if topics is None else set(topics)
        streams = [self._file_messages(file, topics, start_ns) for file in self.files]
        # Split bags are usually sequential, but a merge keeps overlapping files in order.
        yield from heapq.merge(*streams, key=lambda item: item[1])

    def _file_messages(self, file, topics, start_ns):
        with open(file, 'rb') as stream:
            reader = make_reader(stream)
            try:
                for _, channel, message in reader.iter_messages(
                        topics=topics, starting_at=start_ns, log_time_order=True):
                    if channel.topic in self.topics:
                        yield channel.topic, message.log_time, bytes(message.data)
            except McapError as error:
                # A truncated file still plays up to its last complete chunk.
                self.warnings.append(f'{file}: stopped reading: {error}')


def import_message_type(msgtype):
    """
    Return the rclpy message class for a type name, or None if it cannot be imported.

    Parameters
    ----------
    msgtype : str
        ``'sensor_msgs/msg/Imu'`` (``'sensor_msgs/Imu'`` is accepted too).
    """
    parts = _canonical_type(msgtype).split('/')
    if len(parts) != 3 or parts[1] != 'msg':
        return None
    try:
        module = importlib.import_module(f'{parts[0]}.msg')
    except ImportError:
        return None
    message_class = getattr(module, parts[2], None)
    # Every generated rclpy message class carries its type support hook.
    if message_class is None or not hasattr(message_class, '_TYPE_SUPPORT'):
        return None
    return message_class


def qos_from_offers(offers):
    """
    Build the publisher QoS that matches what a topic's recorded publishers offered.

    Like ``ros2 bag play``: reliable or transient-local only when every recorded
    publisher offered it (so that every subscriber that matched the original
    publishers matches the replay), otherwise best effort or volatile; keep-all if
    any offered it, else keep-last with the deepest recorded depth. Deadline,
    lifespan and liveliness are not reproduced. Without offers: reliable, volatile,
    keep-last 10.

    Parameters
    ----------
    offers : list of dict
        Profiles from ``offered_qos_profiles`` (policies as names or rmw enum values).

    Returns
    -------
    rclpy.qos.QoSProfile
    """
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    def policy(offer, key, enum):
        value = offer.get(key)
        try:
            if isinstance(value, str):
                return enum[value.upper()]
            return enum(int(value))
        except (KeyError, TypeError, ValueError):
            return None

    reliabilities = [policy(offer, 'reliability', ReliabilityPolicy) for offer in offers]
    durabilities = [policy(offer, 'durability', DurabilityPolicy) for offer in offers]
    histories = [policy(offer, 'history', HistoryPolicy) for offer in offers]
    depths = []
    for offer in offers:
        try:
            depths.append(int(offer.get('depth', 0)))
        except (TypeError, ValueError):
            pass
    reliable = (not offers or all(r in (ReliabilityPolicy.RELIABLE, None)
                                  for r in reliabilities))
    latched = bool(offers) and all(d == DurabilityPolicy.TRANSIENT_LOCAL for d in durabilities)
    depth = max([d for d in depths if d > 0], default=_DEFAULT_DEPTH)
    history = (HistoryPolicy.KEEP_ALL if HistoryPolicy.KEEP_ALL in histories
               else HistoryPolicy.KEEP_LAST)
    return QoSProfile(
        history=history, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


# --- playing ------------------------------------------------------------------------------

@dataclasses.dataclass
class ReplaySummary:
    """
    What a replay did.

    Attributes
    ----------
    counts : dict of str to int
        Messages published per topic.
    skipped : dict of str to str
        Topics not played and why.
    wall_s : float
        Time from the first to the last publication [s].
    bag_s : float
        Log-time span played, summed over loops [s].
    max_lateness_s : float
        Largest delay of a publication after its due time [s].
    loops : int
        Complete passes through the bag.
    interrupted : bool
        Whether ``stop()`` (or a signal) ended the replay early.
    warnings : list of str
        Problems met while reading (conflicting types, a truncated file).
    """

    counts: dict = dataclasses.field(default_factory=dict)
    skipped: dict = dataclasses.field(default_factory=dict)
    wall_s: float = 0.0
    bag_s: float = 0.0
    max_lateness_s: float = 0.0
    loops: int = 0
    interrupted: bool = False
    warnings: list = dataclasses.field(default_factory=list)

    @property
    def total(self):
        """Messages published on all topics."""
        return sum(self.counts.values())

    def format(self, topics=None):
        """Return a human-readable multi-line summary."""
        lines = [f'played {self.total} messages in {self.wall_s:.3f} s '
                 f'(bag time {self.bag_s:.3f} s, {self.loops} complete pass'
                 f'{"" if self.loops == 1 else "es"}'
                 f'{", interrupted" if self.interrupted else ""}); '
                 f'max lateness {self.max_lateness_s * 1e3:.3f} ms']
        width = max((len(name) for name in self.counts), default=0)
        for name, count in sorted(self.counts.items()):
            msgtype = topics[name].msgtype if topics and name in topics else ''
            lines.append(f'  {name:<{width}}  {count:>8}  {msgtype}')
        for name, reason in sorted(self.skipped.items()):
            lines.append(f'  skipped {name}: {reason}')
        lines.extend(f'  warning: {warning}' for warning in self.warnings)
        return '\n'.join(lines)


class BagReplayer:
    """
    Publish a bag's messages through ``node`` with their recorded timing and QoS.

    Parameters
    ----------
    path : str or os.PathLike
        Bag directory or ``.mcap`` file (see :class:`BagSource`).
    node : rclpy.node.Node
        Node that owns the publishers; it need not be spun.
    rate : float
        Playback speed factor (2 plays twice as fast).
    topics : collection of str, optional
        Play only these topics (default all).
    clock : bool
        Also publish ``/clock`` (rosgraph_msgs/Clock) with the bag time.
    clock_hz : float
        ``/clock`` rate in wall time; 0 publishes it just before every message.
    loop : bool
        Start over at the end until stopped.
    start_offset : float
        Skip this much bag time [s] from the first played message.
    spin_s : float
        Poll the clock instead of sleeping this long before each due time [s]: better
        timing for some CPU (0 sleeps all the way).

    Notes
    -----
    Publishers are created in the constructor, so subscribers can match (see
    :meth:`wait_for_subscribers`) before :meth:`run` starts the clock.
    """

    def __init__(self, path, node, *, rate=1.0, topics=None, clock=False, clock_hz=100.0,
                 loop=False, start_offset=0.0, spin_s=SPIN_S):
        if not rate > 0:
            raise ValueError(f'rate must be positive, got {rate!r}')
        if not start_offset >= 0:
            raise ValueError(f'start_offset must be non-negative, got {start_offset!r}')
        if clock and not clock_hz >= 0:
            raise ValueError(f'clock_hz must be non-negative, got {clock_hz!r}')
        self.node = node
        self.spin_s = max(0.0, float(spin_s))
        self.source = BagSource(path)
        self.rate = float(rate)
        self.loop = loop
        self.start_offset_ns = int(round(start_offset * 1e9))
        self.clock_period_s = 1.0 / clock_hz if clock and clock_hz > 0 else None
        self._clock_per_message = clock and clock_hz == 0
        self._stop_event = threading.Event()
        self.skipped = {}
        self.publishers = {}
        wanted = set(self.source.topics) if topics is None else set(topics)
        for name in sorted(wanted - set(self.source.topics)):
            self.skipped[name] = 'not in the bag'
        for name in sorted(wanted & set(self.source.topics)):
            self._create_publisher(self.source.topics[name])
        self.clock_publisher = None
        if clock:
            from rclpy.qos import QoSProfile, ReliabilityPolicy
            from rosgraph_msgs.msg import Clock
            self._clock_type = Clock
            # Reliable keep-last 1 matches both rclpy's best-effort time source and
            # reliable subscribers, and never blocks on a slow one.
            self.clock_publisher = node.create_publisher(
                Clock, CLOCK_TOPIC, QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        for reason in self.source.warnings:
            node.get_logger().warning(reason)

    def _create_publisher(self, topic):
        if topic.encoding != 'cdr':
            reason = f'message encoding {topic.encoding!r} is not cdr'
        else:
            message_class = import_message_type(topic.msgtype)
            reason = None if message_class else f'unknown message type {topic.msgtype!r}'
        if reason:
            self.skipped[topic.name] = reason
            self.node.get_logger().warning(f'skipping {topic.name}: {reason}')
            return
        self.publishers[topic.name] = self.node.create_publisher(
            message_class, topic.name, qos_from_offers(topic.offered_qos))

    def stop(self):
        """Make :meth:`run` or :meth:`wait_for_subscribers` return soon (thread/signal safe)."""
        self._stop_event.set()

    @property
    def stopped(self):
        """Whether :meth:`stop` was called."""
        return self._stop_event.is_set()

    def subscription_count(self):
        """Return the matched subscriptions summed over the played topics."""
        return sum(publisher.get_subscription_count()
                   for publisher in self.publishers.values())

    def wait_for_subscribers(self, count, timeout_s):
        """
        Wait until ``count`` subscriptions in total match the played topics.

        Parameters
        ----------
        count : int
            Matched subscriptions summed over the played topics (``/clock`` excluded).
        timeout_s : float
            Give up after this long [s].

        Returns
        -------
        bool
            True once matched (after a short settle, see ``MATCH_SETTLE_S``); False on
            timeout or stop.
        """
        deadline = time.monotonic() + timeout_s
        while self.subscription_count() < count:
            if self.stopped or time.monotonic() >= deadline:
                return False
            self._sleep_until(min(deadline, time.monotonic() + 0.01))
        self._sleep_until(time.monotonic() + MATCH_SETTLE_S)
        return not self.stopped

    def flush(self, timeout_s=2.0):
        """
        Let the last messages leave before the node goes away.

        Waits until every reliable publisher's messages are acknowledged (at most
        ``timeout_s``), then ``FLUSH_LINGER_S`` for best-effort ones.

        Returns
        -------
        bool
            False if a reliable subscriber did not acknowledge in time.
        """
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout_s
        acknowledged = True
        for publisher in self.publishers.values():
            remaining = max(0.0, deadline - time.monotonic())
            acknowledged &= publisher.wait_for_all_acked(Duration(seconds=remaining))
        time.sleep(FLUSH_LINGER_S)
        return acknowledged

    def _sleep_until(self, due):
        """Wait until the monotonic time ``due`` unless stopped; return False if stopped."""
        while not self.stopped:
            remaining = due - time.monotonic()
            if remaining <= 0:
                return True
            if remaining > self.spin_s:
                time.sleep(min(remaining - self.spin_s, _SLEEP_SLICE_S))
            # Within spin_s of the due time: poll, as a sleep can overshoot by milliseconds.
        return False

    def _publish_clock(self, bag_time_ns):
        message = self._clock_type()
        message.clock.sec, message.clock.nanosec = divmod(int(bag_time_ns), 1_000_000_000)
        self.clock_publisher.publish(message)

    def _wait_for(self, due, start, origin_ns, next_tick):
        """Sleep until ``due`` publishing ``/clock`` ticks on the way; return the next tick."""
        while next_tick is not None and next_tick <= due:
            if not self._sleep_until(next_tick):
                return next_tick
            self._publish_clock(origin_ns + (next_tick - start) * self.rate * 1e9)
            next_tick += self.clock_period_s
        self._sleep_until(due)
        return next_tick

    def run(self):
        """
        Play the bag (repeatedly with ``loop``) until its end or :meth:`stop`.

        Returns
        -------
        ReplaySummary
        """
        summary = ReplaySummary(counts=dict.fromkeys(self.publishers, 0),
                                skipped=dict(self.skipped))
        first_publish = last_publish = None
        while not self.stopped:
            messages = self.source.messages(self.publishers)
            first = next(messages, None)
            if first is None:
                break
            origin_ns = first[1] + self.start_offset_ns
            if self.start_offset_ns:
                messages.close()
                messages = self.source.messages(self.publishers, start_ns=origin_ns)
            else:
                messages = heapq.merge([first], messages, key=lambda item: item[1])
            start = time.monotonic()
            next_tick = start if self.clock_period_s else None
            last_ns = origin_ns
            for name, log_ns, data in messages:
                due = start + (log_ns - origin_ns) * 1e-9 / self.rate
                next_tick = self._wait_for(due, start, origin_ns, next_tick)
                if self.stopped:
                    break
                if self._clock_per_message:
                    self._publish_clock(log_ns)
                self.publishers[name].publish(data)
                now = time.monotonic()
                summary.max_lateness_s = max(summary.max_lateness_s, now - due)
                summary.counts[name] += 1
                first_publish = first_publish if first_publish is not None else now
                last_publish = now
                last_ns = log_ns
            summary.bag_s += (last_ns - origin_ns) * 1e-9
            if self.stopped:
                break
            summary.loops += 1
            if not self.loop:
                break
        summary.interrupted = self.stopped
        if first_publish is not None:
            summary.wall_s = last_publish - first_publish
        summary.warnings = list(self.source.warnings)
        return summary


# --- DDS start-up -------------------------------------------------------------------------

# --- command line -------------------------------------------------------------------------

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


def main(argv=None):
    """Run the replay command line; return the exit status."""
    args = build_parser().parse_args(argv)
    if not args.rate > 0:
        print('qfa-replay: --rate must be positive', file=sys.stderr)
        return 2
    if args.start_offset < 0 or (args.clock is not None and args.clock < 0):
        print('qfa-replay: --start-offset and --clock must not be negative', file=sys.stderr)
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
