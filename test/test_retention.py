"""Retention of the flight recorder: the oldest finished files go first, only the recorder's.

Driven through :class:`~qfa_ros.bag.retention.Retention` and the
:class:`~qfa_ros.bag.flight_recorder.FlightRecorder` with 1 s splits of a 100 Hz IMU stream
(small files, no node), every bag read back by ``rosbags`` and the mcap seeking reader
(``crash_helpers.read_bag``). A writer killed with SIGKILL inside deletions, the free-space
floor behind retention, and one short node run with a stranger on the domain close it.
"""

import fcntl
import hashlib
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
from types import SimpleNamespace

from crash_helpers import (
    ENCODER,
    feed_imu,
    IMU_TOPIC,
    killed_recording,
    read_bag,
    read_mcap,
    recorded_session,
    ROOT,
    run_stopped,
    SECOND,
    SESSION_RATE,
    SESSION_T0,
    stop_when,
)
from diagnostic_msgs.msg import DiagnosticArray
from mcap.writer import Writer
from node_helpers import Client, domain_id, NodeProcess, RecordingNode
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
import yaml

from qfa_ros.bag import part_files
from qfa_ros.bag.part_files import delete_finished_file, DELETION_SUFFIX
from qfa_ros.bag.recovery import needs_recovery, recover
from qfa_ros.bag.retention import Retention, spans_ns
from qfa_ros.ros import recording as recording_module
from qfa_ros.ros.parameter_table import PARAMETERS
from qfa_ros.ros.recording import FreeSpaceGuard, GUARD_BAND_BYTES, StreamRecording


def listed(bag):
    """Return the file names ``metadata.yaml`` of ``bag`` lists."""
    document = yaml.safe_load((bag / 'metadata.yaml').read_text())
    return document['rosbag2_bagfile_information']['relative_file_paths']


def assert_whole(bag):
    """Check that ``bag`` lists exactly its finished files and reads in full (two readers)."""
    finished = sorted(path.name for path in bag.glob('*.mcap'))
    assert sorted(listed(bag)) == finished
    assert not list(bag.glob(f'*{DELETION_SUFFIX}'))
    return read_bag(bag)


def digests(paths):
    return {path: hashlib.sha256(path.read_bytes()).hexdigest() for path in paths}


def test_by_duration_the_oldest_go_first_earlier_sessions_included(tmp_path):
    first = recorded_session(tmp_path, 0, 3.5).bag_directory
    second = recorded_session(tmp_path, 100, 3.5).bag_directory
    live = recorded_session(tmp_path, 300, 4.5, close=False)
    retention = Retention(tmp_path, 'qfa_node', int(5.5 * SECOND), 0)
    summary = retention.apply(live)
    # Newest first: the live bag's four finished files (1 s each, to the next file's
    # start), then the second recorded_session's last (0.49 s), third and second (1 s each): 6.49 s
    # reaches 5.5 s. The first session goes whole (its directory too), then one file.
    assert not first.exists()
    assert sorted(listed(second)) == [f'{second.name}_{i}.mcap' for i in (1, 2, 3)]
    contents = assert_whole(second)
    assert contents.imu_stamps[0] == SESSION_T0 + 101 * SECOND
    assert len(contents.imu_stamps) == 250
    assert len(listed(live.bag_directory)) == 4 and live.current_path.with_suffix(
        '.mcap.part').exists()
    assert (summary.deleted, summary.kept) == (5, 7)
    assert summary.oldest_kept_ns == SESSION_T0 + 101 * SECOND
    assert summary.kept_ns == pytest.approx(6.49 * SECOND, abs=1)
    with AnyReader([live.bag_directory]) as reader:  # the live bag, as it is
        assert reader.message_count == 400
    # Within the limit: nothing more goes.
    assert retention.apply(live).deleted == 5
    live.close()
    assert len(assert_whole(live.bag_directory).imu_stamps) == 450


def test_a_file_with_no_message_covers_nothing_and_does_not_cut_the_one_before():
    # A kill right after a split leaves a part with no message; recovered, it is listed
    # with start 0 (as rosbag2 lists an empty file).
    entries = [('a', 10 * SECOND, SECOND - 1_000_000, 1000),
               ('b', 11 * SECOND, SECOND - 1_000_000, 1000), ('c', 0, 0, 0)]
    np.testing.assert_array_equal(spans_ns(entries), [SECOND, SECOND - 1_000_000, 0])
    np.testing.assert_array_equal(spans_ns(entries, 12 * SECOND), [SECOND, SECOND, 0])


def test_by_size_never_the_file_being_written(tmp_path):
    live = recorded_session(tmp_path, 0, 6.5, close=False)
    bag = live.bag_directory
    sizes = [(bag / name).stat().st_size for name in listed(bag)]
    assert len(sizes) == 6
    summary = Retention(tmp_path, 'qfa_node', 0, sizes[-1] + sizes[-2]).apply(live)
    assert listed(bag) == [f'{bag.name}_{i}.mcap' for i in (4, 5)]
    assert summary.kept_bytes == sizes[-1] + sizes[-2] and summary.deleted == 4
    # One byte: every finished file goes, the one being written stays and goes on.
    current = live.current_path
    assert Retention(tmp_path, 'qfa_node', 0, 1).apply(live).kept == 0
    assert listed(bag) == [] and Path(f'{current}.part').exists()
    assert not live.delete_finished(current.name)
    feed_imu(live, SESSION_T0 + int(6.5 * SECOND), 1.0)
    live.close()
    contents = assert_whole(bag)
    assert contents.imu_stamps[0] == SESSION_T0 + 6 * SECOND
    assert len(contents.imu_stamps) == 150


def foreign_mcap(path):
    """Write an MCAP file another program wrote (its own library in the header)."""
    with open(path, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='someone else')
        writer.finish()


def test_strangers_files_and_what_lies_outside_are_never_touched(tmp_path):
    recordings, outside = tmp_path / 'recordings', tmp_path / 'outside'
    recordings.mkdir()
    outside.mkdir()
    ours = [recorded_session(recordings, start, 2.5).bag_directory for start in (0, 100, 200)]
    other = recorded_session(recordings, 50, 2.5, prefix='other_node').bag_directory
    linked = recorded_session(outside, -100, 2.5).bag_directory  # ours, but outside
    (recordings / linked.name).symlink_to(linked, target_is_directory=True)
    stranger = recordings / 'stranger.mcap'
    stranger.write_bytes((ours[0] / listed(ours[0])[0]).read_bytes())
    notes = ours[1] / 'notes.txt'
    notes.write_text("a stranger's notes\n")
    copy = ours[1] / 'copy.mcap'
    copy.write_bytes(stranger.read_bytes())
    # Another program's files named as the recorder names them, as old as its own: one
    # unlisted, one in place of a listed file.
    unlisted = ours[1] / f'{ours[1].name}_9.mcap'
    impostor = ours[2] / listed(ours[2])[0]
    for path, bag in ((unlisted, ours[1]), (impostor, ours[2])):
        foreign_mcap(path)
        stamp = (bag / 'metadata.yaml').stat().st_mtime_ns
        os.utime(path, ns=(stamp, stamp))
    watched = [stranger, notes, copy, unlisted, impostor, *other.iterdir(),
               *linked.iterdir()]
    before = digests(watched)
    live = recorded_session(recordings, 300, 2.5, close=False)

    retention = Retention(recordings, 'qfa_node', 0, 1)
    summary = retention.apply(live)
    assert 'not recognised as a recording' in summary.problem
    summary = retention.apply(live)  # the impostor no longer counted: the rest go
    assert digests(watched) == before
    assert (recordings / linked.name).is_symlink() and len(listed(linked)) == 3
    assert not ours[0].exists()
    assert sorted(p.name for p in ours[1].iterdir()) == sorted(
        ['metadata.yaml', notes.name, copy.name, unlisted.name])
    assert listed(ours[1]) == []
    assert listed(ours[2]) == [impostor.name]
    assert listed(live.bag_directory) == [] and summary.kept == 0
    assert summary.deleted == 3 + 3 + 2 + 2
    live.close()


def test_a_bag_in_use_holds_back_everything_newer(tmp_path):
    first = recorded_session(tmp_path, 0, 2.5).bag_directory
    second = recorded_session(tmp_path, 100, 2.5).bag_directory
    live = recorded_session(tmp_path, 200, 2.5, close=False)
    descriptor = os.open(first, os.O_RDONLY | os.O_DIRECTORY)
    fcntl.flock(descriptor, fcntl.LOCK_EX)  # a recovery, or another process recording
    try:
        summary = Retention(tmp_path, 'qfa_node', 0, 1).apply(live)
        assert summary.deleted == 0 and 'in use' in summary.problem
        assert len(listed(second)) == 3 and len(listed(live.bag_directory)) == 2
    finally:
        os.close(descriptor)
    summary = Retention(tmp_path, 'qfa_node', 0, 1).apply(live)
    assert summary.deleted == 3 + 3 + 2 and not first.exists() and not second.exists()
    live.close()


class CutError(Exception):
    """Where a deletion is cut short (a kill there leaves what is on disk at that point)."""


@pytest.mark.parametrize('stage', ['marked', 'unlisted', 'unlinked'])
def test_a_deletion_cut_short_leaves_the_bag_readable_and_recovery_finishes_it(
        tmp_path, monkeypatch, stage):
    bag = recorded_session(tmp_path, 0, 3.5).bag_directory
    victim = listed(bag)[0]
    finish = part_files.finish_deletion

    def unlist():
        if stage == 'marked':
            raise CutError
        document = yaml.safe_load((bag / 'metadata.yaml').read_text())
        information = document['rosbag2_bagfile_information']
        from qfa_ros.bag.bag_directory import BagMetadata
        from qfa_ros.bag.part_repair import finished_file_metadata
        kept = BagMetadata.from_mapping(information)
        kept.remove(victim, finished_file_metadata(bag / victim))
        kept.write(bag)

    def finish_deletion(descriptor, marker):
        if stage == 'unlinked':
            os.unlink(marker[:-len(DELETION_SUFFIX)], dir_fd=descriptor)
        raise CutError

    monkeypatch.setattr(part_files, 'finish_deletion', finish_deletion)
    descriptor = os.open(bag, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    try:
        with pytest.raises(CutError):
            delete_finished_file(descriptor, victim, unlist)
    finally:
        os.close(descriptor)
    monkeypatch.setattr(part_files, 'finish_deletion', finish)
    # As it is: what metadata.yaml lists is there and complete; every file reads.
    assert set(listed(bag)) <= {path.name for path in bag.glob('*.mcap')}
    with AnyReader([bag]) as reader:
        assert reader.message_count == (350 if stage == 'marked' else 250)
    for path in bag.glob('*.mcap'):
        read_mcap(path)
    assert needs_recovery(bag)
    result, = recover(bag)
    assert result.status == 'recovered' and 'finished deleting 1 file' in result.describe()
    assert not (bag / victim).exists()
    assert len(assert_whole(bag).imu_stamps) == 250
    assert not needs_recovery(bag)


DELETING_WRITER = textwrap.dedent("""
    import os, sys
    sys.path.insert(0, 'test')
    from crash_helpers import feed_imu, recorded_session, SECOND, SESSION_T0
    from qfa_ros.bag.retention import Retention, spans_ns
    directory = sys.argv[1]
    for start in (0, 100):
        recorded_session(directory, start, 6.5)
    live = recorded_session(directory, 300, 1.5, close=False)
    retention = Retention(directory, 'qfa_node', 3 * SECOND, 0)
    print('ready', flush=True)
    for second in range(2, 1000):
        feed_imu(live, SESSION_T0 + (300 + second) * SECOND, 1.0)  # one more file finished
        retention.apply(live)  # deletes the oldest: an earlier session's, or the live bag's
""")


def test_kill_9_inside_deletions_leaves_every_recording_readable(tmp_path):
    rng = np.random.default_rng(55)
    inside = 0
    for attempt in range(6):
        directory = tmp_path / str(attempt)
        directory.mkdir()
        process = subprocess.Popen([sys.executable, '-c', DELETING_WRITER, str(directory)],
                                   cwd=ROOT, stdout=subprocess.PIPE, text=True)
        try:
            assert process.stdout.readline() == 'ready\n'
            # Stopped the moment a deletion marker appears, then let run a random number
            # of 0.5 ms slices: the kill lands inside a deletion or just after it.
            stopped = stop_when(process, lambda: any(directory.glob(f'*/*{DELETION_SUFFIX}')),
                                60, poll_s=0.0)
            assert stopped, 'no deletion seen'
            slices = iter(range(int(rng.integers(0, 8))))
            run_stopped(process, stopped, lambda: next(slices, None) is None, step_s=0.0005)
            inside += any(directory.glob(f'*/*{DELETION_SUFFIX}'))
        finally:
            process.send_signal(signal.SIGKILL)
            process.communicate(timeout=60)
        bags = sorted(directory.iterdir())
        # As the kill left it: every bag opens in full as listed, every file reads.
        for bag in bags:
            assert set(listed(bag)) <= {path.name for path in bag.glob('*.mcap')}, bag
            with AnyReader([bag]) as reader:
                assert reader.message_count >= 0
            for path in bag.glob('*.mcap'):
                read_mcap(path)
        # Recovered as the node does at start (qfa-report recover): every bag true to its
        # files, the newest recording whole and nothing of it lost.
        recover(directory)
        stamps = np.concatenate([assert_whole(bag).imu_stamps for bag in bags])
        newest = stamps[stamps >= SESSION_T0 + 300 * SECOND]
        assert np.array_equal(newest, SESSION_T0 + 300 * SECOND + np.arange(len(newest))
                              * (SECOND // SESSION_RATE))
        assert len(newest) >= 150
    assert inside >= 2, f'only {inside} of 6 kills inside a deletion'


class ShrinkingDisk:
    """
    ``shutil.disk_usage`` of a disk ``room`` bytes above the floor less what ``directory`` holds.

    Deleting recordings frees space.
    """

    def __init__(self, directory, floor, room):
        self.directory, self.free_at_start = directory, floor + GUARD_BAND_BYTES + room

    def __call__(self, path):
        used = sum(p.stat().st_size for p in Path(self.directory).rglob('*') if p.is_file())
        return SimpleNamespace(total=1 << 40, used=used, free=self.free_at_start - used)


@pytest.mark.parametrize('keep_files, stops', [(3, False), (10, True)])
def test_the_free_space_floor_comes_after_retention(tmp_path, monkeypatch, keep_files, stops):
    # Room for 8 files above the floor: retention keeping 3 makes room when the floor is
    # near; keeping 10 it deletes nothing (its limit is not passed), and the floor stops
    # the recording instead of retention deleting beyond its limit. Only the pass the
    # floor runs: the passes after each file (a thread's) are left out.
    monkeypatch.setattr(recording_module, 'FREE_SPACE_CHECK_S', 0.0)
    monkeypatch.setattr(StreamRecording, '_retain_soon', lambda self: None)
    file_bytes = 20_000
    values = {spec.name: spec.default for spec in PARAMETERS}
    values.update({'output_dir': str(tmp_path), 'recorder.enabled': True,
                   'recorder.max_bytes': file_bytes, 'recorder.keep_s': 0.0,
                   'recorder.keep_bytes': keep_files * file_bytes})
    floor = 1 << 30
    recording = StreamRecording(RecordingNode(), values, {}, FreeSpaceGuard(
        floor, ShrinkingDisk(tmp_path / 'recordings', floor, 8 * file_bytes)))
    recording.restart()
    data = ENCODER.encode(np.array([SESSION_T0]), np.array([[0.0, 0.0, 9.81]]))[0]
    for index in range(40 * file_bytes // len(data)):  # 40 files' worth
        recording.record(IMU_TOPIC, 'sensor_msgs/msg/Imu', data,
                         SESSION_T0 + index * SECOND // SESSION_RATE)
        if not recording.active:
            break
    stopped, problem = not recording.active, recording.problem
    recording.close()
    # The passes after the last files (on their thread, or the next start's), done here.
    summary = recording.retention.apply()
    kept = sum(path.stat().st_size for path in (tmp_path / 'recordings').rglob('*.mcap'))
    assert stopped == stops and ('min_free_bytes' in (problem or '')) == stops, problem
    if stops:
        assert summary.deleted == 0 and kept > 6 * file_bytes
    else:
        assert summary.deleted_bytes + kept > 8 * file_bytes  # more than the room
        assert kept == summary.kept_bytes <= keep_files * file_bytes
    for bag in (tmp_path / 'recordings').iterdir():
        assert_whole(bag)


def test_the_node_keeps_its_limits_over_restarts_and_from_strangers(tmp_path):
    output = tmp_path / 'output'
    recordings = output / 'recordings'
    recordings.mkdir(parents=True)
    earlier = recorded_session(recordings, 0, 3.5).bag_directory  # an earlier run of this node
    stranger = recordings / 'notes.txt'
    stranger.write_text("not the recorder's\n")
    domain = domain_id('retention')
    node = NodeProcess(domain, tmp_path, {
        'output_dir': str(output), 'state_file': '', 'recorder.enabled': True,
        'recorder.max_duration_s': 1.0, 'recorder.keep_s': 3.0, 'diagnostics_rate_hz': 10.0})
    client = Client(domain)
    try:
        statuses = []
        client.subscribe(DiagnosticArray, '/diagnostics', lambda message: statuses.extend(
            {v.key: v.value for v in status.values} for status in message.status
            if status.name.endswith(': stream')), depth=50)

        def deleted():
            return statuses and int(statuses[-1].get('retention deleted', '0').split()[0]) >= 6
        client.spin_until(deleted, 60.0, 'the earlier run and a file of this one deleted')
        assert not earlier.exists() and stranger.read_text() == "not the recorder's\n"
        assert 'keeps 3 s of recording' in statuses[-1]['retention']
        assert 'since 20' in statuses[-1]['retention kept']
        for name, value in (('recorder.keep_s', 0.0), ('recorder.keep_bytes', 1)):
            result, = client.set_parameters({name: value})
            assert not result.successful and name in result.reason
        # Moved elsewhere by a participant: recorded there, nothing deleted there.
        result, = client.set_parameters({'recorder.directory': 'elsewhere'})
        assert result.successful, result.reason
        count = len(statuses)
        client.spin_until(lambda: len(statuses) > count + 2, 30.0, 'diagnostics')
        assert 'not the one the node started with' in statuses[-1]['retention']
    finally:
        client.close()
        assert node.stop() == 0, node.log()[-2000:]
    for bag in recordings.iterdir():
        if bag.is_dir():
            assert_whole(bag)


def test_a_killed_run_is_trimmed_once_recovered_not_at_the_next_split(tmp_path):
    output = tmp_path / 'output'
    recordings = output / 'recordings'
    recordings.mkdir(parents=True)
    # An earlier run killed: 3 s in 1 s files, its last one a .part, until recovered it
    # holds retention back.
    killed = killed_recording(recordings, 3000, split_s=1.0)
    oldest = min(killed.glob('*.mcap'), key=lambda path: path.stat().st_mtime_ns)
    domain = domain_id('retention_recovered')
    # No split comes in the test (600 s): only the recovery can have the pass run.
    node = NodeProcess(domain, tmp_path, {
        'output_dir': str(output), 'state_file': '', 'recorder.enabled': True,
        'recorder.max_duration_s': 600.0, 'recorder.keep_s': 1.0})
    client = Client(domain)
    try:
        client.spin_until(lambda: not oldest.exists(), 60.0, 'the killed run trimmed')
        assert not list(killed.glob('*.part'))
    finally:
        client.close()
        assert node.stop() == 0, node.log()[-2000:]
    assert_whole(killed)
