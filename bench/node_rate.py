"""Benchmark the node's delivery over real DDS against a bare paced publisher, side by side.

Every case starts a publisher in its own process: either the node (``qfa_ros.cli.node``)
or the *floor*, a bare Python thread that sleeps until each sample instant and publishes a
pre-serialized ``Imu`` (what a Python node can reach at best). Two subscriber processes,
started before it, subscribe to ``imu/data_raw`` as INS stacks and ``ros2 topic hz`` do
(best effort, keep last 5: ``qos_profile_sensor_data``) and as a careful consumer would
(reliable, keep last 10); this process reads the publisher's CPU time from
``/proc/<pid>/stat`` (all threads). Each subscriber has a process of its own, as a real
consumer has: both in one Python process (one GIL, 4 000 callbacks/s at 2 kHz) made that
process the loser on two cores, and the floor itself lost samples at 2 kHz.

Reported per case: samples lost per subscriber (stamps missing between the first and the
last received), latency (receive time - stamp) p50 / p99 / max, the publisher's CPU and
its ratio to the floor's CPU at the same rate, and for the node the lateness of the first
``--startup-samples`` samples after it starts (receive time - stamp).

Before the cases, a *machine probe* measures what no publisher can help: one bare Python
thread per CPU (no ROS), pinned to it, sleeps until each instant at the highest rate and
records how late it woke. A best-effort depth-5 subscriber holds 5 / rate seconds of
samples (2.5 ms at 2 kHz); one frozen longer than that loses samples whoever publishes.
The same probes run beside every case at 500 Hz, and a loss within 5 ms of one of their
stalls is counted as the machine's ("lost (of them at a machine freeze)"). On the
development VM the stalls are the kernel's DAMON thread (``kdamond``), which holds one
CPU for ~4 ms every ~5.1 s (seen with ``perf sched``).

Run (quiet machine, full length; then a 10-minute soak of the node, recorder on, for its memory):
``python bench/node_rate.py --window 60 --soak 600 --out bench/results/node_rate.md``;
a quick check: ``python bench/node_rate.py --window 5``. ``--param NAME=VALUE`` passes node
parameters (e.g. ``stream.batch_s=0.02``). ``--tree LABEL=DIR`` runs another source tree's
node (an export of an earlier commit, with its numba cache warmed by ``python -m
qfa_ros.cli.warm_cache`` in it) beside this one's, case after case, and ``--repeat N`` runs
N rounds: a last table then gives each case's medians side by side (a before/after
comparison in one run). Prints Markdown.
"""

import argparse
import datetime
import json
import os
from pathlib import Path
import platform
import select
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Imu
import yaml

ROOT = Path(__file__).resolve().parents[1]
PROFILES_FILE = ROOT / 'config' / 'fastdds_discovery.xml'
CLOCK_TICKS = os.sysconf('SC_CLK_TCK')
PAGE_BYTES = os.sysconf('SC_PAGE_SIZE')
NS_PER_S = 1_000_000_000
STAMP = struct.Struct('<iI')
"""``header.stamp`` (sec, nanosec) right after the 4-byte CDR encapsulation header."""

SUBSCRIBERS = {
    'best effort, depth 5': qos_profile_sensor_data,
    'reliable, depth 10': QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                     reliability=ReliabilityPolicy.RELIABLE),
}


def cpu_seconds(pid):
    """Return user + system CPU time of process ``pid`` [s] (all its threads)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def rss_bytes(pid):
    """Return the resident set size of process ``pid`` [bytes]."""
    return int(Path(f'/proc/{pid}/statm').read_text().split()[1]) * PAGE_BYTES


def environment(domain):
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                FASTDDS_DEFAULT_PROFILES_FILE=str(PROFILES_FILE), PYTHONUNBUFFERED='1')


# The floor: a bare paced publisher in its own process -------------------------------------
def run_floor(rate):
    """Publish pre-serialized Imu samples at ``rate`` Hz, each at its instant, until SIGTERM."""
    from qfa_ros.bag.imu_cdr import ImuEncoder
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    rclpy.init()
    node = Node('qfa_floor')
    publisher = node.create_publisher(Imu, 'imu/data_raw', QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE))
    encoder = ImuEncoder('imu_link', [1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6])
    period = NS_PER_S / rate
    start = time.time_ns()
    index = 0
    while not stop.is_set():
        # Serialize a second ahead (as cheap as the node's batch encoding), then pace.
        stamps = start + (np.arange(index, index + int(rate)) + 1) * period
        messages = encoder.encode(stamps.astype(np.int64), np.zeros((len(stamps), 3)))
        for stamp, data in zip(stamps.astype(np.int64).tolist(), messages):
            remaining = stamp - time.time_ns()
            if remaining > 0:
                time.sleep(remaining / 1e9)
            if stop.is_set():
                break
            publisher.publish(data)
        index += int(rate)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def start_floor(domain, rate):
    return subprocess.Popen([sys.executable, __file__, '--floor', str(rate)],
                            env=environment(domain), cwd=ROOT, stdout=subprocess.DEVNULL)


def start_node(domain, directory, rate, recorder, extra, tree=ROOT):
    parameters = {**extra, 'sample_rate_hz': float(rate),
                  'state_file': str(Path(directory) / 'state.json'),
                  'output_dir': str(directory),
                  'trace_dir': str(Path(directory) / 'traces'),
                  'recorder.enabled': recorder,
                  'recorder.directory': str(Path(directory) / 'recordings')}
    params_file = Path(directory) / 'params.yaml'
    params_file.write_text(json.dumps({'qfa_node': {'ros__parameters': parameters}}))
    # Another source tree's node: its package first on the path (the same interpreter).
    env = environment(domain) if tree == ROOT else dict(environment(domain), PYTHONPATH=str(tree))
    return subprocess.Popen([sys.executable, '-m', 'qfa_ros.cli.node', '--ros-args',
                             '--params-file', str(params_file)], env=env,
                            cwd=tree, stdout=subprocess.DEVNULL)


# The machine probe: how long a CPU is taken away from a waking thread ---------------------
PROBE_DURING_HZ = 500.0
"""Wake-up rate of the probes that run beside each case (cheap, and a 4 ms freeze shows) [Hz]."""

FREEZE_MARGIN_NS = 5_000_000
"""A loss this close to a probe's stall counts as the machine's [ns]."""

PROBE_STALL_NS = 1_500_000
"""A wake-up later than this starts a stall of the probe [ns] (the pacing's own p99 is ~0.1 ms)."""


def run_probe(rate, seconds, cpu, out):
    """
    Wake at ``rate`` Hz on CPU ``cpu`` (no ROS) for ``seconds`` or until SIGTERM.

    Saves (instants, lateness) [ns] of every wake-up to ``out``.
    """
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    if hasattr(os, 'sched_setaffinity'):
        os.sched_setaffinity(0, {cpu})
    period = NS_PER_S / rate
    print('up', flush=True)
    instants = (time.time_ns() + NS_PER_S // 10
                + (np.arange(int(rate * seconds)) * period).astype(np.int64))
    lateness = np.empty(len(instants), dtype=np.int64)
    count = 0
    for instant in instants.tolist():
        if stop.is_set():
            break
        remaining = instant - time.time_ns()
        if remaining > 0:
            time.sleep(remaining / 1e9)
        lateness[count] = time.time_ns() - instant
        count += 1
    np.save(out, np.stack([instants[:count], lateness[:count]]))
    return 0


def probe_cpus():
    return sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') \
        else list(range(os.cpu_count()))


def start_probes(directory, rate, seconds):
    """Start one probe process per CPU, wait until each runs; return ``[(process, file)]``."""
    started = []
    for cpu in probe_cpus():
        path = Path(directory) / f'probe{cpu}.npy'
        started.append((subprocess.Popen(
            [sys.executable, __file__, '--probe', str(rate), '--probe-cpu', str(cpu),
             '--probe-out', str(path), '--window', str(seconds)], cwd=ROOT,
            stdout=subprocess.PIPE, text=True), path))
    for process, _ in started:
        # Their start-up (imports) must not fall in the publisher's.
        if not select.select([process.stdout], [], [], 60.0)[0] or \
                process.stdout.readline().strip() != 'up':
            raise RuntimeError('a machine probe did not start within 60 s')
    return started


def stall_starts(lateness):
    """Return the indices of the wake-ups that start a stall (later than PROBE_STALL_NS)."""
    late = lateness > PROBE_STALL_NS
    return np.flatnonzero(late & ~np.r_[False, late[:-1]])


def probe_machine(rate, seconds):
    """Run one probe per CPU at once; return a result row per CPU."""
    with tempfile.TemporaryDirectory() as directory:
        started = start_probes(directory, rate, seconds)
        for process, _ in started:
            process.wait()
        rows = []
        for cpu, (_, path) in zip(probe_cpus(), started):
            instants, lateness = np.load(path)
            starts = stall_starts(lateness)
            long_ones = starts[lateness[starts] > 5 * NS_PER_S / 2000.0]
            intervals = np.diff(instants[long_ones]) / 1e9
            rows.append({'cpu': cpu, 'p99': float(np.percentile(lateness, 99)) / 1e6,
                         'max': float(lateness.max()) / 1e6,
                         'stalls': {r: int(np.count_nonzero(lateness[starts] > 5 * NS_PER_S / r))
                                    for r in (1000.0, 2000.0)},
                         'interval': float(np.median(intervals)) if len(intervals) else None,
                         'count': len(starts)})
    return rows


def probe_table(rows, rate, seconds):
    lines = [f'#### Machine probe: a bare thread per CPU waking at {rate:g} Hz '
             f'for {seconds:g} s\n',
             '| CPU | wake-up late p99 / max [ms] | stalls > 1.5 ms | of them > 2.5 ms '
             '(depth 5 at 2 kHz) | > 5 ms (depth 5 at 1 kHz) | '
             'median interval of those > 2.5 ms [s] |',
             '|---|---|---|---|---|---|']
    for row in rows:
        interval = '' if row['interval'] is None else f'{row["interval"]:.2f}'
        lines.append(f'| {row["cpu"]} | {row["p99"]:.2f} / {row["max"]:.2f} | {row["count"]} | '
                     f'{row["stalls"][2000.0]} | {row["stalls"][1000.0]} | {interval} |')
    return '\n'.join(lines) + '\n'


# The subscribers: each in a process of its own ------------------------------------------------
class Receiver:
    """Record the stamp and the receive time of every sample (raw: no deserialization)."""

    def __init__(self, node, qos):
        self.stamps = []
        self.received = []
        node.create_subscription(Imu, 'imu/data_raw', self.callback, qos, raw=True)

    def callback(self, data):
        self.received.append(time.time_ns())
        sec, nanosec = STAMP.unpack_from(data, 4)
        self.stamps.append(sec * NS_PER_S + nanosec)


def run_subscriber(name, out, startup_samples):
    """
    Subscribe as ``name`` until SIGTERM; then save (stamps, receive times) [ns] to ``out``.

    Prints ``up`` once subscribed and ``ready`` after ``startup_samples`` samples.
    """
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    # rclpy's own handler would shut the context down under the spinning executor.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = Node('qfa_bench')
    try:
        from rclpy.experimental import EventsExecutor
        executor = EventsExecutor()
    except ImportError:
        from rclpy.executors import SingleThreadedExecutor
        executor = SingleThreadedExecutor()
    executor.add_node(node)
    receiver = Receiver(node, SUBSCRIBERS[name])
    print('up', flush=True)
    ready = False
    while not stop.is_set():
        executor.spin_once(timeout_sec=0.05)
        if not ready and len(receiver.stamps) >= startup_samples:
            print('ready', flush=True)
            ready = True
    np.save(out, np.array([receiver.stamps, receiver.received], dtype=np.int64))
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


class Subscribers:
    """One subscriber process per QoS of :data:`SUBSCRIBERS`, on ``domain``."""

    def __init__(self, domain, directory, startup_samples):
        self.files = {name: Path(directory) / f'subscriber{index}.npy'
                      for index, name in enumerate(SUBSCRIBERS)}
        self.processes = {name: subprocess.Popen(
            [sys.executable, __file__, '--subscriber', name, '--subscriber-out', str(path),
             '--startup-samples', str(startup_samples)], env=environment(domain), cwd=ROOT,
            stdout=subprocess.PIPE, text=True) for name, path in self.files.items()}
        for name in SUBSCRIBERS:
            self.wait_for(name, 'up', 60.0)

    def wait_for(self, name, line, timeout):
        """Wait until subscriber ``name`` prints ``line``."""
        stream = self.processes[name].stdout
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if select.select([stream], [], [], 0.5)[0]:
                text = stream.readline()
                if text.strip() == line:
                    return
                if not text:
                    break
        raise RuntimeError(f'subscriber {name!r}: no {line!r} within {timeout:g} s')

    def results(self):
        """Stop the subscribers; return ``{name: (stamps, receive times)}`` [ns]."""
        for process in self.processes.values():
            process.send_signal(signal.SIGTERM)
        for name, process in self.processes.items():
            try:
                process.wait(30)
            except subprocess.TimeoutExpired:
                # Its samples are saved before the middleware teardown, which was seen to
                # hang once under load (two Fast DDS threads): the measurement stands.
                process.kill()
                process.wait()
                print(f'subscriber {name!r} hung after saving; killed', file=sys.stderr)
        return {name: tuple(np.load(path)) for name, path in self.files.items()}

    def kill(self):
        for process in self.processes.values():
            if process.poll() is None:
                process.kill()
                process.wait()


def delivery(stamps, received, rate, freezes=()):
    """
    Return lost samples and latency p50 / p99 / max [ms] of one subscriber's window.

    ``lost_at_freeze`` counts the lost samples of gaps within FREEZE_MARGIN_NS of one of
    the ``freezes`` [ns] the probes saw.
    """
    if len(stamps) < 2:
        return {'received': len(stamps), 'lost': float('nan'), 'lost_at_freeze': 0,
                'p50': float('nan'), 'p99': float('nan'), 'max': float('nan')}
    unique = np.unique(stamps)
    expected = int(round((unique[-1] - unique[0]) * rate / NS_PER_S)) + 1
    missing = np.round(np.diff(unique) * rate / NS_PER_S).astype(np.int64) - 1
    freezes = np.sort(np.asarray(freezes, dtype=np.int64))
    at_freeze = 0
    for gap in np.flatnonzero(missing > 0):
        first = np.searchsorted(freezes, unique[gap] - FREEZE_MARGIN_NS)
        if first < len(freezes) and freezes[first] <= unique[gap + 1] + FREEZE_MARGIN_NS:
            at_freeze += int(missing[gap])
    latency = (received - stamps) / 1e6
    return {'received': len(stamps), 'lost': expected - len(unique), 'lost_at_freeze': at_freeze,
            'p50': float(np.median(latency)), 'p99': float(np.percentile(latency, 99)),
            'max': float(latency.max())}


def run_case(domain, kind, rate, recorder, args, window, tree=('', ROOT)):
    """Measure one case over ``window`` seconds; return its result dict."""
    with tempfile.TemporaryDirectory() as directory:
        # The subscribers exist before the publisher: they see its very first samples.
        subscribers = Subscribers(domain, directory, args.startup_samples)
        # The probes beside the case: which losses fall on a freeze of the machine.
        probes = [] if args.no_probe else start_probes(directory, PROBE_DURING_HZ, 3600.0)
        try:
            started = time.time()
            process = start_floor(domain, rate) if kind == 'floor' \
                else start_node(domain, directory, rate, recorder, args.param, tree[1])
            try:
                subscribers.wait_for('reliable, depth 10', 'ready', 120.0)
                time.sleep(args.warmup)
                rss_start = rss_bytes(process.pid)
                cpu_start, wall_start = cpu_seconds(process.pid), time.monotonic()
                window_start = time.time_ns()
                time.sleep(window)
                cpu = cpu_seconds(process.pid) - cpu_start
                wall = time.monotonic() - wall_start
                window_end = time.time_ns()
                rss_end = rss_bytes(process.pid)
            finally:
                process.send_signal(signal.SIGTERM)
                status = process.wait(30)
            received = subscribers.results()
            freezes = []
            for probe, path in probes:
                probe.send_signal(signal.SIGTERM)
                probe.wait(30)
                instants, lateness = np.load(path)
                freezes += instants[stall_starts(lateness)].tolist()
        finally:
            subscribers.kill()
            for probe, _ in probes:
                if probe.poll() is None:
                    probe.kill()
                    probe.wait()
    stamps, times = received['reliable, depth 10']
    first_s = times[0] / 1e9 - started
    lateness = (times[:args.startup_samples] - stamps[:args.startup_samples]) / 1e6
    windows = {}
    for name, (stamps, times) in received.items():
        inside = (times >= window_start) & (times < window_end)
        windows[name] = (stamps[inside], times[inside])
    return {'kind': kind, 'rate': rate, 'recorder': recorder, 'tree': tree[0],
            'cpu': 100.0 * cpu / wall,
            'window': wall, 'rss': rss_end / 1e6, 'rss_change': (rss_end - rss_start) / 1e6,
            'first_s': first_s, 'startup_p99': float(np.percentile(lateness, 99)),
            'startup_max': float(lateness.max()), 'status': status,
            'freezes': sum(window_start <= f < window_end for f in freezes),
            'delivery': {name: delivery(*window, rate, freezes)
                         for name, window in windows.items()}}


def parse_param(text):
    """Return (name, value) of ``NAME=VALUE`` (the value parsed as YAML)."""
    name, separator, value = text.partition('=')
    if not separator:
        raise argparse.ArgumentTypeError(f'expected NAME=VALUE, got {text!r}')
    return name, yaml.safe_load(value)


def label(result):
    if result['kind'] == 'floor':
        return f'floor {result["rate"]:g} Hz'
    text = f'node {result["rate"]:g} Hz' + (', recorder' if result['recorder'] else '')
    text += f' ({result["tree"]})' if result.get('tree') else ''
    return text + (f', soak {result["window"]:.0f} s' if result.get('soak') else '')


def side_by_side(results, trees):
    """
    Return the medians of the node cases over the rounds, each tree beside this one.

    Every tree's node ran in the same rounds, case after case, so the machine's state
    weighs on each alike; the ratios are of medians.
    """
    labels = ['this tree'] + [label for label, _ in trees]
    lines = ['| case | ' + ' | '.join(
        f'{label}: CPU [% core] / lost depth 5 / lost reliable / p99 [ms]' for label in labels)
        + ' | ' + ' | '.join(f'CPU this ÷ {label}' for label in labels[1:]) + ' |',
        '|---|' + '---|' * (len(labels) * 2 - 1)]
    cases = sorted({(r['rate'], r['recorder']) for r in results if r['kind'] == 'node'
                    and not r.get('soak')})
    for rate, recorder in cases:
        cells, cpu = [], {}
        for label in labels:
            runs = [r for r in results if r['kind'] == 'node' and not r.get('soak')
                    and r['rate'] == rate and r['recorder'] == recorder
                    and (r.get('tree') or 'this tree') == label]
            if not runs:
                cells.append('')
                continue
            cpu[label] = np.median([r['cpu'] for r in runs])
            depth5 = np.median([r['delivery']['best effort, depth 5']['lost'] for r in runs])
            reliable = np.median([r['delivery']['reliable, depth 10']['lost'] for r in runs])
            p99 = np.median([r['delivery']['best effort, depth 5']['p99'] for r in runs])
            cells.append(f'{cpu[label]:.1f} / {depth5:g} / {reliable:g} / {p99:.2f} '
                         f'({len(runs)} runs)')
        ratios = [f'{cpu["this tree"] / cpu[label]:.3f}' if label in cpu and 'this tree' in cpu
                  else '' for label in labels[1:]]
        lines.append(f'| node {rate:g} Hz{", recorder" if recorder else ""} | '
                     + ' | '.join(cells + ratios) + ' |')
    return '\n'.join(lines) + '\n'



def table(results, args):
    """Return the Markdown report of ``results``."""
    floor_cpu = {r['rate']: r['cpu'] for r in results if r['kind'] == 'floor'}
    floor_p99 = {r['rate']: max(d['p99'] for d in r['delivery'].values())
                 for r in results if r['kind'] == 'floor'}
    settings = ', '.join(f'`{k}: {v}`' for k, v in args.param.items()) or 'defaults'
    lines = [f'### {args.window:g} s windows after {args.warmup:g} s ({datetime.date.today()}, '
             f'{os.cpu_count()} cores, Python {platform.python_version()}; node {settings})\n',
             '| case | subscriber | received | lost (of them at a machine freeze) | '
             'latency p50 / p99 / max [ms] | '
             'p99 − floor p99 [ms] | CPU [% core] | CPU ÷ floor | start-up: first '
             f'{args.startup_samples} late p99 / max [ms] | RSS [MB] (change in window) |',
             '|---|---|---|---|---|---|---|---|---|---|']
    for result in results:
        ratio = result['cpu'] / floor_cpu[result['rate']] if result['rate'] in floor_cpu \
            else float('nan')
        for index, (name, d) in enumerate(result['delivery'].items()):
            excess = d['p99'] - floor_p99.get(result['rate'], float('nan'))
            common = (f'{result["cpu"]:.1f} | {ratio:.2f} | '
                      f'{result["startup_p99"]:.2f} / {result["startup_max"]:.2f} | '
                      f'{result["rss"]:.0f} ({result["rss_change"]:+.2f})') \
                if index == 0 else ' | | | '
            lines.append(f'| {label(result) if index == 0 else ""} | {name} | {d["received"]} '
                         f'| {d["lost"]} ({d["lost_at_freeze"]}) | '
                         f'{d["p50"]:.2f} / {d["p99"]:.2f} / {d["max"]:.2f} | '
                         f'{excess:+.2f} | {common} |')
    lines.append('')
    lines += [f'- {label(r)}: first sample {r["first_s"]:.2f} s after the process started; '
              f'exit status {r["status"]} after SIGTERM; the probes saw {r["freezes"]} '
              f'stall(s) > {PROBE_STALL_NS / 1e6:g} ms in the window' for r in results]
    return '\n'.join(lines) + '\n'


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--window', '--duration', type=float, default=60.0,
                        help='measurement window per case [s]')
    parser.add_argument('--rates', type=float, nargs='+', default=[1000.0, 2000.0],
                        help='sample rates [Hz]')
    parser.add_argument('--warmup', type=float, default=2.0,
                        help='seconds between the start-up samples and the window')
    parser.add_argument('--startup-samples', type=int, default=2000,
                        help='first samples whose lateness is reported')
    parser.add_argument('--no-recorder', action='store_true',
                        help='skip the cases with the flight recorder on')
    parser.add_argument('--param', type=parse_param, action='append', default=[],
                        metavar='NAME=VALUE', help='node parameter (YAML value; repeatable)')
    parser.add_argument('--soak', type=float, default=0.0,
                        help='then run the node at the first rate this long, with the recorder '
                        'unless --no-recorder [s] (RSS growth)')
    parser.add_argument('--tree', action='append', default=[], metavar='LABEL=DIR',
                        help="another source tree's node beside this one's, case by case "
                        '(e.g. an export of an earlier commit, its numba cache warmed)')
    parser.add_argument('--repeat', type=int, default=1,
                        help='rounds of every case; the side-by-side table gives medians')
    parser.add_argument('--out', type=Path, default=None, help='append the Markdown here')
    parser.add_argument('--no-probe', action='store_true', help='skip the machine probe')
    parser.add_argument('--floor', type=float, default=None, help=argparse.SUPPRESS)
    parser.add_argument('--probe', type=float, default=None, help=argparse.SUPPRESS)
    parser.add_argument('--probe-cpu', type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument('--probe-out', type=Path, default=None, help=argparse.SUPPRESS)
    parser.add_argument('--subscriber', choices=list(SUBSCRIBERS), default=None,
                        help=argparse.SUPPRESS)
    parser.add_argument('--subscriber-out', type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    args.param = dict(args.param)
    if args.floor is not None:
        return run_floor(args.floor)
    if args.subscriber is not None:
        return run_subscriber(args.subscriber, args.subscriber_out, args.startup_samples)
    if args.probe is not None:
        return run_probe(args.probe, args.window, args.probe_cpu, args.probe_out)
    probe = '' if args.no_probe else probe_table(
        probe_machine(max(args.rates), args.window), max(args.rates), args.window)
    results = []
    # QFA_TEST_DOMAINS=LOW-HIGH confines the ROS domains, as for the tests.
    low, high = (int(v) for v in os.environ.get('QFA_TEST_DOMAINS', '1-100').split('-'))
    domain = low + os.getpid() % (high - low + 1)
    recorders = (False,) if args.no_recorder else (False, True)
    trees = [(spec.rpartition('=')[0] or spec, Path(spec.rpartition('=')[2]).resolve())
             for spec in args.tree]
    for _ in range(args.repeat):
        for rate in args.rates:
            cases = [('floor', False, ('', ROOT))] + [
                ('node', r, tree) for r in recorders for tree in [('', ROOT)] + trees]
            for kind, recorder, tree in cases:
                results.append(run_case(domain, kind, rate, recorder, args, args.window,
                                        tree))
                domain = low + (domain + 1 - low) % (high - low + 1)
                print(f'{label(results[-1])}: done', file=sys.stderr)
    if args.soak:
        # The heaviest case soaks: the recorder's buffers and splits are what could grow.
        results.append(run_case(domain, 'node', args.rates[0], not args.no_recorder, args,
                                args.soak))
        results[-1]['soak'] = True
    text = table(results, args) + ('\n' + probe if probe else '')
    if trees or args.repeat > 1:
        text += '\n' + side_by_side(results, trees)
    print(text)
    if args.out:
        with open(args.out, 'a') as stream:
            stream.write(text + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
