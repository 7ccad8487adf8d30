"""Soak the live node for hours: nothing may drift, grow or get lost (issue 35).

The node is started as a user starts it (``python -m qfa_ros.cli.node --ros-args
--params-file config/qfa.yaml -p ...``; its own process group, its own domain) with the
flight recorder on and splitting (``--split-s``, ``--max-bytes``: both limits reached),
self-calibrations in fast mode (``estimation.realtime: false``). Three other processes
meet it over real DDS:

- this one, a participant that changes a writable parameter every ``--param-every``
  seconds through the node's SetParameters service (rotating over drift, orientation,
  ambient, latitude, frame id, room amplitude), calls ``~/capture_reference`` once and
  ``~/self_calibrate`` every ``--calibrate-every`` seconds, listens to ``/diagnostics``
  (the node's own counters: samples withheld during schedules, skipped, late) and samples
  the node process from ``/proc`` (RSS, descriptors, threads, CPU), the recording and
  the state file every ``--sample-every`` seconds;
- a subscriber process (``--subscriber``) with ``SensorDataQoS`` (best effort, keep last 5)
  that counts every ``imu/data_raw`` sample, its gaps, stamps off the 1 kHz grid and the
  offset of the stamps from its system clock (receive time - stamp).

Everything is written as it happens to CSV files beside ``--out`` (``soak.csv``: node and
disk; ``soak_stream.csv``: the subscriber; ``soak_gaps.csv``: every gap;
``soak_events.csv``: service calls and parameter refusals; ``soak_run.json``: the set-up),
so a soak that dies still leaves its measurements. At the end the node gets SIGTERM and
every recorded file is read back with ``rosbags`` (AnyReader) and the ``mcap`` reader
(``soak_files.csv``); then the report (``--out``, Markdown) and its figure (``soak.png``)
are written from the CSV files alone.

Samples the node withholds on purpose are counted apart: during a schedule the stream is
held (``docs/node.md``, *Estimation schedules*: in fast mode the samples due while the
schedule computes are withheld, the stream resumes on its grid; the ``stream`` diagnostic
counts them as ``samples withheld``). A gap of the subscriber inside a schedule call's
window (request sent to answer received, 0.5 s either side) is a schedule pause; every
other missing sample is a loss.

Run (at least two hours; the lead re-runs it on a quiet machine)::

    .venv/bin/python bench/soak.py --hours 2 --domain 60 --out bench/results/soak.md

A try: ``--minutes 10 --out /tmp/soak/soak.md``. The report again from the CSV files:
``--report --out bench/results/soak.md`` (``--readback`` first reads the recording of
that run again, e.g. after the bench itself died). Memory growth by allocation site:
``--tracemalloc`` (snapshots of the node every ``--snapshot-every`` s via
``bench/soak_hook/sitecustomize.py``; slows the node, so not for slopes), then
``--snapshots DIR`` prints the largest growths between the first snapshot after the
warm-up and the last.
"""

import argparse
import csv
import datetime
import json
import os
from pathlib import Path
import platform
import signal
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROFILES_FILE = ROOT / 'config' / 'fastdds_discovery.xml'
HOOK_DIRECTORY = Path(__file__).resolve().parent / 'soak_hook'
NODE = 'qfa_node'
NS_PER_S = 1_000_000_000
PERIOD_NS = 1_000_000
"""The stream's grid at the default 1 kHz [ns]."""
CLOCK_TICKS = os.sysconf('SC_CLK_TCK')
STAMP = struct.Struct('<iI')
"""``header.stamp`` (sec, nanosec) right after the 4-byte CDR encapsulation header."""
PAUSE_MARGIN_NS = 500_000_000
"""A gap this close to a schedule call's window counts as the schedule's pause [ns]."""
STARVED_PERIODS = 4
"""A subscriber that reads the sample after a gap this many periods after it was sent was
behind: the four sent after it were waiting in its history of 5 too."""
MIB = float(1 << 20)

NODE_COLUMNS = [
    'wall_ns', 't_s', 'rss_kib', 'rss_anon_kib', 'fds', 'threads', 'cpu_s', 'load1',
    'recorded_bytes', 'recorded_files', 'part_bytes', 'largest_file_bytes',
    'metadata_bytes', 'trace_files', 'trace_bytes', 'state_bytes', 'state_readable',
    'state_mtime_ns', 'computed', 'published', 'withheld', 'skipped', 'late',
    'max_delay_ms', 'waiting', 'dropped', 'parameter_changes', 'parameter_refusals',
    'calibrations', 'calibration_failures', 'recorder_problem']
STREAM_COLUMNS = [
    'wall_ns', 'received', 'lost', 'gaps', 'off_grid', 'out_of_order', 'first_stamp_ns',
    'last_stamp_ns', 'offset_min_us', 'offset_p50_us', 'offset_p99_us', 'offset_max_us',
    'interval_received']
GAP_COLUMNS = ['received_ns', 'published_ns', 'before_stamp_ns', 'after_stamp_ns', 'missing']
EVENT_COLUMNS = ['kind', 'name', 'sent_ns', 'answered_ns', 'success', 'message']
FILE_COLUMNS = ['bag', 'file', 'bytes', 'metadata_messages', 'mcap_messages',
                'rosbags_messages', 'imu_messages', 'start_ns', 'end_ns', 'readable']


def parameter_rotation():
    """Return ``(name, value maker)`` of the writable parameters the soak changes in turn."""
    def vector(scale):
        return lambda rng: [float(v) for v in rng.uniform(-scale, scale, 3)]

    def scalar(low, high):
        return lambda rng: float(rng.uniform(low, high))

    return [
        ('drift.forward_ppm', vector(300.0)),
        ('input.roll', scalar(-0.05, 0.05)),
        ('temperature_c', scalar(20.0, 30.0)),
        ('drift.feedback_ppm', vector(300.0)),
        ('input.pitch', scalar(-0.05, 0.05)),
        ('frame_id', lambda rng: str(rng.choice(['imu_link', 'imu_link_soak']))),
        ('input.yaw', scalar(-3.0, 3.0)),
        ('thermal.room_amplitude_c', scalar(0.5, 2.5)),
        ('latitude_deg', scalar(40.0, 50.0)),
    ]


# --- paths -------------------------------------------------------------------------------

class Paths:
    """The files of one soak, beside its report ``out`` (``soak.md``)."""

    def __init__(self, out):
        self.out = Path(out)
        stem = self.out.with_suffix('')
        self.run = Path(f'{stem}_run.json')
        self.node = Path(f'{stem}.csv')
        self.stream = Path(f'{stem}_stream.csv')
        self.gaps = Path(f'{stem}_gaps.csv')
        self.events = Path(f'{stem}_events.csv')
        self.files = Path(f'{stem}_files.csv')
        self.recorded_gaps = Path(f'{stem}_recorded_gaps.csv')
        self.figure = Path(f'{stem}.png')


class CsvLog:
    """Append rows to a CSV file, flushed at once (a soak that dies keeps its rows)."""

    def __init__(self, path, columns):
        self._file = open(path, 'w', newline='')
        self._writer = csv.writer(self._file)
        self._writer.writerow(columns)
        self._file.flush()

    def write(self, row):
        self._writer.writerow(row)
        self._file.flush()

    def close(self):
        self._file.close()


def read_csv(path):
    """Return the rows of a CSV file as dicts of strings ([] if it does not exist)."""
    if not Path(path).exists():
        return []
    with open(path, newline='') as file:
        return list(csv.DictReader(file))


def column(rows, name, dtype=float):
    """Return one column of ``rows`` as an array (empty cells as NaN)."""
    return np.array([dtype(row[name]) if row[name] not in ('', 'None') else np.nan
                     for row in rows], dtype=float)


# --- the subscriber process -------------------------------------------------------------

class StreamCounter:
    """
    Count ``imu/data_raw`` samples from their stamps: gaps, off the grid, out of order.

    :param period_ns: Sample period of the grid [ns].
    """

    def __init__(self, period_ns=PERIOD_NS):
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

    def add(self, stamp_ns, received_ns):
        """Count one sample; return ``(before, after, missing)`` when it ends a gap."""
        self.received += 1
        self.interval_received += 1
        self.offsets_ns.append(received_ns - stamp_ns)
        if self.first is None:
            self.first = self.last = stamp_ns
            return None
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
            return before, stamp_ns, missing
        return None

    def row(self, wall_ns):
        """Return the subscriber's row now and start a new interval of offsets."""
        offsets = np.array(self.offsets_ns, dtype=float) / 1e3
        self.offsets_ns = []
        quantiles = (np.quantile(offsets, [0.0, 0.5, 0.99, 1.0]) if len(offsets)
                     else [np.nan] * 4)
        row = [wall_ns, self.received, self.lost, self.gaps, self.off_grid,
               self.out_of_order, self.first, self.last,
               *(f'{q:.1f}' for q in quantiles), self.interval_received]
        self.interval_received = 0
        return row


def run_subscriber(args):
    """Subscribe with SensorDataQoS until SIGTERM; write rows and gaps (process target)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import Imu

    paths = Paths(args.out)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    context = Context()
    rclpy.init(context=context, domain_id=args.domain,
               signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('qfa_soak_subscriber', context=context)
    counter = StreamCounter(round(NS_PER_S / args.rate))
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


# --- the node process, seen from /proc -------------------------------------------------

def proc_sample(pid):
    """Return ``(rss_kib, rss_anon_kib, fds, threads, cpu_s)`` of process ``pid``."""
    status = {}
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        key, _, value = line.partition(':')
        status[key] = value.split()[0] if value.split() else ''
    fds = len(os.listdir(f'/proc/{pid}/fd'))
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    cpu_s = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS
    return (int(status['VmRSS']), int(status.get('RssAnon', 0)), fds, int(status['Threads']),
            cpu_s)


def disk_sample(output_dir):
    """Return what the node wrote under ``output_dir``: recording, traces, state file."""
    recorded = files = part = largest = metadata = traces = trace_bytes = 0
    for path in (output_dir / 'recordings').rglob('*'):
        if not path.is_file():
            continue
        size = path.stat().st_size
        if path.name.endswith('.mcap'):
            recorded += size
            files += 1
            largest = max(largest, size)
        elif path.name.endswith('.part'):
            part += size
        elif path.name == 'metadata.yaml':
            metadata += size
    for path in (output_dir / 'traces').glob('*.mcap'):
        traces += 1
        trace_bytes += path.stat().st_size
    state = output_dir / 'state.json'
    state_bytes, readable, mtime = 0, 0, 0
    try:
        text = state.read_bytes()
        mtime = state.stat().st_mtime_ns
        state_bytes = len(text)
        json.loads(text)
        readable = 1
    except (OSError, ValueError):
        pass
    return [recorded, files, part, largest, metadata, traces, trace_bytes, state_bytes,
            readable, mtime]


# --- the driver -------------------------------------------------------------------------

def node_environment(domain, tracemalloc_dir=None, snapshot_every=300.0):
    """Return the environment of the node and subscriber processes on ``domain``."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.setdefault('FASTDDS_DEFAULT_PROFILES_FILE', str(PROFILES_FILE))
    env['PYTHONUNBUFFERED'] = '1'
    if tracemalloc_dir:
        env['PYTHONPATH'] = os.pathsep.join(
            [str(HOOK_DIRECTORY)] + [p for p in [env.get('PYTHONPATH')] if p])
        env['QFA_SOAK_TRACEMALLOC'] = str(tracemalloc_dir)
        env['QFA_SOAK_TRACEMALLOC_PERIOD_S'] = str(snapshot_every)
    return env


def node_command(output_dir, args):
    """Return the node's command line: the shipped parameters file and the soak's overrides."""
    overrides = {
        'output_dir': str(output_dir), 'state_file': str(output_dir / 'state.json'),
        'recorder.enabled': 'true', 'recorder.max_duration_s': f'{args.split_s:g}',
        'recorder.max_bytes': str(args.max_bytes), 'estimation.realtime': 'false',
        'min_free_bytes': str(args.min_free_bytes), 'sample_rate_hz': f'{args.rate:.1f}',
        'loop_rate_hz': f'{10 * args.rate:.1f}'}
    command = [sys.executable, '-m', 'qfa_ros.cli.node', '--ros-args', '--params-file',
               str(ROOT / 'config' / 'qfa.yaml')]
    for name, value in overrides.items():
        command += ['-p', f'{name}:={value}']
    return command


def git_commit():
    """Return the work tree's commit (and whether it has changes)."""
    try:
        commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT,
                                capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'],
                               cwd=ROOT, capture_output=True, text=True).stdout.strip()
        return commit + (' (with uncommitted changes)' if dirty else '')
    except OSError:
        return 'unknown'


class Driver:
    """The soak's participant: parameters, calibrations, diagnostics, /proc sampling."""

    def __init__(self, args, paths, node_pid, output_dir):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.args = args
        self.node_pid = node_pid
        self.output_dir = output_dir
        self.context = Context()
        rclpy.init(context=self.context, domain_id=args.domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('qfa_soak_driver', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.rows = CsvLog(paths.node, NODE_COLUMNS)
        self.events = CsvLog(paths.events, EVENT_COLUMNS)
        self.paths = paths
        self.counters = {}
        self.recorder_problem = ''
        self.parameter_changes = self.parameter_refusals = 0
        self.calibrations = self.calibration_failures = 0
        self.pending = None  # (kind, name, sent_ns, future)
        self.rotation = parameter_rotation()
        self.turn = 0
        self.rng = np.random.default_rng(args.seed)
        self.started_ns = time.time_ns()
        self._clients = {}
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.on_diagnostics,
                                      QoSProfile(depth=10))

    def close(self):
        import rclpy
        self.rows.close()
        self.events.close()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def on_diagnostics(self, array):
        for status in array.status:
            if status.name.endswith(': stream'):
                values = {kv.key: kv.value for kv in status.values}
                self.counters = {
                    'computed': values.get('samples computed', ''),
                    'published': values.get('messages published', ''),
                    'withheld': values.get('samples withheld', ''),
                    'skipped': values.get('samples skipped', ''),
                    'late': next((v for k, v in values.items()
                                  if k.startswith('messages published >')), ''),
                    'max_delay_ms': values.get('largest publication delay [ms]', ''),
                    'waiting': values.get('messages waiting for their instant', ''),
                    'dropped': next((v for k, v in values.items()
                                     if k.startswith('messages dropped >')), '')}
                self.recorder_problem = values.get('recorder problem', '')

    def client(self, srv_type, name):
        if name not in self._clients:
            self._clients[name] = self.node.create_client(srv_type, name)
        return self._clients[name]

    def wait_for_samples(self, timeout_s=120.0):
        """Spin until the node's diagnostics say it publishes (first samples out)."""
        deadline = time.monotonic() + timeout_s
        while not (self.counters.get('published') and int(self.counters['published']) > 0):
            if time.monotonic() > deadline:
                raise TimeoutError('the node published nothing within '
                                   f'{timeout_s:.0f} s')
            self.executor.spin_once(timeout_sec=0.1)

    def call(self, kind, name, srv_type, request, service=None):
        """Send a request (the answer is picked up by :meth:`poll`)."""
        client = self.client(srv_type, service or name)
        if not client.service_is_ready():
            return False
        self.pending = (kind, name, time.time_ns(), client.call_async(request), client)
        return True

    def poll(self):
        """Record the answer of the pending call, if it came (or give up on it)."""
        if self.pending is None:
            return
        kind, name, sent, future, client = self.pending
        answered = time.time_ns()
        if not future.done():
            if answered - sent > self.args.call_timeout * NS_PER_S:
                # An answer lost on an overloaded machine must not stop the soak.
                client.remove_pending_request(future)
                self.pending = None
                self.calibration_failures += kind == 'schedule'
                self.events.write([kind, name, sent, answered, 0,
                                   f'no answer within {self.args.call_timeout:g} s'])
            return
        self.pending = None
        response = future.result()
        if kind == 'parameter':
            refused = [r.reason for r in response.results if not r.successful]
            self.parameter_changes += 1
            if refused:
                self.parameter_refusals += 1
                self.events.write([kind, name, sent, answered, 0, '; '.join(refused)[:300]])
            return
        self.calibrations += 1
        if not response.success:
            self.calibration_failures += 1
        self.events.write([kind, name, sent, answered, int(response.success),
                           response.message[:300]])

    def change_parameter(self):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        name, make = self.rotation[self.turn % len(self.rotation)]
        self.turn += 1
        request = SetParameters.Request()
        request.parameters = [Parameter(name, value=make(self.rng)).to_parameter_msg()]
        self.call('parameter', name, SetParameters, request, f'/{NODE}/set_parameters')

    def calibrate(self, service):
        from std_srvs.srv import Trigger
        return self.call('schedule', service, Trigger, Trigger.Request())

    def sample(self):
        """Write one row: the node process, the files it wrote, its counters."""
        now = time.time_ns()
        proc = proc_sample(self.node_pid)
        counters = self.counters
        self.rows.write([
            now, f'{(now - self.started_ns) / 1e9:.1f}', *proc[:4], f'{proc[4]:.2f}',
            f'{os.getloadavg()[0]:.2f}', *disk_sample(self.output_dir),
            *(counters.get(key, '') for key in (
                'computed', 'published', 'withheld', 'skipped', 'late', 'max_delay_ms',
                'waiting', 'dropped')),
            self.parameter_changes, self.parameter_refusals, self.calibrations,
            self.calibration_failures, self.recorder_problem[:200]])
        return proc

    def run(self, duration_s, node_process, stopping):
        """Drive the node for ``duration_s``; return why the soak ended."""
        args = self.args
        start = time.monotonic()
        next_parameter = start + args.param_every
        next_calibration = start + args.calibrate_every
        next_sample = start
        next_progress = start + args.progress_every
        referenced = False
        while True:
            now = time.monotonic()
            if stopping:
                return 'the bench got a stop signal'
            if node_process.poll() is not None:
                return f'the node exited with status {node_process.returncode}'
            if now - start >= duration_s and self.pending is None:
                return 'duration reached'
            self.executor.spin_once(timeout_sec=0.02)
            self.poll()
            now = time.monotonic()
            if now >= next_sample:
                next_sample += args.sample_every
                self.sample()
            if self.pending is None and now - start < duration_s:
                if not referenced:
                    referenced = self.calibrate(f'/{NODE}/capture_reference')
                elif now >= next_calibration:
                    if self.calibrate(f'/{NODE}/self_calibrate'):
                        next_calibration += args.calibrate_every
                elif now >= next_parameter:
                    next_parameter += args.param_every
                    self.change_parameter()
            if now >= next_progress:
                next_progress += args.progress_every
                print(self.progress(now - start), flush=True)

    def progress(self, elapsed_s):
        """Return one progress line from the last rows of the CSV files."""
        node = read_csv(self.paths.node)[-1:]
        stream = read_csv(self.paths.stream)[-1:]
        text = f'[{datetime.timedelta(seconds=round(elapsed_s))}]'
        if stream:
            s = stream[0]
            text += (f' samples {int(s["received"]):,} lost {s["lost"]} off-grid '
                     f'{s["off_grid"]} offset p50 {s["offset_p50_us"]} us;')
        if node:
            n = node[0]
            text += (f' RSS {int(n["rss_kib"]) / 1024:.1f} MiB fd {n["fds"]} threads '
                     f'{n["threads"]}; withheld {n["withheld"]} skipped {n["skipped"]}; '
                     f'{n["recorded_files"]} files {int(n["recorded_bytes"]) / MIB:.1f} MiB; '
                     f'{n["calibrations"]} calls ({n["calibration_failures"]} failed), '
                     f'{n["parameter_changes"]} parameter sets; load {n["load1"]}')
        return text


def soak(args):
    """Run the soak, read the recording back, write the report."""
    paths = Paths(args.out)
    paths.out.parent.mkdir(parents=True, exist_ok=True)
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix='qfa_soak_')).resolve()
    output_dir = workdir / 'out'
    output_dir.mkdir(parents=True, exist_ok=True)
    tracemalloc_dir = None
    if args.tracemalloc:
        tracemalloc_dir = workdir / 'tracemalloc'
        tracemalloc_dir.mkdir(exist_ok=True)
    duration_s = args.hours * 3600.0 + args.minutes * 60.0
    command = node_command(output_dir, args)
    env = node_environment(args.domain, tracemalloc_dir, args.snapshot_every)
    stopping = []
    for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(signum, lambda *_: stopping.append(True))
    log = open(workdir / 'node.log', 'w')
    subscriber = subprocess.Popen(
        [sys.executable, __file__, '--subscriber', '--domain', str(args.domain), '--out',
         str(paths.out), '--sample-every', str(args.sample_every), '--rate', str(args.rate)],
        env=node_environment(args.domain), cwd=ROOT)
    node = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT,
                            start_new_session=True)
    run = {
        'bench': ' '.join([Path(sys.executable).name, *sys.argv]),
        'node_command': ' '.join(command[1:]), 'commit': git_commit(),
        'started': datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds'),
        'started_ns': time.time_ns(), 'planned_s': duration_s, 'workdir': str(workdir),
        'node_pid': node.pid, 'subscriber_pid': subscriber.pid, 'domain': args.domain,
        'split_s': args.split_s, 'max_bytes': args.max_bytes, 'rate_hz': args.rate,
        'param_every_s': args.param_every, 'calibrate_every_s': args.calibrate_every,
        'warmup_s': args.warmup_min * 60.0, 'sample_every_s': args.sample_every,
        'tracemalloc': bool(args.tracemalloc),
        'allocator': {k: v for k, v in os.environ.items() if k.startswith('MALLOC_')},
        'machine': f'{platform.node()}, {os.cpu_count()} CPUs, {platform.machine()}, '
                   f'Linux {platform.release()}, Python {platform.python_version()}',
        'rotation': [name for name, _ in parameter_rotation()]}
    paths.run.write_text(json.dumps(run, indent=1))
    print(f'soak: node pid {node.pid} (process group), subscriber pid {subscriber.pid}, '
          f'domain {args.domain}, {duration_s / 3600:.2f} h; workdir {workdir}; '
          f'CSV {paths.node}', flush=True)
    driver = None
    reason = 'not started'
    try:
        driver = Driver(args, paths, node.pid, output_dir)
        driver.wait_for_samples(args.start_timeout)
        reason = driver.run(duration_s, node, stopping)
        driver.sample()
    except Exception as error:
        reason = f'the bench failed: {type(error).__name__}: {error}'
        raise
    finally:
        print(f'soak: ending ({reason})', flush=True)
        status = stop_process(node, group=True)
        stop_process(subscriber)
        if driver is not None:
            driver.close()
        log.close()
        run.update(ended_ns=time.time_ns(), end_reason=reason, node_exit_status=status)
        paths.run.write_text(json.dumps(run, indent=1))
    readback(paths)
    write_report(paths)
    print(f'soak: report {paths.out}, figure {paths.figure}', flush=True)


def stop_process(process, group=False, timeout_s=30.0):
    """SIGTERM ``process`` (its process group); SIGKILL after ``timeout_s``; return its status."""
    if process.poll() is None:
        if group:
            os.killpg(process.pid, signal.SIGTERM)
        else:
            process.send_signal(signal.SIGTERM)
    try:
        return process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        if group:
            os.killpg(process.pid, signal.SIGKILL)
        else:
            process.kill()
        return process.wait()


# --- reading the recording back ---------------------------------------------------------

def readback(paths):
    """Read every recorded file with rosbags and the mcap reader; write ``soak_files.csv``."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader
    import yaml

    run = json.loads(paths.run.read_text())
    period = round(NS_PER_S / run.get('rate_hz', 1000.0))
    recordings = Path(run['workdir']) / 'out' / 'recordings'
    rows = CsvLog(paths.files, FILE_COLUMNS)
    recorded_gaps = CsvLog(paths.recorded_gaps, GAP_COLUMNS)
    for bag in sorted(p for p in recordings.iterdir() if p.is_dir()):
        stamps = []
        listed = {}
        metadata = bag / 'metadata.yaml'
        if metadata.exists():
            info = yaml.safe_load(metadata.read_text())['rosbag2_bagfile_information']
            listed = {Path(f['path']).name: f['message_count'] for f in info['files']}
        for file in sorted(bag.glob('*.mcap'), key=lambda p: int(p.stem.rsplit('_', 1)[1])):
            mcap_count = rosbags_count = imu = 0
            start = end = None
            readable = 1
            try:
                with open(file, 'rb') as stream:
                    for _, channel, message in make_reader(stream).iter_messages():
                        mcap_count += 1
                        if channel.topic == '/imu/data_raw':
                            imu += 1
                            sec, nanosec = STAMP.unpack_from(message.data, 4)
                            stamps.append(sec * NS_PER_S + nanosec)
                        start = message.log_time if start is None else min(start,
                                                                             message.log_time)
                        end = message.log_time if end is None else max(end, message.log_time)
                with AnyReader([file]) as reader:
                    rosbags_count = sum(1 for _ in reader.messages())
            except Exception as error:  # a file neither reader opens is the finding
                readable = 0
                print(f'soak: {file} not readable: {type(error).__name__}: {error}',
                      flush=True)
            rows.write([bag.name, file.name, file.stat().st_size, listed.get(file.name, ''),
                        mcap_count, rosbags_count, imu, start, end, readable])
        for leftover in bag.glob('*.part'):
            rows.write([bag.name, leftover.name, leftover.stat().st_size, '', '', '', '', '',
                        '', 0])
        # What the node published, from the recording: every grid instant between its
        # first and last recorded sample, across the splits.
        stamps = np.array(stamps, dtype=np.int64)
        steps = np.diff(stamps) // period - 1
        for index in np.flatnonzero(steps > 0):
            recorded_gaps.write(['', '', stamps[index], stamps[index + 1], steps[index]])
        if np.any(np.diff(stamps) <= 0) or np.any(np.diff(stamps) % period):
            print(f'soak: {bag}: recorded stamps out of order or off the grid', flush=True)
        try:
            with AnyReader([bag]) as reader:
                whole = sum(1 for _ in reader.messages())
            rows.write([bag.name, '(whole bag, AnyReader)', '', sum(listed.values()), '',
                        whole, '', '', '', 1])
        except Exception as error:
            rows.write([bag.name, '(whole bag, AnyReader)', '', sum(listed.values()), '', '',
                        '', '', '', 0])
            print(f'soak: bag {bag} not readable: {type(error).__name__}: {error}',
                  flush=True)
    rows.close()
    recorded_gaps.close()


# --- the report -------------------------------------------------------------------------

def fit(t_h, y):
    """Return ``(slope per hour, its standard error, intercept)`` of a least-squares line."""
    ok = np.isfinite(t_h) & np.isfinite(y)
    t_h, y = t_h[ok], y[ok]
    if len(t_h) < 3 or np.ptp(t_h) <= 0:
        return np.nan, np.nan, np.nan
    (slope, intercept), cov = np.polyfit(t_h, y, 1, cov=True)
    return slope, float(np.sqrt(cov[0, 0])), intercept


def pause_windows(events):
    """Return the ``(start, end)`` windows of the schedule calls [ns], with the margin."""
    return [(int(e['sent_ns']) - PAUSE_MARGIN_NS, int(e['answered_ns']) + PAUSE_MARGIN_NS)
            for e in events if e['kind'] == 'schedule']


def classify_gaps(gaps, windows):
    """Split the gaps into those inside a schedule call's window and the others."""
    inside, outside = [], []
    for gap in gaps:
        before, after = int(gap['before_stamp_ns']), int(gap['after_stamp_ns'])
        paused = any(before >= start and after <= end for start, end in windows)
        (inside if paused else outside).append(gap)
    return inside, outside


def write_report(paths):
    """Write the Markdown report and the figure from the soak's CSV files."""
    run = json.loads(paths.run.read_text())
    node_rows = read_csv(paths.node)
    stream_rows = read_csv(paths.stream)
    gaps = read_csv(paths.gaps)
    events = read_csv(paths.events)
    files = read_csv(paths.files)
    t0 = run['started_ns']
    t_h = (column(node_rows, 'wall_ns') - t0) / 3.6e12
    warm_h = run['warmup_s'] / 3600.0
    after = t_h >= warm_h
    lines = [f'# Soak: the live node for {t_h[-1] if len(t_h) else 0:.2f} h', '',
             'Command (from the work tree):', '', '```sh', run['bench'], '```', '',
             f'Node (its own process group, domain {run["domain"]}): `python '
             f'{run["node_command"]}`', '',
             f'Code {run["commit"]}; started {run["started"]}; {run["machine"]}; ended: '
             f'{run.get("end_reason", "no end recorded (the bench died)")}, node exit '
             f'status {run.get("node_exit_status", "unknown")}.', '']
    if run.get('tracemalloc'):
        lines += ['**tracemalloc was on** (bench/soak_hook): the slopes below include '
                  'its own bookkeeping; not a measurement of the node.', '']
    if run.get('allocator'):
        lines += ['glibc allocator settings in the environment of the node: '
                  + ', '.join(f'`{k}={v}`' for k, v in run['allocator'].items()) + '.', '']
    load = column(node_rows, 'load1')
    if len(load):
        lines += [f'Load (1-min average, `os.getloadavg`, every row of `soak.csv`): median '
                  f'{np.median(load):.2f}, min {load.min():.2f}, max {load.max():.2f} on '
                  f'{os.cpu_count()} CPUs.', '']
    lines += [f'Recorder split every {run["split_s"]:g} s or '
              f'{run["max_bytes"] / MIB:.1f} MiB (`recorder.max_bytes`), a parameter change '
              f'every {run["param_every_s"]:g} s (rotating: '
              f'{", ".join(run["rotation"])}), `~/self_calibrate` every '
              f'{run["calibrate_every_s"]:g} s in fast mode (`estimation.realtime: false`) '
              f'after one `~/capture_reference`; samples of the node every '
              f'{run["sample_every_s"]:g} s; fits after a warm-up of '
              f'{run["warmup_s"] / 60:g} min.', '']
    lines += stream_section(stream_rows, gaps, events, node_rows,
                            read_csv(paths.recorded_gaps) if files else None,
                            round(NS_PER_S / run.get('rate_hz', 1000.0)))
    lines += resource_section(node_rows, t_h, after)
    lines += disk_section(run, node_rows, t_h, after, files)
    lines += readback_section(files, stream_rows, node_rows)
    calls = [e for e in events if e['kind'] == 'schedule']
    refusals = [e for e in events if e['kind'] == 'parameter']
    lines += ['## Calls', '',
              f'{len(calls)} schedule calls ({sum(e["success"] == "1" for e in calls)} '
              f'succeeded), {node_rows[-1]["parameter_changes"] if node_rows else 0} '
              f'parameter changes ({len(refusals)} refused).']
    durations = [(int(e['answered_ns']) - int(e['sent_ns'])) / 1e9 for e in calls]
    if durations:
        lines[-1] += (f' A call took {np.median(durations):.2f} s (median), '
                      f'{max(durations):.2f} s at most (request to answer).')
    failed = [e for e in calls if e['success'] != '1'] + refusals
    for event in failed[:5]:
        lines.append(f'- {event["name"]}: {event["message"]}')
    lines += ['', f'![RSS, descriptors, threads and stamp offset against time]'
                  f'({paths.figure.name})', '']
    paths.out.write_text('\n'.join(lines) + '\n')
    figure(paths, run, node_rows, stream_rows, t0)


def stream_section(stream_rows, gaps, events, node_rows, recorded_gaps, period):
    """Return the stream's lines: samples received and lost, the grid, the offset."""
    if not stream_rows:
        return ['## Stream', '', 'No subscriber rows.', '']
    last = stream_rows[-1]
    received, lost = int(last['received']), int(last['lost'])
    windows = pause_windows(events)
    inside, outside = classify_gaps(gaps, windows)
    # A keep-last-5 reader that took the sample after a hole this long after the node sent
    # it (DDS source timestamp) had the four after it waiting too: it was itself behind.
    behind = [g for g in outside
              if int(g['received_ns']) - int(g.get('published_ns') or g['after_stamp_ns'])
              >= STARVED_PERIODS * period]
    lost_inside = sum(int(g['missing']) for g in inside)
    lost_outside = sum(int(g['missing']) for g in outside)
    lost_behind = sum(int(g['missing']) for g in behind)
    final = node_rows[-1] if node_rows else {}
    first, end = int(last['first_stamp_ns']), int(last['last_stamp_ns'])
    span = (end - first) // period + 1
    lines = ['## Stream (SensorDataQoS subscriber, best effort, keep last 5, own process)', '',
             '| | samples |', '|---|---|',
             f'| on the grid from the first to the last received | {span:,} |',
             f'| received | {received:,} |',
             f'| missing overall | {lost:,} ({lost / max(span, 1):.2e}) |',
             f'| missing inside schedule pauses ({len(inside)} gaps) | {lost_inside:,} |',
             f'| the node says withheld (`samples withheld`) | {final.get("withheld", "")} |',
             f'| **lost outside pauses** ({len(outside)} gaps) | **{lost_outside:,}** |',
             f'| of them while the subscriber was itself behind (read the next sample '
             f'≥ {STARVED_PERIODS} periods after the node sent it; {len(behind)} gaps) | '
             f'{lost_behind:,} |',
             f'| the node says skipped / dropped > 1 s late / published > 5 ms late | '
             f'{final.get("skipped", "")} / {final.get("dropped", "")} / '
             f'{final.get("late", "")} |',
             f'| stamps off the grid | {last["off_grid"]} |',
             f'| out of order or repeated | {last["out_of_order"]} |', '']
    if recorded_gaps is not None:
        held, missed = classify_gaps(recorded_gaps, windows)
        lines[-1:-1] = [
            f'| the recording (what the pacer published) misses inside pauses | '
            f'{sum(int(g["missing"]) for g in held):,} |',
            f'| **the recording misses outside pauses** ({len(missed)} gaps) | '
            f'**{sum(int(g["missing"]) for g in missed):,}** |',
            f'| the node says it skipped, or dropped > 1 s late (samples and temperature '
            f'readings) | {final.get("skipped", "")} + {final.get("dropped", "")} |']
        lines += ["The recording logs each sample as the node's pacer published it: a sample "
                  'missing at the subscriber but recorded left the node and was lost on the '
                  'way (DDS, or a subscriber starved for more than five sample periods).', '']
    if outside:
        largest = max(outside, key=lambda g: int(g['missing']))
        lines += [f'Largest loss outside pauses: {largest["missing"]} samples at '
                  f'{(int(largest["before_stamp_ns"]) - first) / 3.6e12:.3f} h.', '']
    wall = column(stream_rows, 'wall_ns')
    t_h = (wall - wall[0]) / 3.6e12
    p50 = column(stream_rows, 'offset_p50_us')
    low = column(stream_rows, 'offset_min_us')
    slope_p50, error_p50, _ = fit(t_h, p50)
    slope_min, error_min, _ = fit(t_h, low)
    # The first and last intervals that received samples.
    low, p50 = low[np.isfinite(low)], p50[np.isfinite(p50)]
    lines += ["Offset of the stamps from the subscriber's system clock (receive time - "
              'stamp, per interval; the node stamps on its grid and publishes when the '
              'system clock reaches the stamp, so this is the delivery delay):', '',
              '| per interval | first | last | median | slope [µs/h] |', '|---|---|---|---|---|',
              f'| minimum [µs] | {low[0]:.0f} | {low[-1]:.0f} | {np.nanmedian(low):.0f} | '
              f'{slope_min:+.2f} ± {error_min:.2f} |',
              f'| median [µs] | {p50[0]:.0f} | {p50[-1]:.0f} | {np.nanmedian(p50):.0f} | '
              f'{slope_p50:+.2f} ± {error_p50:.2f} |', '']
    return lines


def resource_section(node_rows, t_h, after):
    """RSS, descriptors and threads: start, end, slopes after the warm-up, 24 h projection."""
    if len(t_h) < 3:
        return ['## Node process', '', 'Too few rows.', '']
    lines = ['## Node process (`/proc/<pid>`)', '',
             '| | at warm-up end | at the end | slope after warm-up [/h] | '
             'first / second half [/h] | projected at 24 h |', '|---|---|---|---|---|---|']
    for name, label, scale in (('rss_kib', 'RSS [MiB]', 1024.0),
                               ('rss_anon_kib', 'RSS anonymous [MiB]', 1024.0),
                               ('fds', 'open descriptors', 1.0), ('threads', 'threads', 1.0)):
        y = column(node_rows, name) / scale
        t, v = t_h[after], y[after]
        slope, error, intercept = fit(t, v)
        half = t[0] + (t[-1] - t[0]) / 2 if len(t) else np.nan
        first, _, _ = fit(t[t <= half], v[t <= half]) if len(t) else (np.nan,) * 3
        second, _, _ = fit(t[t > half], v[t > half]) if len(t) else (np.nan,) * 3
        start = v[0] if len(v) else np.nan
        projected = intercept + slope * 24.0
        lines.append(f'| {label} | {start:.2f} | {y[-1]:.2f} | {slope:+.3f} ± {error:.3f} | '
                     f'{first:+.3f} / {second:+.3f} | {projected:.2f} |')
    cpu = column(node_rows, 'cpu_s')
    wall = column(node_rows, 'wall_ns') / 1e9
    share = (cpu[-1] - cpu[after][0]) / (wall[-1] - wall[after][0]) if after.sum() > 1 \
        else np.nan
    lines += ['', f'CPU of the node after the warm-up: {100 * share:.1f} % of one core.', '']
    return lines


def disk_section(run, node_rows, t_h, after, files):
    """Disk: the recording against ``recorder.max_bytes``, traces, the state file."""
    if not node_rows:
        return []
    last = node_rows[-1]
    recorded = column(node_rows, 'recorded_bytes') / MIB
    slope, _, _ = fit(t_h[after], recorded[after])
    largest = int(last['largest_file_bytes'])
    sizes = [int(f['bytes']) for f in files if f['file'].endswith('.mcap')]
    by_size = sum(s > 0.9 * run['max_bytes'] for s in sizes)
    state = column(node_rows, 'state_bytes')
    readable = column(node_rows, 'state_readable')
    written = len({r['state_mtime_ns'] for r in node_rows if r['state_mtime_ns'] != '0'})
    present = state > 0
    lines = ['## Disk and state file', '',
             f'- Recording: {last["recorded_files"]} finished files, '
             f'{int(last["recorded_bytes"]) / MIB:.1f} MiB ({slope:.1f} MiB/h after the '
             f'warm-up: {24 * slope / 1024:.2f} GiB a day), the largest '
             f'{largest / MIB:.2f} MiB against `recorder.max_bytes` '
             f'{run["max_bytes"] / MIB:.2f} MiB '
             f'({"within" if largest <= run["max_bytes"] else "**over**"}); '
             f'{by_size} of {len(sizes)} files ended within 10 % of the size limit, the others '
             f'at the {run["split_s"]:g} s limit or at the end; `metadata.yaml` '
             f'{int(last["metadata_bytes"]) / 1024:.1f} KiB at the end; `.part` in progress '
             f'{int(last["part_bytes"]) / MIB:.2f} MiB.',
             f'- Traces: {last["trace_files"]} files, {int(last["trace_bytes"]) / MIB:.1f} MiB '
             '(one per schedule call).',
             f'- State file: written {written} times (distinct modification times seen), '
             f'readable JSON in {int(np.nansum(readable[present]))} of {int(present.sum())} '
             f'samples since it was first written, size '
             f'{np.min(state[present]) if present.any() else 0:.0f}…'
             f'{np.max(state[present]) if present.any() else 0:.0f} bytes.', '']
    return lines


def readback_section(files, stream_rows, node_rows):
    """Every recorded file read back by rosbags and the mcap reader."""
    if not files:
        return ['## Read back', '', 'Not read back (the bench ended before; '
                "`--report --readback` reads the run's recording).", '']
    parts = [f for f in files if f['file'].endswith('.part')]
    singles = [f for f in files if f['file'].endswith('.mcap')]
    bags = [f for f in files if f['file'].startswith('(whole bag')]
    agree = sum(f['readable'] == '1' and f['mcap_messages'] == f['rosbags_messages']
                == str(f['metadata_messages']) for f in singles)
    mcap_total = sum(int(f['mcap_messages'] or 0) for f in singles)
    rosbags_total = sum(int(f['rosbags_messages'] or 0) for f in singles)
    imu = sum(int(f['imu_messages'] or 0) for f in singles)
    lines = ['## Read back (after SIGTERM)', '',
             f'{len(singles)} files in {len(bags)} bag(s): {agree} read by both readers with '
             f'the count `metadata.yaml` lists; mcap reader {mcap_total:,} messages, rosbags '
             f'{rosbags_total:,}; whole bags by `AnyReader`: '
             f'{sum(b["readable"] == "1" for b in bags)} of {len(bags)} open, '
             f'{sum(int(b["rosbags_messages"] or 0) for b in bags):,} messages; '
             f'`.part` left: {len(parts)}.', '',
             f'`imu/data_raw` recorded: {imu:,} messages']
    if stream_rows:
        lines[-1] += f'; the subscriber received {int(stream_rows[-1]["received"]):,}'
    lines[-1] += '.'
    bad = [f for f in singles if f['readable'] != '1']
    for f in bad[:5]:
        lines.append(f'- not readable: {f["bag"]}/{f["file"]}')
    return lines + ['']


def figure(paths, run, node_rows, stream_rows, t0):
    """RSS, descriptors, threads and the stamp offset against time."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    t_h = (column(node_rows, 'wall_ns') - t0) / 3.6e12
    warm_h = run['warmup_s'] / 3600.0
    after = t_h >= warm_h
    rss = column(node_rows, 'rss_kib') / 1024
    anon = column(node_rows, 'rss_anon_kib') / 1024
    axes[0].plot(t_h, rss, label='RSS')
    axes[0].plot(t_h, anon, label='RSS anonymous')
    for y in (rss, anon):
        slope, _, intercept = fit(t_h[after], y[after])
        if np.isfinite(slope):
            axes[0].plot(t_h[after], intercept + slope * t_h[after], 'k--', lw=0.8)
    axes[0].set_ylabel('MiB')
    axes[0].legend(loc='lower right')
    axes[1].plot(t_h, column(node_rows, 'fds'), label='open descriptors')
    axes[1].plot(t_h, column(node_rows, 'threads'), label='threads')
    axes[1].set_ylabel('count')
    axes[1].legend(loc='center right')
    if stream_rows:
        ts = (column(stream_rows, 'wall_ns') - t0) / 3.6e12
        axes[2].plot(ts, column(stream_rows, 'offset_min_us') / 1e3, label='minimum')
        axes[2].plot(ts, column(stream_rows, 'offset_p50_us') / 1e3, label='median')
        axes[2].plot(ts, column(stream_rows, 'offset_p99_us') / 1e3, label='99th percentile')
        axes[2].set_yscale('log')
        axes[2].set_ylabel('receive - stamp [ms]')
        axes[2].legend(loc='upper right')
    axes[3].plot(t_h, column(node_rows, 'load1'), label='machine load (1 min)')
    axes[3].set_ylabel('load (1 min)')
    cpu = axes[3].twinx()
    cpu.plot(t_h[1:], 100 * np.diff(column(node_rows, 'cpu_s')) / np.diff(
        column(node_rows, 'wall_ns') / 1e9), color='tab:orange', label='node CPU')
    cpu.set_ylabel('node CPU [% of a core]')
    axes[3].set_xlabel('hours since start')
    axes[3].legend(loc='upper left')
    cpu.legend(loc='upper right')
    for axis in axes:
        axis.axvline(warm_h, color='grey', lw=0.8, ls=':')
        axis.grid(alpha=0.3)
    axes[0].set_title(f'qfa_node soak ({run["commit"]}, {run["started"]})')
    fig.tight_layout()
    fig.savefig(paths.figure, dpi=90)
    plt.close(fig)


# --- tracemalloc snapshots --------------------------------------------------------------

def compare_snapshots(directory, top=25):
    """Print the largest growths between the second snapshot and the last, by traceback."""
    import tracemalloc
    snapshots = sorted(Path(directory).glob('snapshot_*.pickle'))
    if len(snapshots) < 3:
        sys.exit(f'{directory}: fewer than three snapshots')
    first, last = (tracemalloc.Snapshot.load(str(p)) for p in (snapshots[1], snapshots[-1]))
    print(f'{snapshots[1].name} -> {snapshots[-1].name} ({len(snapshots)} snapshots)')
    for stat in last.compare_to(first, 'traceback')[:top]:
        print(f'{stat.size_diff / 1024:+10.1f} KiB {stat.count_diff:+8d} blocks '
              f'(now {stat.size / 1024:.1f} KiB)')
        for line in stat.traceback.format(limit=6):
            print('    ' + line)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--hours', type=float, default=0.0)
    parser.add_argument('--minutes', type=float, default=0.0)
    parser.add_argument('--domain', type=int, default=60, help='ROS domain id (own one)')
    parser.add_argument('--out', default=str(ROOT / 'bench' / 'results' / 'soak.md'))
    parser.add_argument('--workdir', help='where the node writes (default: a new temp dir)')
    parser.add_argument('--split-s', type=float, default=120.0,
                        help='recorder.max_duration_s [s]')
    parser.add_argument('--max-bytes', type=int, default=5 << 20,
                        help='recorder.max_bytes (at least 1 MiB)')
    parser.add_argument('--min-free-bytes', type=int, default=1 << 30)
    parser.add_argument('--param-every', type=float, default=5.0)
    parser.add_argument('--calibrate-every', type=float, default=300.0)
    parser.add_argument('--sample-every', type=float, default=10.0)
    parser.add_argument('--progress-every', type=float, default=60.0)
    parser.add_argument('--warmup-min', type=float, default=10.0,
                        help='slopes are fitted after this many minutes')
    parser.add_argument('--seed', type=int, default=35)
    parser.add_argument('--call-timeout', type=float, default=600.0,
                        help='give up on a service call after this long [s]')
    parser.add_argument('--rate', type=float, default=1000.0,
                        help='sample_rate_hz (loop 10x); lower for a tracemalloc run')
    parser.add_argument('--start-timeout', type=float, default=600.0,
                        help='how long the node may take to publish its first sample [s]')
    parser.add_argument('--tracemalloc', action='store_true',
                        help='snapshot the node with tracemalloc (slows it; not for slopes)')
    parser.add_argument('--snapshot-every', type=float, default=300.0)
    parser.add_argument('--snapshots', help='compare the tracemalloc snapshots in DIR')
    parser.add_argument('--report', action='store_true',
                        help='only write the report from the CSV files of --out')
    parser.add_argument('--readback', action='store_true',
                        help="with --report: read the run's recording back first")
    parser.add_argument('--subscriber', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscriber:
        run_subscriber(args)
    elif args.snapshots:
        compare_snapshots(args.snapshots)
    elif args.report:
        paths = Paths(args.out)
        if args.readback:
            readback(paths)
        write_report(paths)
    else:
        if args.hours * 60 + args.minutes <= 0:
            parser.error('give --hours or --minutes')
        soak(args)


if __name__ == '__main__':
    main()
