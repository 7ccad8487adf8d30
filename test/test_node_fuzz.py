"""
A stranger on the domain against both executables in every state: the boundary's fuzz test.

``qfa_node`` and ``qfa_lifecycle_node`` run side by side (one process each, shared by the
tests of this module); the managed node is taken through its states by another participant
(``~/change_state``): unconfigured before its first ``configure``, inactive, active, and
unconfigured again after a ``cleanup``. In each (the plain node: running), this process as
a stranger:

- sets every parameter a participant may not set then, and every one it may, to valid
  values: the operator's (files, directories, rates, resources: :data:`OPERATOR_ONLY`,
  this test's own list) are refused in every state, the sensor's own settings are accepted
  only while the managed node is unconfigured, the refusals naming the parameter;
- tries the known attacks (:data:`ATTACKS`: writes outside ``output_dir``, where paths
  lead, unbounded recordings and schedules, a wide stamp window, a stranger's megabytes,
  the files the operator names, the recordings' retention), each refused with a short
  reason naming the parameter and telling no path it did not send; and where a unit runs,
  a recorder change whose effect fails, refused and undone;
- runs seeded hypothesis cases: one to three parameters set, nine in ten writable, to
  values in range, on and past the edges (sizes and lengths too), NaN, infinities, other
  types, long strings, arrays of up to 200 000 elements and paths of every kind (a secret
  file, FIFOs, devices, ``/proc/self/cwd``, ``/proc/self/fd/N``, another process's
  ``/proc/<pid>/cwd``, symlinks planted under the output directory leading out of it or in
  a loop, a file where a directory would go, escapes); ground-truth ``Imu`` messages
  stamped relative to the node's clock (mostly inside the stamp window, some on its edges,
  far off and absurd) with random values; and now and then switches of the stored
  corrections.

Invariants: every set answered; nothing accepted that the state does not allow, no array
over its size, no directory outside ``output_dir``, no recorder setting the node cannot
honour; every refusal short, naming the parameter, quoting no long string and telling no
secret or path; the node up. Then, back at the defaults, each node streams at its rate
again (from the topic too after a message stamped far ahead), with one calibration event
per switch and bounded memory; and stopped, neither wrote outside ``output_dir`` (a link
planted where a temporary file could go leads nowhere) nor logged the secret of the state
file it started on. ``QFA_FUZZ_CASES`` sets the number of random cases (the suite's
default is sized so that every defect ``bench/planted_defects.py`` plants fails this
module; the 2000-case run is in ``bench/results/boundary_36.md``).
"""

import math
import os
from pathlib import Path
import time
from types import SimpleNamespace

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from hypothesis import given, HealthCheck, Phase, seed, settings
from hypothesis import strategies as st
from node_helpers import Client, domain_id, Lifecycle, NodeProcess, OPERATOR_ONLY, ROOT
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    qos_profile_sensor_data,
    QoSProfile,
    ReliabilityPolicy,
)
from sensor_msgs.msg import Imu
from std_srvs.srv import SetBool, Trigger

from qfa_ros.model.motion_scripts import CSV_COLUMNS, SCRIPTS
from qfa_ros.ros.parameter_table import PARAMETERS, SPECS

CASES = int(os.environ.get('QFA_FUZZ_CASES', '160'))
"""Random cases in all: half against the plain node, an eighth in each state of the managed
node."""
TARGETS = {'qfa_node': 4, 'unconfigured': 1, 'inactive': 1, 'active': 1, 'cleaned up': 1}
"""What each test of the module runs against, in order, and its share of :data:`CASES` in
eighths: the plain node, then the managed node's states."""
CONFIGURED = ('qfa_node', 'inactive', 'active')
"""The targets with a unit wired (the plain node from its start)."""
SECRET = 'SECRET_TOKEN=fuzz-must-not-echo'
WARMED_CASES = 1000
"""From this many cases on, the plain node first builds every built-in trajectory: the
baseline of the tight memory bounds (building the drive peaks near 120 MiB, which the
allocator keeps; without it, steps of 40-120 MiB where a case selects a trajectory)."""
RSS_GROWTH_LIMIT = 32 << 20
"""Largest growth of the plain node's resident memory from that baseline over its cases
and the checks after them [bytes]: measured 7-14 MiB over 2000 cases."""
RSS_STEADY_LIMIT = 8 << 20
"""Largest growth over the second half of its cases [bytes]: measured 0-3 MiB; a leak of a
few kB per set shows here."""
RSS_UNWARMED_LIMIT = 160 << 20
"""Largest growth without that baseline (the suite's shorter runs, and the managed node
from its first configure on) [bytes]: the bound above and one trajectory build's peak."""
REASON_LIMIT = 1000
"""Longest refusal [characters]: it names the parameter and the rule, it echoes no megabyte."""
LARGEST_ARRAY = 10_000
"""More elements than any array parameter takes: a stranger's array is refused."""
LONGEST_NAME = 255
"""Longest file name the file system takes [bytes]: a recording in a longer one cannot start."""
HUGE_ARRAYS = (10_001, 200_000)
OFFSETS_S = (30.0, 3000.0, 1.0e6)
"""Ground-truth stamps far off the window, ahead and behind [s]."""
WINDOW_FACTORS = (0.5, 0.999, 1.001, 1.5)
"""Ground-truth stamps on and past the window's edges, ahead and behind [the window]."""
LONG_STRINGS = ('x' * 5000, 'y' * 100_000, 'z' * 2000)
"""Longer than any string parameter takes, and one within the limit (a directory name the
file system refuses)."""
MAX_QUOTED = 64
"""Most characters of a stranger's value a refusal quotes back (``MAX_SHOWN``)."""
START = {'min_free_bytes': 1 << 20, 'diagnostics_rate_hz': 10.0, 'estimation.realtime': False,
         'gyro_bias.duration_s': 2.0,
         # A reliable subscriber of this process, starved while it serves the other node,
         # then catches up from the writer's history without a gap.
         'qos_overrides./imu/data_raw.publisher.depth': 1000}
"""Start values of both nodes besides their files."""


def rss_bytes(pid):
    """Return the resident set size of process ``pid`` [bytes]."""
    with open(f'/proc/{pid}/status') as status:
        for line in status:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) * 1024
    raise RuntimeError('no VmRSS')


def attacks(root, out):
    """Return what a stranger tries (name, value): each must be refused, in every state."""
    return [
        ('trace_dir', '/tmp/elsewhere'), ('trace_dir', '../escape'),
        ('trace_dir', 'a/../../escape'), ('trace_dir', '~/traces'),
        ('trace_dir', 'planted/traces'), ('recorder.directory', '/etc/qfa'),
        ('recorder.directory', 'planted'),
        # The operator's: files to write, files to read, where the output goes.
        ('output_dir', '/'), ('output_dir', str(root)), ('state_file', '/etc/passwd'),
        ('state_file', str(root / 'victim.txt')), ('state.fresh', True),
        ('noise.imu_yaml', str(root / 'imu.yaml')),
        ('input.trajectory_file', str(root / 'motion.csv')),
        ('min_free_bytes', 0), ('sample_rate_hz', 10000.0), ('loop_rate_hz', 1.0e6),
        ('stream.lead_s', 1.0),
        # The operator's retention: keeping nothing would delete the recordings.
        ('recorder.keep_s', 1.0), ('recorder.keep_bytes', 1), ('recorder.keep_s', 0.0),
        ('recorder.max_bytes', 0), ('recorder.max_bytes', -1), ('recorder.max_bytes', 2 ** 62),
        ('recorder.max_duration_s', 0.0), ('recorder.max_duration_s', 1.0e9),
        ('recorder.max_duration_s', math.inf),
        ('estimation.forward.points', 1000), ('estimation.forward.average_s', 600.0),
        ('estimation.forward.settle_s', 60.0), ('estimation.feedback.cycles', 10000),
        ('estimation.feedback.average_s', 600.0), ('estimation.feedback.settle_s', 60.0),
        ('temperature_calibration.cycles', 100), ('temperature_calibration.period_s', 1.0e6),
        # Where paths lead: the node's working directory, its open files, another process's.
        ('trace_dir', '/proc/self/cwd'), ('recorder.directory', '/proc/self/cwd/x'),
        *[('trace_dir', f'/proc/self/fd/{fd}') for fd in range(6)],
        ('recorder.directory', f'/proc/{os.getpid()}/cwd'),
        ('input.stamp_window_s', 3600.0),
        # A stranger's megabytes: never taken, never echoed.
        ('input.steps.times_s', [float(k) for k in range(200_000)]),
        ('input.steps.levels', [0.0] * 200_000),
        ('input.mode', 'x' * 100_000), ('frame_id', 'y' * 5000)]


def path_values(root, out, pid):
    """Return strings a stranger might name as a file or a directory (node ``pid``)."""
    return [str(root / 'secret.txt'), str(root / 'fifo'), '/dev/zero', '/dev/urandom',
            '/proc/self/environ', '/etc/shadow', '/', '..', '../..', 'a/../../b',
            '/proc/self/cwd', '/proc/self/cwd/x', '/proc/self/root/tmp',
            *[f'/proc/self/fd/{fd}' for fd in range(12)], f'/proc/{pid}/cwd',
            f'/proc/{os.getpid()}/cwd', '/proc/1/cwd', 'planted', 'planted/x',
            str(out / 'planted'), 'loop', 'loop/x', 'fifo_dir', 'fifo_dir/x', 'blocked',
            'blocked/x', '~', '~/x', '', '.', 'traces', 'recordings', str(out / 'inside'),
            'ü/ñ', ' ']


def typed(type_, strategy):
    return strategy.map(lambda value: (type_, value))


def hostile(paths):
    """Return values of every parameter type, mostly wrong for any one parameter."""
    text = st.text(st.characters(blacklist_categories=('Cs',), blacklist_characters='\x00'),
                   max_size=40)
    floats = st.floats(allow_nan=True, allow_infinity=True)
    huge = st.sampled_from(HUGE_ARRAYS)
    return st.one_of(
        typed(Parameter.Type.DOUBLE, floats),
        typed(Parameter.Type.INTEGER, st.integers(-2 ** 63, 2 ** 63 - 1)),
        typed(Parameter.Type.BOOL, st.booleans()),
        typed(Parameter.Type.STRING, text | st.sampled_from(paths)),
        typed(Parameter.Type.STRING, st.sampled_from(LONG_STRINGS)),
        typed(Parameter.Type.DOUBLE_ARRAY, st.lists(floats, max_size=12)
              | huge.map(lambda n: [1.0] * n)),
        typed(Parameter.Type.INTEGER_ARRAY, st.lists(st.integers(-2 ** 63, 2 ** 63 - 1),
                                                     max_size=12)
              | huge.map(lambda n: [0] * n)),
        typed(Parameter.Type.STRING_ARRAY, st.lists(text, max_size=4)),
    )


def near(spec, paths):
    """Return values of ``spec``'s own type: in range, on and just past its edges.

    A string without choices (a directory, a file, the frame) takes ``paths``: its own
    type's hostile values, the path parameters' main attack.
    """
    default = spec.default
    if isinstance(default, bool):
        return typed(Parameter.Type.BOOL, st.booleans())
    if isinstance(default, int):
        low = -2 ** 40 if spec.low is None else int(spec.low)
        high = 2 ** 40 if spec.high is None else int(spec.high)
        return typed(Parameter.Type.INTEGER, st.integers(low, high)
                     | st.sampled_from([low, high, low - 1, high + 1]))
    if isinstance(default, float):
        low = -1e6 if spec.low is None else spec.low
        high = 1e6 if spec.high is None else spec.high
        edges = [low, high, math.nextafter(low, -math.inf), math.nextafter(high, math.inf),
                 0.0, -0.0, math.nan, math.inf, -math.inf]
        return typed(Parameter.Type.DOUBLE, st.floats(low, high) | st.sampled_from(edges))
    if isinstance(default, list):
        low = -1e6 if spec.low is None else spec.low
        high = 1e6 if spec.high is None else spec.high
        element = st.floats(low, high) | st.sampled_from([math.nan, math.inf, high * 2])
        length = spec.length or len(default)
        # On and past the size's edge, every element in range and increasing (the step
        # times must): only the size can refuse it.
        sizes = [spec.max_length, spec.max_length + 1] if spec.max_length else [length + 1]
        ramp = st.sampled_from([*sizes, *HUGE_ARRAYS]).map(
            lambda n: [low + (high - low) * k / n for k in range(n)])
        return typed(Parameter.Type.DOUBLE_ARRAY,
                     st.lists(element, min_size=length, max_size=length)
                     | st.lists(element, max_size=length + 3) | ramp)
    if spec.choices:
        return typed(Parameter.Type.STRING, st.sampled_from([*spec.choices, *LONG_STRINGS]))
    return typed(Parameter.Type.STRING, st.sampled_from([default, *paths, *LONG_STRINGS]))


def cases(paths):
    """Return the strategy of one case: changes, ground-truth messages, switches."""
    writable = [spec for spec in PARAMETERS if not spec.read_only]
    # Writable parameters as often as all others together: only their values reach the
    # node's own checks in every state. As often again the writable strings and arrays,
    # whose values reach the node's path, choice and size checks; and as often again the
    # directories and the recording's switch, the effect a stranger's value can make fail.
    shaped = [spec for spec in writable if isinstance(spec.default, (str, list))]
    recording = [SPECS[name] for name in ('trace_dir', 'recorder.directory', 'recorder.enabled')]
    spec = st.one_of(*(st.sampled_from(specs) for specs in (writable, PARAMETERS, shaped,
                                                             recording)))
    change = spec.flatmap(lambda spec: st.tuples(
        st.just(spec.name), st.one_of(near(spec, paths), near(spec, paths), hostile(paths))))
    changes = st.lists(change, min_size=1, max_size=3, unique_by=lambda c: c[0])
    signed = st.sampled_from([1.0, -1.0])
    offset_s = st.one_of(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0),
                         st.tuples(st.sampled_from(OFFSETS_S), signed).map(
                             lambda o: o[0] * o[1]),
                         st.tuples(st.sampled_from(WINDOW_FACTORS), signed).map(
                             lambda o: ('window', o[0] * o[1])))
    # Mostly stamped from the node's clock when sent; some absolute stamps.
    stamp = st.one_of(offset_s, offset_s, offset_s,
                      st.tuples(st.integers(-2 ** 31, 2 ** 31 - 1), st.integers(0, 999_999_999)))
    # Values a ground truth may hold, or not: plausible ones (so that a message passes the
    # checks and becomes the one the next are ordered against), plausible ones but one
    # hostile element (NaN, infinities, just past the limits), or anything.
    plausible = st.floats(-30.0, 30.0)
    hostile_float = st.floats(allow_nan=True, allow_infinity=True) \
        | st.sampled_from([1.0e4, 1.0e4 + 1.0, 1.0e3, 1.0e3 + 1.0, math.nan, math.inf])
    values = st.one_of(
        st.lists(plausible, min_size=6, max_size=6),
        st.tuples(st.lists(plausible, min_size=6, max_size=6), st.integers(0, 5),
                  hostile_float).map(lambda v: v[0][:v[1]] + [v[2]] + v[0][v[1] + 1:]),
        st.lists(plausible | hostile_float, min_size=6, max_size=6))
    message = st.tuples(stamp, values, st.sampled_from([-1.0, 0.0]))
    # Switches of the stored corrections, several in a row now and then: milliseconds
    # apart, within one truth tick.
    switches = st.sampled_from([0] * 28 + [2, 3]).flatmap(
        lambda count: st.lists(st.booleans(), min_size=count, max_size=count))
    return st.tuples(changes, st.lists(message, max_size=3), switches)


def imu_message(stamp, values, rate_covariance, window_s=1.0):
    """
    Return a ground-truth Imu.

    ``stamp``: an offset from now [s], ``('window', factor)`` (``factor`` times the stamp
    window ``window_s`` from now) or ``(sec, nanosec)``.
    """
    message = Imu()
    if isinstance(stamp, tuple) and stamp[0] == 'window':
        stamp = stamp[1] * window_s
    if isinstance(stamp, tuple):
        message.header.stamp = Time(sec=stamp[0], nanosec=stamp[1])
    else:
        stamp_ns = time.time_ns() + int(stamp * 1e9)
        message.header.stamp = Time(sec=stamp_ns // 1_000_000_000,
                                    nanosec=stamp_ns % 1_000_000_000)
    a, w = message.linear_acceleration, message.angular_velocity
    a.x, a.y, a.z, w.x, w.y, w.z = values
    message.angular_velocity_covariance[0] = rate_covariance
    return message


def plant(root, out):
    """Plant what a stranger with a shell might have left; return the files to watch."""
    root.mkdir(parents=True)
    (root / 'secret.txt').write_text(f'{SECRET}\n')
    os.mkfifo(root / 'fifo')
    hidden = root / 'hidden_target'
    hidden.mkdir()
    out.mkdir()
    (out / 'planted').symlink_to(hidden, target_is_directory=True)
    (out / 'loop').symlink_to('loop')
    os.mkfifo(out / 'fifo_dir')
    (out / 'blocked').write_text('a file where a directory would go\n')
    # What a save killed mid-write leaves; the node removes it at start and says so.
    (out / '.state.json.k1ll3d.tmp').write_text('{"half": ')
    # A state file of the right format holding the secret where a number goes.
    (out / 'state.json').write_text(
        '{"format": "qfa_ros.calibration/1", "references": [{}, {}, {}], '
        f'"controller_gain": ["{SECRET}", 1.0, 1.0], "n_vref": []}}\n')
    victim = root / 'victim.txt'
    victim.write_text('not yours\n')
    # Files the operator never named, valid for the parameters a stranger would point at
    # them: an imu.yaml and a trajectory.
    (root / 'imu.yaml').write_text(
        'accelerometer_noise_density: 1.0e-4\naccelerometer_random_walk: 1.0e-5\n'
        'gyroscope_noise_density: 1.0e-5\ngyroscope_random_walk: 1.0e-6\n')
    (root / 'motion.csv').write_text(','.join(CSV_COLUMNS) + '\n0,45,0,0,0,0,0\n'
                                     '10,45,0,0,0,0,0\n')
    return hidden, victim


def other_value(spec, root):
    """Return a valid value of ``spec`` other than its default: what only access refuses."""
    default = spec.default
    files = {'output_dir': str(root / 'elsewhere'), 'state_file': str(root / 'victim.txt'),
             'noise.imu_yaml': str(root / 'imu.yaml'),
             'input.trajectory_file': str(root / 'motion.csv')}
    if spec.name in files:
        return files[spec.name]
    if isinstance(default, bool):
        return not default
    if spec.choices:
        return next(choice for choice in spec.choices if choice != default)
    if isinstance(default, str):
        return default + '_2'
    if isinstance(default, list):
        return [spec.low / 2 if v != spec.low / 2 else spec.low / 4 for v in default]
    if isinstance(default, int):
        return default + 1 if default + 1 <= spec.high else default - 1
    middle = (spec.low + spec.high) / 2
    return middle if middle != default else default * 0.9 + 0.01


class Stranger:
    """
    One executable under test and this process as a stranger on its domain.

    :param kind: ``'plain'`` or ``'managed'``.
    :param root: The directory of its files (``out`` below it is its ``output_dir``).
    """

    def __init__(self, kind, root):
        self.kind = kind
        self.root, self.out = root, root / 'out'
        self.hidden, self.victim = plant(self.root, self.out)
        self.before = set(self.root.rglob('*')) - {self.out / '.state.json.k1ll3d.tmp',
                                                   self.out / 'state.json'}
        self.start = {**START, 'output_dir': str(self.out),
                      'state_file': str(self.out / 'state.json')}
        self.node = NodeProcess(domain_id(f'fuzz {kind}'), self.root / 'run', self.start,
                                managed=kind == 'managed')
        # What no answer may tell: where the planted link, the node's working directory and
        # its open files lead; this process's directory.
        self.secrets = [SECRET, 'fuzz-must-not', str(self.hidden), str(ROOT),
                        str(self.root / 'run'), os.getcwd(), str(Path.home() / '.ros'),
                        'socket:[', 'pipe:[', 'anon_inode:']
        self.client = Client(self.node.domain)
        self.lifecycle = Lifecycle(self.client)
        self.received = {'count': 0, 'non_finite': 0, 'newest': None}
        self.count_rate()
        self.events = []
        self.answers = {'sets': 0, 'slowest_s': 0.0, 'refused': 0, 'accepted': 0,
                        'switches': 0}
        self.expected = {'events': 0, 'compensation': None}
        self.rss = []
        self.accepted = self.start_values()
        self.paths = path_values(self.root, self.out, self.node.pid)
        node = self.client.node
        # As an INS takes the stream (every sample checked), and as deep as a busy machine
        # needs for the stamps that tell the rate: a best-effort subscriber of depth 5 in a
        # starved test process drops samples the node did publish.
        node.create_subscription(Imu, 'imu/data_raw', self.on_imu, qos_profile_sensor_data)
        node.create_subscription(Imu, 'imu/data_raw', self.on_stamp, QoSProfile(
            depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        node.create_subscription(
            DiagnosticStatus, f'/{self.node.name}/calibration_events', self.events.append,
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.truth = node.create_publisher(
            Imu, 'input/imu', QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.errors = []
        node.create_subscription(Imu, 'truth/imu_errors', self.errors.append, QoSProfile(depth=10))

    def start_values(self):
        return {**{spec.name: spec.default for spec in PARAMETERS}, **self.start}

    def on_imu(self, message):
        a, w = message.linear_acceleration, message.angular_velocity
        self.received['count'] += 1
        self.received['non_finite'] += not all(math.isfinite(v)
                                               for v in (a.x, a.y, a.z, w.x, w.y, w.z))

    def on_stamp(self, message):
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        self.received['newest'] = stamp
        # Counted as they come: a check that scanned the stamps kept at every spin cost a
        # starved test process more than the stream it was checking.
        rate = self.rate
        if stamp > rate['after_ns']:
            consecutive = rate['last'] is not None and stamp - rate['last'] == 1_000_000
            rate['run'] = rate['run'] + 1 if consecutive else 0
            rate['last'] = stamp
            rate['reached'] = rate['reached'] or rate['run'] >= 500

    def alive(self):
        assert self.node.process.poll() is None, f'the {self.kind} node died: ' \
            + self.node.log()[-2000:]

    def set_many(self, changes, timeout=60.0):
        """Send one SetParameters request of ``changes`` [(name, value)]; return the results."""
        request = SetParameters.Request()
        request.parameters = [Parameter(name, value=value).to_parameter_msg()
                              for name, value in changes]
        results = self.client.call(SetParameters, f'/{self.node.name}/set_parameters',
                                   request, timeout).results
        assert len(results) == len(changes)
        return results

    def reset(self, configured):
        """Set every parameter the state lets a participant set back to its start value."""
        names = [spec.name for spec in PARAMETERS
                 if spec.name not in OPERATOR_ONLY and not (configured and spec.read_only)]
        values = self.start_values()
        # The input off a trajectory first: the others then change no motion script.
        for results in (self.set_many([('input.mode', 'static')]),
                        self.set_many([(name, values[name]) for name in names])):
            assert all(r.successful for r in results), [r.reason for r in results
                                                        if not r.successful]
        self.accepted = values

    def refusal_problem(self, name, reason):
        """Return what is wrong with the refusal ``reason`` of ``name``, or None."""
        if len(reason) > REASON_LIMIT:
            return f'a refusal of {len(reason)} characters: {reason[:300]}'
        # The parameter or its family (a rule across several); rclpy refuses another type
        # before the node sees it, without the name.
        if name.rsplit('.', 1)[0] not in reason and not reason.startswith('Wrong parameter type'):
            return f'a refusal not naming it: {reason[:300]}'
        # Not even 65 characters of a long string, whichever parameter held it (a
        # recording started in a directory set before quotes that one).
        if any(text[:MAX_QUOTED + 1] in reason for text in LONG_STRINGS):
            return f'the refusal quotes a long string: {reason[:300]}'
        told = [text for text in self.secrets if text in reason]
        return f'the refusal tells {told}: {reason}' if told else None

    def acceptance_problem(self, name, value, configured):
        """Return why accepting ``value`` for ``name`` breaks the boundary, or None."""
        spec = SPECS[name]
        size = spec.max_length or spec.length or LARGEST_ARRAY
        if isinstance(value, list) and len(value) > size:
            return f'an array of {len(value)} elements accepted (at most {size})'
        if name in OPERATOR_ONLY:
            return 'accepted: the operator alone sets it, in every state'
        if configured and spec.read_only:
            return 'accepted while a unit runs: read-only then'
        if name in ('trace_dir', 'recorder.directory') and value:
            out = self.out.resolve()
            try:
                inside = (out / value).resolve()
            except (OSError, RuntimeError):
                return None  # a loop: nothing can be written there
            if inside != out and out not in inside.parents:
                return f'a directory outside output_dir accepted: {value[:100]!r}'
        return None

    def check_access(self, configured):
        """Set every parameter a participant may not set, and the others, to valid values."""
        names = sorted(OPERATOR_ONLY | {spec.name for spec in PARAMETERS if spec.read_only})
        changes = [(name, other_value(SPECS[name], self.root)) for name in names]
        problems = []
        for (name, value), result in zip(changes, self.set_many(changes)):
            allowed = name not in OPERATOR_ONLY and not configured
            if result.successful != allowed:
                problems.append(f'{name}: {"accepted" if result.successful else "refused"} '
                                f'({result.reason})')
            elif not result.successful and (name not in result.reason
                                            or 'read-only' not in result.reason):
                problems.append(f'{name}: refused without naming it and the rule: '
                                f'{result.reason}')
        assert not problems, '\n'.join(problems)
        if not configured:
            values = self.start_values()
            results = self.set_many([(name, values[name]) for name in names
                                     if name not in OPERATOR_ONLY])
            assert all(r.successful for r in results)

    def check_attacks(self, configured):
        """Try every attack at once: each refused, briefly, naming it, telling nothing."""
        problems = []
        tried = attacks(self.root, self.out)
        for (name, value), result in zip(tried, self.set_many(tried)):
            shown = f'{name} {value if len(str(value)) < 100 else f"({len(value)} long)"}'
            if result.successful:
                problems.append(f'{shown}: accepted')
            else:
                problem = self.refusal_problem(name, result.reason)
                if problem or name not in result.reason:
                    problems.append(f'{shown}: {problem or result.reason}')
        assert not problems, '\n'.join(problems)
        names = ['trace_dir', 'recorder.directory', 'recorder.max_bytes',
                 'estimation.feedback.cycles', 'output_dir', 'input.stamp_window_s',
                 'input.steps.times_s', 'state_file', 'recorder.keep_s',
                 'recorder.keep_bytes']
        start = self.start_values()
        assert self.client.get_parameters(names) == [start[name] for name in names]
        if configured:
            self.check_failing_effect()

    def check_failing_effect(self):
        """Change the recorder where it cannot start: refused with the system's words, undone."""
        for directory, words in (('blocked/bag', 'Not a directory'),
                                 ('z' * 4000, 'File name too long')):
            assert self.set_many([('recorder.directory', directory)])[0].successful
            result, = self.set_many([('recorder.enabled', True)])
            assert not result.successful, directory[:10]
            assert 'recorder.enabled not changed' in result.reason \
                and f'recorder.directory: {words}' in result.reason, result.reason[:300]
            assert len(result.reason) < 300 and str(self.out) not in result.reason
            assert self.client.get_parameters(['recorder.enabled']) == [False]
        # The node goes on: the same change where a recording can start is accepted.
        for change in (('recorder.directory', 'recordings'), ('recorder.enabled', True),
                       ('recorder.enabled', False)):
            result, = self.set_many([change])
            assert result.successful, result.reason

    def run_cases(self, target):
        """Run this target's share of the seeded hypothesis cases."""
        configured = target in CONFIGURED
        count = max(1, CASES * TARGETS[target] // 8)
        done = {'cases': 0}

        @settings(max_examples=count, deadline=None, database=None, phases=[Phase.generate],
                  suppress_health_check=list(HealthCheck), print_blob=True)
        @seed(20261127)
        @given(cases(self.paths))
        def one_case(case):
            try:
                self.check_case(case, configured, target)
            except AssertionError as error:
                # Which case failed (bench/planted_defects.py reads it).
                error.args = (f'{self.kind} node, {target}: case {done["cases"]} of '
                              f'{count}: {error}',)
                raise
            done['cases'] += 1

        started = time.monotonic()
        middle = count // 2 if self.kind == 'plain' else None
        self.rss_middle = None

        def sample_middle():
            if done['cases'] == middle and self.rss_middle is None:
                self.rss_middle = rss_bytes(self.node.pid)
        self.before_case = sample_middle
        one_case()
        self.answers['seconds'] = self.answers.get('seconds', 0.0) \
            + time.monotonic() - started
        assert done['cases'] == count

    def check_case(self, case, configured, target):
        changes, messages, switches = case
        self.before_case()
        request = SetParameters.Request()
        request.parameters = [Parameter(name, type_, value).to_parameter_msg()
                              for name, (type_, value) in changes]
        started = time.monotonic()
        results = self.client.call(SetParameters, f'/{self.node.name}/set_parameters',
                                   request, timeout=20.0).results
        self.answers['slowest_s'] = max(self.answers['slowest_s'], time.monotonic() - started)
        self.answers['sets'] += 1
        assert len(results) == len(changes)
        for (name, (type_, value)), result in zip(changes, results):
            self.answers['refused'] += not result.successful
            self.answers['accepted'] += result.successful
            if result.successful:
                problem = self.acceptance_problem(name, value, configured)
                assert not problem, f'{name}: {problem}'
                self.accepted[name] = value
            else:
                problem = self.refusal_problem(name, result.reason)
                assert not problem, f'{name}: {problem}'
        directory = self.accepted['recorder.directory']
        assert not (configured and self.accepted['recorder.enabled'] and (
            directory.split('/')[0] in ('blocked', 'fifo_dir')
            or any(len(part) > LONGEST_NAME for part in directory.split('/')))), \
            f'a recording accepted where none can start: {directory[:100]}'
        for stamp, values, covariance in messages:
            self.truth.publish(imu_message(stamp, values, covariance,
                                           self.accepted['input.stamp_window_s']))
        if target in ('qfa_node', 'active', 'inactive'):
            for switch in switches:
                self.switch(switch, active=target != 'inactive')
        self.alive()

    def switch(self, on, active=True):
        """Switch the stored corrections; count the event a change makes."""
        self.answers['switches'] += 1
        response = self.client.call(SetBool, f'/{self.node.name}/set_compensation',
                                    SetBool.Request(data=on), timeout=20.0)
        if not active:
            assert not response.success and response.message.startswith('inactive:'), \
                response.message
            return
        assert response.success, response.message
        if on != self.expected['compensation']:
            self.expected['events'] += 1
            self.expected['compensation'] = on

    def switch_burst(self, active):
        """Switch the corrections three times in a row (within one truth tick when active)."""
        for on in (False, True, False) if active else (True,):
            self.switch(on, active)

    def warm_up(self):
        """Build every built-in trajectory once: the memory baseline (the drive peaks high)."""
        steps = [('input.trajectory', script) for script in SCRIPTS] + [
            ('latitude_deg', latitude) for latitude in (-60.0, 10.0, 80.0, 45.0)]
        assert self.set_many([('input.mode', 'trajectory')])[0].successful
        for name, value in steps:
            result, = self.set_many([(name, value)])
            assert result.successful, result.reason
        self.reset(configured=True)

    def calibrate_gyros(self):
        """Store corrections to switch (one event) and wait for the truth and the event."""
        # A node that starts on a busy machine may take long; one that streams is waited for.
        self.client.spin_until(lambda: self.received['count'] > 100 and self.errors, 120.0,
                               'the first samples and truth', limit=300.0,
                               progress=lambda: self.received['count'])
        response = self.client.call(Trigger, f'/{self.node.name}/calibrate_gyros',
                                    Trigger.Request())
        assert response.success, response.message
        self.expected['events'] += 1
        self.expected['compensation'] = True
        self.client.spin_until(lambda: len(self.events) >= self.expected['events'], 30.0,
                               'the gyro bias event')

    def check_start(self):
        """
        Check what the node logged of the files it started on; plant a link by its temporary.

        The plain node logs it at start, the managed one at its first configure.
        """
        def logged():
            log = self.node.log()
            return 'starting uncalibrated' in log and 'removed 1 temporary' in log
        self.client.spin_until(logged, 60.0, 'the start-up lines')
        log = self.node.log()
        assert not (self.out / '.state.json.k1ll3d.tmp').exists()
        assert 'removed 1 temporary state file(s) an interrupted save left: ' \
            '.state.json.k1ll3d.tmp' in log
        assert 'state file' in log and 'corrupt' in log
        # Where a temporary named after the node's process would go: a link out.
        (self.out / f'.state.json.{self.node.pid}.tmp').symlink_to(self.victim)

    def progress(self):
        """Return the newest stamp received: a starved process drains late, yet gets there."""
        return self.received['newest']

    def count_rate(self, after_ns=0):
        """Count anew: :meth:`at_rate` holds once samples stamped after ``after_ns`` [ns] came."""
        self.rate = {'after_ns': after_ns, 'last': None, 'run': 0, 'reached': False}

    def at_rate(self):
        """Return whether 500 consecutive samples at 1 kHz came since :meth:`count_rate`."""
        return self.rate['reached']

    def close(self):
        self.client.close()
        return self.node.stop()


@pytest.fixture(scope='module')
def strangers(tmp_path_factory):
    root = tmp_path_factory.mktemp('fuzz')
    # Both started before either is waited for: their starts overlap.
    plain = Stranger('plain', root / 'plain')
    managed = Stranger('managed', root / 'managed')
    yield SimpleNamespace(plain=plain, managed=managed)
    for stranger in (plain, managed):
        if stranger.node.process.poll() is None:
            stranger.close()


@pytest.mark.parametrize('target', list(TARGETS))
def test_a_stranger_breaks_nothing(strangers, target):
    stranger = strangers.plain if target == 'qfa_node' else strangers.managed
    configured = target in CONFIGURED
    if target == 'qfa_node':
        stranger.calibrate_gyros()
        stranger.check_start()
        if CASES >= WARMED_CASES:
            stranger.warm_up()
        stranger.rss.append(rss_bytes(stranger.node.pid))
    elif target == 'unconfigured':
        assert stranger.lifecycle.state() == 'unconfigured'
    elif target == 'inactive':
        stranger.reset(configured=False)
        assert stranger.lifecycle.change('configure') == (True, 'inactive'), \
            stranger.node.log()[-2000:]
        stranger.check_start()
        stranger.rss.append(rss_bytes(stranger.node.pid))
    elif target == 'active':
        assert stranger.lifecycle.change('activate') == (True, 'active')
        stranger.reset(configured=True)
        stranger.calibrate_gyros()
    else:
        assert stranger.lifecycle.change('deactivate') == (True, 'inactive')
        assert stranger.lifecycle.change('cleanup') == (True, 'unconfigured')
        stranger.reset(configured=False)
    stranger.check_access(configured)
    stranger.check_attacks(configured)
    if configured:
        stranger.switch_burst(active=target != 'inactive')
    stranger.run_cases(target)
    stranger.alive()


@pytest.mark.parametrize('kind', ['plain', 'managed'])
def test_back_at_its_defaults_the_node_streams_at_its_rate(strangers, kind):
    stranger = getattr(strangers, kind)
    client, received = stranger.client, stranger.received
    if kind == 'managed':
        stranger.reset(configured=False)
        assert stranger.lifecycle.change('configure') == (True, 'inactive')
        assert stranger.lifecycle.change('activate') == (True, 'active')
    else:
        stranger.reset(configured=True)
    stranger.count_rate()
    client.spin_until(stranger.at_rate, 60.0, '500 consecutive samples at 1 kHz',
                      progress=stranger.progress, limit=180.0)
    # Ground truth from the topic: one message stamped far ahead, then valid ones (200 Hz,
    # stamped now): the stream follows the valid ones at its rate. (An input is stale after
    # 1 s, not 0.1: this process, starved on a busy machine, may publish late; a stall by the
    # message stamped ahead would last 1e6 s.)
    results = stranger.set_many([('input.mode', 'topic'), ('input.timeout_s', 1.0)])
    assert all(result.successful for result in results)
    stranger.truth.publish(imu_message(1.0e6, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), -1.0))
    timer = client.node.create_timer(0.005, lambda: stranger.truth.publish(
        imu_message(0.0, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), -1.0)))
    # Only samples stamped past the input's staleness horizon count: had the message
    # stamped ahead been taken, the valid ones would be refused as older, the input stale
    # after 1 s and the stream stopped; samples of that first second prove nothing.
    stranger.count_rate(after_ns=time.time_ns() + int(1.5e9))
    client.spin_until(stranger.at_rate, 60.0,
                      '500 consecutive samples at 1 kHz from the topic',
                      progress=stranger.progress, limit=180.0)
    client.node.destroy_timer(timer)
    assert received['non_finite'] == 0
    # One event per switch that changed the corrections, however close together.
    expected = stranger.expected['events']
    client.spin_until(lambda: len(stranger.events) >= expected, 30.0, f'{expected} events')
    client.spin_for(0.5)
    assert len(stranger.events) == expected
    stranger.rss.append(rss_bytes(stranger.node.pid))
    growth = stranger.rss[-1] - stranger.rss[0]
    profile = ', '.join(f'{b / 2 ** 20:.1f}' for b in stranger.rss)
    warmed = kind == 'plain' and CASES >= WARMED_CASES
    limit = RSS_GROWTH_LIMIT if warmed else RSS_UNWARMED_LIMIT
    assert growth < limit, f'RSS grew {growth >> 20} MiB ({profile} MiB)'
    if warmed:
        steady = stranger.rss[-1] - stranger.rss_middle
        assert steady < RSS_STEADY_LIMIT, \
            f'RSS grew {steady >> 20} MiB over the second half of the cases ({profile} MiB)'
    answers = stranger.answers
    print(f'fuzz, {kind} node: {answers["sets"]} sets ({answers["accepted"]} parameters '
          f'accepted, {answers["refused"]} refused), {answers["switches"]} switches, '
          f'{expected} events in {answers["seconds"]:.0f} s, slowest answer '
          f'{answers["slowest_s"]:.2f} s, RSS growth {growth / 2 ** 20:.1f} MiB ({profile} MiB)')


@pytest.mark.parametrize('kind', ['plain', 'managed'])
def test_stopped_it_wrote_nothing_outside_and_logged_no_secret(strangers, kind):
    stranger = getattr(strangers, kind)
    status = stranger.close()
    log = stranger.node.log()
    assert status == 0, log[-2000:]
    assert SECRET not in log and 'fuzz-must-not' not in log
    assert stranger.victim.read_text() == 'not yours\n'
    # Nothing written outside output_dir (the run directory holds the test's own files).
    written = set(stranger.root.rglob('*')) - stranger.before
    run = stranger.root / 'run'
    stray = [path for path in written
             if stranger.out not in path.parents and run not in path.parents and path != run]
    assert not stray, stray
    assert not any(stranger.hidden.iterdir())
