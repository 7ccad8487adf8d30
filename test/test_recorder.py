"""Tests for the MCAP recorder: files are checked with independent readers (rosbags, mcap)."""

import errno
import hashlib
import json
import os
from pathlib import Path
import re
import signal
import struct
import subprocess
import sys
import textwrap

from crash_helpers import part_messages
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import get_types_from_msg, get_typestore, Stores
import yaml

from qfa_ros.bag.estimation_trace import trace_path, write_estimation_trace
from qfa_ros.bag.flight_recorder import FlightRecorder
from qfa_ros.bag.msgdefs import definition, RECORDED_TYPES, type_hash
from qfa_ros.bag.part_files import RecorderError
from qfa_ros.bag.qos import offered_qos_yaml, QOS_LATCHED, QOS_SENSOR_DATA, QosProfile
from qfa_ros.bag.trace_writer import key_values_to_dict, TraceWriter
from qfa_ros.bag.types import encode_message, stamp
from qfa_ros.bag.writer import McapBagWriter
from qfa_ros.calibration.estimation import (
    capture_reference,
    feedback_schedule,
    FeedbackSettings,
    forward_schedule,
    ForwardSettings,
    self_calibrate,
)
from qfa_ros.calibration.fixed_point_compensator import DoubleExpCompensator
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.temperature import temperature_schedule, TemperatureSettings
from qfa_ros.calibration.tempfit import DoubleExpFit
from qfa_ros.model.constants import STANDARD_GRAVITY
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import AXES, QfaTriad
from qfa_ros.model.triad_config import TriadConfig
from qfa_ros.ros.distro import ros_distribution

REPO = Path(__file__).resolve().parents[1]
T0 = 1_700_000_000_123_456_789
REQUIRED_TYPES = [
    'sensor_msgs/msg/Imu',
    'sensor_msgs/msg/Temperature',
    'diagnostic_msgs/msg/DiagnosticArray',
    'std_msgs/msg/Float64MultiArray',
    'std_msgs/msg/String',
    'std_msgs/msg/Bool',
    'diagnostic_msgs/msg/KeyValue',
    'geometry_msgs/msg/AccelStamped',
    'rosgraph_msgs/msg/Clock',
]


# --- message factories ---------------------------------------------------------------------

def _vector(rng):
    return dict(zip('xyz', rng.normal(size=3).tolist()))


def _random_message(msgtype, rng, time_ns):
    header = {'stamp': stamp(time_ns), 'frame_id': f'frame_{rng.integers(100)}'}
    text = ''.join(rng.choice(list('abcxyz_ 09'), size=rng.integers(0, 12)))
    if msgtype == 'sensor_msgs/msg/Imu':
        return {
            'header': header,
            'orientation': dict(zip('xyzw', rng.normal(size=4).tolist())),
            'orientation_covariance': [-1.0] + [0.0] * 8,
            'angular_velocity': _vector(rng),
            'angular_velocity_covariance': rng.normal(size=9),  # numpy array accepted
            'linear_acceleration': _vector(rng),
            'linear_acceleration_covariance': rng.normal(size=9).tolist(),
        }
    if msgtype == 'sensor_msgs/msg/Temperature':
        return {'header': header, 'temperature': float(rng.normal(25, 5)),
                'variance': float(rng.random())}
    if msgtype == 'diagnostic_msgs/msg/DiagnosticArray':
        return {'header': header, 'status': [
            {'level': int(rng.integers(0, 3)), 'name': f'axis_{i}', 'message': text,
             'hardware_id': 'qfa', 'values': [
                 {'key': f'k{j}', 'value': repr(float(rng.normal()))}
                 for j in range(rng.integers(0, 4))]}
            for i in range(rng.integers(1, 4))]}
    if msgtype == 'std_msgs/msg/Float64MultiArray':
        n = int(rng.integers(0, 20))
        return {'layout': {'dim': [{'label': 'n', 'size': n, 'stride': n}], 'data_offset': 0},
                'data': rng.normal(size=n)}
    if msgtype == 'std_msgs/msg/String':
        return {'data': text}
    if msgtype == 'std_msgs/msg/Bool':
        return {'data': bool(rng.integers(0, 2))}
    if msgtype == 'diagnostic_msgs/msg/KeyValue':
        return {'key': text, 'value': str(rng.integers(1000))}
    if msgtype == 'geometry_msgs/msg/AccelStamped':
        return {'header': header, 'accel': {'linear': _vector(rng), 'angular': _vector(rng)}}
    if msgtype == 'rosgraph_msgs/msg/Clock':
        return {'clock': stamp(time_ns)}
    raise AssertionError(msgtype)


def _assert_same(actual, expected, where='msg'):
    """Compare a rosbags-deserialized message with the mapping it was written from."""
    if isinstance(expected, dict):
        for key, value in expected.items():
            _assert_same(getattr(actual, key), value, f'{where}.{key}')
    elif isinstance(expected, (list, tuple, np.ndarray)) and len(expected) and isinstance(
            expected[0], dict):
        assert len(actual) == len(expected), where
        for index, (item_actual, item_expected) in enumerate(zip(actual, expected)):
            _assert_same(item_actual, item_expected, f'{where}[{index}]')
    elif isinstance(expected, (list, tuple, np.ndarray)):
        np.testing.assert_array_equal(np.asarray(actual), np.asarray(expected), err_msg=where)
    else:
        assert actual == expected, f'{where}: {actual!r} != {expected!r}'


def _string_cdr(text):
    """Hand-encode std_msgs/String as CDR (little endian) independently of the recorder."""
    raw = text.encode() + b'\0'
    return b'\x00\x01\x00\x00' + struct.pack('<I', len(raw)) + raw


def _read_all(path):
    with AnyReader([Path(path)]) as reader:
        return [(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype), bytes(raw))
                for c, t, raw in reader.messages()]


# --- round trip ----------------------------------------------------------------------------

@pytest.mark.parametrize('seed, compression', [(1, 'zstd'), (2, 'lz4'), (2, None)])
def test_round_trip_every_type_through_rosbags(tmp_path, compression, seed):
    """Each compression once; the two seeds' messages once compressed, once not."""
    rng = np.random.default_rng(seed)
    path = tmp_path / 'trip.mcap'
    written = []
    qos = {'sensor_msgs/msg/Imu': QOS_SENSOR_DATA, 'std_msgs/msg/Bool': QOS_LATCHED}
    with McapBagWriter(path, compression=compression, chunk_size=2048,
                       storage_metadata={'seed': seed}) as bag:
        for msgtype in REQUIRED_TYPES:
            bag.add_topic('/t/' + msgtype.split('/')[-1].lower(), msgtype, qos.get(msgtype))
        for index in range(300):
            msgtype = REQUIRED_TYPES[int(rng.integers(len(REQUIRED_TYPES)))]
            topic = '/t/' + msgtype.split('/')[-1].lower()
            time_ns = T0 + index * 1_000_000 + int(rng.integers(0, 1000))
            message = _random_message(msgtype, rng, time_ns)
            bag.write(topic, message, time_ns, publish_time_ns=time_ns + 5)
            written.append((topic, msgtype, time_ns, message))
    assert not path.with_name('trip.mcap.part').exists()

    read = _read_all(path)
    assert len(read) == len(written)
    for (topic, msgtype, time_ns, message), (r_topic, r_type, r_time, r_msg, _) in zip(
            sorted(written, key=lambda w: w[2]), read):
        assert (r_topic, r_type, r_time) == (topic, msgtype, time_ns)
        _assert_same(r_msg, message, topic)

    with AnyReader([path]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        profiles = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    expected_counts = {}
    for topic, *_ in written:
        expected_counts[topic] = expected_counts.get(topic, 0) + 1
    assert {t: n for t, n in counts.items() if n} == expected_counts
    assert profiles['/t/imu'][0].reliability == QosReliability.BEST_EFFORT
    assert profiles['/t/bool'][0].durability == QosDurability.TRANSIENT_LOCAL
    assert profiles['/t/string'][0].reliability == QosReliability.RELIABLE

    with open(path, 'rb') as stream:
        mcap = make_reader(stream)
        header = mcap.get_header()
        summary = mcap.get_summary()
        metadata = {m.name: m.metadata for m in mcap.iter_metadata()}
    assert header.profile == 'ros2'
    assert 'qfa_ros' in header.library
    assert {s.name for s in summary.schemas.values()} == set(REQUIRED_TYPES)
    assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
    for schema in summary.schemas.values():
        assert schema.data.decode() == definition(schema.name)
    assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
    assert summary.statistics.message_count == len(written)
    assert len(summary.chunk_indexes) > 1
    assert all(index.message_index_offsets for index in summary.chunk_indexes)
    assert {index.compression for index in summary.chunk_indexes} == {compression or ''}
    for channel in summary.channels.values():
        schema_name = summary.schemas[channel.schema_id].name
        assert channel.metadata['topic_type_hash'] == type_hash(schema_name)
        qos_list = yaml.safe_load(channel.metadata['offered_qos_profiles'])
        assert set(qos_list[0]) == {
            'history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan',
            'liveliness', 'liveliness_lease_duration', 'avoid_ros_namespace_conventions'}

    bag_info = yaml.safe_load(metadata['rosbag2']['serialized_metadata'])
    times = [w[2] for w in written]
    assert bag_info['version'] == 9
    assert bag_info['storage_identifier'] == 'mcap'
    assert bag_info['message_count'] == len(written)
    assert bag_info['starting_time']['nanoseconds_since_epoch'] == min(times)
    assert bag_info['duration']['nanoseconds'] == max(times) - min(times)
    assert bag_info['custom_data'] == {'seed': str(seed)}
    assert bag_info['relative_file_paths'] == ['trip.mcap']
    topic_counts = {t['topic_metadata']['name']: t['message_count']
                    for t in bag_info['topics_with_message_count'] if t['message_count']}
    assert topic_counts == expected_counts


def test_serialized_path_matches_rclpy_serialization(tmp_path):
    serialization = pytest.importorskip('rclpy.serialization')
    msg_module = pytest.importorskip('sensor_msgs.msg')
    imu = msg_module.Imu()
    imu.header.stamp.sec, imu.header.stamp.nanosec = 17, 250
    imu.header.frame_id = 'imu_link'
    imu.linear_acceleration.x, imu.linear_acceleration.z = 0.125, -STANDARD_GRAVITY
    imu.linear_acceleration_covariance[4] = 3.5e-9
    path = tmp_path / 'rclpy.mcap'
    with McapBagWriter(path) as bag:
        bag.add_topic('/imu/data_raw', 'sensor_msgs/msg/Imu', QOS_SENSOR_DATA)
        bag.write_serialized('/imu/data_raw', serialization.serialize_message(imu), 17_000_000_250)
        bag.write('/imu/data_raw', {'header': {'stamp': stamp(18_000_000_000)},
                                    'linear_acceleration': {'x': 0.125}}, 18_000_000_000)
    (_, _, t1, first, raw1), (_, _, t2, second, raw2) = _read_all(path)
    assert t1 == 17_000_000_250 and first.header.frame_id == 'imu_link'
    assert first.linear_acceleration.z == -STANDARD_GRAVITY
    assert first.linear_acceleration_covariance[4] == 3.5e-9
    # And the dict path produces bytes rclpy itself decodes.
    decoded = serialization.deserialize_message(raw2, msg_module.Imu)
    assert decoded.linear_acceleration.x == 0.125 and decoded.header.stamp.sec == 18


def test_mappings_encode_to_the_bytes_rclpy_serializes():
    # Missing fields take the ROS defaults (Quaternion w = 1), numpy arrays and bytes work,
    # and a byte field given as rclpy spells it (b'\x02') or as an integer is one octet.
    serialization = pytest.importorskip('rclpy.serialization')
    sensor_msgs = pytest.importorskip('sensor_msgs.msg')
    diagnostic_msgs = pytest.importorskip('diagnostic_msgs.msg')
    imu = sensor_msgs.Imu()
    imu.header.frame_id = 'imu_link'
    imu.angular_velocity_covariance[0] = -1.0
    mapping = {'header': {'frame_id': 'imu_link'},
               'angular_velocity_covariance': np.array([-1.0] + [0.0] * 8)}
    # rclpy leaves its padding bytes unset (not always zero): compare the messages.
    data = encode_message(mapping, 'sensor_msgs/msg/Imu')
    assert serialization.deserialize_message(data, sensor_msgs.Imu) == imu
    assert len(data) == len(serialization.serialize_message(imu))
    status = diagnostic_msgs.DiagnosticStatus(level=b'\x02', name='qfa', message='warm',
                                              hardware_id='unit')
    status.values = [diagnostic_msgs.KeyValue(key='t', value='25')]
    array = diagnostic_msgs.DiagnosticArray(status=[status])
    for level in (b'\x02', 2):
        data = encode_message({'status': [{'level': level, 'name': 'qfa', 'message': 'warm',
                                           'hardware_id': 'unit',
                                           'values': [{'key': 't', 'value': '25'}]}]},
                              'diagnostic_msgs/msg/DiagnosticArray')
        assert serialization.deserialize_message(data, diagnostic_msgs.DiagnosticArray) == array
    with pytest.raises(ValueError, match='exactly 9 elements, got 3'):
        encode_message({'linear_acceleration_covariance': [1.0, 2.0, 3.0]},
                       'sensor_msgs/msg/Imu')


def without_comments(definition):
    """Return a ros2msg definition without comments and blank lines: the fields it defines."""
    lines = (line.split('#')[0].split() for line in definition.splitlines())
    return '\n'.join(' '.join(words) for words in lines if words)


def test_embedded_definitions_are_the_installed_distributions_fields():
    """
    The recorder embeds Kilted's text under every distribution (qfa_ros.ros.distro).

    Under Kilted it is the installed text exactly; under Jazzy, whose builtin_interfaces/Time
    and Duration carry longer comments, the same fields, constants and type hashes.
    """
    share = Path(sys.prefix) / 'share'
    if not (share / 'sensor_msgs' / 'msg' / 'Imu.msg').exists():
        pytest.skip('ROS interface files are not installed in this environment')
    field_type = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
    primitives = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                  'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string'}

    def full_text(root):
        seen = set()

        def expand(name):
            package, type_name = name.split('/')[0], name.split('/')[-1]
            text = (share / package / 'msg' / f'{type_name}.msg').read_text()
            dependencies = sorted({t if '/' in t else f'{package}/{t}'
                                   for t in field_type.findall(text) if t not in primitives})
            for dependency in dependencies:
                if dependency not in seen:
                    seen.add(dependency)
                    text += '\n' + '=' * 80 + f'\nMSG: {dependency}\n' + expand(dependency)
            return text
        return expand(root)

    assert set(REQUIRED_TYPES) <= set(RECORDED_TYPES)
    exact = ros_distribution() == 'kilted'
    for msgtype in RECORDED_TYPES:
        installed = full_text(msgtype)
        embedded = definition(msgtype)
        assert without_comments(embedded) == without_comments(installed), msgtype
        assert embedded == installed or not exact, msgtype
        package, _, type_name = msgtype.split('/')
        hashes = json.loads((share / package / 'msg' / f'{type_name}.json').read_text())
        assert {h['type_name']: h['hash_string'] for h in hashes['type_hashes']}[msgtype] \
            == type_hash(msgtype)


@pytest.mark.parametrize('store', [Stores.ROS2_JAZZY, Stores.ROS2_KILTED])
def test_readers_of_either_distribution_take_the_embedded_definitions(store):
    """The rosbags type stores of Jazzy and Kilted: same fields, same RIHS01 hash as embedded."""
    distribution = get_typestore(store)
    for msgtype in RECORDED_TYPES:
        embedded = get_typestore(Stores.EMPTY)
        embedded.register(get_types_from_msg(definition(msgtype), msgtype))
        for name in embedded.fielddefs:
            assert embedded.fielddefs[name] == distribution.fielddefs[name], (store, name)
        assert embedded.hash_rihs01(msgtype) == distribution.hash_rihs01(msgtype) \
            == type_hash(msgtype), (store, msgtype)


# --- durability ----------------------------------------------------------------------------

CRASH_SCRIPT = textwrap.dedent("""
    import os, sys
    from qfa_ros.bag.writer import McapBagWriter
    path, count = sys.argv[1], int(sys.argv[2])
    bag = McapBagWriter(path, chunk_size=1024, compression='zstd')
    bag.add_topic('/count', 'std_msgs/msg/String')
    for index in range(count):
        bag.write('/count', {'data': f'message {index:06d} ' + 'x' * 40}, 1000 + index)
    os._exit(3)  # die without finish(): no summary, no rename
""")


@pytest.fixture(scope='module')
def crashed(tmp_path_factory):
    """Return a directory: a finished bag, then a .part of a process that died mid-file.

    One crash for the cuts below (each works on a copy): ``{'directory', 'earlier_digest'}``.
    """
    directory = tmp_path_factory.mktemp('crashed')
    earlier = directory / 'earlier.mcap'
    with McapBagWriter(earlier) as bag:
        bag.add_topic('/count', 'std_msgs/msg/String')
        bag.write('/count', {'data': 'before the crash'}, 1)
    earlier_digest = hashlib.sha256(earlier.read_bytes()).hexdigest()
    result = subprocess.run([sys.executable, '-c', CRASH_SCRIPT,
                             str(directory / 'crashed.mcap'), '500'], cwd=REPO, timeout=60)
    assert result.returncode == 3
    return {'directory': directory, 'earlier_digest': earlier_digest}


@pytest.mark.parametrize('cut_bytes', [0, 1, 200])
def test_crash_leaves_part_readable_up_to_last_chunk(tmp_path, crashed, cut_bytes):
    earlier = crashed['directory'] / 'earlier.mcap'
    path = crashed['directory'] / 'crashed.mcap'
    source = crashed['directory'] / 'crashed.mcap.part'
    assert source.exists() and not path.exists()
    part = tmp_path / source.name
    data = source.read_bytes()
    # a write torn inside the last chunk
    part.write_bytes(data[:len(data) - cut_bytes])

    # The plain mcap streaming reader, stopping at the first bad record.
    recovered = [message.data for _, message in part_messages(part)]
    assert 50 < len(recovered) < 500  # the chunk in progress is lost, complete ones are not
    assert recovered == [_string_cdr(f'message {i:06d} ' + 'x' * 40)
                         for i in range(len(recovered))]
    assert hashlib.sha256(earlier.read_bytes()).hexdigest() == crashed['earlier_digest']
    assert [m[3].data for m in _read_all(earlier)] == ['before the crash']
    with pytest.raises(FileExistsError):
        McapBagWriter(path)  # the stale .part is kept for recovery, not overwritten


KILL_SCRIPT = textwrap.dedent("""
    import hashlib, os, sys, time
    from qfa_ros.bag.trace_writer import TraceWriter
    directory = sys.argv[1]
    with TraceWriter(os.path.join(directory, 'earlier.mcap'), chunk_size=512) as earlier:
        earlier.write_settings({'run': 'earlier'}, 1)
        earlier.write_table('sweep/points', {'row': range(50), 'value': range(50)},
                            range(10, 60))
        earlier.write_result({'done': True}, 100)
    digest = hashlib.sha256(open(earlier.path, 'rb').read()).hexdigest()
    # One write a line: with PYTHONUNBUFFERED print writes its pieces one by one, and a
    # kill between them left a line cut short.
    os.write(1, f'earlier {digest}\\n'.encode())
    trace = TraceWriter(os.path.join(directory, 'killed.mcap'), chunk_size=2048)
    trace.write_settings({'run': 'killed'}, 1)
    on_disk = trace.bag.bytes_written
    deadline = time.monotonic() + 60
    row = 0
    while time.monotonic() < deadline:
        trace.write_table('sweep/points', {'row': [row], 'value': [0.25 * row]}, 1000 + row)
        row += 1
        if trace.bag.bytes_written != on_disk:  # a chunk went to the file
            on_disk = trace.bag.bytes_written
            os.write(1, f'flushed {row}\\n'.encode())
    os._exit(5)  # never reached when the parent kills in time
""")


def test_sigkill_during_trace_keeps_earlier_files_and_complete_chunks(tmp_path):
    process = subprocess.Popen([sys.executable, '-c', KILL_SCRIPT, str(tmp_path)], cwd=REPO,
                               stdout=subprocess.PIPE, text=True)
    try:
        tag, earlier_digest = process.stdout.readline().split()
        assert tag == 'earlier'
        flushed = [int(process.stdout.readline().split()[1]) for _ in range(6)]
        os.kill(process.pid, signal.SIGKILL)  # mid-run, while rows are being written
        flushed += [int(line.split()[1]) for line in process.stdout.read().splitlines()]
    finally:
        process.kill()
        process.wait(timeout=30)
    assert process.returncode == -signal.SIGKILL

    earlier = tmp_path / 'earlier.mcap'
    assert hashlib.sha256(earlier.read_bytes()).hexdigest() == earlier_digest
    rows = [m[3].data.tolist() for m in _read_all(earlier) if m[0].endswith('/points')]
    assert rows == [[float(i), float(i)] for i in range(50)]

    part = tmp_path / 'killed.mcap.part'
    assert part.exists() and not (tmp_path / 'killed.mcap').exists()
    with open(part, 'rb') as stream:
        assert stream.read(8) == b'\x89MCAP0\r\n'
    # Read with the plain mcap streaming reader and decode with mcap-ros2-support.
    decoder = DecoderFactory()
    schemas, channels, recovered = {}, {}, []
    with open(part, 'rb') as stream:
        try:
            for record in StreamReader(stream, validate_crcs=True).records:
                kind = type(record).__name__
                if kind == 'Schema':
                    schemas[record.id] = record
                elif kind == 'Channel':
                    channels[record.id] = record
                elif kind == 'Message':
                    channel = channels[record.channel_id]
                    decode = decoder.decoder_for('cdr', schemas[channel.schema_id])
                    recovered.append((channel.topic, record.log_time, decode(record.data)))
        except Exception:
            pass  # the record cut by the kill, if any
    assert recovered[0][0] == '/qfa/trace/settings'
    points = [(t, list(m.data)) for topic, t, m in recovered if topic.endswith('/points')]
    # Every row reported on disk before the kill is recovered, in order and intact; at
    # most the one chunk that was flushed between the last report and the kill is extra.
    spacing = max(np.diff([0, *flushed]))
    assert flushed[-1] <= len(points) <= flushed[-1] + spacing
    assert points == [(1000 + i, [float(i), 0.25 * i]) for i in range(len(points))]
    with pytest.raises(FileExistsError):
        TraceWriter(tmp_path / 'killed.mcap')  # the .part stays for recovery


FULL_DISK_SCRIPT = textwrap.dedent("""
    import resource, signal, sys
    from qfa_ros.bag.writer import McapBagWriter
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write then fails with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (16384, 16384))
    bag = McapBagWriter(sys.argv[1], compression=None, chunk_size=1000)
    bag.add_topic('/s', 'std_msgs/msg/String')
    try:
        for index in range(10000):
            bag.write('/s', {'data': 'y' * 100}, index)
    except OSError as error:
        print('write', type(error).__name__, error.errno)
    try:
        bag.finish()
    except OSError as error:
        print('finish', type(error).__name__, error.errno)
""")


def _earlier_trace(directory):
    """Write a finished trace; return its path and digest."""
    with TraceWriter(directory / 'earlier.mcap') as trace:
        trace.write_settings({'run': 'earlier'}, 1)
        trace.write_table('sweep/points', {'value': [1.0, 2.0, 3.0]}, [2, 3, 4])
    return trace.path, hashlib.sha256(trace.path.read_bytes()).hexdigest()


def test_full_disk_raises_oserror_and_publishes_nothing(tmp_path):
    earlier, digest = _earlier_trace(tmp_path)
    path = tmp_path / 'full.mcap'
    result = subprocess.run([sys.executable, '-c', FULL_DISK_SCRIPT, str(path)], cwd=REPO,
                            capture_output=True, text=True, timeout=60, check=True)
    lines = result.stdout.split('\n')
    assert lines[0].startswith('write RecorderError 27'), result.stdout  # EFBIG
    assert lines[1].startswith('finish RecorderError'), result.stdout
    assert not path.exists()
    assert (tmp_path / 'full.mcap.part').stat().st_size <= 16384
    assert hashlib.sha256(earlier.read_bytes()).hexdigest() == digest
    assert sorted(p.name for p in tmp_path.iterdir()) == ['earlier.mcap', 'full.mcap.part']


@pytest.mark.parametrize('stage, fail_after', [
    ('write', 0), ('write', 200), ('write', 3000), ('finish', None)])
def test_no_space_left_raises_oserror_and_keeps_earlier_files(tmp_path, monkeypatch, stage,
                                                              fail_after):
    """ENOSPC from the file system: an OSError naming the file, nothing published."""
    earlier, digest = _earlier_trace(tmp_path)
    trace = TraceWriter(tmp_path / 'full.mcap', chunk_size=1024)
    target = trace.bag._file._fd
    budget = {'left': fail_after if stage == 'write' else 10**9}
    real_write = os.write

    def write(fd, data):
        if fd == target:
            if budget['left'] < len(data):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            budget['left'] -= len(data)
        return real_write(fd, data)

    monkeypatch.setattr(os, 'write', write)
    rows = []
    with pytest.raises(OSError) as raised:
        trace.write_settings({'run': 'full'}, 1)
        for row in range(1000):
            trace.write_table('sweep/points', {'value': [float(row)]}, 10 + row)
            rows.append(row)
        budget['left'] = 0  # the disk fills up just before the summary
        trace.finish()
    assert (len(rows) == 1000) == (stage == 'finish')
    assert raised.value.errno == errno.ENOSPC
    assert isinstance(raised.value, RecorderError)
    assert 'full.mcap.part' in str(raised.value)
    with pytest.raises(RecorderError, match='failed earlier'):
        trace.finish()
    monkeypatch.undo()
    assert not (tmp_path / 'full.mcap').exists()
    assert hashlib.sha256(earlier.read_bytes()).hexdigest() == digest
    assert [m[3].data.tolist() for m in _read_all(earlier) if m[0].endswith('points')] == [
        [1.0], [2.0], [3.0]]
    # The next trace in the same directory works once there is space again.
    with TraceWriter(tmp_path / 'next.mcap') as trace:
        trace.write_settings({'run': 'next'}, 1)
    assert [m[0] for m in _read_all(tmp_path / 'next.mcap')] == ['/qfa/trace/settings']


def _creation_refused(directory):
    try:
        os.close(os.open(directory / 'qfa_probe.mcap.part', os.O_WRONLY | os.O_CREAT | os.O_EXCL))
    except OSError:
        return True
    os.unlink(directory / 'qfa_probe.mcap.part')
    return False


def _unwritable(tmp_path, kind):
    if kind == 'missing':
        return tmp_path / 'no' / 'such' / 'dir'
    if kind == 'file':
        (tmp_path / 'plain').write_text('not a directory')
        return tmp_path / 'plain'
    if os.geteuid() == 0:
        # Permission bits do not stop root; sysfs refuses new files even to root.
        if os.access('/sys', os.W_OK) and not _creation_refused(Path('/sys')):
            pytest.skip('no directory here refuses root')
        return Path('/sys')
    locked = tmp_path / 'locked'
    locked.mkdir(mode=0o500)
    return locked


@pytest.mark.parametrize('kind', ['missing', 'file', 'readonly'])
def test_unwritable_directory_raises_at_creation(tmp_path, kind):
    directory = _unwritable(tmp_path, kind)
    with pytest.raises(OSError, match='cannot create MCAP file'):
        McapBagWriter(directory / 'x.mcap')
    with pytest.raises(OSError, match='cannot create MCAP file'):
        TraceWriter(directory / 'x.mcap')
    with pytest.raises(OSError, match='recording directory'):
        FlightRecorder(directory)


def test_flight_recorder_never_reuses_a_bag_directory(tmp_path):
    session = 1_767_225_600_000_000_000
    bags = []
    for _ in range(2):
        with FlightRecorder(tmp_path, 'same', session_time_ns=session) as flight:
            flight.record('/c', 'std_msgs/msg/String', _string_cdr('x'), T0)
        bags.append(flight.bag_directory.name)
    assert bags == ['same_2026_01_01-00_00_00', 'same_2026_01_01-00_00_00_2']
    with FlightRecorder(tmp_path, 'empty') as flight:
        pass
    assert flight.bag_directory is None
    assert not list(tmp_path.glob('empty*'))


def test_existing_file_is_never_replaced(tmp_path):
    path = tmp_path / 'keep.mcap'
    path.write_bytes(b'precious')
    with pytest.raises(FileExistsError):
        McapBagWriter(path)
    # A file appearing while recording is not clobbered either.
    other = tmp_path / 'race.mcap'
    bag = McapBagWriter(other)
    bag.add_topic('/b', 'std_msgs/msg/Bool')
    bag.write('/b', {'data': True}, 5)
    other.write_bytes(b'also precious')
    with pytest.raises(RecorderError):
        bag.finish()
    assert path.read_bytes() == b'precious' and other.read_bytes() == b'also precious'


def test_finish_is_idempotent_and_errors_abort(tmp_path):
    path = tmp_path / 'once.mcap'
    bag = McapBagWriter(path)
    bag.add_topic('/b', 'std_msgs/msg/Bool')
    bag.write('/b', {'data': True}, 5)
    assert bag.finish() == path
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert bag.finish() == path and bag.finished
    bag.abort()
    assert hashlib.sha256(path.read_bytes()).hexdigest() == digest
    with pytest.raises(RecorderError, match='already finished'):
        bag.write('/b', {'data': False}, 6)

    aborted = tmp_path / 'aborted.mcap'
    with pytest.raises(ZeroDivisionError):
        with McapBagWriter(aborted) as bag:
            bag.add_topic('/b', 'std_msgs/msg/Bool')
            raise ZeroDivisionError
    assert not aborted.exists() and aborted.with_name('aborted.mcap.part').exists()
    with pytest.raises(RecorderError, match='aborted'):
        bag.finish()


@pytest.mark.parametrize('call, error, match', [
    (lambda b: b.write('/b', {'data': True}, 1.5), TypeError, 'integer nanoseconds'),
    (lambda b: b.write('/b', {'data': True}, -1), ValueError, r'\[0, 2\*\*64\)'),
    (lambda b: b.write('/b', {'dat': True}, 1), KeyError, "no field 'dat'"),
    (lambda b: b.write('/nope', {'data': True}, 1), KeyError, 'not registered'),
    (lambda b: b.add_topic('/b', 'std_msgs/msg/String'), ValueError, 'already carries'),
    (lambda b: b.add_topic('/x', 'nav_msgs/msg/Path'), ValueError, 'no message definition'),
    (lambda b: b.add_topic('bad topic', 'std_msgs/msg/Bool'), ValueError, 'invalid topic'),
    (lambda b: b.write_serialized('/b', b'\x01\x02', 1), ValueError, 'not CDR'),
])
def test_bad_input_is_refused(tmp_path, call, error, match):
    with McapBagWriter(tmp_path / 'bad.mcap') as bag:
        bag.add_topic('/b', 'std_msgs/msg/Bool')
        with pytest.raises(error, match=match):
            call(bag)
        bag.write('/b', {'data': True}, 2)  # the writer is still usable afterwards
    assert [m[3].data for m in _read_all(tmp_path / 'bad.mcap')] == [True]


# --- flight recorder -----------------------------------------------------------------------

@pytest.mark.parametrize('seed, limits, count', [
    # 6000 bytes: 15 files, two split where a topic's registration fills the file (seed 4
    # needs 150 messages for that: each split rewrites metadata.yaml, the cost grows with
    # the square of the file count).
    (5, {'max_bytes': 6000}, 60),
    (3, {'max_duration_ns': 250_000_000}, 400),
    (4, {'max_duration_ns': 250_000_000}, 400),
    (3, {'max_bytes': 20000, 'max_duration_ns': 400_000_000}, 400),
    (4, {'max_bytes': 20000, 'max_duration_ns': 400_000_000}, 400),
])
def test_flight_recorder_splits_without_losing_messages(tmp_path, limits, seed, count):
    rng = np.random.default_rng(seed)
    written = []
    session = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z
    with FlightRecorder(tmp_path, 'flight', compression='lz4', session_time_ns=session,
                        qos={'/a': QOS_SENSOR_DATA}, **limits) as flight:
        time_ns = T0
        for _ in range(count):
            time_ns += int(rng.integers(1, 6_000_000))
            topic = '/a' if rng.random() < 0.7 else '/b'
            data = _string_cdr('z' * int(rng.integers(0, 120)))
            flight.record(topic, 'std_msgs/msg/String', data, time_ns)
            written.append((topic, time_ns, data))
    files = flight.files
    assert flight.close() == files  # idempotent
    assert len(files) >= 3
    bag = tmp_path / 'flight_2026_01_01-00_00_00'
    assert flight.bag_directory == bag
    assert [f.name for f in files] == [f'{bag.name}_{i}.mcap' for i in range(len(files))]
    assert sorted(p.name for p in bag.iterdir()) == sorted(
        [f.name for f in files] + ['metadata.yaml'])
    # A rosbag2 bag directory: rosbags' own rosbag2 reader opens it, counts agree.
    with Rosbag2Reader(bag) as reader:
        assert reader.message_count == len(written)
        assert {c.topic: c.msgcount for c in reader.connections} == {
            topic: sum(w[0] == topic for w in written) for topic in ('/a', '/b')}
        assert reader.start_time == written[0][1]
        assert reader.end_time == written[-1][1] + 1
        assert [(c.topic, t, bytes(d)) for c, t, d in reader.messages()] == written
        qos, = next(c for c in reader.connections if c.topic == '/a').ext.offered_qos_profiles
        assert qos.reliability.name.lower() == 'best_effort'

    recovered = []
    for path in files:
        messages = _read_all(path)
        assert messages, path
        times = [m[2] for m in messages]
        if 'max_duration_ns' in limits:
            assert times[-1] - times[0] < limits['max_duration_ns']
        if 'max_bytes' in limits:
            assert path.stat().st_size <= limits['max_bytes']
        recovered.extend((m[0], m[2], m[4]) for m in messages)
    assert recovered == written


def test_flight_recorder_split_finishes_the_file_now_and_goes_on_in_the_next(tmp_path):
    with FlightRecorder(tmp_path, 'flight') as flight:
        assert flight.split() is None  # no file open: nothing to finish, none started
        flight.record('/a', 'std_msgs/msg/String', _string_cdr('first'), T0)
        first = flight.split()
        # Finished and listed while the recording goes on: readable as it is.
        assert first == flight.files[0] and first.exists() and not list(
            tmp_path.glob('**/*.part'))
        with Rosbag2Reader(flight.bag_directory) as reader:
            assert [bytes(d) for _, _, d in reader.messages()] == [_string_cdr('first')]
        assert flight.split() is None
        flight.record('/a', 'std_msgs/msg/String', _string_cdr('second'), T0 + 5)
    assert [p.name for p in flight.files] == [f'{flight.bag_directory.name}_{i}.mcap'
                                              for i in (0, 1)]
    assert flight.split() is None  # closed
    with Rosbag2Reader(flight.bag_directory) as reader:
        assert [bytes(d) for _, _, d in reader.messages()] == [
            _string_cdr('first'), _string_cdr('second')]


@pytest.mark.parametrize('limits, count', [
    ({'max_bytes': 6000}, 150),  # 25 files, 12 runs split between two files
    ({'max_duration_ns': 250_000_000}, 500),
    ({'max_bytes': 20000, 'max_duration_ns': 400_000_000}, 500),
])
def test_flight_recorder_record_many_splits_where_record_does(tmp_path, limits, count):
    rng = np.random.default_rng(5)
    messages = []
    time_ns = T0
    for _ in range(count):
        time_ns += int(rng.integers(1, 6_000_000))
        topic = '/a' if rng.random() < 0.8 else '/b'
        messages.append((topic, _string_cdr('z' * int(rng.integers(0, 120))), time_ns))
    # The same messages one by one, and as runs of one topic of random length.
    runs, start = [], 0
    while start < len(messages):
        end = start + 1
        while (end < len(messages) and end - start < rng.integers(1, 40)
               and messages[end][0] == messages[start][0]):
            end += 1
        runs.append(messages[start:end])
        start = end
    assert max(len(run) for run in runs) > 10
    (tmp_path / 'one').mkdir()
    (tmp_path / 'many').mkdir()
    with FlightRecorder(tmp_path / 'one', bag_name='flight', **limits) as single:
        for topic, data, time_ns in messages:
            single.record(topic, 'std_msgs/msg/String', data, time_ns)
    with FlightRecorder(tmp_path / 'many', bag_name='flight', **limits) as batched:
        for run in runs:
            batched.record_many(run[0][0], 'std_msgs/msg/String', [m[1] for m in run],
                                [m[2] for m in run])
    assert len(single.files) >= 3
    # The same files, split at the same messages: the same bytes.
    assert [path.name for path in batched.files] == [path.name for path in single.files]
    assert all(many.read_bytes() == one.read_bytes()
               for one, many in zip(single.files, batched.files))
    with Rosbag2Reader(batched.bag_directory) as reader:
        assert [(c.topic, t, bytes(d)) for c, t, d in reader.messages()] == [
            (topic, time_ns, data) for topic, data, time_ns in messages]
    if 'max_bytes' in limits:
        assert max(path.stat().st_size for path in batched.files) <= limits['max_bytes']


def test_flight_recorder_record_many_writes_nothing_of_a_bad_batch(tmp_path):
    good = [_string_cdr('a'), _string_cdr('b')]
    with FlightRecorder(tmp_path) as flight:
        flight.record_many('/c', 'std_msgs/msg/String', good, [T0, T0 + 1])
        with pytest.raises(ValueError, match='not CDR'):
            flight.record_many('/c', 'std_msgs/msg/String', [_string_cdr('c'), b'\x01xx'],
                               [T0 + 2, T0 + 3])
        with pytest.raises(ValueError, match='2 messages but 1 times'):
            flight.record_many('/c', 'std_msgs/msg/String', good, [T0 + 4])
        flight.record_many('/c', 'std_msgs/msg/String', [_string_cdr('d')], [T0 + 5])
    file, = flight.files
    assert [(m[2], m[3].data) for m in _read_all(file)] == [(T0, 'a'), (T0 + 1, 'b'),
                                                             (T0 + 5, 'd')]


def test_flight_recorder_rejects_late_writes_and_keeps_sequence(tmp_path):
    with FlightRecorder(tmp_path, max_duration_ns=10) as flight:
        for index in range(5):
            flight.record('/c', 'std_msgs/msg/String', _string_cdr(str(index)), 100 + 10 * index)
    assert len(flight.files) == 5
    with pytest.raises(RecorderError, match='closed'):
        flight.record('/c', 'std_msgs/msg/String', _string_cdr('late'), 1000)


def test_flight_recorder_flush_puts_every_message_so_far_in_complete_chunks(tmp_path):
    """What a kill right after ``flush()`` leaves: every message recorded before it."""
    with FlightRecorder(tmp_path) as flight:
        assert flight.flush() == []  # nothing recorded: no file, nothing to sync
        sent = []
        for round_ in range(3):
            for index in range(40):  # far less than a chunk (768 KiB)
                text = f'round {round_} message {index}'
                flight.record('/c', 'std_msgs/msg/String', _string_cdr(text), 10**9 + len(sent))
                sent.append(_string_cdr(text))
            part = flight.current_path.with_name(flight.current_path.name + '.part')
            paths = flight.flush()
            # The .part as a kill now would leave it holds every message, in complete chunks.
            assert [m.data for _, m in part_messages(part)] == sent
            # The part to fsync; the bag directory once, after the file appeared in it.
            assert paths == [part] + ([flight.bag_directory] if round_ == 0 else [])
        assert flight.flush() == []  # nothing new since: nothing to sync
    assert [m[3].data for m in _read_all(flight.files[0])] == [
        f'round {r} message {i}' for r in range(3) for i in range(40)]


# --- traces --------------------------------------------------------------------------------

def test_trace_writer_is_self_describing(tmp_path):
    rng = np.random.default_rng(7)
    path = tmp_path / 'trace.mcap'
    steps = np.arange(6)
    counts = rng.normal(1000, 3, size=6)
    row_times = T0 + steps * 50_000_000
    settings = {'schedule': 'forward', 'delta_n0': 64, 'steps': 5, 'seed': np.int64(11),
                'axes': ['x', 'y'], 'model': {'k0': 6.3e-6, 'enabled': True}, 'note': None}
    result = {'delta_k_pre_ppm': 181.25, 'slope': np.float64(1.0 / 3.0), 'nan': float('nan')}
    with TraceWriter(path, source='qfa_node') as trace:
        trace.write_settings(settings, T0)
        assert trace.write_table('forward/points', {'step': steps, 'n_out': counts},
                                 row_times) == 6
        trace.write_table('forward/fit', {'slope': [0.5], 'intercept': [2.0]}, T0 + 10**9)
        trace.write_imu({'header': {'stamp': stamp(T0)}, 'linear_acceleration': {'z': 9.8}},
                        T0)
        trace.write_temperature({'temperature': 25.5}, T0)
        trace.write_result(result, T0 + 10**9, level=1, summary='181 ppm')
        with pytest.raises(ValueError, match='reserved'):
            trace.write_table('settings', {'a': [1.0]}, T0)
        with pytest.raises(ValueError, match='2\\*\\*53'):
            trace.write_table('times', {'t_ns': row_times}, T0)
        with pytest.raises(ValueError, match='differ in length'):
            trace.write_table('bad', {'a': [1.0], 'b': [1.0, 2.0]}, T0)
        with pytest.raises(ValueError, match='was written with columns'):
            trace.write_table('forward/points', {'n_out': counts}, T0)
    messages = _read_all(path)
    by_topic = {}
    for topic, msgtype, time_ns, message, _ in messages:
        by_topic.setdefault(topic, []).append((msgtype, time_ns, message))

    assert set(by_topic) == {'/qfa/trace/settings', '/qfa/trace/forward/points',
                             '/qfa/trace/forward/fit', '/qfa/trace/imu/data_raw',
                             '/qfa/trace/imu/temperature', '/qfa/trace/result'}
    (msgtype, _, settings_msg), = by_topic['/qfa/trace/settings']
    assert msgtype == 'diagnostic_msgs/msg/DiagnosticArray'
    status = settings_msg.status[0]
    assert status.hardware_id == 'qfa_node' and status.name == 'qfa/trace/settings'
    assert key_values_to_dict(status.values) == {
        'schedule': 'forward', 'delta_n0': 64, 'steps': 5, 'seed': 11, 'axes': ['x', 'y'],
        'model.k0': 6.3e-6, 'model.enabled': True, 'note': None}
    (_, _, result_msg), = by_topic['/qfa/trace/result']
    decoded = key_values_to_dict(result_msg.status[0].values)
    assert decoded['slope'] == 1.0 / 3.0 and np.isnan(decoded['nan'])
    assert result_msg.status[0].level == 1 and result_msg.status[0].message == '181 ppm'

    points = by_topic['/qfa/trace/forward/points']
    assert [t for _, t, _ in points] == row_times.tolist()
    assert [d.label for d in points[0][2].layout.dim] == ['step', 'n_out']
    np.testing.assert_array_equal([m.data for _, _, m in points], np.column_stack([steps, counts]))
    assert by_topic['/qfa/trace/imu/data_raw'][0][2].linear_acceleration.z == 9.8

    with AnyReader([path]) as reader:
        latched = {c.topic for c in reader.connections
                   if c.ext.offered_qos_profiles[0].durability == QosDurability.TRANSIENT_LOCAL}
    assert latched == {'/qfa/trace/settings', '/qfa/trace/result'}


def test_qos_profile_yaml_round_trip():
    profile = QosProfile(history='keep_all', depth=0, deadline_ns=1_500_000_000)
    parsed = yaml.safe_load(offered_qos_yaml([profile, QOS_SENSOR_DATA]))
    assert parsed[0]['deadline'] == {'sec': 1, 'nsec': 500_000_000}
    assert parsed[0]['lifespan'] == {'sec': 9223372036, 'nsec': 854775807}
    assert parsed[1]['reliability'] == 'best_effort' and parsed[1]['depth'] == 5


# --- estimation traces through rosbags -----------------------------------------------------

@pytest.fixture(scope='module')
def schedule_runs():
    """Run every schedule kind once (short settings); return ``{kind: [results]}``."""
    forward = ForwardSettings(points=5, average_s=0.1)
    feedback = FeedbackSettings(average_s=0.5)
    triad = QfaTriad(TriadConfig(), rng=1)
    state = CalibrationState()
    runs = {'reference': list(run_schedule(
        triad, capture_reference(triad, state, forward, feedback)))}
    for axis in range(len(AXES)):
        triad.drift.set_step(axis, 'k_amp', -150e-6)
        triad.drift.set_step(axis, 'k_vi', 80e-6)
    runs['forward'] = [run_schedule(triad, forward_schedule(triad, state, forward))]
    runs['feedback'] = [run_schedule(triad, feedback_schedule(triad, state, feedback))]
    runs['self_calibrate'] = list(run_schedule(
        triad, self_calibrate(triad, state, forward, feedback)))
    # a 5 s body time constant keeps the chamber program's soaks short: 210 one-second
    # blocks, 30 points (30 s and 120 s: 504 blocks, twice the time)
    hot = QfaTriad(TriadConfig(thermal=ThermalConfig(ambient_profile='constant',
                                                     sensor_tau_s=5.0)), rng=3)
    runs['temperature'] = [run_schedule(hot, temperature_schedule(
        hot, CalibrationState(), TemperatureSettings(period_s=100.0, bins=20)))]
    return runs


def _flatten(mapping, prefix=''):
    """Flatten nested mappings with '.' like the trace does, sequences as lists."""
    flat = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f'{prefix}{key}.'))
        else:
            if isinstance(value, (tuple, np.ndarray)):
                value = list(np.asarray(value).tolist())
            elif isinstance(value, np.generic):
                value = value.item()
            flat[f'{prefix}{key}'] = value
    return flat


def _assert_same_values(actual, expected):
    assert actual.keys() == expected.keys()
    for key, value in expected.items():
        if isinstance(value, float) and np.isnan(value):
            assert np.isnan(actual[key]), key
        else:
            assert actual[key] == value, key  # exact: floats round-trip through JSON


@pytest.mark.parametrize('kind', ['reference', 'forward', 'feedback', 'self_calibrate',
                                  'temperature'])
def test_estimation_trace_round_trip_through_rosbags(tmp_path, schedule_runs, kind):
    results = schedule_runs[kind]
    context = {'node': 'test', 'seed': 1}
    path = write_estimation_trace(trace_path(tmp_path, kind, results[-1].end_ns), kind,
                                  results, source='qfa_test', context=context)
    assert path.name == f'qfa_{kind}_{results[-1].end_ns:019d}.mcap'
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no .part left

    by_topic = {}
    for topic, msgtype, time_ns, message, _ in _read_all(path):
        by_topic.setdefault(topic, []).append((msgtype, time_ns, message))
    expected_topics = {'/qfa/trace/settings', '/qfa/trace/result'}
    for r in results:
        expected_topics |= {f'/qfa/trace/{r.kind}/points', f'/qfa/trace/{r.kind}/residuals'}
        if getattr(r, 'blocks', None):
            expected_topics.add(f'/qfa/trace/{r.kind}/blocks')
    assert set(by_topic) == expected_topics

    (msgtype, time_ns, settings), = by_topic['/qfa/trace/settings']
    assert msgtype == 'diagnostic_msgs/msg/DiagnosticArray'
    assert time_ns == results[0].start_ns
    assert settings.status[0].hardware_id == 'qfa_test'
    _assert_same_values(key_values_to_dict(settings.status[0].values), _flatten(
        {'kind': kind, **{r.kind: r.settings for r in results}, **context}))

    (_, time_ns, result), = by_topic['/qfa/trace/result']
    assert time_ns == results[-1].end_ns
    assert result.status[0].message == '; '.join(r.summary() for r in results)
    _assert_same_values(key_values_to_dict(result.status[0].values),
                        _flatten({r.kind: r.to_mapping() for r in results}))

    for r in results:
        columns = [name for name in r.points if name != 'time_ns']
        points = by_topic[f'/qfa/trace/{r.kind}/points']
        residuals = by_topic[f'/qfa/trace/{r.kind}/residuals']
        assert len(points) == len(residuals) == len(r.points['time_ns'])
        assert [t for _, t, _ in points] == np.asarray(r.points['time_ns']).tolist()
        assert [t for _, t, _ in residuals] == np.asarray(r.points['time_ns']).tolist()
        assert [d.label for d in points[0][2].layout.dim] == columns
        assert [d.label for d in residuals[0][2].layout.dim] == list(AXES)
        np.testing.assert_array_equal(
            [m.data for _, _, m in points],
            np.column_stack([np.asarray(r.points[c], dtype=float) for c in columns]))
        np.testing.assert_array_equal([m.data for _, _, m in residuals], r.residuals)
        if getattr(r, 'blocks', None):
            blocks = by_topic[f'/qfa/trace/{r.kind}/blocks']
            assert [t for _, t, _ in blocks] == r.blocks['time_ns'].tolist()
            assert [d.label for d in blocks[0][2].layout.dim] == [
                'v_temp', 'temperature', *(f'zero_{axis}' for axis in AXES),
                *(f'force_{axis}' for axis in AXES)]
            np.testing.assert_array_equal(
                [m.data for _, _, m in blocks],
                np.column_stack([r.blocks['v_temp'], r.blocks['temperature'],
                                 r.blocks['zero'], r.blocks['force']]))

    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        info = yaml.safe_load(
            next(reader.iter_metadata()).metadata['serialized_metadata'])
    total = sum(len(messages) for messages in by_topic.values())
    assert summary.statistics.message_count == info['message_count'] == total
    assert {t['topic_metadata']['name']: t['message_count']
            for t in info['topics_with_message_count']} == {
        topic: len(messages) for topic, messages in by_topic.items()}


def test_temperature_trace_reproduces_the_fixed_point_compensator(tmp_path, schedule_runs):
    result, = schedule_runs['temperature']
    path = write_estimation_trace(tmp_path / 'temperature.mcap', 'temperature', [result])
    (_, _, _, message, _), = [m for m in _read_all(path) if m[0] == '/qfa/trace/result']
    values = key_values_to_dict(message.status[0].values)
    v = np.linspace(*result.calibrations[0].v_range, 257)
    for axis, calibration in zip(AXES, result.calibrations):
        rom = {key.split('.')[-1]: value for key, value in values.items()
               if key.startswith(f'temperature.rom.{axis}.')}
        fit = DoubleExpFit(values[f'temperature.fit.{axis}.alpha1'],
                           values[f'temperature.fit.{axis}.alpha2'],
                           values[f'temperature.fit.{axis}.beta1'],
                           values[f'temperature.fit.{axis}.beta2'], 0.0, 0.0, 0, True,
                           offset=values[f'temperature.fit.{axis}.offset'],
                           slope=values[f'temperature.fit.{axis}.slope'])
        rebuilt = DoubleExpCompensator(
            fit, m_bits=rom['m_bits'], n_bits=rom['n_bits'], guard_bits=rom['guard_bits'],
            v_range=rom['v_range'], output_frac_bits=rom['output_frac_bits'])
        assert {**rebuilt.rom(), 'v_range': list(rebuilt.v_range)} == rom
        compensator = calibration.compensator()
        np.testing.assert_array_equal(rebuilt.evaluate_fixed_q(rebuilt.quantize_v(v)),
                                      compensator.evaluate_fixed_q(compensator.quantize_v(v)))
