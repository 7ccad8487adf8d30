"""Kill -9 the recording node at random instants: is every directory readable, what is lost.

Run (the tables in ``bench/results/crash_recording.md``)::

    .venv/bin/python bench/crash_recording.py --kills 20 --trace-kills 5 --big-gib 1

Each **recording kill** starts the node (``qfa_ros.cli.node``, ``recorder.enabled: true``,
every other parameter at its default but ``recorder.max_duration_s``, which alternates
between 600 s and 2 s so that some kills come after splits) in a fresh ``output_dir``,
waits for its first sample, lets it run a random 2-12 s and sends SIGKILL. A witness in
this process subscribes to ``imu/data_raw`` **reliable, keep last 5000** (deep and
reliable so that it holds every sample the node published even while this process is
slow; a best-effort depth-5 subscriber drops samples of its own) and notes when each
arrived. Then the directory is opened as it is with ``rosbags`` (``AnyReader``), recovered
(``qfa-report recover DIR`` for odd kills, the next node start for even ones: a node with
the recorder off started on the same ``output_dir`` until its WARN line), and read back
by ``AnyReader`` and the mcap seeking reader with CRCs (``test/crash_helpers.read_bag``).
The loss is judged against the witness (``crash_helpers.loss``): samples it received and
the bag lacks; whether any sample received one second or more before the kill is missing
(the bound of issue 35: it had been published by then); how far before the kill the loss
reaches: at least from the receipt of the first missing sample, at most from its stamp
(the node publishes a sample at its stamp or later; a node running behind its clock on a
busy machine widens the gap); and from the last sample in the bag to the kill (the loss
plus any time the node published nothing).

Each **trace kill** starts the node with the recorder on and a short fast schedule, calls
``capture_reference``, stops the node (SIGSTOP) the moment the trace's ``.part`` appears,
lets it run in 2 ms slices until the part holds a random 0-16 kB (a finished trace: ~17 kB)
and kills it: a kill at a random point of the trace's writing, whatever the load.
``qfa-report recover OUTPUT_DIR`` then finishes trace and recording.

**Recovery at start of a big part** (``--big-gib``): a killed recording of that size is
left in ``output_dir`` and a node started on it. The part is a real killed recording's
(60 s of IMU samples at 1 kHz, a chunk every 0.25 s as the node writes them) chunks
repeated until the size is reached: the recovery's work depends on the bytes, chunks and
messages, not on their times, and writing 1 GiB message by message takes the mcap writer
about 20 minutes here. Measured: the time to its first sample (a SensorDataQoS
subscriber), the samples that subscriber lost while the recovery ran, and when the WARN
line came, against the same start without the leftover; then the CPU and wall time of
``qfa-report recover`` on a copy.

**Recording cost** (``--cost-seconds``): the recording thread's work for a 1 kHz stream,
with the crash safety (a chunk and an fsync every 0.25 s) and without (768 KiB chunks,
no fsync before the file is finished), alternately: CPU, file size, fsync wall times. The
node-level cost (CPU, first sample, the 1 kHz grid) is ``bench/node_rate.py`` and
``bench/first_sample.py`` with ``--tree`` (the commit before, beside this one).

A power cut cannot be simulated here: see
``docs/node.md`` (*Flight recorder*) for what is durable when.
"""

import argparse
import datetime
import os
from pathlib import Path
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from crash_helpers import (  # noqa: E402
    killed_recording,
    loss,
    LOSS_BOUND_S,
    part_reached,
    read_bag,
    run_stopped,
    stop_when,
)
from node_helpers import NodeProcess  # noqa: E402

from qfa_ros.bag.recovery import unfinished_recordings, unfinished_traces  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / 'bench' / 'results' / 'crash_recording.md'
SHORT_SCHEDULE = {'estimation.realtime': False, 'estimation.forward.points': 3,
                  'estimation.forward.average_s': 0.1, 'estimation.feedback.average_s': 0.3}
WARN_RE = re.compile(r'^\[WARN\] \[(\d+\.\d+)\] \[qfa_node\]: recovered ')


class Witness:
    """Subscribers of ``imu/data_raw`` in this process, spun by a thread of their own."""

    def __init__(self, domain):
        self._context = Context()
        rclpy.init(context=self._context, domain_id=domain)
        self.node = rclpy.create_node('crash_witness', context=self._context)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self.node)
        self.lock = threading.Lock()
        self.received = []  # reliable, keep last 5000: (stamp, receive time) [ns]
        self.sensor = []  # SensorDataQoS (best effort, keep last 5): stamps [ns]
        self.node.create_subscription(Imu, 'imu/data_raw', self._reliable, QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=5000,
            reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(Imu, 'imu/data_raw', self._sensor,
                                      qos_profile_sensor_data)
        self._running = True
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while self._running:
            self._executor.spin_once(timeout_sec=0.05)

    @staticmethod
    def _stamp(message):
        return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec

    def _reliable(self, message):
        with self.lock:
            self.received.append((self._stamp(message), time.time_ns()))

    def _sensor(self, message):
        with self.lock:
            self.sensor.append((self._stamp(message), time.time_ns()))

    def take(self):
        """Return and forget ``(received, sensor)`` so far."""
        with self.lock:
            taken = self.received, self.sensor
            self.received, self.sensor = [], []
        return taken

    def wait_first(self, after_ns, timeout_s):
        """
        Return when the first sample stamped after ``after_ns`` arrived [ns, system clock].

        Samples stamped earlier (a previous node's, still in flight) are dropped.
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                self.received = [r for r in self.received if r[0] >= after_ns]
                self.sensor = [r for r in self.sensor if r[0] >= after_ns]
                if self.received:
                    return self.received[0][1]
            time.sleep(0.01)
        raise TimeoutError('no sample from the node')

    def call(self, name):
        """Call a Trigger service without waiting for its answer."""
        client = self.node.create_client(Trigger, name)
        if not client.wait_for_service(timeout_sec=60.0):
            raise TimeoutError(f'no service {name}')
        return client.call_async(Trigger.Request())

    def close(self):
        self._running = False
        self._thread.join()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self._context)


def as_it_is(bag):
    """Return how ``AnyReader`` fares with the directory as the kill left it."""
    try:
        with AnyReader([bag]) as reader:
            return f'yes, {sum(1 for _ in reader.messages())} messages'
    except Exception as error:  # rosbags refuses in several ways: say which
        return f'no ({type(error).__name__})'


def qfa_report_recover(path):
    """Run ``qfa-report recover PATH``; return (wall s, CPU s, exit status)."""
    started = time.perf_counter()
    before = os.times()
    result = subprocess.run([sys.executable, '-m', 'qfa_ros.cli.report', 'recover', str(path)],
                            capture_output=True, text=True, cwd=ROOT, timeout=3600)
    after = os.times()
    cpu = after.children_user - before.children_user + after.children_system \
        - before.children_system
    return time.perf_counter() - started, cpu, result.returncode


def recover_by_start(domain, directory, parameters, timeout_s=300.0):
    """Start a node (recorder off) on ``output_dir``; return s from Popen to its WARN line."""
    started = time.time()
    node = NodeProcess(domain, directory, {**parameters, 'recorder.enabled': False})
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            match = next((WARN_RE.match(line) for line in node.log().splitlines()
                          if WARN_RE.match(line)), None)
            if match:
                return float(match.group(1)) - started
            time.sleep(0.05)
        raise TimeoutError('no recovery WARN line from the node:\n' + node.log())
    finally:
        node.stop(signal.SIGINT, timeout=60)


def recording_kill(index, domain, witness, scratch, rng):
    """One kill while recording; return its row."""
    output = scratch / f'kill_{index}'
    split_s = 600.0 if index % 2 else 2.0
    parameters = {'output_dir': str(output), 'state_file': str(output / 'state.json'),
                  'recorder.enabled': True, 'recorder.max_duration_s': split_s}
    witness.take()
    started_ns = time.time_ns()
    node = NodeProcess(domain, output / 'node', parameters)
    try:
        first_ns = witness.wait_first(started_ns, 300.0)
        time.sleep(rng.uniform(2.0, 12.0))
        kill_ns = time.time_ns()
        os.kill(node.pid, signal.SIGKILL)
        node.wait(30)
    finally:
        node.stop(signal.SIGKILL)
    received, _ = witness.take()
    bag, = unfinished_recordings(output / 'recordings', 'qfa_node')
    row = {'kill': index + 1, 'split_s': split_s, 'after_s': (kill_ns - first_ns) / 1e9,
           'as_it_is': as_it_is(bag)}
    if index % 2:
        row['by'] = 'qfa-report recover'
        row['recovery_s'], _, status = qfa_report_recover(bag)
        assert status == 0, f'qfa-report recover exited {status}'
    else:
        row['by'] = 'next node start'
        row['recovery_s'] = recover_by_start(domain, output / 'restart', parameters)
    contents = read_bag(bag)
    row.update(files=contents.files, messages=sum(contents.counts.values()),
               imu=len(contents.imu_stamps), loss=loss(contents.imu_stamps, received, kill_ns))
    return row


def trace_kill(index, domain, witness, scratch, rng):
    """One kill while the node writes a schedule's trace; return its row."""
    output = scratch / f'trace_{index}'
    traces = output / 'traces'
    witness.take()
    started_ns = time.time_ns()
    node = NodeProcess(domain, output / 'node', {
        'output_dir': str(output), 'state_file': str(output / 'state.json'),
        'recorder.enabled': True, **SHORT_SCHEDULE})
    try:
        witness.wait_first(started_ns, 300.0)
        time.sleep(rng.uniform(1.0, 3.0))
        witness.call('/qfa_node/capture_reference')
        stopped_ns = stop_when(node.process, lambda: unfinished_traces(traces), 300.0)
        assert stopped_ns, 'the trace never appeared:\n' + node.log()
        target = int(rng.uniform(0, 16_000))
        stopped_ns = run_stopped(node.process, stopped_ns, part_reached(traces, target))
        part = unfinished_traces(traces)
        written = part[0].stat().st_size if part else None
        os.kill(node.pid, signal.SIGKILL)
        node.wait(30)
    finally:
        node.stop(signal.SIGKILL)
    received, _ = witness.take()
    wall, _, status = qfa_report_recover(output)
    assert status == 0, f'qfa-report recover exited {status}'
    trace, = traces.glob('*.mcap')
    bag, = (output / 'recordings').iterdir()
    contents = read_bag(bag)
    return {'kill': index + 1, 'target': target, 'written': written, 'trace_part': bool(part),
            'trace_topics': len(read_bag(trace).counts), 'recovery_s': wall,
            'files': contents.files, 'messages': sum(contents.counts.values()),
            'loss': loss(contents.imu_stamps, received, stopped_ns)}


def grow_part(part, size):
    """Repeat the chunks of ``part`` until it is ``size`` bytes; return how many times."""
    data = part.read_bytes()
    header_end = 8 + 9 + int.from_bytes(data[9:17], 'little')
    chunks = data[header_end:]
    copies = max(1, -(-(size - header_end) // len(chunks)))
    with open(part, 'ab') as stream:
        for _ in range(copies - 1):
            stream.write(chunks)
    return copies


def lost_sensor(stamps_ns, rate=1000.0):
    """Return samples missing between the first and last stamp a subscriber received."""
    stamps = np.unique(np.array(stamps_ns, dtype=np.int64))
    if len(stamps) < 2:
        return 0
    return int(round((stamps[-1] - stamps[0]) * rate / 1e9)) + 1 - len(stamps)


def big_start(domain, witness, scratch, gib, seconds):
    """Start the node with and without a ``gib`` GiB killed recording left; return rows."""
    output = scratch / 'big'
    recordings = output / 'recordings'
    recordings.mkdir(parents=True)
    started = time.perf_counter()
    bag = killed_recording(recordings, 60_000, split_s=86400.0)
    part, = bag.glob('*.part')
    messages = grow_part(part, int(gib * (1 << 30))) * 60_000
    made_s = time.perf_counter() - started
    size = part.stat().st_size
    copy = scratch / 'big_copy' / bag.name
    shutil.copytree(bag, copy)
    rows = []
    for leftover in (False, True, False, True):
        directory = output if leftover else scratch / 'empty'
        parameters = {'output_dir': str(directory), 'state_file': str(scratch / 'state.json')}
        witness.take()
        started = time.time()
        node = NodeProcess(domain, scratch / 'big_node', parameters)
        try:
            first_ns = witness.wait_first(int(started * 1e9), 600.0)
            time.sleep(seconds)
            deadline = time.monotonic() + 1800.0
            while True:
                warn = next((float(m.group(1)) - started for m in map(
                    WARN_RE.match, node.log().splitlines()) if m), None)
                if not leftover or warn is not None:
                    break
                if time.monotonic() > deadline:
                    raise RuntimeError('no recovery WARN line:\n' + node.log())
                time.sleep(0.5)
        finally:
            node.stop(signal.SIGINT, timeout=120)
        _, sensor = witness.take()
        window = [stamp for stamp, arrived in sensor if arrived <= first_ns + seconds * 1e9]
        rows.append({'leftover': leftover, 'first_s': first_ns / 1e9 - started,
                     'warn_s': warn, 'lost': lost_sensor(window), 'received': len(window)})
        if leftover and len(rows) < 4:
            # The recovered part for the next round: the pristine copy again.
            shutil.rmtree(bag)
            shutil.copytree(copy, bag)
    wall, cpu, status = qfa_report_recover(copy)
    assert status == 0
    return rows, {'gib': size / (1 << 30), 'messages': messages, 'made_s': made_s,
                  'cli_wall_s': wall, 'cli_cpu_s': cpu}


def recording_cost(scratch, seconds, rounds, rate=1000.0):
    """
    CPU of the recording thread's work with and without the crash safety, alternately.

    ``seconds`` of a 1 kHz Imu stream are recorded in runs of ``RECORD_PERIOD_S`` as the
    node's recording thread does: *crash-safe* ends the chunk and fsyncs the ``.part`` after
    every run (``StreamRecording.checkpoint``), *before* lets chunks fill to 768 KiB and
    never fsyncs until the file is finished. Returns ``{variant: [(CPU s, wall s, bytes,
    fsync wall times)]}``.
    """
    from qfa_ros.bag.flight_recorder import FlightRecorder
    from qfa_ros.bag.imu_cdr import ImuEncoder
    from qfa_ros.bag.part_files import make_durable
    from qfa_ros.ros.pacing import RECORD_PERIOD_S

    encoder = ImuEncoder('imu_link', [1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6])
    rng = np.random.default_rng(1)
    batch = int(rate * RECORD_PERIOD_S)
    start = 1_767_225_600_000_000_000
    batches = []
    for first in range(0, int(seconds * rate), batch):
        stamps = start + int(1e9 / rate) * np.arange(first, first + batch, dtype=np.int64)
        accel = rng.normal([0.0, 0.0, 9.81], 1e-4, size=(batch, 3))
        batches.append((encoder.encode(stamps, accel), stamps.tolist()))
    results = {'crash-safe': [], 'before': []}
    for round_ in range(rounds):
        for variant in results:
            directory = scratch / f'cost_{variant}_{round_}'
            directory.mkdir()
            syncs = []
            cpu, wall = time.process_time(), time.perf_counter()
            recorder = FlightRecorder(directory, 'qfa_node')
            for datas, stamps in batches:
                recorder.record_many('/imu/data_raw', 'sensor_msgs/msg/Imu', datas, stamps)
                if variant == 'crash-safe':
                    paths = recorder.flush()
                    synced = time.perf_counter()
                    make_durable(paths)
                    syncs.append(time.perf_counter() - synced)
            recorder.close()
            cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
            size = sum(path.stat().st_size for path in recorder.bag_directory.iterdir())
            results[variant].append((cpu, wall, size, syncs))
            shutil.rmtree(directory)
    return results


def cost_lines(cost, seconds):
    lines = [f'**Recording cost** ({seconds:g} s of a 1 kHz Imu stream recorded in runs of '
             f'0.25 s, {len(cost["before"])} rounds alternately; medians):', '',
             '| variant | CPU per stream second [ms] | file [bytes per sample] | fsync wall '
             'median / p99 / max [ms] |', '|---|---:|---:|---:|']
    for variant, runs in cost.items():
        cpu = statistics.median(run[0] for run in runs) / seconds * 1e3
        size = statistics.median(run[2] for run in runs) / (seconds * 1000)
        syncs = np.array([s for run in runs for s in run[3]]) * 1e3
        sync = (f'{np.median(syncs):.2f} / {np.percentile(syncs, 99):.2f} / {syncs.max():.2f}'
                if len(syncs) else 'none')
        lines.append(f'| {variant} | {cpu:.2f} | {size:.1f} | {sync} |')
    ratio = statistics.median(r[0] for r in cost['crash-safe']) / statistics.median(
        r[0] for r in cost['before'])
    lines += ['', f'CPU crash-safe ÷ before: {ratio:.2f}.']
    return lines


def loss_cells(judged):
    return (f'{judged.witnessed} | {judged.missing} | {judged.missing_before_bound} | '
            f'{judged.reach_receipt_s:.3f} – {judged.reach_s:.3f} | {judged.last_s:.3f}')


def report(rows, traces, big, cost, args, load_before, load_after):
    command = ' '.join(['.venv/bin/python', 'bench/crash_recording.py', *sys.argv[1:]])
    lines = [f'### {len(rows)} kills while recording, {len(traces)} while writing a trace, '
             f'{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC', '',
             f'`{command}` ({os.cpu_count()} cores; load average {load_before:.1f} before, '
             f'{load_after:.1f} after; seed {args.seed})', '',
             '| kill | split [s] | killed after first sample [s] | as it is (`AnyReader`) | '
             'recovered by | recovery [s] | files | messages in bag | IMU in bag | witnessed '
             f'(≥ {LOSS_BOUND_S:g} s before kill) | lost of them | lost ≥ {LOSS_BOUND_S:g} s '
             'before kill | loss reaches back [s] (by receipt – by stamp) | last sample → kill '
             '[s] |',
             '|---:|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    for row in rows:
        lines.append(f'| {row["kill"]} | {row["split_s"]:g} | {row["after_s"]:.2f} | '
                     f'{row["as_it_is"]} | {row["by"]} | {row["recovery_s"]:.2f} | '
                     f'{row["files"]} | {row["messages"]} | {row["imu"]} | '
                     f'{loss_cells(row["loss"])} |')
    lines += ['', '| trace kill | killed once the .part held [bytes] | .part at the kill '
              '[bytes] (none: finished) | trace topics recovered (of 6) | '
              '`qfa-report recover` [s] '
              '| recording files | messages | witnessed | lost of them | lost ≥ 1 s before '
              'kill | loss reaches back [s] (by receipt – by stamp) | last sample → kill [s] |',
              '|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    for row in traces:
        written = 'none' if row['written'] is None else row['written']
        lines.append(f'| {row["kill"]} | {row["target"]} | {written}'
                     f' | {row["trace_topics"]} | {row["recovery_s"]:.2f} | {row["files"]} | '
                     f'{row["messages"]} | {loss_cells(row["loss"])} |')
    everything = [row['loss'] for row in rows + traces]
    if everything:
        reach = [judged.reach_s for judged in everything]
        receipt = [judged.reach_receipt_s for judged in everything]
        missing = [judged.missing for judged in everything]
        last = [judged.last_s for row, judged in zip(rows, everything)]
        lines += ['', f'Every directory and trace read back by `AnyReader` and the mcap seeking '
                  f'reader after recovery: {len(everything)} of {len(everything)}. Samples lost '
                  f'≥ {LOSS_BOUND_S:g} s before the kill: '
                  f'{sum(j.missing_before_bound for j in everything)}. Loss per kill: median '
                  f'{statistics.median(missing):g} samples reaching back '
                  f'{statistics.median(receipt):.3f} s by receipt, '
                  f'{statistics.median(reach):.3f} s by stamp; worst {max(missing)} samples, '
                  f'{max(receipt):.3f} s by receipt, {max(reach):.3f} s by stamp. Last recorded '
                  f'sample to the kill (recording kills): median '
                  f'{statistics.median(last):.3f} s, worst {max(last):.3f} s.']
    if big:
        starts, made = big
        lines += ['', f'**Recovery at start** of a {made["gib"]:.2f} GiB `.part` '
                  f'({made["messages"]} IMU samples, written in {made["made_s"]:.0f} s): '
                  f'`qfa-report recover` on a copy took {made["cli_wall_s"]:.1f} s wall, '
                  f'{made["cli_cpu_s"]:.1f} s CPU. Node starts, alternately without and with '
                  f'the leftover, a SensorDataQoS subscriber over the first {args.window:g} s:',
                  '', '| start | leftover | first sample [s after Popen] | recovery WARN '
                  '[s after Popen] | received | lost (best effort, depth 5) |',
                  '|---:|---|---:|---:|---:|---:|']
        for number, row in enumerate(starts, 1):
            warn = '' if row['warn_s'] is None else f'{row["warn_s"]:.1f}'
            leftover = f'{made["gib"]:.2f} GiB part' if row['leftover'] else 'none'
            lines.append(f'| {number} | {leftover} | {row["first_s"]:.2f} | {warn} | '
                         f'{row["received"]} | {row["lost"]} |')
    if cost:
        lines += [''] + cost_lines(cost, args.cost_seconds)
    return '\n'.join(lines) + '\n'


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--kills', type=int, default=20, help='kills while recording')
    parser.add_argument('--trace-kills', type=int, default=5, help='kills during a trace')
    parser.add_argument('--big-gib', type=float, default=1.0,
                        help='size of the killed part a node start recovers (0: skip) [GiB]')
    parser.add_argument('--window', type=float, default=30.0,
                        help='seconds of stream watched after each big start')
    parser.add_argument('--cost-seconds', type=float, default=120.0,
                        help='stream recorded per round of the cost comparison (0: skip) [s]')
    parser.add_argument('--cost-rounds', type=int, default=5)
    parser.add_argument('--seed', type=int, default=35)
    parser.add_argument('--scratch', type=Path, default=None,
                        help='where the recordings go (default: a temporary directory)')
    parser.add_argument('--out', type=Path, default=RESULTS, help='Markdown file to append to')
    args = parser.parse_args()
    # SIGTERM ends the run through the finally blocks: no node is left running.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    low, high = (int(v) for v in os.environ.get('QFA_TEST_DOMAINS', '1-100').split('-'))
    domain = low + os.getpid() % (high - low + 1)
    rng = np.random.default_rng(args.seed)
    load_before = os.getloadavg()[0]
    witness = Witness(domain)
    rows, traces, big, cost = [], [], None, None
    scratch = Path(tempfile.mkdtemp(prefix='crash_recording_', dir=args.scratch))
    try:
        for index in range(args.kills):
            rows.append(recording_kill(index, domain, witness, scratch, rng))
            print(f'kill {index + 1}: {rows[-1]["loss"]}', file=sys.stderr, flush=True)
        for index in range(args.trace_kills):
            traces.append(trace_kill(index, domain, witness, scratch, rng))
            print(f'trace kill {index + 1}: {traces[-1]}', file=sys.stderr, flush=True)
        if args.big_gib:
            big = big_start(domain, witness, scratch, args.big_gib, args.window)
        if args.cost_seconds:
            cost = recording_cost(scratch, args.cost_seconds, args.cost_rounds)
    finally:
        witness.close()
        shutil.rmtree(scratch, ignore_errors=True)
    text = report(rows, traces, big, cost, args, load_before, os.getloadavg()[0])
    print(text)
    with open(args.out, 'a') as stream:
        stream.write('\n' + text)


if __name__ == '__main__':
    main()
