"""
Issue 36's probes of the trust boundary, from another participant, against a real node.

Run: ``ROS_DOMAIN_ID=<id> .venv/bin/python bench/boundary_probes.py [--out FILE]``. Starts
``qfa_node`` as a user would (the installed entry point, ``--ros-args -p ...``, its own
process and working directory, ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and probes it
from this process, a separate rclpy participant, through ``SetParameters``, the
``input/imu`` topic and ``~/set_compensation``: paths that lead somewhere
(``/proc/self/cwd``, ``/proc/self/fd/N``, another process's ``/proc/<pid>/cwd``, a symlink
planted under ``output_dir``), the stamp window and one message stamped far ahead, arrays
of 200 000 elements and a 100 000-character choice, a recorder change whose effect fails;
then ``--churn`` participants (300) coming and going, each subscribing to the stream and
living 0 to 60 ms (some discovered fully, some half way, some not at all) with one core kept
busy, after which a newcomer must find the node, its samples and a parameter answer; then
restarts on a state file holding a word where a number goes, on one nested too deeply and on
one with an infinity in an integer field. Prints a Markdown transcript: every answer quoted,
the node alive, the honest input's samples before and after.
"""

import argparse
import datetime
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import time
from types import SimpleNamespace

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))

from node_helpers import Client, Lifecycle  # noqa: E402

SECRET = 'SECRET_WORD_in_the_state_file'
PROBES_HEADING = '## Probes from another participant'
TITLE = '# Issue 36: the trust boundary, second pass'
INPUT_RATE_HZ = 200.0


class UserNode:
    """``qfa_node`` (``qfa_lifecycle_node``) started as a user would, in its own directory."""

    def __init__(self, work, domain, parameters, managed=False):
        self.log_path = work / f'node_{time.monotonic_ns()}.log'
        self._log = open(self.log_path, 'w')
        arguments = [f'{name}:={value}' for name, value in parameters.items()]
        name = 'qfa_lifecycle_node' if managed else 'qfa_node'
        executable = shutil.which(name, path=str(Path(sys.executable).parent))
        env = {**os.environ, 'ROS_DOMAIN_ID': str(domain),
               'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'PYTHONUNBUFFERED': '1'}
        self.command = [name, '--ros-args'] + [part for argument in arguments
                                               for part in ('-p', argument)]
        self.process = subprocess.Popen([executable] + self.command[1:], cwd=work, env=env,
                                        stdout=self._log, stderr=subprocess.STDOUT)

    @property
    def alive(self):
        return self.process.poll() is None

    def log(self):
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def stop(self):
        if self.alive:
            self.process.terminate()
        try:
            return self.process.wait(30)
        finally:
            self._log.close()


class Probe:
    """The participant: parameters, the input topic, the stream and the diagnostics."""

    def __init__(self, domain):
        self.client = Client(domain)
        self.stamps = []
        self.diagnostics = []
        node = self.client.node
        node.create_subscription(Imu, 'imu/data_raw', self._on_imu, qos_profile_sensor_data)
        node.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics.append, 10)
        self.truth = node.create_publisher(
            Imu, 'input/imu', QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))

    def _on_imu(self, message):
        stamp = message.header.stamp
        self.stamps.append(stamp.sec * 1_000_000_000 + stamp.nanosec)

    def close(self):
        self.client.close()

    def set(self, name, value):
        """Set one parameter; return (successful, reason)."""
        result, = self.client.set_parameters({name: value}, timeout=60.0)
        return result.successful, result.reason

    def publish(self, offset_s=0.0):
        """Publish one ground-truth Imu at rest, stamped ``offset_s`` from now."""
        stamp_ns = time.time_ns() + int(offset_s * 1e9)
        message = Imu()
        message.header.stamp = Time(sec=stamp_ns // 1_000_000_000,
                                    nanosec=stamp_ns % 1_000_000_000)
        message.linear_acceleration.z = 9.8
        message.angular_velocity_covariance[0] = -1.0
        self.truth.publish(message)

    def honest_input(self, seconds):
        """Publish the honest input at 200 Hz for ``seconds``; return the samples received."""
        count = len(self.stamps)
        period = 1.0 / INPUT_RATE_HZ
        start = time.monotonic()
        next_at = start
        while time.monotonic() - start < seconds:
            now = time.monotonic()
            if now >= next_at:
                self.publish()
                next_at += period
            self.client.executor.spin_once(timeout_sec=max(0.0, min(period, next_at - now)))
        return len(self.stamps) - count

    def status(self, name):
        """Return the node's diagnostic ``name`` as {key: value, 'message': ...} (the latest)."""
        count = len(self.diagnostics)
        self.client.spin_until(lambda: len(self.diagnostics) > count, 30.0, 'diagnostics')
        for status in self.diagnostics[-1].status:
            if status.name.endswith(f': {name}'):
                return {'message': status.message, **{kv.key: kv.value for kv in status.values}}
        return {}


def churn(domain, count, budget_s):
    """
    Create and destroy up to ``count`` participants, each subscribing to ``imu/data_raw``.

    Each lives between 0 and 60 ms after its node is up, so that the node discovers some
    fully, some half way and some not at all before they leave. Returns how many ran.
    """
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    deadline = time.monotonic() + budget_s
    done = 0
    for index in range(count):
        if time.monotonic() > deadline:
            break
        context = Context()
        rclpy.init(context=context, domain_id=domain)
        try:
            node = Node(f'churn_{index}', context=context)
            node.create_subscription(Imu, 'imu/data_raw', lambda message: None, qos)
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            until = time.monotonic() + (index % 4) * 0.02
            while time.monotonic() < until:
                executor.spin_once(timeout_sec=0.01)
            executor.shutdown()
            node.destroy_node()
        finally:
            rclpy.try_shutdown(context=context)
        done += 1
    return done


def write_section(path, heading, text, title=TITLE):
    """Write ``text`` (starting with ``heading``) into ``path``, replacing that section.

    A new file starts with ``title``.
    """
    sections = path.read_text().rstrip('\n').split('\n\n' + '## ') if path.exists() \
        else [title]
    body = text.rstrip('\n').removeprefix('## ')
    title = heading.removeprefix('## ')
    index = next((k for k, section in enumerate(sections) if k and section.startswith(title)),
                 len(sections))
    sections[index:index + 1] = [body]
    path.write_text('\n\n## '.join(sections) + '\n')


def delta(key, first, second):
    """Return how much the diagnostic counter ``key`` grew from ``first`` to ``second``."""
    return int(second.get(key, 0)) - int(first.get(key, 0))


def quoted(lines, name, value, answer):
    successful, reason = answer
    shown = value if len(repr(value)) < 80 else f'<{len(value)} {type(value[0]).__name__}s>'
    lines.append(f'| `{name}` | `{shown!r}` | {"accepted" if successful else "refused"} | '
                 f'{len(reason)} | {reason.replace("|", "/") or "—"} |')


HOSTILE_STATES = {
    'a word where a number goes': json.dumps({
        'format': 'qfa_ros.calibration/1', 'references': [{}, {}, {}],
        'controller_gain': [SECRET, 1.0, 1.0], 'n_vref': []}),
    'nested 100 000 deep': '[' * 100_000 + ']' * 100_000,
    'Infinity in an integer field': json.dumps({
        'format': 'qfa_ros.calibration/1', 'references': [{}, {}, {}],
        'controller_gain': [], 'n_vref': [float('inf'), 1, 1]}),
}
"""State files a stranger with a shell might leave: the node starts (configures) on each."""


def plant(scratch):
    """Make the node's directories and what a stranger left around them; return them."""
    files = SimpleNamespace(work=scratch / 'work', out=scratch / 'out',
                            elsewhere=scratch / 'elsewhere', victim=scratch / 'victim.txt',
                            imu_yaml=scratch / 'imu.yaml', motion=scratch / 'motion.csv')
    for directory in (files.work, files.out, files.elsewhere):
        directory.mkdir()
    (files.out / 'planted').symlink_to(files.elsewhere, target_is_directory=True)
    (files.out / 'blocked').write_text('a file where a directory would go\n')
    files.victim.write_text('not yours\n')
    files.imu_yaml.write_text(
        'accelerometer_noise_density: 1.0e-4\naccelerometer_random_walk: 1.0e-5\n'
        'gyroscope_noise_density: 1.0e-5\ngyroscope_random_walk: 1.0e-6\n')
    files.motion.write_text('time_s,latitude_deg,longitude_deg,height_m,roll_deg,pitch_deg,'
                            'yaw_deg\n0,45,0,0,0,0,0\n10,45,0,0,0,0,0\n')
    return files


def parameter_probes(files, configured):
    """Return the SetParameters probes of one state: (name, value)."""
    probes = [('trace_dir', '/proc/self/cwd'), ('recorder.directory', '/proc/self/cwd'),
              *[('trace_dir', f'/proc/self/fd/{fd}') for fd in range(6)],
              ('trace_dir', f'/proc/{os.getpid()}/cwd'), ('trace_dir', 'planted'),
              ('recorder.directory', 'planted/x'), ('trace_dir', 'planted/../..'),
              ('input.stamp_window_s', 3600.0),
              ('input.steps.times_s', [float(k) for k in range(200_000)]),
              ('input.steps.levels', [0.0] * 200_000), ('input.mode', 'x' * 100_000),
              # The operator's (issue 43): a user's file as the state, the output elsewhere,
              # files to read, the resources; a setting of the sensor's own.
              ('state_file', str(files.victim)), ('output_dir', str(files.elsewhere)),
              ('noise.imu_yaml', str(files.imu_yaml)),
              ('input.trajectory_file', str(files.motion)), ('state.fresh', True),
              ('min_free_bytes', 1 << 20), ('recorder.keep_s', 1.0),
              ('recorder.keep_bytes', 1), ('sample_rate_hz', 2000.0), ('seed', 7)]
    if configured:
        # A recording running, then moved where it cannot start: the change is refused
        # and the recording goes on where it was.
        probes += [('recorder.directory', 'recordings'), ('recorder.enabled', True),
                   ('recorder.directory', 'blocked/bag')]
    return probes


def probe_parameters(probe, lines, files, configured, publishing=True):
    """Send the state's probes; write their answers (publishing: and where it records)."""
    lines += ['| parameter | value | answer | length | reason |', '|---|---|---|---|---|']
    reasons = []
    for name, value in parameter_probes(files, configured):
        answer = probe.set(name, value)
        reasons.append(answer[1])
        quoted(lines, name, value, answer)
    if probe.set('seed', 1)[0]:
        lines.append('| `seed` | `1` | accepted | 0 | — (back to the start value) |')
    told = [text for text in (str(files.work), str(files.elsewhere))
            if any(text in reason for reason in reasons)]
    lines += ['', f'Paths of the node the answers tell: {told or "none"}.', '']
    if configured:
        directory, = probe.client.get_parameters(['recorder.directory'])
        recording = 'not published while inactive'
        if publishing:
            probe.client.spin_for(1.0)  # the recorder opens its file with the next samples
            recording = probe.status('stream').get('recording', 'none')
        lines += [f'After the refused move: `recorder.directory` is `{directory!r}`; stream '
                  f'diagnostic, recording: `{recording}`.', '']
        probe.set('recorder.enabled', False)


def probe_ground_truth(probe, lines):
    """Honest input, one message stamped ahead, honest input again; write what happened."""
    assert probe.set('input.mode', 'topic')[0]
    lines += ['Ground truth from the participant:', '']
    for offset_s, label in ((3000.0, '+3000 s'), (0.9, '+0.9 s (inside the window)')):
        before = probe.honest_input(3.0)
        start = probe.status('input')
        for _ in range(3):  # best effort: sent thrice, so that one arrives
            probe.publish(offset_s)
        after = probe.honest_input(4.0)
        held = probe.status('input')
        recovered = probe.honest_input(2.0)
        end = probe.status('input')
        lines += [f'- honest input at 200 Hz, then one message stamped {label} (sent '
                  f'thrice), then the honest input again. `imu/data_raw` samples received '
                  f'(best effort, depth 5): {before} in the 3 s before, {after} in the 4 s '
                  f'after, {recovered} in the 2 s after those. Input diagnostic: stamps '
                  f'refused {delta("refused stamps", start, held)}; honest messages rejected '
                  f'as out of order {delta("rejected inputs", start, held)} in the 4 s after, '
                  f'{delta("rejected inputs", held, end)} in the 2 s after those; last '
                  f'rejection "{end.get("last rejection", "none")}"']
    probe.set('input.mode', 'static')
    stream = probe.status('stream')
    lines += ['', f'`imu/data_raw` samples received in 1 s, static input: '
              f'{probe.honest_input(1.0)}; stream diagnostic: "{stream.get("message")}", '
              f'samples computed {stream.get("samples computed")}, withheld '
              f'{stream.get("samples withheld")}, skipped {stream.get("samples skipped")}.', '']


def probe_churn(args, node, lines):
    """Participants coming and going by the hundred, one core busy; then a newcomer."""
    busy = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    try:
        started = time.monotonic()
        ran = churn(args.domain, args.churn, 120.0)
        churned_s = time.monotonic() - started
    finally:
        busy.kill()
        busy.wait()
    newcomer = Probe(args.domain)
    try:
        newcomer.client.spin_until(lambda: 'qfa_node' in newcomer.client.node.get_node_names(),
                                   30.0, 'the node in the graph')
        newcomer.client.spin_until(lambda: len(newcomer.stamps) > 500, 30.0,
                                   'samples after the churn')
        answer = newcomer.client.get_parameters(['sample_rate_hz'])
    finally:
        newcomer.close()
    lines += ['### Participants coming and going', '',
              f'{ran} participants in {churned_s:.0f} s (one core busy), each subscribing to '
              '`imu/data_raw` (best effort, depth 5) and living 0 to 60 ms; then a newcomer '
              f'found the node, received 500 samples and the answer `sample_rate_hz` = '
              f'{answer}; node alive: {node.alive}.', '']


def change(probe, label):
    """Ask for a lifecycle transition as the participant; return (success, state after)."""
    return Lifecycle(probe.client).change(label)


def plain_node(args, scratch, lines):
    """Probe ``qfa_node``: parameters, ground truth, churn; then restarts on hostile state."""
    files = plant(scratch)
    parameters = {'output_dir': str(files.out), 'state_file': str(files.out / 'state.json'),
                  'diagnostics_rate_hz': 10.0}
    node = UserNode(files.work, args.domain, parameters)
    probe = Probe(args.domain)
    try:
        probe.client.spin_until(lambda: len(probe.stamps) > 100, 120.0, 'the node')
        lines += ['## `qfa_node`', '', f'Node: `{" ".join(node.command)}` (working directory '
                  f'`{files.work}`, output_dir `{files.out}`, `out/planted` -> '
                  f'`{files.elsewhere}`).', '', '### SetParameters from the participant', '']
        probe_parameters(probe, lines, files, configured=True)
        probe_ground_truth(probe, lines)
        lines.append(f'Node alive after the probes: {node.alive}.')
        lines.append('')
        probe_churn(args, node, lines)
    finally:
        probe.close()
        stopping = time.monotonic()
        status = node.stop()
        stopped_s = time.monotonic() - stopping
    untouched = files.victim.read_text() == 'not yours\n'
    lines += [f'Node stopped (SIGTERM) with status {status} in {stopped_s:.1f} s; the '
              f"user's file untouched: {untouched}.", '']

    # Restarts on hostile state files: the start goes on, the file is set aside.
    lines += ['### Restarts on a hostile state file', '']
    for label, text in HOSTILE_STATES.items():
        (files.out / 'state.json').write_text(text)
        node = UserNode(files.work, args.domain, parameters)
        probe = Probe(args.domain)
        try:
            up = False
            try:
                probe.client.spin_until(lambda: len(probe.stamps) > 100 or not node.alive,
                                        120.0, 'the node')
                up = node.alive
            finally:
                probe.close()
        finally:
            node.stop()
        hostile_lines(lines, label, node.log(), f'node publishing {up}')


def hostile_lines(lines, label, log, outcome):
    errors = [line for line in log.splitlines() if '[ERROR]' in line]
    lines += [f'- {label}: {outcome}; traceback in its output: {"Traceback" in log}; the '
              f'word in its output: {SECRET in log}; ERROR lines:', '', '```text', *errors,
              '```', '']


def managed_node(args, scratch, lines):
    """Probe ``qfa_lifecycle_node`` in every state; the participant drives its transitions."""
    files = plant(scratch)
    parameters = {'output_dir': str(files.out), 'state_file': str(files.out / 'state.json'),
                  'diagnostics_rate_hz': 10.0}
    node = UserNode(files.work, args.domain, parameters, managed=True)
    probe = Probe(args.domain)
    lifecycle = Lifecycle(probe.client)
    try:
        probe.client.spin_until(lambda: lifecycle.state() == 'unconfigured', 120.0,
                                'the node unconfigured')
        lines += ['## `qfa_lifecycle_node`', '', f'Node: `{" ".join(node.command)}` (working '
                  f'directory `{files.work}`, output_dir `{files.out}`, `out/planted` -> '
                  f'`{files.elsewhere}`). This participant, a stranger, asks for every '
                  'transition through `~/change_state`: nothing stops it (ROS 2 has no access '
                  'control on services without SROS2 permissions).', '']
        steps = [('unconfigured, before the first configure', []),
                 ('inactive', ['configure']), ('active', ['activate']),
                 ('unconfigured, after a cleanup', ['deactivate', 'cleanup'])]
        for label, transitions in steps:
            answers = [f'`{name}`: {change(probe, name)}' for name in transitions]
            lines += [f'### {label}', '']
            if answers:
                lines += [f'Transitions asked for (success, state after): {", ".join(answers)}.',
                          '']
            configured = label in ('inactive', 'active')
            probe_parameters(probe, lines, files, configured, publishing=label == 'active')
            if label == 'active':
                probe_ground_truth(probe, lines)
        lines += ['### Configured again on a hostile state file', '']
        for label, text in HOSTILE_STATES.items():
            (files.out / 'state.json').write_text(text)
            count = len(node.log())
            configured = change(probe, 'configure')
            activated = change(probe, 'activate')
            published = len(probe.stamps)
            probe.client.spin_until(lambda: len(probe.stamps) > published + 100, 60.0,
                                    'samples')
            after = [change(probe, name) for name in ('deactivate', 'cleanup')]
            hostile_lines(lines, label, node.log()[count:],
                          f'configure {configured}, activate {activated}, publishing, '
                          f'deactivate and cleanup {after}')
        shutdown = change(probe, 'shutdown')
        lines += ['### A stranger ends it', '', f'`shutdown` from the participant: {shutdown}; '
                  f'`configure` afterwards: {change(probe, "configure")} (finalized until the '
                  f'process is started again); process alive: {node.alive}.', '']
    finally:
        probe.close()
        status = node.stop()
    untouched = files.victim.read_text() == 'not yours\n'
    outside = sorted(path.name for path in files.elsewhere.iterdir()) or 'none'
    lines += [f"Node stopped (SIGTERM) with status {status}; the user's file untouched: "
              f'{untouched}; files written outside output_dir: {outside}.', '']


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--domain', type=int, default=int(os.environ.get('ROS_DOMAIN_ID', 77)))
    parser.add_argument('--out', type=Path, help='also write the transcript here')
    parser.add_argument('--churn', type=int, default=300,
                        help='participants coming and going (default 300)')
    args = parser.parse_args(argv)
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    lines = [PROBES_HEADING, '', f'`ROS_DOMAIN_ID={args.domain} .venv/bin/python '
             f'bench/boundary_probes.py --out bench/results/boundary_36.md`', '',
             f'{datetime.date.today()}, commit {commit} (+ working tree), load average '
             f'{os.getloadavg()[0]:.1f} at the start, ROS domain {args.domain}; both '
             'executables, the managed one in every state.', '']
    for run in (plain_node, managed_node):
        with tempfile.TemporaryDirectory(prefix='qfa_probes_') as scratch:
            run(args, Path(scratch), lines)
    # One level down: the executables' sections sit under the probes' heading.
    text = '\n'.join(('#' + line) if line.startswith('##') and line != PROBES_HEADING
                     else line for line in lines)
    print(text)
    if args.out:
        write_section(args.out, PROBES_HEADING, text)


if __name__ == '__main__':
    main()
