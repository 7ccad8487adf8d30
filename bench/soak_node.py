"""
The soak's node process: its environment and command, a start, a kill and a stop.

Also what a kill waits for, and the node's resources from ``/proc``: ``soak.py``'s
helpers (its docstring describes the run).
"""

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))  # crash_helpers: the crash tests' own tools

from crash_helpers import deletion_watch, split_watch, stop_when  # noqa: E402
from soak_csv import CLOCK_TICKS  # noqa: E402

PROFILES_FILE = ROOT / 'config' / 'fastdds_discovery.xml'
HOOK_DIRECTORY = Path(__file__).resolve().parent / 'soak_hook'
RETENTION = {'keep_s': 'recorder.keep_s', 'keep_bytes': 'recorder.keep_bytes'}
"""The recorder's retention parameters, set from ``--keep-s`` and ``--keep-bytes``."""


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


# --- the node process ---------------------------------------------------------------------

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
    for option, name in RETENTION.items():
        if getattr(args, option) is not None:
            overrides[name] = f'{getattr(args, option):g}'
    command = [sys.executable, '-m', 'qfa_ros.cli.node', '--ros-args', '--params-file',
               str(ROOT / 'config' / 'qfa.yaml')]
    for name, value in overrides.items():
        command += ['-p', f'{name}:={value}']
    return command


class NodeRunner:
    """
    The node process, started again with the same command after each kill.

    Parameters
    ----------
    command : list of str
        Its command line.
    env : dict
        Its environment.
    workdir : pathlib.Path
        Where its logs go (``node_<run>.log``).
    """

    def __init__(self, command, env, workdir):
        self.command = command
        self.env = env
        self.workdir = workdir
        self.run = -1
        self.process = None
        self.log_path = None
        self.started_ns = None
        self._log = None

    def start(self):
        """Start the next run of the node in its own process group."""
        self.run += 1
        self.log_path = self.workdir / f'node_{self.run}.log'
        self._log = open(self.log_path, 'w')
        self.started_ns = time.time_ns()
        self.process = subprocess.Popen(
            self.command, env=self.env, stdout=self._log, stderr=subprocess.STDOUT, cwd=ROOT,
            start_new_session=True)

    def kill(self):
        """SIGKILL the node's process group and reap the node."""
        os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait()
        self._log.close()

    def stop(self):
        """SIGTERM the process group (SIGKILL after 30 s); return the exit status."""
        status = stop_process(self.process, group=True)
        self._log.close()
        return status


def stop_process(process, group=False, timeout_s=30.0):
    """SIGTERM ``process`` (its process group); SIGKILL after ``timeout_s``; return its status."""
    send = (lambda signum: os.killpg(process.pid, signum)) if group else process.send_signal
    if process.poll() is None:
        send(signal.SIGTERM)
    try:
        return process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        send(signal.SIGKILL)
        return process.wait()


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


# --- kills ------------------------------------------------------------------------------

class KillWatch:
    """
    Stop the node (SIGSTOP) at the instant a kill mode waits for, in a thread of its own.

    Parameters
    ----------
    process : subprocess.Popen
        The node.
    mode : str
        One of ``soak.KILL_MODES``.
    recordings : pathlib.Path
        The recorder directory.
    timeout_s : float
        How long to wait for a split or a deletion; then the node is stopped where it is.
    """

    def __init__(self, process, mode, recordings, timeout_s):
        self.mode = mode
        self.stopped_ns = None
        self.hit = 0
        self.done = threading.Event()
        check = {'split': split_watch, 'deletion': deletion_watch}.get(mode)
        if check is None:
            self.stopped_ns = time.time_ns()
            os.kill(process.pid, signal.SIGSTOP)
            self.hit = 1
            self.done.set()
            return
        threading.Thread(target=self._watch, args=(process, check(recordings), timeout_s),
                         daemon=True).start()

    def _watch(self, process, check, timeout_s):
        try:
            self.stopped_ns = stop_when(process, check, timeout_s)
            self.hit = int(self.stopped_ns is not None)
            if self.stopped_ns is None and process.poll() is None:
                self.stopped_ns = time.time_ns()
                os.kill(process.pid, signal.SIGSTOP)
        finally:
            self.done.set()


class Restart:
    """
    What the driver knows of one kill until its check is under way.

    Parameters
    ----------
    watch : KillWatch
        The kill's watch (its mode, whether it hit, when the node was stopped).
    run : int
        The run started after it.
    state : dict
        The recorder directory as the kill left it (``disk_state``).
    killed_bag : pathlib.Path or None
        The bag the killed run recorded into.
    """

    def __init__(self, watch, run, state, killed_bag):
        self.mode = watch.mode
        self.hit = watch.hit
        self.kill_ns = watch.stopped_ns
        self.run = run
        self.state = state
        self.killed_bag = killed_bag
        self.restarted_ns = None
        self.log = None
        """The restarted node's log (its start-up recovery's WARN line)."""
        self.first_published_ns = None
        self.deadline = None

    def recovered(self):
        """Return whether the killed run's bag needs nothing more (or is gone)."""
        from qfa_ros.bag.recovery import needs_recovery
        if self.killed_bag is None or time.monotonic() > self.deadline:
            return True
        try:
            return not needs_recovery(self.killed_bag)
        except FileNotFoundError:
            return True
