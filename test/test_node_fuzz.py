"""
A stranger on the domain: thousands of parameter sets, ground-truth messages, switches.

Property-based (hypothesis, seeded so a failure replays). Each case sets one to three
parameters, nine in ten writable (the strings and arrays a quarter of the time, the
directories and the recording's switch another quarter), to values from their ranges, on
and just past their edges (sizes and lengths too), NaN and infinities, other types, long
strings, arrays of up to 200 000 elements and paths of every kind (a secret file, FIFOs,
devices, ``/proc/self/cwd``, ``/proc/self/fd/N``, another process's ``/proc/<pid>/cwd``,
symlinks planted under the output directory leading out of it or in a loop, a file where
a directory would go, escapes); publishes a few ground-truth ``Imu`` messages stamped
relative to the node's clock when sent (mostly inside the stamp window, so the value
checks behind it are reached, some on its edges, far off and absurd), with random values;
and now and then switches the stored corrections on or off. Invariants: every set
answered, every refusal short and naming the parameter, no answer or log line quoting a
file or telling where a path leads; no refusal quoting a long string, no accepted array
over its parameter's size, no accepted recorder setting the node cannot honour; the node
up with tightly bounded memory, nothing written outside ``output_dir`` (a link planted
where a temporary file could go leads nowhere), no non-finite sample (specific force or
rate), one calibration event per switch; once the parameters are back to their defaults
the stream at its rate again, from the topic too after a message stamped far ahead; and
the node starts again on a state file nested too deeply.
"""

import math
import os
from pathlib import Path
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from hypothesis import given, HealthCheck, Phase, seed, settings
from hypothesis import strategies as st
from node_helpers import Client, domain_id, NodeProcess, ROOT
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

from qfa_ros.model.trajectory import SCRIPTS
from qfa_ros.ros.parameter_table import PARAMETERS, SPECS

CASES = int(os.environ.get('QFA_FUZZ_CASES', '2000'))
SECRET = 'SECRET_TOKEN=fuzz-must-not-echo'
RSS_GROWTH_LIMIT = 32 << 20
"""Largest growth of the node's resident memory over the cases [bytes], from a baseline
taken once the node has built every built-in trajectory (building the drive peaks near
120 MiB, which the allocator keeps): measured 7-14 MiB over 2000 cases (without that
baseline, steps of 40-120 MiB where a case selects a trajectory)."""
RSS_STEADY_LIMIT = 8 << 20
"""Largest growth over the second half of the cases [bytes]: measured 0-3 MiB; a leak of
a few kB per set shows here."""
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
"""Ground-truth stamps on and past the window's edges, ahead and behind [the window]: the
window the node accepted last (read-only, so its default, unless it can be widened)."""


def rss_bytes(pid):
    """Return the resident set size of process ``pid`` [bytes]."""
    with open(f'/proc/{pid}/status') as status:
        for line in status:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) * 1024
    raise RuntimeError('no VmRSS')


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


LONG_STRINGS = ('x' * 5000, 'y' * 100_000, 'z' * 2000)
"""Longer than any string parameter takes, and one within the limit (a directory name the
file system refuses)."""
MAX_QUOTED = 64
"""Most characters of a stranger's value a refusal quotes back (``params.MAX_SHOWN``)."""


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

    A string without choices (a directory, the frame) takes ``paths``: its own type's
    hostile values, the path parameters' main attack.
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
    # Writable parameters as often as all read-only ones together: only their values
    # reach the node's own checks (rclpy refuses a read-only one first). As often again
    # the writable strings and arrays, whose values reach the node's path, choice and size
    # checks; and as often again the directories and the recording's switch, the effect
    # a stranger's value can make fail.
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
    return hidden, victim


def test_a_strangers_parameters_and_messages_break_nothing(tmp_path):
    root, out = tmp_path, tmp_path / 'out'
    hidden, victim = plant(root, out)
    before = set(root.rglob('*')) - {out / '.state.json.k1ll3d.tmp', out / 'state.json'}
    domain = domain_id('fuzz')
    node = NodeProcess(domain, root / 'run', {
        'output_dir': str(out), 'state_file': str(out / 'state.json'),
        'min_free_bytes': 1 << 20, 'diagnostics_rate_hz': 10.0,
        'estimation.realtime': False, 'gyro_bias.duration_s': 2.0})
    # What no answer may tell: where the planted link, the node's working directory and
    # its open files lead; this process's directory.
    secrets = [SECRET, 'fuzz-must-not', str(hidden), str(ROOT), str(root / 'run'),
               os.getcwd(), str(Path.home() / '.ros'), 'socket:[', 'pipe:[', 'anon_inode:']
    client = Client(domain)
    received = {'count': 0, 'non_finite': 0, 'stamps': []}
    events = []

    def on_imu(message):
        a, w = message.linear_acceleration, message.angular_velocity
        received['count'] += 1
        received['non_finite'] += not all(math.isfinite(v)
                                          for v in (a.x, a.y, a.z, w.x, w.y, w.z))

    def on_stamp(message):
        stamp = message.header.stamp
        received['stamps'].append(stamp.sec * 1_000_000_000 + stamp.nanosec)
        del received['stamps'][:-2000]

    answers = {'sets': 0, 'slowest_s': 0.0, 'refused': 0, 'accepted': 0, 'switches': 0}
    try:
        # As an INS takes the stream (every sample checked), and as deep as a busy machine
        # needs for the stamps that tell the rate: a best-effort subscriber of depth 5 in a
        # starved test process drops samples the node did publish.
        client.node.create_subscription(Imu, 'imu/data_raw', on_imu, qos_profile_sensor_data)
        client.node.create_subscription(Imu, 'imu/data_raw', on_stamp, QoSProfile(
            depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        client.node.create_subscription(
            DiagnosticStatus, f'/{node.name}/calibration_events', events.append,
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        truth = client.node.create_publisher(
            Imu, 'input/imu', QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
        # The truth published: from then on a correction is an event.
        errors = []
        client.node.create_subscription(Imu, 'truth/imu_errors', errors.append,
                                        QoSProfile(depth=10))
        client.spin_until(lambda: received['count'] > 100 and errors, 60.0,
                          'the first samples and truth')
        log = node.log()
        assert not (out / '.state.json.k1ll3d.tmp').exists()
        assert 'removed 1 temporary state file(s) an interrupted save left: ' \
            '.state.json.k1ll3d.tmp' in log
        assert 'state file' in log and 'corrupt' in log and 'starting uncalibrated' in log
        # Where a temporary named after the node's process would go: a link out.
        (out / f'.state.json.{node.pid}.tmp').symlink_to(victim)
        # The baseline of the memory: the node once it has built each built-in trajectory
        # (the drive's construction peaks near 120 MiB; the allocator keeps what it freed).
        warm_up = [('input.trajectory', script) for script in SCRIPTS] + [
            ('latitude_deg', latitude) for latitude in (-60.0, 10.0, 80.0, 45.0)]
        assert client.set_parameters({'input.mode': 'trajectory'})[0].successful
        for name, value in warm_up:
            result, = client.set_parameters({name: value}, timeout=60.0)
            assert result.successful, result.reason
        assert client.set_parameters({'input.mode': 'static'})[0].successful
        # Stored corrections to switch: the gyro bias (one event).
        response = client.call(Trigger, f'/{node.name}/calibrate_gyros', Trigger.Request())
        assert response.success, response.message
        expected = {'events': 1, 'compensation': True}
        client.spin_until(lambda: events, 30.0, 'the gyro bias event')
        accepted = {spec.name: spec.default for spec in PARAMETERS}
        accepted.update({'estimation.realtime': False, 'gyro_bias.duration_s': 2.0})
        paths = path_values(root, out, node.pid)

        @settings(max_examples=CASES, deadline=None, database=None, phases=[Phase.generate],
                  suppress_health_check=list(HealthCheck), print_blob=True)
        @seed(20261127)
        @given(cases(paths))
        def one_case(case):
            try:
                check_case(case)
            except AssertionError as error:
                # Which case failed, out of how many (bench/planted_defects.py reads it).
                error.args = (f'case {answers["sets"]} of {CASES}: {error}',)
                raise

        def check_case(case):
            changes, messages, switches = case
            request = SetParameters.Request()
            request.parameters = [Parameter(name, type_, value).to_parameter_msg()
                                  for name, (type_, value) in changes]
            started = time.monotonic()
            results = client.call(SetParameters, f'/{node.name}/set_parameters', request,
                                  timeout=20.0).results
            answers['slowest_s'] = max(answers['slowest_s'], time.monotonic() - started)
            answers['sets'] += 1
            assert len(results) == len(changes)
            for (name, (type_, value)), result in zip(changes, results):
                answers['refused'] += not result.successful
                answers['accepted'] += result.successful
                if result.successful:
                    spec = SPECS[name]
                    size = spec.max_length or spec.length or LARGEST_ARRAY
                    assert not (isinstance(value, list) and len(value) > size), \
                        f'{name}: an array of {len(value)} elements accepted (at most {size})'
                    accepted[name] = value
                else:
                    reason = result.reason
                    # The parameter or its family (a rule across several); rclpy refuses
                    # another type before the node sees it, without the name.
                    assert len(reason) <= REASON_LIMIT and (
                        name.rsplit('.', 1)[0] in reason
                        or reason.startswith('Wrong parameter type')), \
                        f'{name}: a refusal of {len(reason)} characters: {reason[:300]}'
                    # Not even 65 characters of a long string, whichever parameter held it
                    # (a recording started in a directory set before quotes that one).
                    assert not any(text[:MAX_QUOTED + 1] in reason for text in LONG_STRINGS), \
                        f'{name}: the refusal quotes a long string: {reason[:300]}'
                    told = [text for text in secrets if text in reason]
                    assert not told, f'{name}: the refusal tells {told}: {reason}'
            directory = accepted['recorder.directory']
            assert not (accepted['recorder.enabled'] and (
                directory.split('/')[0] in ('blocked', 'fifo_dir')
                or any(len(part) > LONGEST_NAME for part in directory.split('/')))), \
                f'a recording accepted where none can start: {directory[:100]}'
            for stamp, values, covariance in messages:
                truth.publish(imu_message(stamp, values, covariance,
                                          accepted['input.stamp_window_s']))
            for switch in switches:
                answers['switches'] += 1
                response = client.call(SetBool, f'/{node.name}/set_compensation',
                                       SetBool.Request(data=switch), timeout=20.0)
                assert response.success, response.message
                if switch != expected['compensation']:
                    expected['events'] += 1
                    expected['compensation'] = switch
            assert node.process.poll() is None, 'the node died'
            if answers['sets'] % (CASES // 4 or 1) == 0:
                rss.append(rss_bytes(node.pid))

        rss = [rss_bytes(node.pid)]
        started = time.monotonic()
        one_case()
        answers['seconds'] = time.monotonic() - started
        assert answers['sets'] == CASES and answers['refused'] and answers['accepted']
        # Back to the defaults, the stream comes back to its rate by itself.
        for _ in range(2):
            client.set_parameters({'input.mode': 'static', 'recorder.enabled': False})
            for spec in PARAMETERS:
                if not spec.read_only:
                    client.set_parameters({spec.name: spec.default})
        received['stamps'].clear()

        def at_rate():
            stamps = received['stamps']
            run = 0
            for previous, stamp in zip(stamps, stamps[1:]):
                run = run + 1 if stamp - previous == 1_000_000 else 0
                if run >= 500:
                    return True
            return False

        client.spin_until(at_rate, 60.0, '500 consecutive samples at 1 kHz')
        # Ground truth from the topic: one message stamped far ahead, then valid ones
        # (200 Hz, stamped now): the stream follows the valid ones at its rate.
        assert client.set_parameters({'input.mode': 'topic'})[0].successful
        truth.publish(imu_message(1.0e6, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), -1.0))
        timer = client.node.create_timer(0.005, lambda: truth.publish(
            imu_message(0.0, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), -1.0)))
        received['stamps'].clear()
        client.spin_until(at_rate, 60.0, '500 consecutive samples at 1 kHz from the topic')
        client.node.destroy_timer(timer)
        assert received['non_finite'] == 0
        # One event per switch that changed the corrections, however close together.
        client.spin_until(lambda: len(events) >= expected['events'], 30.0,
                          f'{expected["events"]} calibration events')
        client.spin_for(0.5)
        assert len(events) == expected['events']
        rss.append(rss_bytes(node.pid))
        growth = rss[-1] - rss[0]
        steady = rss[-1] - rss[2]  # from the middle of the cases
        profile = ', '.join(f'{b / 2 ** 20:.1f}' for b in rss)
        assert growth < RSS_GROWTH_LIMIT, f'RSS grew {growth >> 20} MiB ({profile} MiB)'
        assert steady < RSS_STEADY_LIMIT, \
            f'RSS grew {steady >> 20} MiB over the second half ({profile} MiB)'
    finally:
        client.close()
        status = node.stop()
    log = node.log()
    assert status == 0, log[-2000:]
    assert SECRET not in log and 'fuzz-must-not' not in log
    assert victim.read_text() == 'not yours\n'
    # Nothing written outside output_dir (the run directory holds the test's own files).
    written = set(root.rglob('*')) - before
    stray = [path for path in written
             if out not in path.parents and (root / 'run') not in path.parents
             and path != root / 'run']
    assert not stray, stray
    assert not any(hidden.iterdir())
    print(f'fuzz: {answers["sets"]} sets ({answers["accepted"]} parameters accepted, '
          f'{answers["refused"]} refused), {answers["switches"]} switches, '
          f'{expected["events"]} events in {answers["seconds"]:.0f} s, slowest answer '
          f'{answers["slowest_s"]:.2f} s, RSS growth {growth / 2 ** 20:.1f} MiB (RSS {profile} '
          f'MiB at the start, each quarter, the end)')

    # The node starts again on a state file nested too deeply for the parser.
    (out / 'state.json').write_text('[' * 100_000 + ']' * 100_000)
    node = NodeProcess(domain, root / 'run', {
        'output_dir': str(out), 'state_file': str(out / 'state.json')})
    client = Client(domain)
    received['count'] = 0
    try:
        client.node.create_subscription(Imu, 'imu/data_raw', on_imu, qos_profile_sensor_data)

        def started():
            assert node.process.poll() is None, node.log()[-2000:]
            return received['count'] > 10
        client.spin_until(started, 60.0, 'the samples of the restarted node')
    finally:
        client.close()
        status = node.stop()
    log = node.log()
    assert status == 0 and 'nested too deeply' in log and 'Traceback' not in log, log[-2000:]
    assert list(out.glob('state.json.corrupt-*'))
