"""
Nothing grows or drifts while the node runs: the soak's invariants over a minute (issue 35).

``bench/soak.py`` runs the node for hours and fits slopes; these tests hold what a minute
can: the recorder's memory per split, and a real node splitting its recording every few
seconds while parameters change and a self-calibration runs, seen by a ``SensorDataQoS``
subscriber in another process.
"""

import gc
import sys
import time
import types

from qfa_ros.bag.flight_recorder import FlightRecorder
from qfa_ros.bag.qos import QOS_LATCHED, QosProfile
from qfa_ros.bag.types import encode_message
from qfa_ros.model.triad import NS_PER_S
from qfa_ros.ros.pacing import Pacer

T0 = 1_700_000_000_000_000_000

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
