"""Truth without duplicate stamps: count them on a running node (issue 38's acceptance).

Run: ``QFA_TEST_DOMAINS=LOW-HIGH .venv/bin/python bench/truth_duplicates.py [--seconds 600]
[--rate-hz 10]``. Starts ``qfa_node`` in its own process (defaults but ``output_dir``,
``state_file`` and ``truth.rate_hz``), subscribes ``truth/odometry`` and
``truth/imu_errors`` reliably (depth 1000, so nothing is lost to the test process) and, as
an INS would, with SensorDataQoS, for ``--seconds`` of wall time; prints per topic and
reader the messages, the stamps that do not move past the previous one (duplicates), and
the spacing of the stamps. Before issue 38, about 3 % of the messages at 10 Hz repeated
the previous stamp and state.
"""

import argparse
import os
from pathlib import Path
import sys
import tempfile
import time

from nav_msgs.msg import Odometry
import numpy as np
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from node_helpers import Client, domain_id, NodeProcess  # noqa: E402


def main():
    """Run the node, count, print."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=600.0)
    parser.add_argument('--rate-hz', type=float, default=10.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        domain = domain_id('truth duplicates')
        node = NodeProcess(domain, scratch, {'output_dir': scratch, 'state_file': '',
                                             'truth.rate_hz': args.rate_hz})
        client = Client(domain)
        stamps = {}
        try:
            for topic, kind in (('truth/odometry', Odometry), ('truth/imu_errors', Imu)):
                for reader, qos in (('reliable', None),
                                    ('SensorDataQoS', qos_profile_sensor_data)):
                    received = stamps[(topic, reader)] = []

                    def keep(message, received=received):
                        stamp = message.header.stamp
                        received.append(stamp.sec * 1_000_000_000 + stamp.nanosec)
                    if qos is None:
                        client.subscribe(kind, topic, keep)
                    else:
                        client.node.create_subscription(kind, topic, keep, qos)
            client.spin_until(lambda: all(stamps.values()), 120, 'the first truth')
            for received in stamps.values():
                received.clear()
            start = time.monotonic()
            load = os.getloadavg()[0]
            client.spin_for(args.seconds)
            wall = time.monotonic() - start
        finally:
            client.close()
            node.stop()
    print(f'qfa_node defaults, truth.rate_hz {args.rate_hz:g}, {wall:.0f} s of wall time; '
          f'load {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end\n')
    print('| topic | reader | messages | duplicate stamps | stamp spacing min / median / '
          'max ms |')
    print('|---|---|---|---|---|')
    for (topic, reader), received in stamps.items():
        values = np.array(received, dtype=np.int64)
        steps = np.diff(values)
        print(f'| `{topic}` | {reader} | {len(values)} | {int(np.sum(steps <= 0))} | '
              f'{steps.min() / 1e6:.0f} / {np.median(steps) / 1e6:.0f} / '
              f'{steps.max() / 1e6:.0f} |')


if __name__ == '__main__':
    main()
