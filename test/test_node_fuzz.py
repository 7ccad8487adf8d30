"""
A stranger on the domain: thousands of random parameter sets and ground-truth messages.

Property-based (hypothesis, seeded so a failure replays). Each case sets one to three
parameters to values drawn from their ranges, just past their edges, NaN and infinities,
huge strings, other types and paths of every kind (a secret file, a FIFO, devices,
``/proc``, escapes from the output directory), and publishes a few ground-truth
``Imu`` messages with random stamps and values. Invariants: every set is answered within
seconds, no answer and no log line quotes a file, the node stays up with bounded memory,
writes nothing outside ``output_dir``, publishes no non-finite sample, and streams at
its rate again once the parameters are back to their defaults.
"""

import math
import os
import time

from builtin_interfaces.msg import Time
from hypothesis import given, HealthCheck, Phase, seed, settings
from hypothesis import strategies as st
from node_helpers import Client, domain_id, NodeProcess
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

from qfa_ros.ros.params import PARAMETERS

CASES = int(os.environ.get('QFA_FUZZ_CASES', '2000'))
SECRET = 'SECRET_TOKEN=fuzz-must-not-echo'
RSS_GROWTH_LIMIT = 400 << 20
"""Largest growth of the node's resident memory over the run [bytes]."""


def rss_bytes(pid):
    """Return the resident set size of process ``pid`` [bytes]."""
    with open(f'/proc/{pid}/status') as status:
        for line in status:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) * 1024
    raise RuntimeError('no VmRSS')


def path_values(root):
    """Return strings a stranger might name as a file or a directory."""
    return [str(root / 'secret.txt'), str(root / 'fifo'), '/dev/zero', '/dev/urandom',
            '/proc/self/environ', '/etc/shadow', '/', '..', '../..', 'a/../../b',
            str(root / 'elsewhere' / 'x'), str(root / 'link_out'), 'link_out/x', '~', '~/x',
            '', '.', 'traces', str(root / 'out' / 'inside'), 'x' * 5000, 'ü/ñ', ' ']


def typed(type_, strategy):
    return strategy.map(lambda value: (type_, value))


def junk(root):
    """Return values of every parameter type, mostly wrong for any one parameter."""
    text = st.text(st.characters(blacklist_categories=('Cs',), blacklist_characters='\x00'),
                   max_size=40)
    floats = st.floats(allow_nan=True, allow_infinity=True)
    return st.one_of(
        typed(Parameter.Type.DOUBLE, floats),
        typed(Parameter.Type.INTEGER, st.integers(-2 ** 63, 2 ** 63 - 1)),
        typed(Parameter.Type.BOOL, st.booleans()),
        typed(Parameter.Type.STRING, text | st.sampled_from(path_values(root))),
        typed(Parameter.Type.DOUBLE_ARRAY, st.lists(floats, max_size=12)),
        typed(Parameter.Type.INTEGER_ARRAY, st.lists(st.integers(-2 ** 63, 2 ** 63 - 1),
                                                     max_size=12)),
        typed(Parameter.Type.STRING_ARRAY, st.lists(text, max_size=4)),
    )


def near(spec):
    """Return values of ``spec``'s own type: in range, on and just past its edges."""
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
        return typed(Parameter.Type.DOUBLE_ARRAY,
                     st.lists(element, min_size=length, max_size=length)
                     | st.lists(element, max_size=length + 3))
    choices = list(spec.choices or []) or [default]
    return typed(Parameter.Type.STRING, st.sampled_from(choices))


def cases(root):
    """Return the strategy of one case: parameter changes and ground-truth messages."""
    writable = [spec for spec in PARAMETERS if not spec.read_only]
    change = st.sampled_from(PARAMETERS).flatmap(
        lambda spec: st.tuples(st.just(spec.name),
                               near(spec) if spec in writable and spec.name != 'input.mode'
                               else st.one_of(near(spec), junk(root))))
    random_changes = st.lists(change, min_size=1, max_size=3, unique_by=lambda c: c[0])
    # One case in ten names a file and selects it as the input, in a random order: the
    # sequence that made the node read (and quote) any file.
    string = Parameter.Type.STRING
    attack = st.tuples(st.sampled_from(path_values(root)), st.permutations([
        'input.trajectory_file', 'input.trajectory', 'input.mode'])).map(
        lambda case: [(name, (string, {'input.trajectory_file': case[0],
                                       'input.trajectory': 'file',
                                       'input.mode': 'trajectory'}[name]))
                      for name in case[1]])
    changes = st.integers(0, 9).flatmap(lambda k: attack if k == 0 else random_changes)
    now = int(time.time())
    seconds = st.one_of(st.integers(now - 2, now + 2), st.integers(0, 2 ** 31 - 1),
                        st.integers(-2 ** 31, -1))
    floats = st.floats(allow_nan=True, allow_infinity=True) | st.floats(-30.0, 30.0)
    message = st.tuples(seconds, st.integers(0, 999_999_999), st.lists(floats, min_size=6,
                                                                       max_size=6),
                        st.sampled_from([-1.0, 0.0]))
    return st.tuples(changes, st.lists(message, max_size=3))


def imu_message(stamp_s, nanosec, values, rate_covariance):
    message = Imu()
    message.header.stamp = Time(sec=stamp_s, nanosec=nanosec)
    a, w = message.linear_acceleration, message.angular_velocity
    a.x, a.y, a.z, w.x, w.y, w.z = values
    message.angular_velocity_covariance[0] = rate_covariance
    return message


def test_a_strangers_parameters_and_messages_break_nothing(tmp_path):
    root = tmp_path
    (root / 'secret.txt').write_text(f'{SECRET}\n')
    os.mkfifo(root / 'fifo')
    (root / 'elsewhere').mkdir()
    out = root / 'out'
    out.mkdir()
    (out / 'link_out').symlink_to(root / 'elsewhere', target_is_directory=True)
    # What a save killed mid-write leaves; the node removes it at start and says so.
    leftover = out / '.state.json.k1ll3d.tmp'
    leftover.write_text('{"half": ')
    (root / 'link_out').symlink_to(root / 'elsewhere', target_is_directory=True)
    before = set(root.rglob('*')) - {leftover}
    domain = domain_id('fuzz')
    node = NodeProcess(domain, root / 'run', {
        'output_dir': str(out), 'state_file': str(out / 'state.json'),
        'min_free_bytes': 1 << 20, 'diagnostics_rate_hz': 10.0})
    client = Client(domain)
    received = {'count': 0, 'non_finite': 0, 'stamps': []}

    def on_imu(message):
        values = (message.linear_acceleration.x, message.linear_acceleration.y,
                  message.linear_acceleration.z)
        received['count'] += 1
        received['non_finite'] += not all(math.isfinite(v) for v in values)
        stamp = message.header.stamp
        received['stamps'].append(stamp.sec * 1_000_000_000 + stamp.nanosec)
        del received['stamps'][:-2000]

    answers = {'sets': 0, 'slowest_s': 0.0, 'refused': 0, 'accepted': 0}
    try:
        client.node.create_subscription(Imu, 'imu/data_raw', on_imu, qos_profile_sensor_data)
        truth = client.node.create_publisher(
            Imu, 'input/imu', QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
        client.spin_until(lambda: received['count'] > 100, 60.0, 'the first samples')
        rss_start = rss_bytes(node.pid)
        assert not leftover.exists()
        assert 'removed 1 temporary state file(s) an interrupted save left: ' \
            '.state.json.k1ll3d.tmp' in node.log()

        @settings(max_examples=CASES, deadline=None, database=None, phases=[Phase.generate],
                  suppress_health_check=list(HealthCheck), print_blob=True)
        @seed(20261126)
        @given(cases(root))
        def one_case(case):
            changes, messages = case
            request = SetParameters.Request()
            request.parameters = [Parameter(name, type_, value).to_parameter_msg()
                                  for name, (type_, value) in changes]
            started = time.monotonic()
            results = client.call(SetParameters, f'/{node.name}/set_parameters', request,
                                  timeout=20.0).results
            answers['slowest_s'] = max(answers['slowest_s'], time.monotonic() - started)
            answers['sets'] += 1
            assert len(results) == len(changes)
            for result in results:
                answers['refused'] += not result.successful
                answers['accepted'] += result.successful
                assert SECRET not in result.reason and 'fuzz-must-not' not in result.reason
            for stamp_s, nanosec, values, covariance in messages:
                truth.publish(imu_message(stamp_s, nanosec, values, covariance))
            assert node.process.poll() is None, 'the node died'

        one_case()
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
        far = int(time.time()) + 1_000_000
        truth.publish(imu_message(far, 0, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), -1.0))

        def publish_now():
            stamp_ns = time.time_ns()
            truth.publish(imu_message(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000,
                                      (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), -1.0))

        timer = client.node.create_timer(0.005, publish_now)
        received['stamps'].clear()
        client.spin_until(at_rate, 60.0, '500 consecutive samples at 1 kHz from the topic')
        client.node.destroy_timer(timer)
        assert received['non_finite'] == 0
        growth = rss_bytes(node.pid) - rss_start
        assert growth < RSS_GROWTH_LIMIT, f'RSS grew {growth >> 20} MiB'
    finally:
        client.close()
        status = node.stop()
    log = node.log()
    assert status == 0, log[-2000:]
    assert SECRET not in log and 'fuzz-must-not' not in log
    # Nothing written outside output_dir (the run directory holds the test's own files).
    written = set(root.rglob('*')) - before
    stray = [path for path in written
             if out not in path.parents and (root / 'run') not in path.parents
             and path != root / 'run']
    assert not stray, stray
    assert not any((root / 'elsewhere').iterdir())
    print(f'fuzz: {answers["sets"]} sets ({answers["accepted"]} parameters accepted, '
          f'{answers["refused"]} refused), slowest '
          f'answer {answers["slowest_s"]:.2f} s, RSS growth {growth / 2 ** 20:.0f} MiB')
