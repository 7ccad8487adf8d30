"""Kill a writer at an instant, read back what it left, and hold it against a witness.

Used by ``test_recovery.py``, ``test_crash_recording.py`` and ``bench/crash_recording.py``:

- :func:`killed_recording` runs a :class:`FlightRecorder` in a process of its own, fed
  ``sensor_msgs/Imu`` the way the node feeds it (a flush every 0.25 s of stream), and ends
  that process with ``os._exit`` mid-file, as a kill would;
- :func:`read_bag` reads a bag directory back with ``rosbags``' ``AnyReader`` and every
  file of it with the mcap seeking reader (summary, CRCs), and says whether both agree;
- :func:`loss` compares the IMU stamps of a bag with those an independent subscriber
  received, against the instant of the kill;
- :func:`recorded_session` records a short session of a 100 Hz IMU stream in 1 s files
  (:func:`feed_imu`), for retention (``test_retention.py``).
"""

import collections
import dataclasses
import os
from pathlib import Path
import signal
import struct
import subprocess
import sys
import textwrap
import time

from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
import numpy as np
from rosbags.highlevel import AnyReader
import yaml

from qfa_ros.bag.flight_recorder import FlightRecorder
from qfa_ros.bag.imu_cdr import ImuEncoder

ROOT = Path(__file__).resolve().parents[1]
IMU_TOPIC = '/imu/data_raw'
STAMP = struct.Struct('<iI')
"""``header.stamp`` (sec, nanosec) right after the 4-byte CDR encapsulation header."""
LOSS_BOUND_S = 1.0
"""What a kill may lose: messages published in the last second before it (issue 35)."""
SECOND = 1_000_000_000
SESSION_T0 = 1_767_225_600_000_000_000
"""2026-01-01 00:00:00 UTC [ns]: when :func:`recorded_session` times start."""
SESSION_RATE = 100
"""IMU rate of :func:`recorded_session` [Hz]."""
ENCODER = ImuEncoder('imu_link', [1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6])

KILLED_RECORDER = textwrap.dedent("""
    import os, sys
    import numpy as np
    from qfa_ros.bag.flight_recorder import FlightRecorder
    from qfa_ros.bag.imu_cdr import ImuEncoder
    directory, prefix, count, rate, split_s, session_ns = sys.argv[1:7]
    count, rate, split_s = int(count), float(rate), float(split_s)
    recorder = FlightRecorder(directory, prefix, max_duration_ns=int(split_s * 1e9),
                              session_time_ns=int(session_ns))
    encoder = ImuEncoder('imu_link', [1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6])
    rng = np.random.default_rng(int(session_ns) % 2**32)
    start, period, batch = int(session_ns), int(1e9 / rate), max(1, int(rate / 4))
    for first in range(0, count, batch):
        stamps = start + period * np.arange(first, min(count, first + batch), dtype=np.int64)
        accel = rng.normal([0.0, 0.0, 9.81], 1e-4, size=(len(stamps), 3))
        recorder.record_many('/imu/data_raw', 'sensor_msgs/msg/Imu',
                             encoder.encode(stamps, accel), stamps.tolist())
        recorder.flush()  # as the node's recording thread does every 0.25 s of stream
    print(recorder.bag_directory, flush=True)
    os._exit(9)  # no close(): the .part stays as a kill leaves it
""")


def part_messages(path):
    """
    Return ``[(channel, message)]`` of the complete chunks of an unfinished MCAP file.

    mcap's plain streaming reader, chunk CRCs checked, stopped at the first record it
    cannot read (a cut fails in the parser, zstd, lz4 or the CRC check depending on where
    it is): what any reader salvages from a ``.part`` without recovering it.
    """
    channels, messages = {}, []
    with open(path, 'rb') as stream:
        try:
            for record in StreamReader(stream, validate_crcs=True).records:
                if isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    messages.append((channels[record.channel_id], record))
        except OSError:
            raise
        except Exception:  # the end of the complete chunks
            pass
    return messages


def killed_recording(directory, messages, *, prefix='qfa_node', rate=1000.0, split_s=600.0,
                     session_ns=1_767_225_600_000_000_000, timeout=600):
    """
    Record ``messages`` Imu samples in a process that then dies without closing.

    :returns: The bag directory (its last file a ``.part``).
    """
    result = subprocess.run(
        [sys.executable, '-c', KILLED_RECORDER, str(directory), prefix, str(messages),
         str(rate), str(split_s), str(session_ns)],
        cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 9, result.stderr
    return Path(result.stdout.strip())


@dataclasses.dataclass
class BagContents:
    """What a bag directory holds, read back by two independent readers."""

    counts: dict
    """Messages per topic (``AnyReader``)."""
    imu_stamps: np.ndarray
    """Header stamps of ``/imu/data_raw`` [ns], in log-time order."""
    last_log_ns: int
    """Log time of the last message of any topic [ns] (0: none)."""
    files: int
    """Files ``metadata.yaml`` lists."""


def read_bag(directory):
    """
    Read a bag directory (or one MCAP file) with ``AnyReader`` and the mcap seeking reader.

    The seeking reader validates the chunk CRCs and must find as many messages as each
    file's summary states, and the same IMU stamps as ``AnyReader``; an assertion fails
    otherwise.
    """
    directory = Path(directory)
    if directory.is_file():
        with AnyReader([directory]) as reader:
            counts = collections.Counter(c.topic for c, _, _ in reader.messages())
        stamps = read_mcap(directory)
        return BagContents(dict(counts), np.array(stamps, dtype=np.int64), 0, 1)
    counts = collections.Counter()
    stamps, last_log = [], 0
    with AnyReader([directory]) as reader:
        for connection, log_time, raw in reader.messages():
            counts[connection.topic] += 1
            last_log = max(last_log, log_time)
            if connection.topic == IMU_TOPIC:
                sec, nanosec = STAMP.unpack_from(raw, 4)
                stamps.append(sec * 1_000_000_000 + nanosec)
    metadata = yaml.safe_load((directory / 'metadata.yaml').read_text())
    files = metadata['rosbag2_bagfile_information']['relative_file_paths']
    seen = []
    for name in files:
        seen += read_mcap(directory / name)
    assert seen == stamps, 'the mcap seeking reader and AnyReader disagree'
    assert metadata['rosbag2_bagfile_information']['message_count'] == sum(counts.values())
    return BagContents(dict(counts), np.array(stamps, dtype=np.int64), last_log, len(files))


def read_mcap(path):
    """Return the IMU stamps of one MCAP file read by the seeking reader (CRCs checked)."""
    stamps = []
    with open(path, 'rb') as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        messages = 0
        for _, channel, message in reader.iter_messages(log_time_order=True):
            messages += 1
            if channel.topic == IMU_TOPIC:
                sec, nanosec = STAMP.unpack_from(message.data, 4)
                stamps.append(sec * 1_000_000_000 + nanosec)
        assert messages == summary.statistics.message_count, path
    return stamps


@dataclasses.dataclass
class Loss:
    """A kill's loss, judged against an independent subscriber's samples."""

    missing: int
    """Samples the subscriber received that the bag lacks."""
    missing_before_bound: int
    """Of them, received ``LOSS_BOUND_S`` or more before the kill: must be 0."""
    reach_s: float
    """How far before the kill the loss reaches at most: from the stamp of the first missing
    sample to the kill [s] (0 when none is missing). An upper bound: the node publishes a
    sample at its stamp or later (the receipt, a lower bound, may follow the kill)."""
    reach_receipt_s: float
    """The same from the receipt of the first missing sample [s]: a lower bound (a receipt
    follows the publication, and may follow the kill: then it is negative)."""
    last_s: float
    """From the stamp of the last sample in the bag to the kill [s]: the loss, plus any
    time the node published nothing (a schedule, a stall of the machine)."""
    witnessed: int
    """Samples the subscriber received up to ``LOSS_BOUND_S`` before the kill."""


def loss(bag_stamps, received, kill_ns):
    """
    Return the :class:`Loss` of a bag against ``received``.

    :param bag_stamps: IMU stamps in the bag [ns].
    :param received: ``(stamp, receive time)`` pairs of the witness [ns], the receive time
        on the system clock: a sample received at ``t`` was published before ``t``.
    :param kill_ns: When SIGKILL was sent (system clock) [ns].
    """
    stamps = np.array([stamp for stamp, _ in received], dtype=np.int64)
    times = np.array([time_ns for _, time_ns in received], dtype=np.int64)
    missing = ~np.isin(stamps, bag_stamps)
    early = times <= kill_ns - int(LOSS_BOUND_S * 1e9)
    last = int(bag_stamps.max()) if len(bag_stamps) else 0
    reach = (kill_ns - int(stamps[missing].min())) / 1e9 if missing.any() else 0.0
    receipt = (kill_ns - int(times[missing].min())) / 1e9 if missing.any() else 0.0
    return Loss(int(missing.sum()), int((missing & early).sum()), reach, receipt,
                (kill_ns - last) / 1e9, int(early.sum()))


def stop_when(process, predicate, timeout, poll_s=0.001):
    """
    SIGSTOP ``process`` as soon as ``predicate()`` is true (polled).

    A stopped process writes nothing more; a SIGKILL then leaves the disk as a kill at the
    instant of the stop would.

    :returns: When it was stopped (system clock) [ns], or None if ``predicate`` never held
        (or the process ended) within ``timeout`` seconds.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and process.poll() is None:
        if predicate():
            stopped = time.time_ns()
            os.kill(process.pid, signal.SIGSTOP)
            return stopped
        time.sleep(poll_s)
    return None


def run_stopped(process, stopped_ns, until, limit_s=60.0, step_s=0.002):
    """
    Let a stopped ``process`` run in slices of ``step_s`` (SIGCONT, sleep, SIGSTOP).

    Stops slicing once ``until()`` is true (checked while the process is stopped), or after
    ``limit_s`` seconds. The process is left stopped.

    :returns: When it was last stopped (``stopped_ns`` if it never ran) [ns]: the instant a
        SIGKILL now stands for.
    """
    deadline = time.monotonic() + limit_s
    while not until() and time.monotonic() < deadline:
        os.kill(process.pid, signal.SIGCONT)
        time.sleep(step_s)
        stopped_ns = time.time_ns()
        os.kill(process.pid, signal.SIGSTOP)
    return stopped_ns


def part_reached(directory, size):
    """Return a check: no ``.mcap.part`` left in ``directory``, or one of ``size`` bytes."""
    def reached():
        parts = list(Path(directory).glob('*.mcap.part'))
        return not parts or any(part.stat().st_size >= size for part in parts)
    return reached


def stop_mid_file(process, recordings, timeout=60.0, retry_s=0.005):
    """
    SIGSTOP ``process`` at an instant its flight recorder is writing a file.

    Between two files (the one finished published and listed or about to be, the next not
    yet begun: a few fsyncs long, longer on a busy disk) a kill leaves a bag whose
    ``metadata.yaml`` at most needs rewriting, or nothing to recover at all
    (``test_recovery.py`` covers it). To be sure a ``.part`` is left, the process is
    stopped, looked at, and let run ``retry_s`` more while no ``.part`` without its
    finished name is in a bag directory of ``recordings``.

    :returns: When it was stopped (system clock) [ns]; the process is left stopped.
    """
    deadline = time.monotonic() + timeout
    while True:
        stopped = time.time_ns()
        os.kill(process.pid, signal.SIGSTOP)
        parts = Path(recordings).glob('*/*.mcap.part')
        if any(not part.with_suffix('').exists() for part in parts):
            return stopped
        assert time.monotonic() < deadline, f'no .part in {recordings} in {timeout} s'
        os.kill(process.pid, signal.SIGCONT)
        time.sleep(retry_s)


def feed_imu(recorder, start_ns, seconds):
    """Record ``seconds`` of a :data:`SESSION_RATE` IMU stream stamped from ``start_ns``."""
    stamps = start_ns + np.arange(int(seconds * SESSION_RATE), dtype=np.int64) * (
        SECOND // SESSION_RATE)
    accel = np.tile([0.0, 0.0, 9.81], (len(stamps), 1))
    recorder.record_many(IMU_TOPIC, 'sensor_msgs/msg/Imu', ENCODER.encode(stamps, accel),
                         stamps.tolist())


def recorded_session(directory, start_s, seconds, close=True, prefix='qfa_node'):
    """
    Record a session of ``seconds`` of IMU stream split every second; return its recorder.

    The session (its bag's name and its first stamp) starts ``start_s`` after
    :data:`SESSION_T0`; ``close`` finishes it, otherwise its last file stays a ``.part``.
    """
    start = SESSION_T0 + int(start_s * SECOND)
    recorder = FlightRecorder(directory, prefix, max_duration_ns=SECOND, session_time_ns=start)
    feed_imu(recorder, start, seconds)
    if close:
        recorder.close()
    return recorder
