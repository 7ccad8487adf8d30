"""The soak's subscriber: ``imu/data_raw`` as a ``SensorDataQoS`` user sees it (own process).

``bench/soak.py --subscriber`` runs :func:`run_subscriber` until SIGTERM: best effort, keep
last 5, every sample counted from its stamp (gaps, off the grid, out of order) and the
offset of the stamps from this process's system clock. SIGUSR1 says that the node was
killed and is being started again: its first sample begins a grid of its own.
"""

import signal
import time

import numpy as np
from soak_csv import CsvLog, GAP_COLUMNS, NS_PER_S, Paths, STAMP, STREAM_COLUMNS


class StreamCounter:
    """
    Count ``imu/data_raw`` samples from their stamps: gaps, off the grid, out of order.

    Parameters
    ----------
    period_ns : int
        Sample period of the grid [ns].
    """

    def __init__(self, period_ns):
        self.period_ns = period_ns
        self.first = None
        self.last = None
        self.received = 0
        self.lost = 0
        self.gaps = 0
        self.off_grid = 0
        self.out_of_order = 0
        self.offsets_ns = []
        self.interval_received = 0
        self.grids = 0
        self.restart_ns = None
        """Set by :meth:`restart`: the first sample stamped at or after it is a new node's."""

    def restart(self, now_ns):
        """Say that the node was killed at or before ``now_ns`` and starts again after it."""
        self.restart_ns = now_ns

    def add(self, stamp_ns, received_ns):
        """
        Count one sample.

        Parameters
        ----------
        stamp_ns : int
            Its ``header.stamp`` [ns].
        received_ns : int
            When it was received (system clock) [ns].

        Returns
        -------
        tuple or None
            ``(before, after, missing, kind)`` when it ends a gap (``kind`` ``restart``: the
            first sample of a restarted node; ``missing`` then counts the periods of the old
            grid in the hole), else None.
        """
        self.received += 1
        self.interval_received += 1
        self.offsets_ns.append(received_ns - stamp_ns)
        if self.first is None:
            self.first = self.last = stamp_ns
            self.grids = 1
            return None
        if self.restart_ns is not None and stamp_ns >= self.restart_ns:
            # A node stamps its samples at its start or later: this one is the new node's.
            before, self.first, self.last = self.last, stamp_ns, stamp_ns
            self.restart_ns = None
            self.grids += 1
            missing = max(0, (stamp_ns - before) // self.period_ns - 1)
            self.lost += missing
            self.gaps += 1
            return before, stamp_ns, missing, 'restart'
        if (stamp_ns - self.first) % self.period_ns:
            self.off_grid += 1
        if stamp_ns <= self.last:
            self.out_of_order += 1
            return None
        before, self.last = self.last, stamp_ns
        missing = (stamp_ns - before) // self.period_ns - 1
        if missing > 0:
            self.lost += missing
            self.gaps += 1
            return before, stamp_ns, missing, ''
        return None

    def row(self, wall_ns):
        """Return the subscriber's row now and start a new interval of offsets."""
        offsets = np.array(self.offsets_ns, dtype=float) / 1e3
        self.offsets_ns = []
        quantiles = (np.quantile(offsets, [0.0, 0.5, 0.99, 1.0]) if len(offsets)
                     else [np.nan] * 4)
        row = [wall_ns, self.received, self.lost, self.gaps, self.off_grid,
               self.out_of_order, self.first, self.last,
               *(f'{q:.1f}' for q in quantiles), self.interval_received, self.grids]
        self.interval_received = 0
        return row


def run_subscriber(args):
    """
    Subscribe with SensorDataQoS until SIGTERM; write rows and gaps (process target).

    Parameters
    ----------
    args : argparse.Namespace
        ``out``, ``domain``, ``rate`` and ``sample_every`` of ``bench/soak.py``.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import Imu

    paths = Paths(args.out)
    stop = []
    counter = StreamCounter(round(NS_PER_S / args.rate))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    signal.signal(signal.SIGUSR1, lambda *_: counter.restart(time.time_ns()))
    context = Context()
    rclpy.init(context=context, domain_id=args.domain,
               signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('qfa_soak_subscriber', context=context)
    rows = CsvLog(paths.stream, STREAM_COLUMNS)
    gaps = CsvLog(paths.gaps, GAP_COLUMNS)

    def callback(data, info):
        received = time.time_ns()
        sec, nanosec = STAMP.unpack_from(data, 4)
        gap = counter.add(sec * NS_PER_S + nanosec, received)
        if gap is not None:
            # The DDS source timestamp: when the node's writer sent the sample.
            gaps.write([received, info['source_timestamp'], *gap])

    node.create_subscription(Imu, 'imu/data_raw', callback, qos_profile_sensor_data, raw=True)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    next_row = time.monotonic() + args.sample_every
    while not stop:
        executor.spin_once(timeout_sec=0.1)
        if time.monotonic() >= next_row:
            next_row += args.sample_every
            rows.write(counter.row(time.time_ns()))
    rows.write(counter.row(time.time_ns()))
    rows.close()
    gaps.close()
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)
