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
then two restarts on a state file holding a word where a number goes and on one nested too
deeply. Prints a Markdown transcript: every answer quoted, the node alive, the honest
input's samples before and after.
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

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))

from node_helpers import Client  # noqa: E402

SECRET = 'SECRET_WORD_in_the_state_file'
PROBES_HEADING = '## Probes from another participant'
TITLE = '# Issue 36: the trust boundary, second pass'
INPUT_RATE_HZ = 200.0


class UserNode:
    """``qfa_node`` started as a user would, in its own working directory."""

    def __init__(self, work, domain, parameters):
        self.log_path = work / f'node_{time.monotonic_ns()}.log'
        self._log = open(self.log_path, 'w')
        arguments = [f'{name}:={value}' for name, value in parameters.items()]
        executable = shutil.which('qfa_node', path=str(Path(sys.executable).parent))
        env = {**os.environ, 'ROS_DOMAIN_ID': str(domain),
               'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'PYTHONUNBUFFERED': '1'}
        self.command = ['qfa_node', '--ros-args'] + [part for argument in arguments
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


def write_section(path, heading, text):
    """Write ``text`` (starting with ``heading``) into ``path``, replacing that section."""
    sections = path.read_text().rstrip('\n').split('\n\n' + '## ') if path.exists() \
        else [TITLE]
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


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--domain', type=int, default=int(os.environ.get('ROS_DOMAIN_ID', 77)))
    parser.add_argument('--out', type=Path, help='also write the transcript here')
    args = parser.parse_args(argv)
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    lines = [PROBES_HEADING, '', f'`ROS_DOMAIN_ID={args.domain} .venv/bin/python '
             f'bench/boundary_probes.py --out bench/results/boundary_36.md`', '',
             f'{datetime.date.today()}, commit {commit} (+ working tree), load average '
             f'{os.getloadavg()[0]:.1f} at the start, ROS domain {args.domain}.', '']
    with tempfile.TemporaryDirectory(prefix='qfa_probes_') as scratch:
        work = Path(scratch) / 'work'          # the node's working directory
        out = Path(scratch) / 'out'            # its output_dir
        elsewhere = Path(scratch) / 'elsewhere'
        for directory in (work, out, elsewhere):
            directory.mkdir()
        (out / 'planted').symlink_to(elsewhere, target_is_directory=True)
        (out / 'blocked').write_text('a file where a directory would go\n')
        parameters = {'output_dir': str(out), 'state_file': str(out / 'state.json'),
                      'diagnostics_rate_hz': 10.0}
        node = UserNode(work, args.domain, parameters)
        probe = Probe(args.domain)
        try:
            probe.client.spin_until(lambda: len(probe.stamps) > 100, 120.0, 'the node')
            lines += [f'Node: `{" ".join(node.command)}` (working directory `{work}`, '
                      f'output_dir `{out}`, `out/planted` -> `{elsewhere}`).', '',
                      '### SetParameters from the participant', '',
                      '| parameter | value | answer | length | reason |', '|---|---|---|---|---|']
            probes = [('trace_dir', '/proc/self/cwd'), ('recorder.directory', '/proc/self/cwd'),
                      *[('trace_dir', f'/proc/self/fd/{fd}') for fd in range(6)],
                      ('trace_dir', f'/proc/{os.getpid()}/cwd'), ('trace_dir', 'planted'),
                      ('recorder.directory', 'planted/x'), ('trace_dir', 'planted/../..'),
                      ('input.stamp_window_s', 3600.0),
                      ('input.steps.times_s', [float(k) for k in range(200_000)]),
                      ('input.steps.levels', [0.0] * 200_000), ('input.mode', 'x' * 100_000),
                      # A recording running, then moved where it cannot start: the change
                      # is refused and the recording goes on where it was.
                      ('recorder.directory', 'recordings'), ('recorder.enabled', True),
                      ('recorder.directory', 'blocked/bag')]
            reasons = []
            for name, value in probes:
                answer = probe.set(name, value)
                reasons.append(answer[1])
                quoted(lines, name, value, answer)
            told = [text for text in (str(work), str(elsewhere))
                    if any(text in reason for reason in reasons)]
            directory, = probe.client.get_parameters(['recorder.directory'])
            probe.client.spin_for(1.0)  # the recorder opens its file with the next samples
            recording = probe.status('stream').get('recording', 'none')
            lines += ['', f'Paths of the node the answers tell: {told or "none"}. After the '
                      f'refused move: `recorder.directory` is `{directory!r}`; stream diagnostic, '
                      f'recording: `{recording}`.', '']
            probe.set('recorder.enabled', False)

            # The stall: honest input, one message stamped ahead, honest input again; the
            # input diagnostic's counters before and after each phase tell how many honest
            # messages were turned away.
            assert probe.set('input.mode', 'topic')[0]
            lines += ['### Ground truth from the participant', '']
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
                          f'thrice), then the honest input again. `imu/data_raw` samples '
                          f'received (best effort, depth 5): {before} in the 3 s before, '
                          f'{after} in the 4 s after, {recovered} in the 2 s after those. '
                          f'Input diagnostic: stamps refused '
                          f'{delta("refused stamps", start, held)}; honest messages rejected '
                          f'as out of order {delta("rejected inputs", start, held)} in the 4 s '
                          f'after, {delta("rejected inputs", held, end)} in the 2 s after '
                          f'those; last rejection "{end.get("last rejection", "none")}"']
            probe.set('input.mode', 'static')
            stream = probe.status('stream')
            lines += ['', f'Node alive after the probes: {node.alive}; `imu/data_raw` samples '
                      f'received in 1 s, static input: {probe.honest_input(1.0)}; stream '
                      f'diagnostic: "{stream.get("message")}", samples computed '
                      f'{stream.get("samples computed")}, withheld '
                      f'{stream.get("samples withheld")}, skipped '
                      f'{stream.get("samples skipped")}.', '']
        finally:
            probe.close()
            status = node.stop()
        lines += [f'Node stopped with status {status}.', '']

        # Restarts on hostile state files: the start goes on, the file is set aside.
        lines += ['### Restarts on a hostile state file', '']
        hostile = {
            'a word where a number goes': json.dumps({
                'format': 'qfa_ros.calibration/1', 'references': [{}, {}, {}],
                'controller_gain': [SECRET, 1.0, 1.0], 'n_vref': []}),
            'nested 100 000 deep': '[' * 100_000 + ']' * 100_000,
            'Infinity in an integer field': json.dumps({
                'format': 'qfa_ros.calibration/1', 'references': [{}, {}, {}],
                'controller_gain': [], 'n_vref': [float('inf'), 1, 1]}),
        }
        for label, text in hostile.items():
            (out / 'state.json').write_text(text)
            node = UserNode(work, args.domain, parameters)
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
            log = node.log()
            errors = [line for line in log.splitlines() if '[ERROR]' in line]
            lines += [f'- {label}: node publishing {up}; traceback in its output: '
                      f'{"Traceback" in log}; the word in its output: {SECRET in log}; '
                      f'ERROR lines:', '', '```text', *errors, '```', '']
    text = '\n'.join(lines)
    print(text)
    if args.out:
        write_section(args.out, PROBES_HEADING, text)


if __name__ == '__main__':
    main()
