"""How soon an Imu publisher matches a SensorDataQoS subscriber whose participant it knows.

Run (the figures in ``bench/results/first_sample.md``)::

    .venv/bin/python bench/endpoint_match.py --starts 10

Would creating the node's ``imu/data_raw`` publisher before the model is built let DDS
endpoint discovery overlap the model's start-up? One subscriber (``qos_profile_sensor_data``)
runs in this process; a child process, started ``--starts`` times, initialises rclpy (its
participant), waits ``--settle`` seconds (participant discovery over), creates the
publisher with the node's QoS and notes how long ``create_publisher`` took and when
``get_subscription_count()`` first turns positive, both from the call. Same environment as
``bench/first_sample.py`` (own domain, localhost discovery, the shipped Fast DDS profile).
"""

import argparse
import datetime
import os
import statistics
import subprocess
import sys

from first_sample import environment, FirstSample

CHILD = """
import sys
import time

import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

rclpy.init()
node = rclpy.create_node('endpoint_match')
time.sleep(float(sys.argv[1]))
started = time.perf_counter()
publisher = node.create_publisher(Imu, 'imu/data_raw', QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE))
created = time.perf_counter()
while not publisher.get_subscription_count():
    if time.perf_counter() - started > 10.0:
        break
    time.sleep(0.0002)
print(f'MATCH {created - started:.4f} {time.perf_counter() - started:.4f}', flush=True)
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--starts', type=int, default=10)
    parser.add_argument('--settle', type=float, default=1.0,
                        help='seconds between rclpy.init and create_publisher')
    parser.add_argument('--domain', type=int, default=int(os.environ.get('ROS_DOMAIN_ID', 78)))
    args = parser.parse_args()
    env = environment(args.domain)
    os.environ.update({k: env[k] for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE',
                                           'FASTDDS_DEFAULT_PROFILES_FILE')})
    load = os.getloadavg()[0]
    subscriber = FirstSample()
    created, matched = [], []
    try:
        for _ in range(args.starts):
            run = subprocess.run([sys.executable, '-c', CHILD, str(args.settle)], env=env,
                                 capture_output=True, text=True, timeout=60)
            line = [x for x in run.stdout.splitlines() if x.startswith('MATCH ')]
            if line:
                create_s, match_s = map(float, line[0].split()[1:])
                created.append(create_s)
                matched.append(match_s)
    finally:
        subscriber.close()
    command = ' '.join(['.venv/bin/python', 'bench/endpoint_match.py'] + sys.argv[1:])
    print(f'`{command}` ({datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, '
          f'load average {load:.2f}, {len(matched)} starts)\n')
    print('| From `create_publisher` [ms] | p50 | max |\n|---|---:|---:|')
    for name, values in (('call returned', created), ('subscriber matched', matched)):
        print(f'| {name} | {1e3 * statistics.median(values):.1f} | {1e3 * max(values):.1f} |')


if __name__ == '__main__':
    main()
