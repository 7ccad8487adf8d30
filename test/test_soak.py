"""
Nothing grows or drifts while the node runs: the soak's invariants in seconds (issue 35).

``bench/soak.py`` runs the node for hours and fits slopes (``bench/results/soak.md``);
these tests hold what seconds can: the recorder's memory per split, the pacer's backlog,
and a real node (its own process) splitting its recording every second while parameters
change and a self-calibration runs, seen by a ``SensorDataQoS`` subscriber in the test
process.
"""

import gc
import json
import os
from pathlib import Path
import shutil
import signal
import struct
import sys
import tempfile
import threading
import time
import tracemalloc
import types

from crash_helpers import (
    bag_directories,
    deletion_watch,
    entries,
    live_bag,
    loss,
    split_index,
    stop_when,
)
from diagnostic_msgs.msg import DiagnosticArray
from mcap.reader import make_reader
from node_helpers import Client, domain_id, NODE, NodeProcess
import numpy as np
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger
import yaml

from qfa_ros.bag.flight_recorder import FlightRecorder
from qfa_ros.bag.part_files import DELETION_SUFFIX
from qfa_ros.bag.qos import QOS_LATCHED, QosProfile
from qfa_ros.bag.recovery import needs_recovery
from qfa_ros.bag.types import encode_message
from qfa_ros.model.triad import NS_PER_S
from qfa_ros.ros.pacing import CATCH_UP_BURST, CATCH_UP_SPACING_NS, LATE_NS, Pacer
from qfa_ros.ros.stream import publishable

T0 = 1_700_000_000_000_000_000
STAMP = struct.Struct('<iI')
"""``header.stamp`` (sec, nanosec) right after the 4-byte CDR encapsulation header."""

# The eight topics the node records, each with the QoS it offers (docs/node.md).
RECORDED = {
    '/imu/data_raw': ('sensor_msgs/msg/Imu', QosProfile(depth=100)),
    '/imu/temperature': ('sensor_msgs/msg/Temperature', QosProfile(depth=100)),
    '/diagnostics': ('diagnostic_msgs/msg/DiagnosticArray', QosProfile(depth=10)),
    '/qfa_node/is_calibrated': ('std_msgs/msg/Bool', QOS_LATCHED),
    '/qfa_node/calibration_events': ('diagnostic_msgs/msg/DiagnosticStatus',
                                     QosProfile(depth=20, durability='transient_local')),
    '/truth/odometry': ('nav_msgs/msg/Odometry', QosProfile(depth=10)),
    '/truth/origin': ('sensor_msgs/msg/NavSatFix', QOS_LATCHED),
    '/truth/imu_errors': ('sensor_msgs/msg/Imu', QosProfile(depth=10)),
}


def reachable_bytes(root):
    """Return the bytes of every object reachable from ``root`` (modules, types, code aside)."""
    skip = (type, types.ModuleType, types.FunctionType, types.BuiltinFunctionType,
            types.CodeType)
    seen, stack, total = set(), [root], 0
    while stack:
        item = stack.pop()
        if id(item) in seen or isinstance(item, skip):
            continue
        seen.add(id(item))
        total += sys.getsizeof(item)
        stack.extend(gc.get_referents(item))
    return total


def test_flight_recorder_keeps_one_metadata_entry_per_split(tmp_path):
    """
    A recording that splits for days holds only metadata.yaml's entry per finished file.

    Every split file gets the same messages, and the recorder is weighed right after the
    first message of a new file, so the file in progress weighs the same each time: what
    grows is what the recorder keeps of the files it finished. metadata.yaml's entry of
    a file (name, start, duration, count) is a few hundred bytes; the whole per-file
    metadata with every topic's parsed QoS was ~12 kB, 0.35 MiB an hour at 2-min splits.
    """
    messages = [(topic, msgtype, encode_message({}, msgtype))
                for topic, (msgtype, _) in RECORDED.items()]
    split_ns = 1_000_000_000
    recorder = FlightRecorder(tmp_path, max_duration_ns=split_ns,
                              qos={topic: qos for topic, (_, qos) in RECORDED.items()})

    def record_splits(first, count):
        for index in range(first, first + count):
            for step in range(3):
                for topic, msgtype, data in messages:
                    recorder.record(topic, msgtype, data, T0 + index * split_ns + step)
        # The first message of the next file: the file just finished is merged in.
        topic, msgtype, data = messages[0]
        recorder.record(topic, msgtype, data, T0 + (first + count) * split_ns)

    with recorder:
        record_splits(0, 3)
        before = reachable_bytes(recorder)
        record_splits(3, 16)
        after = reachable_bytes(recorder)
        per_split = (after - before) / 16
        assert len(recorder.files) == 19
    assert per_split < 1024, f'the recorder keeps {per_split:.0f} bytes per finished file'


def test_flight_recorder_split_costs_about_what_metadata_yaml_grows(tmp_path):
    """
    A split's transient memory does not grow with the bag's metadata.yaml.

    Each split rewrites metadata.yaml listing every file. Rendered whole by PyYAML, the
    document cost ~23 bytes of short-lived Python objects per byte written (5 MB and
    1.5 s at 1000 files, on an allocator that keeps the peak: the node's RSS grew with the
    bag); here the document is written in parts, each file's rendered once, and the peak
    of a split at 150 files exceeds that at 20 by less than half of what metadata.yaml
    grew meanwhile (nothing, measured; the whole document rendered: ~23 bytes a byte).
    """
    shm = Path('/dev/shm')
    # fsync is free on tmpfs: 150 splits in a second or two.
    directory = Path(tempfile.mkdtemp(dir=shm)) if shm.is_dir() else tmp_path
    imu, (msgtype, qos) = '/imu/data_raw', RECORDED['/imu/data_raw']
    data = encode_message({}, msgtype)
    recorder = FlightRecorder(directory, max_duration_ns=1, qos={imu: qos})
    try:
        def split_peak(index):
            gc.collect()
            tracemalloc.start()
            try:
                recorder.record(imu, msgtype, data, T0 + index)  # finishes file index - 1
                return tracemalloc.get_traced_memory()[1]
            finally:
                tracemalloc.stop()

        def metadata_bytes():
            return (recorder.bag_directory / 'metadata.yaml').stat().st_size

        for index in range(20):
            recorder.record(imu, msgtype, data, T0 + index)
        small = split_peak(20), metadata_bytes()
        for index in range(21, 150):
            recorder.record(imu, msgtype, data, T0 + index)
        large = split_peak(150), metadata_bytes()
        recorder.close()
    finally:
        shutil.rmtree(directory, ignore_errors=True)
    assert large[1] > 5 * small[1]
    growth = (large[0] - small[0]) / (large[1] - small[1])
    assert growth <= 0.5, (f'a split at 150 files takes {large[0] / 1024:.0f} KiB, at 20 '
                           f'{small[0] / 1024:.0f} KiB: {growth:.1f} bytes per byte of '
                           f'metadata.yaml')


class _SystemClockNode:
    """What the pacer needs of a node: a clock that is the system clock (no use_sim_time)."""

    class _Clock:
        ros_time_is_active = False

    def get_clock(self):
        return self._Clock()


class _Publisher:
    topic_name = '/imu/data_raw'

    def __init__(self):
        self.published = []

    def publish(self, data):
        self.published.append(data)


def test_pacer_drops_what_it_reaches_more_than_a_second_late():
    """
    A pacer held up for minutes resumes at the present instead of publishing the backlog.

    Messages it reaches more than a second (pacing.STALE_NS) after their stamp are
    dropped and counted, those late by less are published (late), the others at their
    instant. Without the
    bound, a pacer slower than the stream (tracemalloc on a machine at load 30) held
    430 s of samples, 150 MB, every one published later than the one before.
    """
    publisher = _Publisher()
    recorded = []
    pacer = Pacer(_SystemClockNode(), on_published=lambda *args: recorded.append(args[2]))
    now = time.time_ns()
    # 2 s of samples 3 to 1.001 s old, then some 0.3 s old, then some due in 50 ms.
    stale = [(now - 3 * NS_PER_S + i * 1_000_000, publisher, 'sensor_msgs/msg/Imu', b'stale')
             for i in range(1999)]
    late = [(now - 300_000_000 + i * 1_000_000, publisher, 'sensor_msgs/msg/Imu', b'late')
            for i in range(10)]
    due = [(now + 50_000_000 + i * 1_000_000, publisher, 'sensor_msgs/msg/Imu', b'due')
           for i in range(10)]
    pacer.put(stale + late + due)
    pacer.start()
    deadline = time.monotonic() + 60.0
    while len(publisher.published) < 20 and time.monotonic() < deadline:
        time.sleep(0.01)
    pacer.stop()
    assert publisher.published == [b'late'] * 10 + [b'due'] * 10
    assert recorded == publisher.published
    assert pacer.dropped == len(stale)
    assert pacer.published == 20



def test_pause_returns_after_the_recording_hook():
    """
    Once ``pause()`` returns, a message published before it has reached the recording hook.

    A deactivation pauses, flushes the recording's queue and splits the file: a message
    published before the pause but handed to the hook after the flush began the next active
    period's file (seen once in CI, Jazzy: a sample stamped 113 ms before its activation).
    Here the hook waits for the pause to return: it never may.
    """
    pause_returned = threading.Event()
    hook_saw_pause_returned = []

    def on_published(*_):
        hook_saw_pause_returned.append(pause_returned.wait(0.5))

    class _BlockingPublisher(_Publisher):
        def __init__(self):
            super().__init__()
            self.publishing = threading.Event()
            self.release = threading.Event()

        def publish(self, data):
            self.publishing.set()
            assert self.release.wait(60.0)
            super().publish(data)

    publisher = _BlockingPublisher()
    pacer = Pacer(_SystemClockNode(), on_published=on_published)
    pacer.put([(time.time_ns(), publisher, 'sensor_msgs/msg/Imu', b'x')])
    pacer.start()
    try:
        assert publisher.publishing.wait(60.0)
        pausing = threading.Thread(target=lambda: (pacer.pause(), pause_returned.set()))
        pausing.start()
        publisher.release.set()
        pausing.join(60.0)
    finally:
        pacer.stop()
    assert pause_returned.is_set()
    assert publisher.published == [b'x'] and hook_saw_pause_returned == [False]


def test_a_resumption_publishes_every_message_stamped_from_the_instant_it_returns():
    """
    A message due while ``resume()`` waits to take effect is published, not dropped as paused.

    An activation read the clock, then resumed the pacer: held up in between (the GIL, a
    busy core), the first sample stamped after that reading came due while still paused
    and went missing from its period (a Jazzy suite run: the managed node's third period
    began a sample late). Here the clock is read, then the reader held up for 50 ms while
    a message stamped 10 ms on comes due.
    """
    publisher = _Publisher()
    pacer = Pacer(_SystemClockNode())
    pacer.pause()
    pacer.start()
    stamp = []

    def held_up_clock():
        now = time.time_ns()
        stamp.append(now + 10_000_000)
        pacer.put([(stamp[0], publisher, 'sensor_msgs/msg/Imu', b'due')])
        time.sleep(0.05)
        return now

    try:
        from_ns = pacer.resume(held_up_clock)
        deadline = time.monotonic() + 60.0
        while not publisher.published and pacer.unpublished == 0 \
                and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        pacer.stop()
    assert stamp[0] >= from_ns
    assert publisher.published == [b'due'] and pacer.unpublished == 0


def test_a_batch_computed_ahead_when_paused_keeps_what_is_not_yet_due():
    """
    A batch handed over during a short pause keeps its samples stamped after the present.

    A managed node deactivated and at once activated again (7 ms apart, a busy machine)
    while the sensor thread computed a batch ahead: the batch was discarded whole as
    paused, and its period's recording had a hole of 104 samples, 14 after its activation.
    """
    items = [(stamp, 'imu') for stamp in range(100, 110)]
    assert publishable(items, None, lambda: 104) == items[4:]
    assert publishable(items, None, lambda: 200) == []
    assert publishable(items, 107, lambda: 0) == items[7:]
    assert publishable(items, 50, lambda: 0) is items and publishable([], None, lambda: 0) == []


# --- seconds of the live node -------------------------------------------------------------

RATE = 250.0
"""Sample rate of the short soak [Hz]: a keep-last-5 subscriber in the (busy) test process
has 20 ms of slack; the invariants do not depend on the rate (bench/soak.py runs 1 kHz)."""
PERIOD_NS = int(1e9 / RATE)
SPLIT_S = 1.0
"""Recording file length [s]: the shortest the node takes, the most splits per second."""
MAX_BYTES = 1 << 20
SOAK_S = 6.0
"""Node time of parameter changes and splits after the baseline [s]: each of the
:data:`ROTATION` changed twice, six splits (a descriptor or thread kept per split or per
change shows after one; 12 s until issue 44; the hours: ``bench/soak.py``)."""
PAUSE_MARGIN_NS = 500_000_000
"""A gap this close to a schedule call (request to answer) is the schedule's pause [ns]."""
LOSS_BOUND = 0.01
"""Samples the SensorDataQoS subscriber may lose outside pauses, as a fraction: those the node
published (by its recording) neither late in a paced catch-up after its own stall nor while
this process took nothing for ``STARVED_NS``. Seen: none in 8 runs (six of them two copies
at once with ``--busy-cores 2``, load 8-9), where the subscriber missed up to 7 % of the
samples, each while it was behind or after the node published it late (up to 1.3 s: the
old judgement, by the lateness of the sample read after a hole, failed 2 runs in 2 at load
14 with 11-13 % lost "while it kept up"); a node publishing each 0.1 s batch late and back
to back loses 45 %."""
STARVED_NS = 4 * PERIOD_NS
"""A keep-last-5 reader that takes nothing for this long after the node published a sample
lets four more in on its history at the grid's pace: a sample it then misses is its own
loss (this test process starved on a busy machine; seen: 2.4 s at load 27), not the
node's. Judged from the missing sample's publication (the node's recording), not from the
lateness of the sample read after the hole: a reader back after a long stall reads first
the oldest of the five it kept, published four periods (16 ms) before the newest, and the
pacer's jitter put that on either side of 16 ms (seen: a 247 ms stall judged kept up)."""

ROTATION = [
    ('drift.forward_ppm', lambda i: [100.0 * (i % 3), -50.0, 20.0 * i % 200]),
    ('input.roll', lambda i: 0.01 * (i % 5)),
    ('temperature_c', lambda i: 20.0 + i % 10),
    ('drift.feedback_ppm', lambda i: [-30.0 * (i % 4), 60.0, 0.0]),
    ('frame_id', lambda i: f'imu_link_{i % 2}'),
    ('input.yaw', lambda i: 0.1 * (i % 7)),
]


class RawStamps:
    """Stamps and receive times of ``imu/data_raw`` as a SensorDataQoS subscriber sees them."""

    def __init__(self, client):
        self.stamps = []
        self.received = []
        client.node.create_subscription(Imu, 'imu/data_raw', self.callback,
                                        qos_profile_sensor_data, raw=True)

    def callback(self, data):
        self.received.append(time.time_ns())
        sec, nanosec = STAMP.unpack_from(data, 4)
        self.stamps.append(sec * 1_000_000_000 + nanosec)


def process_resources(client, pid, recordings, samples=3):
    """
    Return ``(descriptors, recording descriptors, threads)`` of process ``pid``.

    Descriptors other than the recording's, and threads, each the least of a few looks
    0.2 s apart: a split, a trace or a state write holds a file open for a moment. The
    client spins meanwhile (its subscriber keeps reading).
    """
    looks = []
    for _ in range(samples):
        targets = []
        for fd in os.listdir(f'/proc/{pid}/fd'):
            try:
                targets.append(os.readlink(f'/proc/{pid}/fd/{fd}'))
            except OSError:  # closed meanwhile
                pass
        # The bag directory itself is held open (locked) while it records: not a file.
        recording = sum(t.startswith(str(recordings)) and not os.path.isdir(t)
                        for t in targets)
        status = Path(f'/proc/{pid}/status').read_text()
        threads = int(status.split('Threads:')[1].split()[0])
        looks.append((len(targets) - recording, recording, threads))
        client.spin_for(0.2)
    return tuple(min(look[i] for look in looks) for i in range(3))


def gaps(stamps):
    """Return ``(before, after, missing)`` for every hole in sorted grid stamps."""
    stamps = np.asarray(stamps, dtype=np.int64)
    missing = np.diff(stamps) // PERIOD_NS - 1
    return [(int(stamps[i]), int(stamps[i + 1]), int(missing[i]))
            for i in np.flatnonzero(missing > 0)]


def inside(gap, windows):
    return any(gap[0] >= start - PAUSE_MARGIN_NS and gap[1] <= end + PAUSE_MARGIN_NS
               for start, end in windows)


def test_splits_parameter_changes_and_a_calibration_of_the_live_node(tmp_path):
    """
    Hold the soak's invariants over seconds of the live node.

    The node as a user runs it, recording split every second, a parameter change every 0.5 s,
    a capture and a self-calibration (fast mode), a SensorDataQoS subscriber in this
    process.

    Every stamp on the grid; every sample the node did not publish accounted for by its own
    counters (withheld during the schedules, skipped or dropped after a stall), none outside
    a schedule's pause otherwise; of the samples the subscriber missed outside pauses, those
    the node published on time while it kept reading within ``LOSS_BOUND``; descriptors and
    threads back to their level after the splits, no recording file held open but the
    current one; every split file within ``recorder.max_bytes``, readable by rosbags and
    the mcap reader with the counts metadata.yaml lists, no ``.part`` left; the state file
    readable.
    """
    domain = domain_id('short soak')
    out = tmp_path / 'out'
    recordings = out / 'recordings'
    client = Client(domain)
    received = RawStamps(client)
    node = NodeProcess(domain, tmp_path, {
        'sample_rate_hz': RATE, 'loop_rate_hz': 10 * RATE, 'output_dir': str(out),
        'state_file': str(out / 'state.json'), 'estimation.realtime': False,
        'recorder.enabled': True, 'recorder.max_duration_s': SPLIT_S,
        'recorder.max_bytes': MAX_BYTES})
    windows = []

    def schedule(name):
        sent = time.time_ns()
        response = client.call(Trigger, f'/{NODE}/{name}', Trigger.Request(), timeout=300)
        windows.append((sent, time.time_ns()))
        assert response.success, response.message

    try:
        client.spin_until(lambda: len(received.stamps) > 50, 120, 'the first samples')
        schedule('capture_reference')
        # The baseline once the recorder has split twice and every service has run once.
        client.spin_for(2 * SPLIT_S)
        baseline = process_resources(client, node.pid, recordings)
        files_at_baseline = len(list(recordings.glob('*/*.mcap')))
        started = time.monotonic()
        turn = 0
        calibrated = False
        while time.monotonic() - started < SOAK_S:
            name, value = ROTATION[turn % len(ROTATION)]
            result, = client.set_parameters({name: value(turn)})
            assert result.successful, f'{name}: {result.reason}'
            turn += 1
            if not calibrated and time.monotonic() - started > SOAK_S / 2:
                schedule('self_calibrate')
                calibrated = True
            client.spin_for(0.5)
        client.spin_for(3.0)
        after = process_resources(client, node.pid, recordings)
        splits = len(list(recordings.glob('*/*.mcap'))) - files_at_baseline
        assert node.stop() == 0
    finally:
        client.close()
        if node.process.poll() is None:
            node.stop(signal.SIGKILL)

    assert splits >= SOAK_S / SPLIT_S / 2, f'only {splits} splits'
    assert after[0] <= baseline[0] and after[2] <= baseline[2], (
        f'after {splits} splits, {turn} parameter changes and a calibration the node holds '
        f'{after[0]} descriptors and {after[2]} threads (before: {baseline[0]}, '
        f'{baseline[2]})')
    assert after[1] <= 1, f'{after[1]} recording files open'

    bag, = (p for p in recordings.iterdir() if p.is_dir())
    recorded, reports = read_recording(bag, MAX_BYTES)
    assert json.loads((out / 'state.json').read_text())['compensation_enabled'] is True
    published_at = assert_published_accounted(recorded, reports, windows)
    assert_subscriber_losses_bounded(received.stamps, received.received, published_at,
                                     windows)


KEEP = {'recorder.keep_bytes': 192 << 10}
"""Retention of the short days [bytes]: a few seconds of the 250 Hz recording."""
DAYS_S = 2.0
"""Node time of parameter changes in each run of the short days [s] (a change every 0.25 s)."""


def recorder_bytes(recordings):
    """Return ``(bytes of every MCAP file and part, the largest)`` in a recorder directory."""
    sizes = [stat.st_size for bag in bag_directories(recordings)
             for files in entries(bag) for stat in files.values()]
    return sum(sizes), max(sizes, default=0)


def test_a_kill_9_and_a_restart_keep_the_newest_recording_readable_and_bounded(tmp_path):
    """
    Days in seconds: a node that records and trims its recording, killed -9 and started again.

    The node as a user runs it, its recording split every second and its retention tiny
    (:data:`KEEP`), a capture, a self-calibration and a parameter change every 0.25 s; stopped
    the moment its recorder deletes a file, killed -9 and
    started again with the same parameters; its recovery at start finishes the killed run's
    recording; more parameter changes, then SIGTERM. A SensorDataQoS subscriber in this
    process throughout.

    After the restart: the files finished at the kill are all there but the oldest that
    retention deleted, every file readable as metadata.yaml lists it, and the killed run's
    recording holds every sample the subscriber had a second before the kill (the crash
    bound). Each run's recording accounted for by its own counters (nothing unpublished
    outside the schedules that the node did not count), the subscriber's losses within
    ``LOSS_BOUND`` where the recording tells what was published; at the end every bag and
    file readable, no ``.part``; the recorder directory never larger than the retention limit
    plus its largest file.
    """
    domain = domain_id('short days')
    out = tmp_path / 'out'
    recordings = out / 'recordings'
    parameters = {
        'sample_rate_hz': RATE, 'loop_rate_hz': 10 * RATE, 'output_dir': str(out),
        'state_file': str(out / 'state.json'), 'estimation.realtime': False,
        'recorder.enabled': True, 'recorder.max_duration_s': SPLIT_S,
        'recorder.max_bytes': MAX_BYTES, **KEEP}
    client = Client(domain)
    received = RawStamps(client)
    disk, windows, turns = [], [], [0]

    def schedule(name):
        sent = time.time_ns()
        response = client.call(Trigger, f'/{NODE}/{name}', Trigger.Request(), timeout=300)
        windows.append((sent, time.time_ns()))
        assert response.success, response.message

    def change_parameters(seconds):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            name, value = ROTATION[turns[0] % len(ROTATION)]
            result, = client.set_parameters({name: value(turns[0])})
            assert result.successful, f'{name}: {result.reason}'
            turns[0] += 1
            for _ in range(5):
                client.spin_for(0.05)
                disk.append(recorder_bytes(recordings))

    node = NodeProcess(domain, tmp_path / 'killed', parameters)
    try:
        client.spin_until(lambda: len(received.stamps) > 50, 120, 'the first samples')
        schedule('capture_reference')
        change_parameters(DAYS_S / 2)
        schedule('self_calibrate')
        change_parameters(DAYS_S / 2)
        # Stopped (SIGSTOP) in a thread the moment retention deletes a file, while this one
        # reads the stream: then SIGKILL, as a kill at that instant.
        stopped = []
        check = deletion_watch(recordings)
        watch = threading.Thread(target=lambda: stopped.append(
            stop_when(node.process, check, 60)))
        watch.start()
        client.spin_until(lambda: not watch.is_alive(), 120, 'a deletion')
        kill_ns, = stopped
        assert kill_ns, 'no deletion within 60 s'
        at_kill = [(bag.name, name) for bag in bag_directories(recordings)
                   for name in sorted(entries(bag)[0], key=split_index)]
        killed = live_bag(recordings) or bag_directories(recordings)[-1]
        os.kill(node.pid, signal.SIGKILL)
        assert node.wait(30) == -signal.SIGKILL

        restarted_ns = time.time_ns()
        node = NodeProcess(domain, tmp_path / 'restarted', parameters)
        client.spin_until(lambda: received.stamps[-1] >= restarted_ns, 120,
                          "the restarted node's first samples")
        client.spin_until(lambda: not needs_recovery(killed), 60,
                          "the recovery at start of the killed run's recording")
        present = {(bag.name, name) for bag in bag_directories(recordings)
                   for name in entries(bag)[0]}
        gone = [item for item in at_kill if item not in present]
        assert gone == at_kill[:len(gone)], (
            f'of the files finished at the kill, gone since: {gone}')
        first_run = read_recording(killed, MAX_BYTES)
        change_parameters(DAYS_S)
        assert node.stop() == 0
    finally:
        client.close()
        if node.process.poll() is None:
            node.stop(signal.SIGKILL)

    stamps = np.asarray(received.stamps, dtype=np.int64)
    receipts = np.asarray(received.received, dtype=np.int64)
    runs = {'killed': (first_run, stamps < kill_ns, windows),
            'restarted': (read_recording(bag_directories(recordings)[-1], MAX_BYTES),
                          stamps >= restarted_ns, [])}
    for run, ((recorded, reports), mine, pauses) in runs.items():
        assert len(recorded), f'nothing of the {run} run kept'
        published_at = assert_published_accounted(recorded, reports, pauses)
        assert_subscriber_losses_bounded(stamps[mine], receipts[mine], published_at, pauses)
    # The crash bound: what the subscriber had a second before the kill is recorded.
    kept = stamps[stamps < kill_ns] >= first_run[0][0, 0]
    judged = loss(first_run[0][:, 0], list(zip(stamps[stamps < kill_ns][kept].tolist(),
                                               receipts[stamps < kill_ns][kept].tolist())),
                  kill_ns)
    assert judged.missing_before_bound == 0, f'the kill lost more than its bound: {judged}'
    for bag in bag_directories(recordings):  # every bag left as its users read it
        read_recording(bag, MAX_BYTES)
    largest = max(size for _, size in disk)
    assert max(total for total, _ in disk) <= KEEP['recorder.keep_bytes'] + largest


SETTLE_TRIES = 20
"""Reads of a bag that a retention pass changed meanwhile, before one counts [number]."""


def bag_state(bag):
    """Return what a retention pass changes in ``bag``: its files and its listing's time."""
    names = sorted(path.name for path in bag.iterdir())
    return names, (bag / 'metadata.yaml').stat().st_mtime_ns if 'metadata.yaml' in names else 0


def read_recording(bag, max_bytes):
    """
    Read a bag directory back as its users would; return what the node published.

    A retention pass (after every split, and once the killed run is recovered) may delete
    files meanwhile: it rewrites ``metadata.yaml`` first, then unlinks the file and its
    ``.deleting`` marker. A read that fails while the bag changed, or with a marker there,
    is read again; one that fails on a bag left alone fails.

    Asserts that no ``.part`` is left, that ``metadata.yaml`` lists exactly the finished
    files, each within ``max_bytes`` and read by the mcap reader and ``AnyReader`` with the
    count it lists, and that ``AnyReader`` opens the whole bag with the total.

    Parameters
    ----------
    bag : pathlib.Path
        The bag directory.
    max_bytes : int
        ``recorder.max_bytes``.

    Returns
    -------
    tuple
        ``(recorded, reports)``: ``(stamp, log time)`` of every ``imu/data_raw`` sample
        [ns] (int64, shape (n, 2)) and the ``/diagnostics`` arrays, in recording order.
    """
    for attempt in range(SETTLE_TRIES):
        before = bag_state(bag)
        try:
            return read_recording_once(bag, max_bytes)
        except (AssertionError, FileNotFoundError):
            moving = before != bag_state(bag) or any(
                name.endswith(DELETION_SUFFIX) for name in before[0])
            if not moving or attempt == SETTLE_TRIES - 1:
                raise
            time.sleep(0.05)


def read_recording_once(bag, max_bytes):
    """Read ``bag`` once (:func:`read_recording`)."""
    assert not list(bag.glob('*.part'))
    listed = {Path(f['path']).name: f['message_count'] for f in yaml.safe_load(
        (bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']['files']}
    files = sorted(bag.glob('*.mcap'), key=lambda p: int(p.stem.rsplit('_', 1)[1]))
    assert [f.name for f in files] == list(listed)
    recorded, reports = [], []
    for file in files:
        assert file.stat().st_size <= max_bytes
        with open(file, 'rb') as stream:
            messages = list(make_reader(stream).iter_messages())
        with AnyReader([file]) as reader:
            assert sum(1 for _ in reader.messages()) == len(messages) == listed[file.name]
        for _, channel, message in messages:
            if channel.topic == '/imu/data_raw':
                sec, nanosec = STAMP.unpack_from(message.data, 4)
                recorded.append((sec * 1_000_000_000 + nanosec, message.log_time))
            elif channel.topic == '/diagnostics':
                reports.append(deserialize_message(message.data, DiagnosticArray))
    if files:
        with AnyReader([bag]) as reader:
            assert sum(1 for _ in reader.messages()) == sum(listed.values())
    return np.asarray(recorded, dtype=np.int64).reshape(-1, 2), reports


def assert_published_accounted(recorded, reports, windows):
    """
    Hold what the node published (its recording) against its own counters.

    On the grid and continuous across the splits; each hole accounted for by the node's
    counters, and outside a schedule's pause only if the node said it skipped or dropped
    samples. The counters are those of the last diagnostics recorded, up to the last sample
    published before they were read: the pacer publishes in stamp order, so every sample
    before it was decided by then.

    Parameters
    ----------
    recorded : numpy.ndarray
        ``(stamp, log time)`` of the recorded samples [ns] (:func:`read_recording`).
    reports : list of diagnostic_msgs.msg.DiagnosticArray
        The diagnostics recorded with them.
    windows : list of tuple
        ``(sent, answered)`` of the schedule calls [ns].

    Returns
    -------
    dict
        ``{stamp: log time}``: when the node published each sample [ns].
    """
    recorded = np.asarray(recorded, dtype=np.int64)
    stamps = recorded[:, 0]
    assert np.all(np.diff(stamps) > 0) and np.all(np.diff(stamps) % PERIOD_NS == 0)
    report = reports[-1]
    counters = {kv.key: kv.value for kv in next(
        s for s in report.status if s.name.endswith(': stream')).values}
    read_ns = report.header.stamp.sec * 1_000_000_000 + report.header.stamp.nanosec
    decided = stamps[recorded[:, 1] <= read_ns].max()
    holes = [h for h in gaps(stamps) if h[1] <= decided]
    withheld = int(counters['samples withheld'])
    unpublished = int(counters['samples skipped']) + int(
        next(v for k, v in counters.items() if k.startswith('messages dropped')))
    missing = sum(h[2] for h in holes)
    assert missing <= withheld + unpublished, (
        f'{missing} samples missing from the recording; the node accounts for {withheld} '
        f'withheld and {unpublished} skipped or dropped; holes (s after the first sample, '
        f'samples): {[((h[0] - stamps[0]) / 1e9, h[2]) for h in holes][:10]}')
    # A fast schedule withholds the samples that fall due while it computes, beyond those
    # computed ahead before it began (stream.lead_s): one computed within that lead
    # withholds none and leaves no hole (docs/node.md, Estimation schedules; seen: a
    # self-calibration answered in 84 ms). So no count is promised, but every sample
    # withheld is a hole in a pause, and every hole in a pause one withheld (or dropped).
    # A recording retention trimmed lacks the holes of the pauses before its first sample:
    # the node's count of what it withheld then bounds the visible holes from above only.
    paused = sum(h[2] for h in holes if inside(h, windows))
    trimmed = any(sent < stamps[0] for sent, _ in windows)
    assert (trimmed or withheld <= paused) and paused <= withheld + unpublished, (
        f'{paused} samples missing from the recording during the schedules, {withheld} '
        f'withheld by the node ({unpublished} skipped or dropped); pauses (s after the first '
        f'sample): {[((a - stamps[0]) / 1e9, (b - stamps[0]) / 1e9) for a, b in windows]}')
    outside = missing - paused
    assert outside <= unpublished, f'{outside} samples never published outside the pauses'
    # The node's account of lateness, which the subscriber's losses below rely on.
    late_key = f'messages published > {LATE_NS / 1e6:g} ms late'
    published_late = np.count_nonzero((recorded[:, 1] - stamps > LATE_NS)
                                      & (recorded[:, 1] <= read_ns))
    assert published_late <= int(counters[late_key]), (
        f'{published_late} samples recorded as published more than {LATE_NS / 1e6:g} ms '
        f'late, the node counts {counters[late_key]}')
    return dict(zip(stamps.tolist(), recorded[:, 1].tolist()))


def assert_subscriber_losses_bounded(stamps, receipts, published_at, windows):
    """
    Hold what the SensorDataQoS subscriber saw against what the node published.

    On the grid. Each sample it missed outside the pauses is one the node never published
    (accounted for by :func:`assert_published_accounted`), one it published late in a
    catch-up after its own stall (counted by the node; paced: ``CATCH_UP_BURST`` back to
    back, then a spacing, which its recording shows), one published while this process
    took nothing for ``STARVED_NS`` after (its own loss), or lost: within ``LOSS_BOUND``.

    Parameters
    ----------
    stamps, receipts : sequence of int
        The stamps of one node's samples as the subscriber received them and when [ns].
    published_at : dict
        ``{stamp: log time}`` of that node's recording [ns]: the samples from its first to
        its last are judged (those of files deleted by retention are not).
    windows : list of tuple
        ``(sent, answered)`` of the schedule calls [ns].
    """
    stamps = np.asarray(stamps, dtype=np.int64)
    assert np.all((stamps - stamps[0]) % PERIOD_NS == 0)
    unique, first = np.unique(stamps, return_index=True)
    read_at = dict(zip(unique.tolist(), np.asarray(receipts)[first].tolist()))
    unique = unique[(unique >= min(published_at)) & (unique <= max(published_at))]
    missed = {'not published': 0, 'published late': 0, 'while behind': 0, 'lost': 0}
    lost_holes = []
    for before, after, count in gaps(unique):
        if inside((before, after, count), windows):
            continue
        lost = 0
        for stamp in range(before + PERIOD_NS, after, PERIOD_NS):
            sent = published_at.get(stamp)
            if sent is None:
                missed['not published'] += 1
            elif sent - stamp > LATE_NS and sent - published_at.get(
                    stamp - (CATCH_UP_BURST + 1) * PERIOD_NS, 0) >= CATCH_UP_SPACING_NS:
                missed['published late'] += 1
            elif read_at[after] - sent >= STARVED_NS:
                missed['while behind'] += 1
            else:
                lost += 1
        if lost:
            missed['lost'] += lost
            lost_holes.append(((before - unique[0]) / 1e9, count, lost,
                               (read_at[after] - read_at[before]) / 1e6))
    span = (unique[-1] - unique[0]) // PERIOD_NS
    assert missed['lost'] <= LOSS_BOUND * span, (
        f'{missed["lost"]} of {span} samples lost outside the pauses, neither in a paced '
        f'catch-up nor while the subscriber was behind; missed in all: {missed}; the largest '
        f'holes (s after the first sample, samples missing, of them lost, ms between the '
        f'reads around it): {sorted(lost_holes, key=lambda h: -h[2])[:8]}')
