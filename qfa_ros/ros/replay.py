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

import dataclasses
import heapq
import importlib
import threading
import time

from qfa_ros.bag.reader import BagSource, normalized_type
from qfa_ros.model.checks import is_finite

__all__ = [
    'BagReplayer',
    'ReplaySummary',
    'import_message_type',
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


def import_message_type(msgtype):
    """
    Return the rclpy message class for a type name, or None if it cannot be imported.

    Parameters
    ----------
    msgtype : str
        ``'sensor_msgs/msg/Imu'`` (``'sensor_msgs/Imu'`` is accepted too).
    """
    parts = normalized_type(msgtype).split('/')
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
        if not (is_finite(start_offset) and start_offset >= 0):
            raise ValueError(f'start_offset must be finite and non-negative, got {start_offset!r}')
        if clock and not (is_finite(clock_hz) and clock_hz >= 0):
            raise ValueError(f'clock_hz must be finite and non-negative, got {clock_hz!r}')
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


