"""Benchmark the node over real DDS: delivery, stamp spacing, latency, CPU and memory.

Each case starts the node in its own process; this process subscribes to
``imu/data_raw`` with a SingleThreadedExecutor and reads the node's CPU time and RSS
from ``/proc/<pid>`` (all threads: the sensor thread, the executor, Fast DDS).

Run: ``.venv/bin/python bench/node_rate.py [--duration 60] [--case RATE:TICK[:rec] ...]
[--soak 600] [--out bench/results/node_rate.md]``. Without ``--case`` it runs the
standard cases: 1 kHz at the default tick rate, the same with the flight recorder on,
2 kHz, and 1 kHz with a 1000 Hz tick. Prints Markdown.
"""

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

from qfa_ros.ros.params import SPECS

ROOT = Path(__file__).resolve().parents[1]
PROFILES_FILE = ROOT / 'config' / 'fastdds_discovery.xml'
CLOCK_TICKS = os.sysconf('SC_CLK_TCK')
PAGE_BYTES = os.sysconf('SC_PAGE_SIZE')
DEFAULT_TICK = SPECS['tick_rate_hz'].default
STANDARD_CASES = (f'1000:{DEFAULT_TICK:g}', f'1000:{DEFAULT_TICK:g}:rec',
                  f'2000:{DEFAULT_TICK:g}', '1000:1000')


def cpu_seconds(pid):
    """Return user + system CPU time of process ``pid`` [s] (all its threads)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def rss_bytes(pid):
    """Return the resident set size of process ``pid`` [bytes]."""
    return int(Path(f'/proc/{pid}/statm').read_text().split()[1]) * PAGE_BYTES


class Receiver:
    """Record the header stamp and the receive time of every sample."""

    def __init__(self, node, depth):
        self.stamps = []
        self.received = []
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
        self.subscription = node.create_subscription(Imu, 'imu/data_raw', self.callback, qos)

    def callback(self, message):
        self.received.append(time.time_ns())
        stamp = message.header.stamp
        self.stamps.append(stamp.sec * 1_000_000_000 + stamp.nanosec)

    def clear(self):
        self.stamps = []
        self.received = []


def spin(executor, seconds, stop=lambda: False):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not stop():
        executor.spin_once(timeout_sec=0.05)


def parse_case(text):
    """Return (rate Hz, tick rate Hz, recorder on) of ``RATE:TICK[:rec]``."""
    parts = text.split(':')
    if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] != 'rec'):
        raise argparse.ArgumentTypeError(f'expected RATE:TICK or RATE:TICK:rec, got {text!r}')
    return float(parts[0]), float(parts[1]), len(parts) == 3


def start_node(domain, directory, rate, tick_rate, recorder, depth):
    parameters = {'sample_rate_hz': rate, 'tick_rate_hz': tick_rate, 'qos.depth': depth,
                  'state_file': str(Path(directory) / 'state.json'),
                  'output_dir': str(directory),
                  'trace_dir': str(Path(directory) / 'traces'),
                  'recorder.enabled': recorder,
                  'recorder.directory': str(Path(directory) / 'recordings')}
    params_file = Path(directory) / 'params.yaml'
    params_file.write_text(json.dumps({'qfa_node': {'ros__parameters': parameters}}))
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILES_FILE))
    return subprocess.Popen([sys.executable, '-m', 'qfa_ros.cli.node', '--ros-args',
                             '--params-file', str(params_file)], env=env, cwd=ROOT)


def summarize(receiver, rate, cpu, wall):
    stamps = np.asarray(receiver.stamps, dtype=np.int64)
    received = np.asarray(receiver.received, dtype=np.int64)
    period = 1e9 / rate
    expected = int(round((stamps[-1] - stamps[0]) / period)) + 1
    unique = len(np.unique(stamps))
    spacing = np.diff(stamps)
    arrival = np.diff(received) / 1e6
    latency = (received - stamps) / 1e6
    return {
        'received': len(stamps), 'expected': expected, 'dropped': expected - unique,
        'duplicates': len(stamps) - unique,
        'spacing error max [us]': float(np.max(np.abs(spacing - period)) / 1e3),
        'inter-arrival mean [ms]': float(arrival.mean()),
        'inter-arrival std [ms]': float(arrival.std()),
        'inter-arrival p99 [ms]': float(np.percentile(arrival, 99)),
        'latency median [ms]': float(np.median(latency)),
        'latency p99 [ms]': float(np.percentile(latency, 99)),
        'node CPU [% of one core]': 100.0 * cpu / wall,
    }


class Bench:
    """A subscriber node in its own context on ``domain`` (one per case: no stale samples)."""

    def __init__(self, depth, domain):
        self.domain = domain
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain)
        self.node = Node('qfa_bench', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.receiver = Receiver(self.node, depth)
        self.depth = depth

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def run_case(self, case, args):
        """Measure one case; return (result dict, first-sample delay [s], exit status)."""
        rate, tick_rate, recorder = case
        receiver = self.receiver
        receiver.clear()
        with tempfile.TemporaryDirectory() as directory:
            process = start_node(self.domain, directory, rate, tick_rate, recorder, self.depth)
            try:
                started = time.monotonic()
                spin(self.executor, 60.0, lambda: receiver.stamps)
                if not receiver.stamps:
                    raise RuntimeError('no sample within 60 s')
                first_sample_s = time.monotonic() - started
                spin(self.executor, args.warmup)
                rss_start = rss_bytes(process.pid)
                receiver.clear()
                cpu_start, wall_start = cpu_seconds(process.pid), time.monotonic()
                spin(self.executor, args.duration)
                cpu = cpu_seconds(process.pid) - cpu_start
                wall = time.monotonic() - wall_start
                rss_end = rss_bytes(process.pid)
                result = summarize(receiver, rate, cpu, wall)
                result['RSS [MB]'] = rss_end / 1e6
                result['RSS change over the window [MB]'] = (rss_end - rss_start) / 1e6
                soak = self.soak(process, rate, args.soak) if args.soak else None
            finally:
                process.send_signal(signal.SIGTERM)
                status = process.wait(30)
                receiver.clear()
        return result, first_sample_s, status, soak

    def soak(self, process, rate, seconds):
        """Return the soak table rows: RSS over ``seconds`` and the samples lost."""
        receiver = self.receiver
        receiver.clear()
        samples = [(0.0, rss_bytes(process.pid), 0)]
        soak_start = time.monotonic()
        cpu_start = cpu_seconds(process.pid)
        while time.monotonic() - soak_start < seconds:
            spin(self.executor, min(30.0, seconds - (time.monotonic() - soak_start)))
            lost = 0
            stamps = receiver.stamps
            if len(stamps) > 2:
                gaps = np.diff(np.asarray(stamps, dtype=np.int64))
                lost = int(np.sum(np.round(gaps * rate / 1e9)) - len(gaps))
                # Keep the receiver's own memory flat over a long soak.
                receiver.stamps = stamps[-1:]
                receiver.received = receiver.received[-1:]
            samples.append((time.monotonic() - soak_start, rss_bytes(process.pid), lost))
        cpu = cpu_seconds(process.pid) - cpu_start
        wall = time.monotonic() - soak_start
        lines = [f'### Soak: {wall:.0f} s at {rate:g} Hz\n', '| measure | value |', '|---|---|',
                 f'| RSS at start [MB] | {samples[0][1] / 1e6:.1f} |',
                 f'| RSS at end [MB] | {samples[-1][1] / 1e6:.1f} |',
                 f'| RSS growth [MB] | {(samples[-1][1] - samples[0][1]) / 1e6:.2f} |',
                 f'| samples dropped | {sum(s[2] for s in samples)} |',
                 f'| node CPU [% of one core] | {100.0 * cpu / wall:.1f} |']
        trend = ', '.join(f'{t:.0f} s: {r / 1e6:.1f}' for t, r, _ in samples)
        return '\n'.join(lines) + f'\n\nRSS [MB] over time: {trend}\n'


def case_label(case):
    rate, tick_rate, recorder = case
    return f'{rate:g} Hz, tick {tick_rate:g} Hz' + (', recorder on' if recorder else '')


def run(args):
    cases = args.case or [parse_case(text) for text in STANDARD_CASES]
    results, notes, soaks = [], [], []
    for index, case in enumerate(cases):
        bench = Bench(args.depth, 1 + (os.getpid() + index) % 100)
        try:
            result, first_sample_s, status, soak = bench.run_case(case, args)
        finally:
            bench.close()
        results.append(result)
        notes.append(f'{case_label(case)}: first sample {first_sample_s:.2f} s after the '
                     f'process started; exit status {status} after SIGTERM')
        if soak:
            soaks.append(soak)
    lines = [f'### {args.duration:g} s windows (after {args.warmup:g} s of warm-up)\n',
             '| measure | ' + ' | '.join(case_label(c) for c in cases) + ' |',
             '|---|' + '---|' * len(cases)]
    for key in results[0]:
        cells = [f'{r[key]:.3f}' if isinstance(r[key], float) else str(r[key]) for r in results]
        lines.append(f'| {key} | ' + ' | '.join(cells) + ' |')
    lines.append('')
    lines += [f'- {note}' for note in notes]
    lines.append('')
    return '\n'.join(lines + soaks)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=60.0, help='window per case [s]')
    parser.add_argument('--case', type=parse_case, action='append',
                        help='RATE:TICK or RATE:TICK:rec (repeatable; default: the standard '
                             f'cases {", ".join(STANDARD_CASES)})')
    parser.add_argument('--depth', type=int, default=1000, help='history depth both sides')
    parser.add_argument('--warmup', type=float, default=2.0, help='seconds before the window')
    parser.add_argument('--soak', type=float, default=0.0,
                        help='after each case window, soak this long [s] and report RSS growth')
    parser.add_argument('--out', type=Path, default=None, help='append the Markdown here')
    args = parser.parse_args()
    text = run(args)
    print(text)
    if args.out:
        with open(args.out, 'a') as stream:
            stream.write(text + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
