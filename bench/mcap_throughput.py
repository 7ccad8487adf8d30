"""Measure MCAP write throughput of the recorder for sensor_msgs/msg/Imu.

Four paths: mappings serialized by the recorder (``McapBagWriter.write``), CDR bytes
serialized beforehand (``write_serialized``), and the flight recorder with the node's
default split limits, 1 GiB / 600 s, on the bytes of ``qfa_ros.bag.imu_cdr.ImuEncoder``:
one message per call (``FlightRecorder.record``) and runs of 100 (``record_many``: the
node's recording thread writes each run of one topic with one call, and at 1 kHz 100 Imu
samples lie between two 10 Hz temperature readings). The messages carry seeded
noise like a real 1 kHz stream, so compression ratios are realistic. Writes the table to
``bench/results/mcap_throughput.md``.

Usage: ``python bench/mcap_throughput.py [--messages N] [--repeat R]``
"""

import argparse
import datetime
from pathlib import Path
import platform
import shutil
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from qfa_ros.bag.flight_recorder import FlightRecorder
from qfa_ros.bag.imu_cdr import ImuEncoder  # noqa: E402
from qfa_ros.bag.qos import QOS_SENSOR_DATA
from qfa_ros.bag.types import encode_message, stamp
from qfa_ros.bag.writer import DEFAULT_CHUNK_SIZE, McapBagWriter
from qfa_ros.model.units import STANDARD_GRAVITY

TOPIC = '/imu/data_raw'
MSGTYPE = 'sensor_msgs/msg/Imu'
START_NS = 1_700_000_000_000_000_000
PERIOD_NS = 1_000_000


def imu_messages(count, seed=0):
    """Return ``count`` Imu mappings of a static sensor with 50 µg/√Hz-like noise."""
    rng = np.random.default_rng(seed)
    accel = np.array([0.0, 0.0, STANDARD_GRAVITY]) + rng.normal(0.0, 5e-4, size=(count, 3))
    covariance = [2.5e-7, 0.0, 0.0, 0.0, 2.5e-7, 0.0, 0.0, 0.0, 2.5e-7]
    unknown = [-1.0] + [0.0] * 8
    return [
        {
            'header': {'stamp': stamp(START_NS + i * PERIOD_NS), 'frame_id': 'imu_link'},
            'orientation_covariance': unknown,
            'angular_velocity_covariance': unknown,
            'linear_acceleration': {'x': a[0], 'y': a[1], 'z': a[2]},
            'linear_acceleration_covariance': covariance,
        }
        for i, a in enumerate(accel.tolist())
    ]


def run(path, messages, serialized, compression):
    """Write all messages once; return elapsed seconds and the file size."""
    started = time.perf_counter()
    with McapBagWriter(path, compression=compression, overwrite=True) as bag:
        bag.add_topic(TOPIC, MSGTYPE, QOS_SENSOR_DATA)
        if serialized is None:
            for i, message in enumerate(messages):
                bag.write(TOPIC, message, START_NS + i * PERIOD_NS)
        else:
            for i, data in enumerate(serialized):
                bag.write_serialized(TOPIC, data, START_NS + i * PERIOD_NS)
    return time.perf_counter() - started, path.stat().st_size


def record(directory, serialized, run=None):
    """Record all messages through a FlightRecorder; return elapsed seconds and bytes.

    One call per message, or per ``run`` messages (``record_many``).
    """
    for old in Path(directory).glob('flight_*'):
        shutil.rmtree(old)  # the bag directory of the previous repetition
    started = time.perf_counter()
    with FlightRecorder(directory, prefix='flight', max_bytes=1 << 30,
                        max_duration_ns=600 * 1_000_000_000,
                        qos={TOPIC: QOS_SENSOR_DATA}) as recorder:
        if run is None:
            for i, data in enumerate(serialized):
                recorder.record(TOPIC, MSGTYPE, data, START_NS + i * PERIOD_NS)
        else:
            for first in range(0, len(serialized), run):
                datas = serialized[first:first + run]
                recorder.record_many(TOPIC, MSGTYPE, datas,
                                     [START_NS + (first + i) * PERIOD_NS
                                      for i in range(len(datas))])
    elapsed = time.perf_counter() - started
    return elapsed, sum(f.stat().st_size for f in recorder.files)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--messages', type=int, default=20000)
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--out', type=Path,
                        default=Path(__file__).resolve().parent / 'results' / 'mcap_throughput.md')
    args = parser.parse_args()

    messages = imu_messages(args.messages)
    started = time.perf_counter()
    serialized = [encode_message(message, MSGTYPE) for message in messages]
    encode_rate = len(messages) / (time.perf_counter() - started)

    rows = []
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / 'bench.mcap'
        for compression in ('zstd', 'lz4', None):
            for label, payload in (('mapping', None), ('pre-serialized', serialized)):
                best = min(run(path, messages, payload, compression)
                           for _ in range(args.repeat))
                seconds, size = best
                rows.append((label, compression or 'none', len(messages) / seconds,
                             size / len(messages)))
                print(f'{label:15s} {compression or "none":5s} '
                      f'{rows[-1][2]:10.0f} msg/s {rows[-1][3]:7.1f} B/msg', flush=True)
        accel = np.array([[m['linear_acceleration'][k] for k in 'xyz'] for m in messages])
        node_bytes = ImuEncoder('imu_link', messages[0]['linear_acceleration_covariance']) \
            .encode(START_NS + np.arange(len(messages)) * PERIOD_NS, accel)
        for label, run_length in (('flight recorder, one per call', None),
                                  ('flight recorder, runs of 100 (node)', 100)):
            seconds, size = min(record(directory, node_bytes, run_length)
                                for _ in range(args.repeat))
            rows.append((label, 'zstd', len(messages) / seconds, size / len(messages)))
            print(f'{label} zstd {rows[-1][2]:10.0f} msg/s {rows[-1][3]:7.1f} B/msg')

    lines = [
        '# MCAP write throughput (sensor_msgs/msg/Imu)',
        '',
        f'Generated by `bench/mcap_throughput.py` on '
        f'{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}; '
        f'Python {platform.python_version()}, {platform.machine()}, '
        f'{args.messages} messages per file, best of {args.repeat}, '
        f'chunk size {DEFAULT_CHUNK_SIZE // 1024} KiB, chunk CRCs on, one topic.',
        '',
        f'CDR payload {len(serialized[0])} bytes per message; serializing a mapping alone '
        f'(recorder field check + rosbags type-store encoder) runs at {encode_rate:,.0f} msg/s.',
        'Times include opening, the summary, fsync and the atomic rename.',
        '',
        '| path | compression | messages/s | file bytes/message |',
        '|---|---|---:|---:|',
    ]
    lines += [f'| {label} | {compression} | {rate:,.0f} | {per_message:.1f} |'
              for label, compression, rate, per_message in rows]
    lines.append('')
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text('\n'.join(lines))
    print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
