"""Acceptance tests of ``qfa-replay``: a subprocess plays a bag, this process listens.

Each test isolates DDS with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, its own
``ROS_DOMAIN_ID`` and topics under a namespace unique to the test, and waits for
the match with ``--wait-for-subscribers`` instead of sleeping.
"""

import itertools
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from mcap.reader import make_reader
from node_helpers import domain_id as helper_domain_id
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock

from qfa_ros.bag.flight_recorder import FlightRecorder
from qfa_ros.bag.qos import QOS_LATCHED, QOS_SENSOR_DATA
from qfa_ros.bag.reader import BagError, BagSource
from qfa_ros.bag.types import register_message_definition, stamp
from qfa_ros.bag.writer import McapBagWriter
from qfa_ros.model.constants import STANDARD_GRAVITY
from qfa_ros.ros.fastdds import shipped_fastdds_profile, use_shipped_fastdds_profile
from qfa_ros.ros.replay import import_message_type, qos_from_offers, ReplaySummary

REPO = Path(__file__).resolve().parents[1]
T0 = 1_700_000_000_000_000_000
UNKNOWN_TYPE = 'qfa_no_such_msgs/msg/Gizmo'
TIMING_TOLERANCE_S = 0.005
TIMING_ATTEMPTS = 2
# The longest a busy machine may stall the replayer or the listener.
STALL_LIMIT_S = 0.5
RECEIVE_TIMEOUT_S = 30.0
_domain_offsets = itertools.count()


# --- bags ----------------------------------------------------------------------------------

def _irregular_times(seconds, rate_hz, rng):
    """Return log times [ns] at ``rate_hz`` with jitter and a few long gaps."""
    period = 1.0 / rate_hz
    gaps = rng.uniform(0.6 * period, 1.4 * period, size=int(seconds * rate_hz) - 1)
    gaps[rng.choice(len(gaps), size=4, replace=False)] = [0.03, 0.05, 0.1, 0.012]
    offsets = np.concatenate([[0.0], np.cumsum(gaps)])
    return (T0 + np.round(offsets * 1e9)).astype(np.int64).tolist()


def _imu(time_ns, index):
    unknown = [-1.0] + [0.0] * 8
    return {
        'header': {'stamp': stamp(time_ns), 'frame_id': 'imu_link'},
        'orientation_covariance': unknown,
        'angular_velocity_covariance': unknown,
        'linear_acceleration': {'x': 0.001 * index, 'y': -0.5,
                                'z': STANDARD_GRAVITY + 1e-6 * index},
        'linear_acceleration_covariance': [1e-8, 0, 0, 0, 1e-8, 0, 0, 0, 1e-8],
    }


def write_project_bag(path, namespace, seconds=2.0, rate_hz=200.0, seed=0):
    """Write Imu with irregular gaps, a latched DiagnosticArray and a topic of unknown type."""
    rng = np.random.default_rng(seed)
    register_message_definition(UNKNOWN_TYPE, 'float64 value\n')
    imu_topic = f'{namespace}/imu/data_raw'
    status_topic = f'{namespace}/status'
    unknown_topic = f'{namespace}/gizmo'
    times = _irregular_times(seconds, rate_hz, rng)
    with McapBagWriter(path) as bag:
        bag.add_topic(imu_topic, 'sensor_msgs/msg/Imu', QOS_SENSOR_DATA)
        bag.add_topic(status_topic, 'diagnostic_msgs/msg/DiagnosticArray', QOS_LATCHED)
        bag.add_topic(unknown_topic, UNKNOWN_TYPE)
        bag.write(status_topic, {
            'header': {'stamp': stamp(times[0]), 'frame_id': ''},
            'status': [{'level': 0, 'name': 'replay test', 'message': 'latched',
                        'hardware_id': 'test', 'values': [{'key': 'a', 'value': '1'}]}],
        }, times[0])
        for index, time_ns in enumerate(times):
            bag.write(imu_topic, _imu(time_ns, index), time_ns)
            if index % 50 == 0:
                bag.write(unknown_topic, {'value': float(index)}, time_ns)
        bag.finish()
    return {'imu': imu_topic, 'status': status_topic, 'unknown': unknown_topic}


def read_messages(path, topic):
    """Return ``[(log_time_ns, cdr bytes)]`` of ``topic`` read with the plain MCAP reader.

    ``path`` is an ``.mcap`` file or a bag directory (its files are read in name order).
    """
    path = Path(path)
    messages = []
    for file in sorted(path.glob('*.mcap')) if path.is_dir() else [path]:
        with open(file, 'rb') as stream:
            messages.extend((message.log_time, bytes(message.data)) for _, _, message
                            in make_reader(stream).iter_messages(topics=[topic]))
    return messages


# --- ROS side ------------------------------------------------------------------------------

class BagListener(Node):
    """
    Subscribe raw to topics and record (arrival time [s], CDR bytes, publish time [s]).

    The arrival time is the middleware's reception timestamp, so executor latency in
    this process does not count against the replay; the publish time is the source
    timestamp the replaying writer stamped.
    """

    def __init__(self, context, subscriptions):
        super().__init__('replay_listener', context=context)
        self.received = {}
        self.listeners = []
        for topic, message_type, qos in subscriptions:
            self.received[topic] = []
            self.listeners.append(self.create_subscription(
                message_type, topic, self._make_callback(topic), qos, raw=True))

    def _make_callback(self, topic):
        def message_callback(data, info):
            self.received[topic].append((info['received_timestamp'] * 1e-9, data,
                                         info['source_timestamp'] * 1e-9))
        return message_callback


SENSOR_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
LATCHED_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1000)


@pytest.fixture
def ros_domain(monkeypatch):
    """Yield ``(context, env)`` for one isolated domain shared with the replay subprocess."""
    domain_id = helper_domain_id(f'replay-{next(_domain_offsets)}')
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain_id))
    monkeypatch.delenv('ROS_LOCALHOST_ONLY', raising=False)
    # The listener is the long-running participant here: it needs the profile too.
    use_shipped_fastdds_profile()
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        yield context, dict(os.environ)
    finally:
        rclpy.try_shutdown(context=context)


def replay(context, env, bag, subscriptions, extra_args=(), subscribers=None):
    """
    Play ``bag`` in a subprocess into a listener; return (listener, completed process).

    The subprocess waits for ``subscribers`` matched subscriptions (default: one per
    subscription given) before it plays.
    """
    listener = BagListener(context, subscriptions)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(listener)
    count = len(subscriptions) if subscribers is None else subscribers
    command = [sys.executable, '-m', 'qfa_ros.cli.replay', str(bag),
               '--wait-for-subscribers', str(count), '--domain-ready-timeout', '20',
               *extra_args]
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + RECEIVE_TIMEOUT_S
    try:
        while process.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        # Drain what is still in flight after the publisher exits: until nothing came for
        # 0.2 s (a busy machine delivers the last messages late), 5 s at most.
        drain_until = time.monotonic() + 5.0
        quiet_until, seen = time.monotonic() + 0.2, -1
        while time.monotonic() < min(quiet_until, drain_until):
            executor.spin_once(timeout_sec=0.01)
            count = sum(len(messages) for messages in listener.received.values())
            if count != seen:
                quiet_until, seen = time.monotonic() + 0.2, count
    finally:
        if process.poll() is None:
            process.kill()
        stdout, stderr = process.communicate()
        executor.shutdown()
        listener.destroy_node()
    completed = subprocess.CompletedProcess(command, process.returncode, stdout, stderr)
    assert completed.returncode == 0, completed.stdout + completed.stderr
    return listener, completed


def assert_same_messages(received, expected):
    """Check that ``received`` holds the CDR payloads of ``expected``, in order.

    Fast DDS delivers a payload padded with zeros to a multiple of 4 bytes, so the
    comparison allows up to 3 trailing zero bytes more than were recorded.
    """
    received_data = [item[1] for item in received]
    expected_data = [data for _, data in expected]
    if len(received_data) == len(expected_data):
        received_data = [
            got[:len(want)] if (len(got) == len(want) + (-len(want)) % 4
                                and got.startswith(want)
                                and not got[len(want):].strip(b'\x00')) else got
            for got, want in zip(received_data, expected_data)]
    missing = [index for index, data in enumerate(expected_data) if data not in received_data]
    assert received_data == expected_data, (
        f'received {len(received_data)} of {len(expected_data)}; missing indexes {missing}')


def timing_error(received, expected_log_ns, rate=1.0, column=0, statistic=np.max):
    """Return the ``statistic`` of |arrival-time difference - log-time difference / rate| [s].

    ``column`` 2 measures the publish (source) times instead of the arrival times.
    """
    arrival = np.array([item[column] for item in received])
    logged = np.array(expected_log_ns, dtype=np.int64)
    return float(statistic(np.abs(np.diff(arrival) - np.diff(logged) * 1e-9 / rate)))


def replay_timed(context, env, bag, subscriptions, topic, rate=1.0, **options):
    """
    Replay, check ``topic``'s content and timing; return (listener, process, errors [s]).

    Every message must arrive intact and in order. The errors returned are the median
    gap errors: a busy machine stalls either process now and then for tens of
    milliseconds (the worst gap error, printed, measures that, not the replayer), but a
    replayer off its schedule or at the wrong rate is off on most gaps. An attempt over
    the tolerance is tried again once.
    """
    expected = read_messages(bag, topic)
    logged = [t for t, _ in expected]
    errors = []
    for _ in range(TIMING_ATTEMPTS):
        listener, completed = replay(context, env, bag, subscriptions, **options)
        received = listener.received[topic]
        assert_same_messages(received, expected)
        errors.append(timing_error(received, logged, rate, statistic=np.median))
        if errors[-1] < TIMING_TOLERANCE_S:
            break
    worst = timing_error(received, logged, rate)
    publish_error = timing_error(received, logged, rate, column=2)
    print(f'replay timing {topic} at rate {rate:g}: {len(received)} messages, |arrival '
          f'gap - log gap / rate| median {", ".join(f"{e * 1e3:.3f}" for e in errors)} ms, '
          f'max {worst * 1e3:.3f} ms (publish gaps max {publish_error * 1e3:.3f} ms)')
    return listener, completed, errors


# --- tests ---------------------------------------------------------------------------------

def test_replay_reproduces_content_and_timing(ros_domain, tmp_path):
    context, env = ros_domain
    bag = tmp_path / 'project.mcap'
    topics = write_project_bag(bag, f'/replay_{os.getpid()}_content', seconds=1.0)
    imu_class = import_message_type('sensor_msgs/msg/Imu')
    diagnostics_class = import_message_type('diagnostic_msgs/msg/DiagnosticArray')
    listener, completed, errors = replay_timed(context, env, bag, [
        (topics['imu'], imu_class, SENSOR_QOS),
        (topics['status'], diagnostics_class, LATCHED_QOS),
    ], topics['imu'])
    assert errors[-1] < TIMING_TOLERANCE_S
    assert_same_messages(listener.received[topics['status']],
                         read_messages(bag, topics['status']))
    assert f'skipped {topics["unknown"]}: unknown message type' in completed.stdout
    assert 'max lateness' in completed.stdout


def test_rate_topics_and_clock_options(ros_domain, tmp_path):
    """
    One replay of a bag with three topics, three options at once.

    ``--rate 2`` halves every gap, ``--topics`` plays the named topics only, ``--clock``
    publishes the bag time.
    """
    context, env = ros_domain
    bag = tmp_path / 'options.mcap'
    topics = write_project_bag(bag, f'/replay_{os.getpid()}_options', seconds=1.0, seed=1)
    listener, completed, errors = replay_timed(context, env, bag, [
        (topics['imu'], import_message_type('sensor_msgs/msg/Imu'), SENSOR_QOS),
        (topics['status'], import_message_type('diagnostic_msgs/msg/DiagnosticArray'),
         LATCHED_QOS),
        ('/clock', Clock, RELIABLE_QOS),
    ], topics['imu'], rate=2.0, extra_args=['--rate', '2', '--topics', topics['imu'],
                                            '--clock', '100'], subscribers=1)
    assert errors[-1] < TIMING_TOLERANCE_S
    expected = read_messages(bag, topics['imu'])
    received = listener.received[topics['imu']]
    played = received[-1][0] - received[0][0]
    recorded = (expected[-1][0] - expected[0][0]) * 1e-9
    # The gaps are halved (median, above); the whole is off by a stall at most, no drift.
    assert played == pytest.approx(recorded / 2, abs=STALL_LIMIT_S)
    # The status topic (latched, subscribed here) is not among the named topics.
    assert listener.received[topics['status']] == []
    assert topics['status'] not in completed.stdout
    ticks = []
    for _, data, _ in listener.received['/clock']:
        message = deserialize_message(data, Clock)
        ticks.append(message.clock.sec * 1_000_000_000 + message.clock.nanosec)
    assert len(ticks) >= 40  # 0.5 s at 100 Hz
    assert ticks == sorted(ticks)
    assert expected[0][0] <= ticks[0] and ticks[-1] <= expected[-1][0]


def test_rosbag2_directory_bag(ros_domain, tmp_path):
    context, env = ros_domain
    namespace = f'/replay_{os.getpid()}_rosbag2'
    store = get_typestore(Stores.ROS2_KILTED)
    String = store.types['std_msgs/msg/String']
    Vector3 = store.types['geometry_msgs/msg/Vector3']
    infinite = QosTime(sec=9223372036, nsec=854775807)

    def offer(reliability, durability, depth):
        return Qos(QosHistory.KEEP_LAST, depth, reliability, durability, infinite, infinite,
                   QosLiveliness.AUTOMATIC, infinite, False)

    bag = tmp_path / 'rosbag2'
    expected = {f'{namespace}/chatter': [], f'{namespace}/vector': []}
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        chatter = writer.add_connection(
            f'{namespace}/chatter', 'std_msgs/msg/String', typestore=store,
            offered_qos_profiles=[offer(QosReliability.RELIABLE, QosDurability.VOLATILE, 7)])
        vector = writer.add_connection(
            f'{namespace}/vector', 'geometry_msgs/msg/Vector3', typestore=store,
            offered_qos_profiles=[offer(QosReliability.BEST_EFFORT, QosDurability.VOLATILE,
                                        3)])
        for index in range(40):
            time_ns = T0 + index * 10_000_000 + (index % 3) * 2_000_000
            connection, message = ((chatter, String(data=f'hello {index}')) if index % 2
                                   else (vector, Vector3(x=index, y=0.5, z=-1.0)))
            data = bytes(store.serialize_cdr(message, connection.msgtype))
            writer.write(connection, time_ns, data)
            expected[connection.topic].append((time_ns, data))
    assert (bag / 'metadata.yaml').exists()

    source = BagSource(bag)
    assert source.topics[f'{namespace}/chatter'].msgtype == 'std_msgs/msg/String'
    vector_qos = qos_from_offers(source.topics[f'{namespace}/vector'].offered_qos)
    assert vector_qos.reliability == ReliabilityPolicy.BEST_EFFORT and vector_qos.depth == 3
    assert [time_ns for _, time_ns, _ in source.messages()] == sorted(
        time_ns for messages in expected.values() for time_ns, _ in messages)

    listener, _, errors = replay_timed(context, env, bag, [
        (f'{namespace}/chatter', import_message_type('std_msgs/msg/String'), RELIABLE_QOS),
        (f'{namespace}/vector', import_message_type('geometry_msgs/msg/Vector3'), SENSOR_QOS),
    ], f'{namespace}/chatter')
    assert errors[-1] < TIMING_TOLERANCE_S
    assert_same_messages(listener.received[f'{namespace}/vector'],
                         expected[f'{namespace}/vector'])


def test_flight_recorder_directory_plays_across_its_splits(ros_domain, tmp_path):
    context, env = ros_domain
    topic = f'/replay_{os.getpid()}_flight/imu/data_raw'
    source = tmp_path / 'source.mcap'
    write_project_bag(source, topic.rsplit('/imu', 1)[0], seconds=1.0, seed=6)
    expected = read_messages(source, topic)
    with FlightRecorder(tmp_path, 'flight', max_bytes=12000,
                        qos={topic: QOS_SENSOR_DATA}) as flight:
        for time_ns, data in expected:
            flight.record(topic, 'sensor_msgs/msg/Imu', data, time_ns)
    assert len(flight.files) >= 3
    listener, completed = replay(context, env, flight.bag_directory, [
        (topic, import_message_type('sensor_msgs/msg/Imu'), SENSOR_QOS)])
    assert_same_messages(listener.received[topic], expected)
    assert f'{len(expected)}' in completed.stdout


def test_sigint_stops_a_looping_replay_cleanly(ros_domain, tmp_path):
    _, env = ros_domain
    bag = tmp_path / 'loop.mcap'
    write_project_bag(bag, f'/replay_{os.getpid()}_loop', seconds=0.2, seed=4)
    process = subprocess.Popen([sys.executable, '-m', 'qfa_ros.cli.replay', str(bag), '--loop'],
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    # This line is printed just before playback starts.
    assert process.stdout.readline().startswith('qfa-replay: playing')
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 0, stdout + stderr
    assert 'interrupted' in stdout and 'Traceback' not in stderr


# --- units ---------------------------------------------------------------------------------

def test_qos_follows_the_recorded_offers():
    best_effort = qos_from_offers([{'reliability': 'best_effort', 'durability': 'volatile',
                                    'history': 'keep_last', 'depth': 5}])
    assert best_effort.reliability == ReliabilityPolicy.BEST_EFFORT
    assert best_effort.depth == 5
    latched = qos_from_offers([{'reliability': 1, 'durability': 1, 'history': 1, 'depth': 1}])
    assert latched.reliability == ReliabilityPolicy.RELIABLE
    assert latched.durability == DurabilityPolicy.TRANSIENT_LOCAL
    mixed = qos_from_offers([{'reliability': 'reliable', 'durability': 'transient_local'},
                             {'reliability': 'best_effort', 'durability': 'volatile',
                              'history': 'keep_all'}])
    assert mixed.reliability == ReliabilityPolicy.BEST_EFFORT
    assert mixed.durability == DurabilityPolicy.VOLATILE
    assert mixed.history == HistoryPolicy.KEEP_ALL
    fallback = qos_from_offers([])
    assert (fallback.reliability, fallback.durability, fallback.depth) == (
        ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, 10)


def test_message_types_import_by_name():
    assert import_message_type('sensor_msgs/msg/Imu').__name__ == 'Imu'
    assert import_message_type('std_msgs/String').__name__ == 'String'
    assert import_message_type(UNKNOWN_TYPE) is None
    assert import_message_type('sensor_msgs/msg/NoSuchThing') is None
    assert import_message_type('sensor_msgs/srv/Imu') is None


def test_bag_source_reads_project_bags_and_refuses_others(tmp_path):
    bag = tmp_path / 'project.mcap'
    topics = write_project_bag(bag, '/source', seconds=0.2)
    source = BagSource(bag)
    assert set(source.topics) == set(topics.values())
    assert source.topics[topics['status']].offered_qos[0]['durability'] == 'transient_local'
    times = [time_ns for _, time_ns, _ in source.messages([topics['imu']])]
    assert times == sorted(times) and len(times) == 40
    later = list(source.messages([topics['imu']], start_ns=times[10]))
    assert later[0][1] == times[10]
    with pytest.raises(BagError, match='no bag'):
        BagSource(tmp_path / 'missing.mcap')
    sqlite = tmp_path / 'sqlite'
    sqlite.mkdir()
    (sqlite / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: sqlite3\n'
        '  relative_file_paths: [sqlite_0.db3]\n')
    with pytest.raises(BagError, match='sqlite3'):
        BagSource(sqlite)


@pytest.mark.parametrize('metadata, expected', [
    # Before: RecursionError, AttributeError and TypeError tracebacks, a YAML error quoting
    # the file, /dev/zero read until memory ran out, a string taken as a list of one-letter
    # file names.
    ('[' * 1000, 'metadata.yaml: not YAML'),
    ('rosbag2_bagfile_information: [SECRET]\n', 'no rosbag2_bagfile_information mapping'),
    ('rosbag2_bagfile_information:\n  x: [SECRET\n', 'metadata.yaml: not YAML'),
    ('rosbag2_bagfile_information:\n  relative_file_paths: SECRET.mcap\n',
     'relative_file_paths must be a list of file names'),
    ('rosbag2_bagfile_information:\n  relative_file_paths: [{a: 1}]\n',
     'relative_file_paths must be a list of file names'),
    ('device', 'not a regular file'),
])
def test_a_malformed_metadata_yaml_is_one_line_without_quoting_it(tmp_path, metadata, expected):
    bag = tmp_path / 'bag'
    bag.mkdir()
    write_project_bag(bag / 'bag_0.mcap', '/source', seconds=0.1)
    if metadata == 'device':
        (bag / 'metadata.yaml').symlink_to('/dev/zero')
    else:
        (bag / 'metadata.yaml').write_text(metadata)
    with pytest.raises(BagError, match=expected) as caught:
        BagSource(bag)
    assert 'SECRET' not in str(caught.value) and '\n' not in str(caught.value)


def test_wrongly_typed_topic_metadata_is_ignored():
    """Before: an AttributeError for a type that is not a string."""
    source = BagSource.__new__(BagSource)
    source.topics, source.warnings = {}, []

    class Channel:
        topic, message_encoding, metadata = '/t', 'cdr', {'offered_qos_profiles': '[' * 1000}

    source._add_channel(Channel(), '', {'type': [1], 'offered_qos_profiles': '[' * 1000})
    assert source.topics['/t'].msgtype == '' and source.topics['/t'].offered_qos == []


@pytest.mark.parametrize('argv', [
    # Before: --domain-ready-timeout nan waited forever; the others printed tracebacks
    # (ValueError from BagReplayer, OverflowError for an infinite offset).
    ['--rate', '0'], ['--rate', 'nan'], ['--start-offset', '-1'], ['--start-offset', 'nan'],
    ['--start-offset', 'inf'], ['--clock', 'nan'], ['--clock', 'inf'], ['--clock', '-1'],
    ['--wait-for-subscribers', '1', '--domain-ready-timeout', 'nan'],
])
def test_bad_replay_options_are_one_line_before_ros_starts(monkeypatch, capsys, argv):
    from qfa_ros.cli import replay

    def no_ros():
        raise AssertionError('ROS started')

    monkeypatch.setattr(replay, 'use_shipped_fastdds_profile', no_ros)
    assert replay.main(['bag.mcap', *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith('qfa-replay: --') and err.count('\n') == 1, err


def test_summary_format_lists_topics_and_skips():
    summary = ReplaySummary(counts={'/a': 3}, skipped={'/b': 'unknown message type'},
                            wall_s=1.0, bag_s=1.0, max_lateness_s=0.0002, loops=1)
    text = summary.format()
    assert 'played 3 messages' in text and '/a' in text and 'skipped /b' in text
    assert '0.200 ms' in text


def test_shipped_fastdds_profile_is_used_unless_the_user_set_one():
    assert shipped_fastdds_profile() == REPO / 'config' / 'fastdds_discovery.xml'
    environ = {}
    assert use_shipped_fastdds_profile(environ) == str(REPO / 'config' /
                                                       'fastdds_discovery.xml')
    mine = {'FASTDDS_DEFAULT_PROFILES_FILE': '/etc/my_profile.xml'}
    assert use_shipped_fastdds_profile(mine) == '/etc/my_profile.xml'
