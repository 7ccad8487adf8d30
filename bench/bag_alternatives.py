"""The bag layer's hand-written pieces against the libraries that could replace them.

Run: ``nice -n 10 .venv/bin/python bench/bag_alternatives.py [--messages N] [--part-gib G]``
(``--part-gib 0`` skips the recovery rows). Prints Markdown; the docs cite
``bench/results/bag_alternatives.md`` (docs/architecture.md, "Hand-written code and the
libraries that cover it").

* **Imu encoding** (a 1 kHz stream; a ``qfa-sim`` hour writes 3.6 M of them):
  ``qfa_ros.bag.imu_cdr.ImuEncoder.encode`` (numpy over one template) against rosbags'
  ``Typestore.serialize_cdr`` of a message object built per sample, rclpy's
  ``serialize_message`` and mcap-ros2-support's ``Writer.write_message`` (encoding and
  MCAP writing of a mapping); checked to give the same message.
* **Imu decoding** (``qfa-report imu-yaml`` reads hours): ``imu_cdr.decode_imu`` against
  rosbags' ``deserialize_cdr`` and mcap-ros2-support's decoder.
* **Recording with crash safety** at full speed: ``FlightRecorder.record_many`` in runs of
  250 messages (0.25 s of the 1 kHz stream), each run followed by ``flush()`` (a chunk) and
  ``make_durable`` (``fdatasync``), as the node's recording thread does; the multiple of
  the 1 kHz stream it keeps up with. Beside it rosbags' rosbag2 ``Writer`` (MCAP storage)
  with the same bytes, which has no flush, no fsync and no ``.part``.
* **Recovery of a cut part** of ``--part-gib`` GiB (Imu at 1 kHz, a chunk every 250
  messages, cut after its last flush): ``recover_part`` in place against a rewrite through
  mcap's public ``StreamReader`` (CRCs checked) and ``Writer`` into a new file, what a
  library-only recovery would be (``mcap recover`` does the same); wall and CPU time.
"""

import argparse
import io
import os
from pathlib import Path
import shutil
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from qfa_ros.bag.flight_recorder import FlightRecorder  # noqa: E402
from qfa_ros.bag.imu_cdr import decode_imu, ImuEncoder  # noqa: E402
from qfa_ros.bag.msgdefs import definition, type_hash  # noqa: E402
from qfa_ros.bag.part_files import make_durable  # noqa: E402
from qfa_ros.bag.part_repair import recover_part  # noqa: E402
from qfa_ros.bag.writer import McapBagWriter  # noqa: E402
from qfa_ros.model.constants import STANDARD_GRAVITY  # noqa: E402

TOPIC = '/imu/data_raw'
IMU = 'sensor_msgs/msg/Imu'
START_NS = 1_767_225_600_000_000_000
PERIOD_NS = 1_000_000
RUN = 250
"""Messages per flush: 0.25 s of the 1 kHz stream, the node's chunk period."""
ACCEL_COV = [2.5e-7, 0, 0, 0, 2.5e-7, 0, 0, 0, 2.5e-7]
RATE_COV = [1e-8, 0, 0, 0, 1e-8, 0, 0, 0, 1e-8]
UNKNOWN = [-1.0] + [0.0] * 8


def stream(count, seed=0):
    """Return stamps [ns], specific force and rate of a noisy static 1 kHz stream."""
    rng = np.random.default_rng(seed)
    stamps = START_NS + PERIOD_NS * np.arange(count, dtype=np.int64)
    accel = np.array([0.0, 0.0, STANDARD_GRAVITY]) + rng.normal(0.0, 5e-4, size=(count, 3))
    rate = rng.normal(0.0, 1e-4, size=(count, 3))
    return stamps, accel, rate


def timed(function):
    """Return (result, wall s, CPU s) of ``function()``."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def imu_mapping(stamp_ns, accel, rate):
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return {'header': {'stamp': {'sec': sec, 'nanosec': nanosec}, 'frame_id': 'imu_link'},
            'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
            'orientation_covariance': UNKNOWN,
            'angular_velocity': dict(zip('xyz', rate)), 'angular_velocity_covariance': RATE_COV,
            'linear_acceleration': dict(zip('xyz', accel)),
            'linear_acceleration_covariance': ACCEL_COV}


def encoding_rows(count):
    """Return table rows: encoders of one Imu stream, µs per message, same message or not."""
    from rosbags.typesys import get_typestore, Stores

    stamps, accel, rate = stream(count)
    encoder = ImuEncoder('imu_link', ACCEL_COV, RATE_COV)
    ours, wall, _ = timed(lambda: encoder.encode(stamps, accel, rate))
    rows = [('`imu_cdr.ImuEncoder.encode` (batch)', wall, 'reference')]
    store = get_typestore(Stores.ROS2_KILTED)
    types = store.types
    accel_list, rate_list = accel.tolist(), rate.tolist()

    def rosbags_encode():
        header, time_ = types['std_msgs/msg/Header'], types['builtin_interfaces/msg/Time']
        vector, quaternion = types['geometry_msgs/msg/Vector3'], types[
            'geometry_msgs/msg/Quaternion']
        covariances = [np.array(c, dtype=float) for c in (UNKNOWN, RATE_COV, ACCEL_COV)]
        out = []
        for stamp_ns, a, w in zip(stamps.tolist(), accel_list, rate_list):
            sec, nanosec = divmod(stamp_ns, 1_000_000_000)
            message = types[IMU](header(time_(sec, nanosec), 'imu_link'),
                                 quaternion(0.0, 0.0, 0.0, 1.0), covariances[0], vector(*w),
                                 covariances[1], vector(*a), covariances[2])
            out.append(bytes(store.serialize_cdr(message, IMU)))
        return out

    theirs, wall, _ = timed(rosbags_encode)
    rows.append(('rosbags `Typestore.serialize_cdr` (a message object per sample)', wall,
                 'same bytes' if theirs == ours else 'DIFFERENT'))
    try:
        from rclpy.serialization import deserialize_message, serialize_message
        from sensor_msgs.msg import Imu
    except ImportError:
        Imu = None
    if Imu is not None:
        def rclpy_encode():
            out = []
            for stamp_ns, a, w in zip(stamps.tolist(), accel_list, rate_list):
                message = Imu()
                message.header.stamp.sec, message.header.stamp.nanosec = divmod(
                    stamp_ns, 1_000_000_000)
                message.header.frame_id = 'imu_link'
                message.orientation_covariance = UNKNOWN
                message.angular_velocity_covariance = RATE_COV
                message.linear_acceleration_covariance = ACCEL_COV
                message.angular_velocity.x, message.angular_velocity.y, \
                    message.angular_velocity.z = w
                message.linear_acceleration.x, message.linear_acceleration.y, \
                    message.linear_acceleration.z = a
                out.append(serialize_message(message))
            return out

        theirs, wall, _ = timed(rclpy_encode)
        # rclpy leaves its padding bytes unset: compare the decoded messages.
        same = all(deserialize_message(a, Imu) == deserialize_message(b, Imu)
                   for a, b in zip(theirs[:1000], ours[:1000]))
        rows.append(('rclpy `serialize_message` (a message object per sample)', wall,
                     'same message' if same else 'DIFFERENT'))
    from mcap_ros2.writer import Writer as Ros2Writer

    def mcap_ros2_write():
        buffer = io.BytesIO()
        writer = Ros2Writer(buffer)
        schema = writer.register_msgdef(IMU, definition(IMU))
        for stamp_ns, a, w in zip(stamps.tolist(), accel_list, rate_list):
            writer.write_message(TOPIC, schema, imu_mapping(stamp_ns, a, w), stamp_ns)
        writer.finish()
        return buffer

    _, wall, _ = timed(mcap_ros2_write)
    rows.append(('mcap-ros2-support `Writer.write_message` (a mapping; encoding and MCAP '
                 'writing)', wall, 'no channel metadata (QoS, type hash)'))
    return [(name, 1e6 * seconds / count, note) for name, seconds, note in rows], ours


def decoding_rows(messages):
    """Return table rows: decoders of the encoded stream, µs per message."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.typesys import get_typestore, Stores

    count = len(messages)
    (stamps, accel, _), wall, _ = timed(lambda: decode_imu(messages))
    rows = [('`imu_cdr.decode_imu` (batch)', wall, 'reference')]
    store = get_typestore(Stores.ROS2_KILTED)
    decoded, wall, _ = timed(lambda: [store.deserialize_cdr(m, IMU) for m in messages])
    same = all(d.linear_acceleration.z == a for d, a in zip(decoded, accel[:, 2]))
    rows.append(('rosbags `Typestore.deserialize_cdr`', wall, 'same values' if same
                 else 'DIFFERENT'))
    decode = DecoderFactory().decoder_for('cdr', Schema(
        id=1, name=IMU, encoding='ros2msg', data=definition(IMU).encode()))
    decoded, wall, _ = timed(lambda: [decode(m) for m in messages])
    same = all(d.linear_acceleration.z == a for d, a in zip(decoded, accel[:, 2]))
    rows.append(('mcap-ros2-support `DecoderFactory().decoder_for`', wall,
                 'same values' if same else 'DIFFERENT'))
    return [(name, 1e6 * seconds / count, note) for name, seconds, note in rows]


def recording_rows(messages, directory):
    """Return rows: messages per second recorded with crash safety, and rosbags' Writer."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores

    count = len(messages)
    times = (START_NS + PERIOD_NS * np.arange(count, dtype=np.int64)).tolist()

    def crash_safe():
        with FlightRecorder(directory, 'crash_safe') as recorder:
            for first in range(0, count, RUN):
                recorder.record_many(TOPIC, IMU, messages[first:first + RUN],
                                     times[first:first + RUN])
                make_durable(recorder.flush())
        return recorder.files

    files, wall, cpu = timed(crash_safe)
    size = sum(path.stat().st_size for path in files)
    rows = [('`FlightRecorder.record_many` + `flush()` + `fdatasync` every 250 messages, '
             '`.part`, `flock`', count / wall, count / cpu, size / count)]
    store = get_typestore(Stores.ROS2_KILTED)

    def rosbags_writer():
        path = Path(directory) / 'rosbags_writer'
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with writer:
            connection = writer.add_connection(TOPIC, IMU, typestore=store,
                                               msgdef=definition(IMU), rihs01=type_hash(IMU))
            for data, time_ns in zip(messages, times):
                writer.write(connection, time_ns, data)
        return sorted(path.glob('*.mcap'))

    files, wall, cpu = timed(rosbags_writer)
    size = sum(path.stat().st_size for path in files)
    rows.append(('rosbags `rosbag2.Writer` (MCAP storage, zstd; no flush, fsync or `.part`)',
                 count / wall, count / cpu, size / count))
    return rows


def write_part(directory, gib):
    """Write a cut ``.part`` of about ``gib`` GiB (Imu, a chunk every 250); return its path."""
    path = Path(directory) / 'cut.mcap'
    encoder = ImuEncoder('imu_link', ACCEL_COV, RATE_COV)
    writer = McapBagWriter(path)
    writer.add_topic(TOPIC, IMU)
    stamps, accel, rate = stream(100 * RUN)
    batch = encoder.encode(stamps, accel, rate)
    start, target = 0, int(gib * 2**30)
    while writer.bytes_written < target:
        times = (stamps + start * PERIOD_NS).tolist()
        for first in range(0, len(batch), RUN):
            writer.write_serialized_many(TOPIC, batch[first:first + RUN],
                                         times[first:first + RUN])
            writer.flush()
        start += len(batch)
    writer.abort()  # a kill after the last flush: complete chunks, no summary
    return writer.part_path, start


def rewrite_through_mcap(part, out):
    """Rewrite the complete chunks of ``part`` into a new file with mcap's Writer."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    schemas, channels, messages = {}, {}, 0
    with open(part, 'rb') as source, open(out, 'wb') as target:
        writer = Writer(target, chunk_size=768 * 1024)
        writer.start(profile='ros2', library='rewrite')
        records = StreamReader(source, validate_crcs=True).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception:  # the end of the complete chunks
                break
            if isinstance(record, Schema):
                schemas[record.id] = writer.register_schema(record.name, record.encoding,
                                                            record.data)
            elif isinstance(record, Channel):
                channels[record.id] = writer.register_channel(
                    record.topic, record.message_encoding, schemas[record.schema_id],
                    record.metadata)
            elif isinstance(record, Message):
                writer.add_message(channels[record.channel_id], record.log_time, record.data,
                                   record.publish_time, record.sequence)
                messages += 1
        writer.finish()
    return messages


def recovery_rows(directory, gib):
    """Return rows: recovering a cut part in place and by rewriting it through mcap."""
    (part, samples), wall, _ = timed(lambda: write_part(directory, gib))
    size = part.stat().st_size
    print(f'part: {size / 2**30:.2f} GiB, {samples} Imu messages, written in {wall:.0f} s',
          file=sys.stderr)
    rows = []
    os.sync()
    out = Path(directory) / 'rewritten.mcap'
    messages, wall, cpu = timed(lambda: rewrite_through_mcap(part, out))
    rows.append(('mcap `StreamReader` + `Writer`: the messages rewritten into a new file',
                 wall, cpu, messages, out.stat().st_size))
    out.unlink()
    os.sync()
    result, wall, cpu = timed(lambda: recover_part(part))
    final = result.path
    rows.append(('`part_repair.recover_part`: summary appended in place', wall, cpu,
                 result.messages, final.stat().st_size))
    final.unlink()
    return size, rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--messages', type=int, default=100_000)
    parser.add_argument('--part-gib', type=float, default=1.0)
    parser.add_argument('--scratch', default=None, help='directory for the files (default /tmp)')
    args = parser.parse_args()
    directory = tempfile.mkdtemp(prefix='qfa_bag_alternatives_', dir=args.scratch)
    try:
        load = os.getloadavg()
        print(f'{args.messages} Imu messages (frame imu_link, with rates); load average '
              f'{load[0]:.2f} at the start\n')
        rows, messages = encoding_rows(args.messages)
        print('| Imu encoding | µs per message | result |\n|---|---:|---|')
        for name, us, note in rows:
            print(f'| {name} | {us:.2f} | {note} |')
        print('\n| Imu decoding | µs per message | result |\n|---|---:|---|')
        for name, us, note in decoding_rows(messages):
            print(f'| {name} | {us:.2f} | {note} |')
        print('\n| recording the encoded stream | messages/s (wall) | x the 1 kHz stream '
              '| messages per CPU second | file bytes per message |\n|---|---:|---:|---:|---:|')
        for name, rate, cpu_rate, size in recording_rows(messages, directory):
            print(f'| {name} | {rate:,.0f} | {rate / 1000:.0f} | {cpu_rate:,.0f} '
                  f'| {size:.1f} |')
        if args.part_gib > 0:
            size, rows = recovery_rows(directory, args.part_gib)
            print(f'\n| recovering a cut part of {size / 2**30:.2f} GiB | wall s | CPU s '
                  '| messages | file GiB |\n|---|---:|---:|---:|---:|')
            for name, wall, cpu, messages, out_size in rows:
                print(f'| {name} | {wall:.1f} | {cpu:.1f} | {messages} '
                      f'| {out_size / 2**30:.2f} |')
        load = os.getloadavg()
        print(f'\nload average {load[0]:.2f} at the end')
    finally:
        shutil.rmtree(directory, ignore_errors=True)


if __name__ == '__main__':
    main()
