"""Soak the live node for hours: nothing may drift, grow or get lost, kill -9 included.

The node is started as a user starts it (``python -m qfa_ros.cli.node --ros-args
--params-file config/qfa.yaml -p ...``; its own process group, its own domain) with the
flight recorder on and splitting (``--split-s``, ``--max-bytes``), its retention when
asked (``--keep-s``, ``--keep-bytes``: :data:`RETENTION`), self-calibrations in fast mode
(``estimation.realtime: false``). Two other processes meet it over real DDS, a third reads
what it recorded:

- this one, a participant that changes a writable parameter every ``--param-every``
  seconds through the node's SetParameters service (rotating over drift, orientation,
  ambient, latitude, frame id, room amplitude), calls ``~/capture_reference`` once and
  ``~/self_calibrate`` every ``--calibrate-every`` seconds, listens to ``/diagnostics``
  (the node's own counters: samples withheld during schedules, skipped, late) and samples
  the node process from ``/proc`` (RSS, descriptors, threads, CPU), the recording and
  the state file every ``--sample-every`` seconds;
- a subscriber process (``--subscriber``, ``soak_stream.py``) with ``SensorDataQoS`` (best
  effort, keep last 5) that counts every ``imu/data_raw`` sample, its gaps, stamps off the
  grid and the offset of the stamps from its system clock (receive time - stamp);
- after each restart, a checker at niceness 19 (``--check-restart``,
  ``soak_recording.py``).

**Kills** (``--kill-every S``, with jitter of +-:data:`KILL_JITTER`): the node is stopped
(SIGSTOP) at an instant chosen in turn by :data:`KILL_MODES` (right then; the moment the
recorder finishes a file; the moment a finished file is deleted, with retention), the
recorder directory is noted as the kill leaves it, the node's process group gets SIGKILL,
and the node is started again with the same command (``soak_node.py``). Its start-up
recovery finishes the killed run's bag; then the checker reads every bag directory's
``metadata.yaml`` against its files and every file not read before with the ``mcap``
reader and ``rosbags``, and says whether the files finished at the kill are still there
(only the oldest may go, and only with retention). No kill comes while a schedule runs.

Everything is written as it happens to CSV files beside ``--out`` (``soak_csv.py``), so a
soak that dies still leaves its measurements. At the end the node gets SIGTERM and what
was not read yet is read back; then the report (``--out``, Markdown) and its figure
(``soak.png``) are written from the CSV files alone (``soak_report.py``).

Samples the node withholds on purpose are counted apart: during a schedule the stream is
held (``docs/node.md``, *Estimation schedules*; the ``stream`` diagnostic counts them as
``samples withheld``). A gap of the subscriber inside a schedule call's window (request
sent to answer received, 0.5 s either side) is a schedule pause, one from a kill to the
restarted node's first sample the kill's; every other missing sample is a loss.

Run (at least two hours, on a quiet machine)::

    .venv/bin/python bench/soak.py --hours 2 --domain 60 --out bench/results/soak.md

Days of operation, simulated (retention small, a kill -9 every 10 minutes; on Jazzy
``.venv-jazzy`` and ``--out bench/results/soak_days_jazzy.md``)::

    .venv/bin/python bench/soak.py --hours 2 --domain 111 --split-s 60 --keep-s 300 \
        --keep-bytes 33554432 --param-every 5 --calibrate-every 180 --kill-every 600 \
        --progress-every 600 --out bench/results/soak_days.md

A try: ``--minutes 10 --out /tmp/soak/soak.md``. The report again from the CSV files:
``--report --out bench/results/soak.md`` (``--readback`` first reads what the run left,
e.g. after the bench itself died). Memory growth by allocation site: ``--tracemalloc``
(snapshots of the node every ``--snapshot-every`` s via ``bench/soak_hook/sitecustomize.py``;
slows the node, so not for slopes), then ``--snapshots DIR`` prints the largest growths
between the first snapshot after the warm-up and the last.
"""

import argparse
import datetime
import json
import os
from pathlib import Path
import platform
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))  # crash_helpers: the crash tests' own tools

from crash_helpers import bag_directories, live_bag  # noqa: E402
from soak_csv import (  # noqa: E402
    CsvLog,
    EVENT_COLUMNS,
    MIB,
    NODE_COLUMNS,
    NS_PER_S,
    Paths,
    read_csv,
)
from soak_node import (  # noqa: E402
    git_commit,
    KillWatch,
    node_command,
    node_environment,
    NodeRunner,
    parameter_rotation,
    proc_sample,
    Restart,
    RETENTION,
    stop_process,
)
from soak_recording import (  # noqa: E402
    check_restart,
    disk_sample,
    disk_state,
    readback,
)
from soak_report import write_report  # noqa: E402
from soak_stream import run_subscriber  # noqa: E402

NODE = 'qfa_node'
KILL_MODES = ('random', 'split', 'deletion')
"""When a kill lands, in turn: at its instant; the moment the recorder has finished a file;
the moment a finished file was deleted (with retention only)."""
KILL_JITTER = 0.25
"""A kill comes ``--kill-every`` times 1 +- this after the previous one (uniform)."""
WATCH_SPLITS = 3.0
"""A kill waiting for a split or a deletion waits this many ``--split-s`` at most, then
lands where it is (its ``hit`` is 0)."""
RECOVERY_TIMEOUT_S = 300.0
"""How long the restarted node's start-up recovery may take before the check runs anyway."""


# --- the driver -------------------------------------------------------------------------

class Driver:
    """
    The soak's participant: parameters, calibrations, kills, diagnostics, /proc sampling.

    Parameters
    ----------
    args : argparse.Namespace
        The bench's options.
    paths : Paths
        The soak's files.
    runner : NodeRunner
        The node (started).
    output_dir : pathlib.Path
        The node's ``output_dir``.
    subscriber : subprocess.Popen
        The subscriber process (told of each restart by SIGUSR1).
    """

    def __init__(self, args, paths, runner, output_dir, subscriber):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.args = args
        self.runner = runner
        self.output_dir = output_dir
        self.recordings = output_dir / 'recordings'
        self.subscriber = subscriber
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
        self.pending = None  # (kind, name, sent_ns, future, client)
        self.rotation = parameter_rotation()
        self.turn = 0
        self.rng = np.random.default_rng(args.seed)
        self.kill_rng = np.random.default_rng(np.random.SeedSequence([args.seed, 9]))
        self.kills = 0
        self.modes = KILL_MODES if args.keep_s or args.keep_bytes else KILL_MODES[:2]
        self.watch = None
        self.restarts = []
        self.checker = None
        self.started_ns = time.time_ns()
        self._clients = {}
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.on_diagnostics,
                                      QoSProfile(depth=10))

    def close(self):
        """Wait for a check under way, then close the files and the participant."""
        import rclpy
        if self.checker is not None:
            stop_process(self.checker, timeout_s=600.0)
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
            if self.runner.process.poll() is not None:
                raise RuntimeError(f'the node exited with status '
                                   f'{self.runner.process.returncode} before publishing')
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
        proc = proc_sample(self.runner.process.pid)
        counters = self.counters
        self.rows.write([
            now, f'{(now - self.started_ns) / 1e9:.1f}', self.runner.run,
            self.runner.process.pid, *proc[:4], f'{proc[4]:.2f}',
            f'{os.getloadavg()[0]:.2f}', *disk_sample(self.output_dir),
            *(counters.get(key, '') for key in (
                'computed', 'published', 'withheld', 'skipped', 'late', 'max_delay_ms',
                'waiting', 'dropped')),
            self.parameter_changes, self.parameter_refusals, self.calibrations,
            self.calibration_failures, self.recorder_problem[:200]])
        return proc

    # --- kills -------------------------------------------------------------------------

    def next_kill_after(self, now):
        """Return when the next kill is due (monotonic) [s]; infinity without kills."""
        if not self.args.kill_every:
            return float('inf')
        return now + self.args.kill_every * self.kill_rng.uniform(1 - KILL_JITTER,
                                                                   1 + KILL_JITTER)

    def arm_kill(self):
        """Stop the node now or at the next split or deletion (the mode's turn)."""
        mode = self.modes[self.kills % len(self.modes)]
        self.kills += 1
        self.watch = KillWatch(self.runner.process, mode, self.recordings,
                               WATCH_SPLITS * self.args.split_s)

    def kill_and_restart(self):
        """Note what the stopped node leaves, SIGKILL it, start it again until it publishes."""
        watch, self.watch = self.watch, None
        state = disk_state(self.recordings)
        self.sample()  # the stopped run's last row: the counters of its last diagnostics
        bags = bag_directories(self.recordings)
        killed = live_bag(self.recordings) or (bags[-1] if bags else None)
        killed_pid = self.runner.process.pid
        self.runner.kill()
        if self.pending is not None:  # a call to the dead node: no answer comes
            self.pending[4].remove_pending_request(self.pending[3])
            self.pending = None
        for _ in range(5):  # what the dead node sent before its stop, taken now
            self.executor.spin_once(timeout_sec=0.01)
        restart = Restart(watch, self.runner.run + 1, state, killed)
        self.subscriber.send_signal(signal.SIGUSR1)
        self.counters, self.recorder_problem = {}, ''
        self.runner.start()
        restart.restarted_ns = self.runner.started_ns
        restart.log = self.runner.log_path
        self.events.write(['kill', watch.mode, watch.stopped_ns, restart.restarted_ns,
                           watch.hit, f'run {restart.run - 1} (pid {killed_pid}) killed in '
                           f'{killed.name if killed else "no bag"}; run {restart.run} (pid '
                           f'{self.runner.process.pid}) started'])
        self.wait_for_samples(self.args.start_timeout)
        restart.first_published_ns = time.time_ns()
        restart.deadline = time.monotonic() + RECOVERY_TIMEOUT_S
        self.restarts.append(restart)

    def after_restart(self, wait=False):
        """
        Start the check of the oldest restart once its bag is recovered; one at a time.

        With ``wait`` (the end of the soak), run every check left and wait for it.
        """
        while True:
            if self.checker is not None:
                if wait:
                    self.checker.wait()
                if self.checker.poll() is None:
                    return
                if self.checker.returncode:  # its row is missing: the report says so
                    print(f'soak: the check after a restart failed (status '
                          f'{self.checker.returncode})', flush=True)
                self.checker = None
            if not self.restarts or not (wait or self.restarts[0].recovered()):
                return
            restart = self.restarts.pop(0)
            path = self.runner.workdir / f'restart_{restart.run}.json'
            path.write_text(json.dumps({
                'run': restart.run, 'mode': restart.mode, 'kill_ns': restart.kill_ns,
                'hit': restart.hit, 'restarted_ns': restart.restarted_ns,
                'first_published_ns': restart.first_published_ns,
                'recovered_ns': time.time_ns(), 'recordings': str(self.recordings),
                'killed_bag': restart.killed_bag.name if restart.killed_bag else '',
                'state': restart.state, 'retention': bool(self.args.keep_s
                                                          or self.args.keep_bytes),
                'period_ns': round(NS_PER_S / self.args.rate), 'log': str(restart.log)}))
            # At niceness 19: the check takes what the node and the subscriber leave.
            self.checker = subprocess.Popen(
                [sys.executable, __file__, '--check-restart', str(path), '--out',
                 str(self.paths.out)], cwd=ROOT, preexec_fn=lambda: os.nice(19))

    # --- the loop ------------------------------------------------------------------------

    def run(self, duration_s, stopping):
        """Drive the node for ``duration_s``; return why the soak ended."""
        args = self.args
        start = time.monotonic()
        next_parameter = start + args.param_every
        next_calibration = start + args.calibrate_every
        next_sample = start
        next_progress = start + args.progress_every
        next_kill = self.next_kill_after(start)
        referenced = False
        while True:
            now = time.monotonic()
            if stopping:
                return 'the bench got a stop signal'
            if self.watch is None and self.runner.process.poll() is not None:
                return f'the node exited with status {self.runner.process.returncode}'
            if now - start >= duration_s and self.pending is None and self.watch is None:
                return 'duration reached'
            self.executor.spin_once(timeout_sec=0.02)
            self.poll()
            if self.watch is not None and self.watch.done.is_set():
                if self.watch.stopped_ns is None:
                    return f'the node exited with status {self.runner.process.returncode}'
                self.kill_and_restart()
                next_kill = self.next_kill_after(time.monotonic())
            now = time.monotonic()
            if now >= next_sample:
                next_sample = max(next_sample + args.sample_every, now)
                self.sample()
            scheduling = self.pending is not None and self.pending[0] == 'schedule'
            if (self.watch is None and referenced and now >= next_kill and not scheduling
                    and now - start < duration_s):
                self.arm_kill()
            if self.pending is None and now - start < duration_s:
                if not referenced:
                    referenced = self.calibrate(f'/{NODE}/capture_reference')
                elif now >= next_calibration and self.watch is None:
                    if self.calibrate(f'/{NODE}/self_calibrate'):
                        next_calibration += args.calibrate_every
                elif now >= next_parameter:
                    next_parameter += args.param_every
                    self.change_parameter()
            self.after_restart()
            if now >= next_progress:
                next_progress += args.progress_every
                print(self.progress(now - start), flush=True)

    def progress(self, elapsed_s):
        """Return one progress line from the last rows of the CSV files."""
        node = read_csv(self.paths.node)[-1:]
        stream = read_csv(self.paths.stream)[-1:]
        text = f'[{datetime.timedelta(seconds=round(elapsed_s))}] run {self.runner.run}'
        if stream:
            s = stream[0]
            text += (f'; samples {int(s["received"]):,} lost {s["lost"]} off-grid '
                     f'{s["off_grid"]} offset p50 {s["offset_p50_us"]} us;')
        if node:
            n = node[0]
            text += (f' RSS {int(n["rss_kib"]) / 1024:.1f} MiB fd {n["fds"]} threads '
                     f'{n["threads"]}; withheld {n["withheld"]} skipped {n["skipped"]}; '
                     f'{n["recorded_files"]} files {int(n["recorder_bytes"]) / MIB:.1f} MiB; '
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
    for path in (paths.files, paths.bags, paths.restarts, paths.recorded_gaps):
        path.unlink(missing_ok=True)  # appended to by each check
    tracemalloc_dir = None
    if args.tracemalloc:
        tracemalloc_dir = workdir / 'tracemalloc'
        tracemalloc_dir.mkdir(exist_ok=True)
    duration_s = args.hours * 3600.0 + args.minutes * 60.0
    command = node_command(output_dir, args)
    stopping = []
    for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(signum, lambda *_: stopping.append(True))
    subscriber = subprocess.Popen(
        [sys.executable, __file__, '--subscriber', '--domain', str(args.domain), '--out',
         str(paths.out), '--sample-every', str(args.sample_every), '--rate', str(args.rate)],
        env=node_environment(args.domain), cwd=ROOT)
    runner = NodeRunner(command, node_environment(args.domain, tracemalloc_dir,
                                                  args.snapshot_every), workdir)
    runner.start()
    run = {
        'bench': ' '.join([Path(sys.executable).name, *sys.argv]),
        'python': sys.executable, 'node_command': ' '.join(command[1:]),
        'commit': git_commit(),
        'started': datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds'),
        'started_ns': time.time_ns(), 'planned_s': duration_s, 'workdir': str(workdir),
        'node_pid': runner.process.pid, 'subscriber_pid': subscriber.pid,
        'domain': args.domain, 'split_s': args.split_s, 'max_bytes': args.max_bytes,
        'keep_s': args.keep_s, 'keep_bytes': args.keep_bytes, 'retention': RETENTION,
        'kill_every_s': args.kill_every, 'kill_jitter': KILL_JITTER, 'rate_hz': args.rate,
        'param_every_s': args.param_every, 'calibrate_every_s': args.calibrate_every,
        'warmup_s': args.warmup_min * 60.0, 'sample_every_s': args.sample_every,
        'tracemalloc': bool(args.tracemalloc),
        'allocator': {k: v for k, v in os.environ.items() if k.startswith('MALLOC_')},
        'machine': f'{platform.node()}, {os.cpu_count()} CPUs, {platform.machine()}, '
                   f'Linux {platform.release()}, Python {platform.python_version()}',
        'rotation': [name for name, _ in parameter_rotation()]}
    paths.run.write_text(json.dumps(run, indent=1))
    print(f'soak: node pid {runner.process.pid} (process group), subscriber pid '
          f'{subscriber.pid}, domain {args.domain}, {duration_s / 3600:.2f} h; workdir '
          f'{workdir}; CSV {paths.node}', flush=True)
    driver = None
    reason = 'not started'
    status = None
    try:
        driver = Driver(args, paths, runner, output_dir, subscriber)
        driver.wait_for_samples(args.start_timeout)
        reason = driver.run(duration_s, stopping)
        driver.sample()
    except Exception as error:
        reason = f'the bench failed: {type(error).__name__}: {error}'
        raise
    finally:
        print(f'soak: ending ({reason})', flush=True)
        if runner.process.poll() is None:
            os.kill(runner.process.pid, signal.SIGCONT)  # a kill's watch may have stopped it
        status = runner.stop()
        stop_process(subscriber)
        if driver is not None:
            driver.after_restart(wait=True)
            driver.close()
        run.update(ended_ns=time.time_ns(), end_reason=reason, node_exit_status=status,
                   runs=runner.run + 1)
        paths.run.write_text(json.dumps(run, indent=1))
    readback(paths, output_dir / 'recordings', round(NS_PER_S / args.rate))
    write_report(paths)
    print(f'soak: report {paths.out}, figure {paths.figure}', flush=True)


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
    parser.add_argument('--keep-s', type=float, help=f'{RETENTION["keep_s"]} [s]')
    parser.add_argument('--keep-bytes', type=int, help=RETENTION['keep_bytes'])
    parser.add_argument('--min-free-bytes', type=int, default=1 << 30)
    parser.add_argument('--param-every', type=float, default=5.0)
    parser.add_argument('--calibrate-every', type=float, default=300.0)
    parser.add_argument('--kill-every', type=float, default=0.0,
                        help='kill -9 and restart the node about this often [s] (0: never)')
    parser.add_argument('--sample-every', type=float, default=10.0)
    parser.add_argument('--progress-every', type=float, default=60.0)
    parser.add_argument('--warmup-min', type=float, default=10.0,
                        help='slopes are fitted after this many minutes of each run')
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
                        help="with --report: read what the run's recording holds first")
    parser.add_argument('--subscriber', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--check-restart', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscriber:
        run_subscriber(args)
    elif args.check_restart:
        check_restart(Paths(args.out), args.check_restart)
    elif args.snapshots:
        compare_snapshots(args.snapshots)
    elif args.report:
        paths = Paths(args.out)
        if args.readback:
            run = json.loads(paths.run.read_text())
            readback(paths, Path(run['workdir']) / 'out' / 'recordings',
                     round(NS_PER_S / run.get('rate_hz', 1000.0)))
        write_report(paths)
    else:
        if args.hours * 60 + args.minutes <= 0:
            parser.error('give --hours or --minutes')
        soak(args)


if __name__ == '__main__':
    main()
