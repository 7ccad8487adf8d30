"""The flight recorder's disk rate at the default rates: MiB an hour per topic and in all.

Run (the table in ``bench/results/recorder_disk_rate.md``)::

    .venv/bin/python bench/recorder_disk_rate.py --seconds 300

Starts the node as its users do (``python -m qfa_ros.cli.node``) with ``recorder.enabled:
true`` and every other parameter at its default (1 kHz ``imu/data_raw``, 10 Hz
``imu/temperature``, 1 Hz ``/diagnostics``, the truth topics at 10 Hz, zstd chunks ended
every 0.25 s by the crash safety) in a fresh ``output_dir``, lets it run ``--seconds`` of
wall time after its first sample and stops it with SIGTERM (the file finished). The bag's
files on disk over the time ``imu/data_raw`` was recorded (its first to its last message,
log time) give the rate in all. Each topic's own share: what its messages add to a file
when recorded alone the way the node records them (a
:class:`~qfa_ros.bag.flight_recorder.FlightRecorder` with the node's compression, a chunk
ended every 0.25 s of log time; less the file of its first message alone, which holds
what a file has once), beside its message bytes before compression. Alone, a topic
compresses a little differently than mixed in the node's chunks, so the per-topic figures
add up to about the total, not exactly. The sizing line is the total rate times 24 h.
"""

import argparse
import datetime
import os
from pathlib import Path
import platform
import shutil
import sys
import tempfile
import time

from mcap.reader import make_reader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from node_helpers import Client, ImuCollector, NodeProcess  # noqa: E402

from qfa_ros.bag.flight_recorder import FlightRecorder  # noqa: E402
from qfa_ros.ros.pacing import RECORD_PERIOD_S  # noqa: E402
from qfa_ros.ros.parameter_table import SPECS  # noqa: E402

MIB = float(1 << 20)
GIB = float(1 << 30)
HOUR_S = 3600.0
IMU_TOPIC = '/imu/data_raw'
NOMINAL_HZ = SPECS['sample_rate_hz'].default
"""The default rate of ``imu/data_raw`` [Hz]."""
COMPRESSION = 'zstd'
"""What the node's recorder compresses its chunks with (``FlightRecorder``'s default)."""


def run_node(domain, scratch, seconds):
    """Run the recording node ``seconds`` after its first sample; return its bag directory."""
    output = scratch / 'output'
    node = NodeProcess(domain, scratch, {'output_dir': str(output), 'state_file': '',
                                         'recorder.enabled': True},
                       command=[sys.executable, '-m', 'qfa_ros.cli.node'])
    client = Client(domain)
    try:
        imu = ImuCollector(client)
        client.spin_until(lambda: imu.samples, 120.0, 'the first sample')
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            client.spin_for(min(5.0, deadline - time.monotonic()))
            imu.samples.clear()  # received, not kept: the bag is what is measured
    finally:
        client.close()
        status = node.stop(timeout=60.0)
    if status != 0:
        raise RuntimeError(f'the node ended with status {status}: {node.log()[-2000:]}')
    bag, = (output / 'recordings').iterdir()
    return bag


def read_topics(bag):
    """Return ``{topic: (msgtype, [(log time, data)])}``, in log-time order per topic."""
    topics = {}
    for path in sorted(bag.glob('*.mcap'), key=lambda p: int(p.stem.rsplit('_', 1)[1])):
        with open(path, 'rb') as stream:
            reader = make_reader(stream, validate_crcs=True)
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                entry = topics.setdefault(channel.topic, (schema.name, []))
                entry[1].append((message.log_time, message.data))
    return topics


def alone_bytes(scratch, topic, msgtype, messages):
    """
    Return the bytes one topic's messages add to a file recorded alone as the node does.

    The file of all its messages less the file of its first message alone: what the topic
    adds as the recording goes on, without the definitions and summary a file has once.
    """
    sizes = []
    for name, taken in (('all', messages), ('first', messages[:1])):
        directory = scratch / 'alone' / name / topic.strip('/').replace('/', '_')
        directory.mkdir(parents=True)
        period_ns = int(RECORD_PERIOD_S * 1e9)
        recorder = FlightRecorder(directory, 'alone', compression=COMPRESSION,
                                  max_bytes=1 << 40, max_duration_ns=10 ** 15)
        next_flush = taken[0][0] + period_ns
        for time_ns, data in taken:
            while time_ns >= next_flush:
                recorder.flush()  # as the node's recording thread does every 0.25 s
                next_flush += period_ns
            recorder.record(topic, msgtype, data, time_ns)
        sizes.append(sum(path.stat().st_size for path in recorder.close()))
    return sizes[0] - sizes[1]


def report(bag, topics, alone, args, started):
    """Return the Markdown of one run."""
    stamps = [time_ns for time_ns, _ in topics[IMU_TOPIC][1]]
    span_ns = stamps[-1] - stamps[0]
    hours = span_ns / 1e9 / HOUR_S
    total = sum(path.stat().st_size for path in bag.glob('*.mcap'))
    rate = total / MIB / hours
    load = os.getloadavg()
    lines = [
        f'### {args.seconds:g} s of the node at its default rates, '
        f'{started:%Y-%m-%d %H:%M} UTC', '',
        f'`.venv/bin/python bench/recorder_disk_rate.py --seconds {args.seconds:g}` '
        f'({platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; '
        f'load average {load[0]:.1f} after; `imu/data_raw` recorded for {span_ns / 1e9:.1f} s, '
        f'{len(list(bag.glob("*.mcap")))} file(s), compression {COMPRESSION}, a chunk ended '
        f'every {RECORD_PERIOD_S:g} s)', '',
        '| topic | type | messages/s | message bytes [MiB/h] | recorded alone [MiB/h] |',
        '|---|---|---:|---:|---:|']
    for topic in sorted(topics, key=lambda t: -alone[t]):
        msgtype, messages = topics[topic]
        raw = sum(len(data) for _, data in messages)
        lines.append(f'| `{topic}` | `{msgtype}` | {len(messages) / (span_ns / 1e9):.2f} | '
                     f'{raw / MIB / hours:.1f} | {alone[topic] / MIB / hours:.1f} |')
    lines.append(f'| **all, as the node records them** | | '
                 f'{sum(len(t[1]) for t in topics.values()) / (span_ns / 1e9):.1f} | '
                 f'{sum(len(d) for t in topics.values() for _, d in t[1]) / MIB / hours:.1f}'
                 f' | **{rate:.1f}** |')
    imu_rate = len(stamps) / (span_ns / 1e9)
    if imu_rate < 0.999 * NOMINAL_HZ:
        # The node skipped samples (a loaded machine): what the full rate adds, as the
        # topic alone compresses.
        full = rate + (NOMINAL_HZ / imu_rate - 1.0) * alone[IMU_TOPIC] / MIB / hours
        lines += ['', f'`imu/data_raw` came at {imu_rate:.1f} of {NOMINAL_HZ:g} samples/s '
                  f'(samples skipped on the loaded machine); at the full rate: {full:.1f} '
                  'MiB/h in all.']
    lines += ['', f'Sizing: {rate:.1f} MiB/h is {rate * 24 / 1024:.2f} GiB a day: to keep the '
              f'last 24 h (`recorder.keep_s: 86400.0`) you need '
              f'{rate * 24 * MIB / GIB:.1f} GiB plus the file being written '
              '(`recorder.max_bytes`, or `recorder.max_duration_s` of recording: '
              f'{rate * 600 / 3600:.0f} MiB at the default 600 s).', '',
              '```figures', '- id: recorder_disk_rate', '  group: Recording',
              '  what: Disk the flight recorder takes at the default rates, every recorded '
              'topic', f"  value: '{rate:.0f}'", '  unit: MiB/h',
              f'  note: {rate * 24 / 1024:.1f} GiB a day',
              '  command: .venv/bin/python bench/recorder_disk_rate.py --seconds '
              f'{args.seconds:g}', f'  machine: {platform.machine()}, {os.cpu_count()} cores',
              f'  date: {started:%Y-%m-%d}', '```', '']
    return '\n'.join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=300.0,
                        help='wall time recorded after the first sample [s]')
    parser.add_argument('--scratch', type=Path, default=None,
                        help='where the recording goes (default: a temporary directory)')
    args = parser.parse_args()
    low, high = (int(v) for v in os.environ.get('QFA_TEST_DOMAINS', '1-100').split('-'))
    domain = low + os.getpid() % (high - low + 1)
    started = datetime.datetime.now(datetime.timezone.utc)
    scratch = Path(tempfile.mkdtemp(prefix='recorder_disk_rate_', dir=args.scratch))
    try:
        bag = run_node(domain, scratch, args.seconds)
        topics = read_topics(bag)
        counts = {topic: len(entry[1]) for topic, entry in topics.items()}
        print(f'recorded {counts}', file=sys.stderr)
        alone = {topic: alone_bytes(scratch, topic, *topics[topic]) for topic in topics}
        print(report(bag, topics, alone, args, started))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == '__main__':
    main()
