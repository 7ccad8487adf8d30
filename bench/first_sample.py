"""Time from process start to the first sample a SensorDataQoS subscriber receives.

Run (the table in ``bench/results/first_sample.md``)::

    .venv/bin/python bench/first_sample.py --starts 10
    .venv/bin/python bench/first_sample.py --starts 10 --busy

One subscriber (``imu/data_raw``, ``qos_profile_sensor_data``: best effort, depth 5) runs
in this process for the whole run, on a ROS domain of its own, with the localhost-only
discovery and the Fast DDS profile the node uses (``config/fastdds_discovery.xml``).
Alternately, it starts

* the node as the tree's ``make run`` starts it (``.venv/bin/python -m qfa_ros.cli.node
  --ros-args --params-file config/qfa.yaml``, or the ``qfa_node`` console script in
  trees whose ``make run`` used it; the source tree first on ``PYTHONPATH``), fresh:
  ``output_dir`` and ``state_file`` in an empty temporary directory, so no stored state
  is loaded;
* a bare rclpy publisher of ``sensor_msgs/Imu`` at 1 kHz (the script at the end of this
  file) with the same interpreter, environment and publisher QoS as the node's;

and measures the wall time from ``subprocess.Popen`` to the first message received, and
the CPU time (user + system) the process had used by then (robust on a shared machine,
where the wall time is not); each process is then stopped (SIGINT, SIGKILL after 10 s)
before the next one starts. ``--tree LABEL=DIR`` adds the node of another source tree
(e.g. an export of an earlier commit) to the rotation, so that a before/after comparison
shares the machine's conditions. One start of each command runs untimed first (numba's
cache written after a source change, the sources' bytecode, the page cache;
``PYTHONDONTWRITEBYTECODE`` is removed from the environment). ``--busy`` keeps one core busy
(``while True: pass``) for the whole run. ``--phases`` instead times when each phase of the
node's start ends (imports, model, warm-up, first publication), by wall time since
Popen and by the CPU time (all threads) the process had used by then, tree after tree.
``--cold-cache`` instead checks ``make setup``'s warm-up: into an empty ``NUMBA_CACHE_DIR``,
``python -m qfa_ros.cli.warm_cache``, then ``qfa-sim static --duration 1`` and the node to
its first sample, each with ``NUMBA_DEBUG_CACHE=1``: neither may compile (save) a kernel.
"""

import argparse
import datetime
import json
import os
from pathlib import Path
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = Path(__file__).resolve().parents[1]
PROFILES_FILE = ROOT / 'config' / 'fastdds_discovery.xml'
RESULTS = ROOT / 'bench' / 'results' / 'first_sample.md'

BARE_PUBLISHER = """
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

rclpy.init()
node = rclpy.create_node('bare_imu')
publisher = node.create_publisher(Imu, 'imu/data_raw', QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE))
message = Imu()
message.header.frame_id = 'imu_link'


def tick():
    message.header.stamp = node.get_clock().now().to_msg()
    publisher.publish(message)


node.create_timer(0.001, tick)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
    pass
"""


PHASE_PROBE = """
import json
import os
import sys
import time

T0 = float(os.environ['FIRST_SAMPLE_T0'])
marks = {}


def mark(name):
    marks.setdefault(name, (time.time() - T0, time.process_time()))


mark('interpreter up')
import qfa_ros.cli.node as cli  # noqa: E402

mark('rclpy and qfa_ros.cli.node imported')
create_node = cli.create_node


def report():
    print('PHASES ' + json.dumps(marks), file=sys.stderr, flush=True)
    os.kill(os.getpid(), 2)


def probed_create_node(secured, managed=False):
    import qfa_ros.ros.node as node_module
    import qfa_ros.ros.pacing as pacing
    import qfa_ros.ros.stream as stream
    mark('qfa_ros.ros.node imported')
    make_triad = node_module.make_triad

    def probed_make_triad(*args):
        triad = make_triad(*args)
        mark('model built (numba initialised)')
        return triad

    node_module.make_triad = probed_make_triad
    start, warm_up = stream.SampleStream.start, stream.SampleStream._warm_up

    def probed_start(self):
        mark('sensor thread started')
        start(self)

    def probed_warm_up(self):
        warm_up(self)
        mark('warm-up done')

    stream.SampleStream.start, stream.SampleStream._warm_up = probed_start, probed_warm_up
    publish_hand = pacing.Pacer._publish_hand

    def probed_publish_hand(self, *args):
        publisher = self._hand[0][1]
        publish = publisher.publish

        def first_publish(data):
            mark('first sample published')
            publish(data)
            publisher.publish = publish
            report()

        if 'first sample published' not in marks:
            publisher.publish = first_publish
        publish_hand(self, *args)

    pacing.Pacer._publish_hand = probed_publish_hand
    result = create_node(secured, managed)
    mark('node created')
    return result


cli.create_node = probed_create_node
sys.argv[0] = 'qfa_node'
cli.main()
"""


def phases(trees, starts, directory, env):
    """
    Time the node's start-up phases from Popen, ``starts`` times per tree, in turn.

    The node runs under a probe (``PHASE_PROBE``: the module is imported by a script, not
    the console script) that notes when each phase ends, by wall time since Popen.
    """
    probe = Path(directory) / 'phase_probe.py'
    probe.write_text(PHASE_PROBE)
    seen = {label: [] for label, _ in trees}
    for n in range(starts + 1):
        for label, tree in trees:
            argv, cwd, extra = node_command(tree, Path(directory) / f'phases_{label}_{n}')
            argv = [sys.executable, str(probe), *argv[argv.index('--ros-args'):]]
            run = subprocess.run(argv, cwd=cwd, env={
                **env, **extra, 'FIRST_SAMPLE_T0': repr(time.time())},
                capture_output=True, text=True, timeout=120)
            line = [x for x in run.stderr.splitlines() if x.startswith('PHASES ')]
            if n and line:
                seen[label].append(json.loads(line[0].split(' ', 1)[1]))
    names = list(next(iter(seen.values()))[0])
    lines = ['| Phase ends: wall s since Popen (CPU s of the process), p50 | '
             + ' | '.join(label for label, _ in trees) + ' |',
             '|---|' + '---:|' * len(trees)]
    for name in names:
        cells = []
        for label, _ in trees:
            values = [run[name] for run in seen[label] if name in run]
            cells.append(f'{statistics.median(v[0] for v in values):.3f} '
                         f'({statistics.median(v[1] for v in values):.2f})' if values else '')
        lines.append(f'| {name} | ' + ' | '.join(cells) + ' |')
    return lines, {label: len(runs) for label, runs in seen.items()}


def environment(domain):
    """Return the environment of every process of the run (subscriber included)."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['FASTDDS_DEFAULT_PROFILES_FILE'] = str(PROFILES_FILE)
    env['PYTHONUNBUFFERED'] = '1'
    env.pop('PYTHONPATH', None)
    # As in a user's shell: the untimed first start caches the sources' bytecode (which
    # `make setup` also compiles), instead of every start compiling the project's sources.
    env.pop('PYTHONDONTWRITEBYTECODE', None)
    return env


class FirstSample:
    """A SensorDataQoS subscriber of ``imu/data_raw`` noting when a message arrives."""

    def __init__(self):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import Imu

        self._context = Context()
        rclpy.init(context=self._context)
        self._node = rclpy.create_node('first_sample_bench', context=self._context)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._arrived = threading.Event()
        self.arrival = None
        self._armed = False
        self._node.create_subscription(Imu, 'imu/data_raw', self._callback,
                                       qos_profile_sensor_data)
        self._running = True
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while self._running:
            self._executor.spin_once(timeout_sec=0.05)

    def _callback(self, message):
        if self._armed and not self._arrived.is_set():
            self.arrival = time.perf_counter()
            self._arrived.set()

    def arm(self):
        """Forget the last arrival; note the next one."""
        self.arrival = None
        self._arrived.clear()
        self._armed = True

    def wait(self, timeout_s):
        """Return the arrival time (perf_counter) of the first message, or None."""
        self._arrived.wait(timeout_s)
        self._armed = False
        return self.arrival

    def close(self):
        self._running = False
        self._thread.join()
        self._node.destroy_node()
        self._context.try_shutdown()


def stop(process):
    """Stop ``process`` (SIGINT, SIGKILL after 10 s) and reap it."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(10.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def node_command(tree, directory):
    """Return ``(argv, cwd, env additions)`` of the node of source tree ``tree``, fresh."""
    # What the tree's `make run` starts: the module, or the console script (.venv/bin/qfa_node).
    script = Path(sys.executable).parent / 'qfa_node'
    recipe = (Path(tree) / 'Makefile').read_text()
    start = [sys.executable, '-m', 'qfa_ros.cli.node']
    if '-m qfa_ros.cli.node' not in recipe and script.exists():
        start = [str(script)]
    return ([*start, '--ros-args', '--params-file',
             str(Path(tree) / 'config' / 'qfa.yaml'),
             '-p', f'output_dir:={directory}',
             '-p', f'state_file:={directory}/calibration.json'],
            str(tree), {'PYTHONPATH': str(tree)})


def cpu_seconds(pid):
    """Return the user + system CPU time process ``pid`` has used so far [s]."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def time_start(subscriber, argv, cwd, env, timeout_s):
    """
    Start ``argv``; return ``(wall s, CPU s)`` to its first sample (None: none in time).

    The CPU time (user + system of the process, read as soon as the sample is seen) does
    not depend on what else the machine runs, as the wall time does.
    """
    subscriber.arm()
    with open(os.devnull, 'w') as sink:
        started = time.perf_counter()
        process = subprocess.Popen(argv, cwd=cwd, env=env, stdout=sink, stderr=sink)
        arrival = subscriber.wait(timeout_s)
        cpu = cpu_seconds(process.pid) if arrival is not None else None
        stop(process)
    return (None, None) if arrival is None else (arrival - started, cpu)


def cold_cache(subscriber, env, timeout_s):
    """Return the Markdown lines of what each step compiled after warming an empty cache."""
    with tempfile.TemporaryDirectory() as scratch:
        env = {**env, 'NUMBA_CACHE_DIR': f'{scratch}/numba', 'NUMBA_DEBUG_CACHE': '1',
               'PYTHONPATH': str(ROOT)}
        steps = []
        for label, argv in (
                ('python -m qfa_ros.cli.warm_cache (make setup)',
                 [sys.executable, '-m', 'qfa_ros.cli.warm_cache']),
                ('qfa-sim static --duration 1 (make sim)',
                 [sys.executable, '-m', 'qfa_ros.cli.sim', 'static', '--duration', '1'])):
            done = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True,
                                  timeout=900)
            steps.append((label, done.returncode, done.stdout))
        log = Path(scratch) / 'node.log'
        argv, cwd, _ = node_command(ROOT, Path(scratch) / 'node')
        subscriber.arm()
        with open(log, 'w') as stream:
            process = subprocess.Popen(argv, cwd=cwd, env=env, stdout=stream,
                                       stderr=subprocess.STDOUT)
            arrival = subscriber.wait(timeout_s)
            stop(process)
        steps.append(('the node to its first sample (make run)',
                      0 if arrival is not None else 'no sample', log.read_text()))
    lines = ['| step | status | kernels loaded from the cache | kernels compiled (saved) |',
             '|---|---|---:|---:|']
    lines += [f'| {label} | {status} | {output.count("data loaded")} | '
              f'{output.count("data saved")} |' for label, status, output in steps]
    return lines


def summary(values):
    good = [v for v in values if v is not None]
    missing = len(values) - len(good)
    if not good:
        return 'none', 'none', missing
    return f'{statistics.median(good):.2f}', f'{max(good):.2f}', missing


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--starts', type=int, default=10, help='timed starts per command')
    parser.add_argument('--busy', action='store_true', help='keep one core busy')
    parser.add_argument('--tree', action='append', default=[],
                        help='another source tree whose node joins the rotation '
                        '(label=DIR or DIR)')
    parser.add_argument('--domain', type=int, default=int(os.environ.get('ROS_DOMAIN_ID', 77)))
    parser.add_argument('--timeout', type=float, default=60.0)
    parser.add_argument('--label', default='this tree', help="label of this tree's node")
    parser.add_argument('--out', default=str(RESULTS), help='Markdown file to append to')
    parser.add_argument('--phases', action='store_true',
                        help="time the node's start-up phases instead (no subscriber)")
    parser.add_argument('--cold-cache', action='store_true',
                        help="check make setup's warm-up of an empty numba cache instead")
    args = parser.parse_args()

    env = environment(args.domain)
    os.environ.update({k: env[k] for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE',
                                           'FASTDDS_DEFAULT_PROFILES_FILE')})
    trees = [(args.label, ROOT)]
    for spec in args.tree:
        label, _, path = spec.rpartition('=')
        trees.append((label or path, Path(path).resolve()))
    load = os.getloadavg()[0]
    command = ' '.join(['.venv/bin/python', 'bench/first_sample.py'] + sys.argv[1:])
    if args.phases:
        busy = subprocess.Popen([sys.executable, '-c', 'while True: pass']) if args.busy \
            else None
        try:
            with tempfile.TemporaryDirectory() as scratch:
                table, counts = phases(trees, args.starts, scratch, env)
        finally:
            if busy is not None:
                busy.kill()
                busy.wait()
        text = '\n'.join([
            f'### Start-up phases{", one core busy" if args.busy else ""}, '
            f'{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC', '',
            f'`{command}` ({os.cpu_count()} cores; load average before the run '
            f'{load:.2f}; starts per tree: {counts})', '', *table]) + '\n'
        print(text)
        with open(args.out, 'a') as stream:
            stream.write('\n' + text)
        return
    if args.cold_cache:
        subscriber = FirstSample()
        try:
            table = cold_cache(subscriber, env, args.timeout)
        finally:
            subscriber.close()
        text = '\n'.join([
            f'### After the warm-up of an empty cache, '
            f'{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC', '',
            f'`{command}` (load average before the run {load:.2f})', '', *table]) + '\n'
        print(text)
        with open(args.out, 'a') as stream:
            stream.write('\n' + text)
        return
    busy = None
    if args.busy:
        busy = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    subscriber = FirstSample()
    commands = []
    with tempfile.TemporaryDirectory() as scratch:
        bare = Path(scratch) / 'bare_publisher.py'
        bare.write_text(BARE_PUBLISHER)
        commands.append(('bare rclpy publisher', lambda n: ([sys.executable, str(bare)],
                                                            str(ROOT), {})))
        for label, tree in trees:
            commands.append((f'node ({label})', lambda n, tree=tree: node_command(
                tree, Path(scratch) / f'node_{n}')))
        times = {label: [] for label, _ in commands}
        cpu = {label: [] for label, _ in commands}
        first = {}
        try:
            for n in range(args.starts + 1):
                for label, make in commands:
                    argv, cwd, extra = make(f'{len(times[label])}_{n}_{label[:4]}')
                    elapsed, used = time_start(subscriber, argv, cwd, {**env, **extra},
                                               args.timeout)
                    if n == 0:
                        first[label] = elapsed
                    else:
                        times[label].append(elapsed)
                        cpu[label].append(used)
                    print(f'{label}: {elapsed} s, {used} CPU s', flush=True)
        finally:
            subscriber.close()
            if busy is not None:
                busy.kill()
                busy.wait()

    bare_p50 = statistics.median(v for v in times['bare rclpy publisher'] if v is not None)
    lines = [
        f'### {"One core busy" if args.busy else "No load added"}, '
        f'{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC',
        '',
        f'`{command}` ({os.cpu_count()} cores; load average before the run '
        f'{load:.2f})',
        '',
        '| Process | Starts | p50 [s] | max [s] | p50 / bare p50 | CPU p50 [s] | no sample '
        '| untimed first start [s] |',
        '|---|---:|---:|---:|---:|---:|---:|---:|',
    ]
    for label, values in times.items():
        p50, worst, missing = summary(values)
        ratio = '' if p50 == 'none' else f'{float(p50) / bare_p50:.2f}'
        cpu_p50 = summary(cpu[label])[0]
        untimed = first.get(label)
        lines.append(f'| {label} | {len(values)} | {p50} | {worst} | {ratio} | {cpu_p50} | '
                     f'{missing} | {"none" if untimed is None else f"{untimed:.2f}"} |')
    text = '\n'.join(lines) + '\n'
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, 'a') as stream:
        stream.write('\n' + text)


if __name__ == '__main__':
    main()
