"""What a kill leaves, recovered: ``qfa-report recover`` and :mod:`qfa_ros.bag.recovery`.

A recording killed mid-file (a process ending with ``os._exit``, as SIGKILL leaves it)
is cut at every kind of place and recovered; the result is read back by ``rosbags`` and
the mcap seeking reader and must hold every message of every complete chunk, which the
plain mcap streaming reader of the cut ``.part`` names independently. The node's own
kills are in ``test_crash_recording.py``.
"""

import hashlib
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import textwrap
import time

from crash_helpers import (
    IMU_TOPIC,
    killed_recording,
    part_messages,
    read_bag,
    read_mcap,
    ROOT,
    STAMP,
    stop_when,
)
import numpy as np
import pytest

from qfa_ros.bag.flight_recorder import FlightRecorder
from qfa_ros.bag.part_repair import recover_part
from qfa_ros.bag.recovery import (
    needs_recovery,
    recover,
    recover_bag_directory,
    recover_trace,
    unfinished_recordings,
    unfinished_traces,
)
from qfa_ros.bag.types import encode_message
from qfa_ros.bag.writer import McapBagWriter
from qfa_ros.cli.report import main as report_main


@pytest.fixture(scope='module')
def killed(tmp_path_factory):
    """Return a bag killed in its fourth file: three finished 1 s files, a .part of 0.5 s."""
    return killed_recording(tmp_path_factory.mktemp('killed'), 3500, split_s=1.0)


def _digests(directory):
    return {path.name: hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(Path(directory).iterdir())}


def _part_stamps(part):
    """Return the stamps a plain streaming read of a .part finds (CRC-checked chunks)."""
    return [sum(x * m for x, m in zip(STAMP.unpack_from(message.data, 4), (10**9, 1)))
            for channel, message in part_messages(part) if channel.topic == IMU_TOPIC]


def _chunk_ends(part):
    """Offsets right after each record of a .part (the places a write can stop)."""
    data = Path(part).read_bytes()
    offset, ends = 8, []
    while offset + 9 <= len(data):
        offset += 9 + int.from_bytes(data[offset + 1:offset + 9], 'little')
        if offset <= len(data):
            ends.append(offset)
    return ends


def test_every_cut_of_a_killed_recording_recovers_every_complete_chunk(tmp_path, killed):
    part, = killed.glob('*.part')
    finished = sorted(killed.glob('*.mcap'))
    assert [p.name[-7:] for p in finished] == ['_0.mcap', '_1.mcap', '_2.mcap']
    before = []
    for path in finished:
        before += read_mcap(path)
    size = part.stat().st_size
    ends = _chunk_ends(part)
    rng = np.random.default_rng(35)
    # A kill stops a write anywhere: in the header, on a record boundary, one byte either
    # side of it, inside a chunk; a power cut leaves zeros where the pages never landed.
    cuts = [0, 5, 20, ends[1], ends[-2] - 1, ends[-2], ends[-1] - 1, ends[-1],
            *rng.integers(30, size, 2)]
    plain = {}  # cut: digests of the bag recovered from the plain cut
    for index, cut in enumerate(sorted({int(c) for c in cuts if c <= size})):
        for zeros in (False, True):
            if zeros and cut == size:
                continue  # nothing left to zero: the same bytes as the plain cut
            bag = tmp_path / f'{index}_{zeros}' / killed.name
            shutil.copytree(killed, bag)
            copy = bag / part.name
            data = copy.read_bytes()
            copy.write_bytes(data[:cut] + (bytes(size - cut) if zeros else b''))
            if not zeros:
                expected = before + (_part_stamps(copy) if cut >= 8 else [])

            result, = recover(bag)
            assert result.status == 'recovered', result.describe()
            assert not list(bag.glob('*.part')), result.describe()
            assert not needs_recovery(bag)
            digests = _digests(bag)
            if zeros:
                # Zeros where the pages never landed recover to the very bag the plain cut
                # of the same length does (read back in full just before).
                assert digests == plain[cut], (cut, zeros)
            else:
                contents = read_bag(bag)
                assert contents.imu_stamps.tolist() == expected, (cut, zeros)
                assert contents.files == 4
                plain[cut] = digests
            again, = recover(bag)
            assert again.status == 'nothing to recover'
            assert _digests(bag) == digests, 'a second recovery changed something'
    # Nothing lost when the file was cut after its last complete chunk: all 3500 samples.
    assert len(expected) <= 3500


RECOVER_SCRIPT = textwrap.dedent("""
    import sys, time
    from qfa_ros.bag.recovery import recover
    print('ready', flush=True)
    started = time.perf_counter()
    recover(sys.argv[1])
    print(time.perf_counter() - started, flush=True)
""")


def test_a_recovery_killed_half_way_is_finished_by_the_next(tmp_path, killed):
    reference = tmp_path / 'reference' / killed.name
    shutil.copytree(killed, reference)
    part, = reference.glob('*.part')
    final = part.with_name(part.name[:-len('.part')])
    original = part.read_bytes()
    recover(reference)
    finished = final.read_bytes()
    assert finished[:len(MAGIC)] == MAGIC and finished[-len(MAGIC):] == MAGIC
    # Where the kept data ends: the finished file starts with the same bytes.
    data_end = next((i for i in range(min(len(original), len(finished)))
                     if original[i] != finished[i]), min(len(original), len(finished)))

    def state(name, part_bytes=None, link=False, leftover=False):
        bag = tmp_path / name / killed.name
        shutil.copytree(killed, bag)
        if part_bytes is not None:
            (bag / part.name).write_bytes(part_bytes)
        if link:  # killed between the link to the final name and the unlink of the part
            (bag / part.name).write_bytes(finished)
            os.link(bag / part.name, bag / final.name)
        if leftover:  # killed while metadata.yaml was being replaced
            (bag / '.metadata.yaml.123.tmp').write_text('rosbag2_bagfile_information: {')
        return bag

    bags = [state(f'tail_{k}', finished[:data_end + k]) for k in (0, 9, 100, 1000)]
    bags += [state('complete_part', finished), state('linked', link=True),
             state('leftover', leftover=True)]
    stamps = read_bag(reference).imu_stamps.tolist()
    assert len(stamps) == 3500
    reference_digests = _digests(reference)
    for bag in bags:
        result, = recover(bag)
        assert result.status == 'recovered', result.describe()
        assert (bag / final.name).read_bytes() == finished, bag.parent.name
        # The very bag the uninterrupted recovery left, metadata.yaml included (read back
        # in full above): byte for byte.
        assert _digests(bag) == reference_digests, bag.parent.name



def test_a_recovery_killed_at_random_instants_is_finished_by_the_next(tmp_path):
    killed = killed_recording(tmp_path, 10000)  # one .part of 10 s at 1 kHz
    part, = killed.glob('*.part')
    reference = tmp_path / 'reference' / killed.name
    shutil.copytree(killed, reference)
    # How long a recovery takes, timed here (as RECOVER_SCRIPT times it, after the imports):
    # the kills below land at random instants within it.
    started = time.perf_counter()
    recover(reference)
    duration = time.perf_counter() - started
    finished = (reference / part.name[:-len('.part')]).read_bytes()
    rng = np.random.default_rng(11)
    final = part.name[:-len('.part')]
    # Two kills at random instants, and one the moment the final name appears: a file
    # published before it is complete would be caught there. The kills at fixed states
    # (a tail of the finished file, a complete part, linked, a metadata leftover) are in
    # test_a_recovery_killed_half_way_is_finished_by_the_next.
    for attempt in range(3):
        bag = tmp_path / str(attempt) / killed.name
        shutil.copytree(killed, bag)
        process = subprocess.Popen([sys.executable, '-c', RECOVER_SCRIPT, str(bag)],
                                   cwd=ROOT, stdout=subprocess.PIPE, text=True)
        assert process.stdout.readline() == 'ready\n'
        if attempt < 2:
            time.sleep(rng.uniform(0.0, 1.0) * duration)
        else:
            assert stop_when(process, (bag / final).exists, 60, poll_s=0.0)
        process.send_signal(signal.SIGKILL)
        process.communicate(timeout=60)
        recover(bag)
        assert (bag / final).read_bytes() == finished, attempt
        assert not needs_recovery(bag)
    assert len(read_bag(reference).imu_stamps) == 10000


MAGIC = b'\x89MCAP0\r\n'


def test_what_a_live_writer_writes_is_left_alone(tmp_path):
    data = encode_message({'data': 'x' * 50}, 'std_msgs/msg/String')
    with FlightRecorder(tmp_path, 'qfa_node', max_duration_ns=10**9) as recorder:
        for index in range(2500):
            recorder.record('/s', 'std_msgs/msg/String', data, 10**18 + index * 10**6)
        recorder.flush()
        bag = recorder.bag_directory
        assert needs_recovery(bag)  # a .part: it looks unfinished, but it is in use
        digests = _digests(bag)
        assert recover_bag_directory(bag).status == 'in use'
        assert [r.status for r in recover(tmp_path)] == ['in use']
        assert unfinished_recordings(tmp_path, 'qfa_node') == [bag]
        assert _digests(bag) == digests
    assert recover_bag_directory(bag).status == 'nothing to recover'
    assert not unfinished_recordings(tmp_path, 'qfa_node')

    trace = McapBagWriter(tmp_path / 'qfa_self_calibrate_0000000000000000001.mcap')
    trace.add_topic('/s', 'std_msgs/msg/String')
    trace.write('/s', {'data': 'row'}, 1)
    trace.flush()
    assert unfinished_traces(tmp_path) == [trace.part_path]
    assert recover_trace(trace.part_path).status == 'in use'
    trace.finish()  # the writer still finishes normally after the attempt
    assert unfinished_traces(tmp_path) == []


def _copy_bag(source, target):
    """Copy a bag directory under another name, its files named after it as a recorder does."""
    target.mkdir()
    for path in source.iterdir():
        shutil.copy2(path, target / path.name.replace(source.name, target.name))


def test_the_node_looks_only_at_its_own_unfinished_names(tmp_path, killed):
    recordings = tmp_path / 'recordings'
    recordings.mkdir()
    own = recordings / killed.name
    _copy_bag(killed, own)
    other = recordings / killed.name.replace('qfa_node', 'other_node')
    _copy_bag(killed, other)
    healthy = recordings / (killed.name + '_2')
    _copy_bag(killed, healthy)
    assert recover(healthy)[0].status == 'recovered'
    (recordings / (killed.name + '_3')).symlink_to(own)  # a symlink is not followed
    (recordings / 'qfa_node_notes').mkdir()
    assert unfinished_recordings(recordings, 'qfa_node') == [own]
    assert unfinished_recordings(tmp_path / 'missing', 'qfa_node') == []

    # metadata.yaml older than the newest file: killed between a finish and its listing.
    stale = recordings / (killed.name + '_4')
    _copy_bag(healthy, stale)
    newest = sorted(stale.glob('*.mcap'))[-1]
    listed = (stale / 'metadata.yaml').stat().st_mtime_ns
    os.utime(newest, ns=(listed + 10**9, listed + 10**9))
    assert unfinished_recordings(recordings, 'qfa_node') == [own, stale]

    traces = tmp_path / 'traces'
    traces.mkdir()
    (traces / 'qfa_self_calibrate_1767225600000000000.mcap.part').write_bytes(MAGIC)
    (traces / 'notes.mcap.part').write_bytes(MAGIC)
    (traces / 'qfa_reference_1767225600000000000.mcap').write_bytes(MAGIC)
    assert [p.name for p in unfinished_traces(traces)] == [
        'qfa_self_calibrate_1767225600000000000.mcap.part']


SECRET = 'secret-content-7b1f'


def test_strangers_files_are_bounded_set_aside_and_never_quoted(tmp_path, killed):
    bag = tmp_path / killed.name
    shutil.copytree(killed, bag)
    secret = tmp_path / 'secret.txt'
    secret.write_text(SECRET)
    name = killed.name
    (bag / f'{name}_7.mcap.part').symlink_to(secret)
    os.mkfifo(bag / f'{name}_8.mcap.part')
    (bag / f'{name}_9.mcap.part').write_text(SECRET * 100)
    # An MCAP start, then a record that claims 1 TiB.
    header_end = _chunk_ends(bag / f'{name}_0.mcap')[0]
    (bag / f'{name}_10.mcap.part').write_bytes((bag / f'{name}_0.mcap').read_bytes()[
        :header_end] + b'\x06' + (1 << 40).to_bytes(8, 'little') + b'\0' * 100)

    result, = recover(bag)
    text = result.describe()
    assert SECRET not in text
    # Not a regular file under the recorder's name: neither followed nor opened.
    assert f'{name}_7' not in text and f'{name}_8' not in text
    assert recover_part(bag / f'{name}_7.mcap.part').problem == 'a symlink, not followed'
    assert recover_part(bag / f'{name}_8.mcap.part').problem == 'not a regular file'
    assert f'{name}_9.mcap: not recovered: not an MCAP file (no MCAP magic at its start): ' \
           f'kept as {name}_9.mcap.unreadable' in text
    assert (bag / f'{name}_9.mcap.unreadable').read_text() == SECRET * 100
    assert secret.read_text() == SECRET and (bag / f'{name}_7.mcap.part').is_symlink()
    recovered = {f.path.name: f for f in result.files}
    assert recovered[f'{name}_10.mcap'].status == 'recovered'
    assert 'more than recovery reads' in recovered[f'{name}_10.mcap'].stopped
    contents = read_bag(bag)
    assert contents.files == 5  # _0 to _3 and the empty _10
    assert len(contents.imu_stamps) == 3500


def test_a_part_whose_offered_qos_nests_too_deep_is_recovered_without_it(tmp_path):
    """Before: PyYAML's RecursionError ended ``qfa-report recover`` in a traceback."""
    from mcap.writer import Writer
    part = tmp_path / 'deep.mcap.part'
    with open(part, 'wb') as stream:
        writer = Writer(stream)
        writer.start('ros2', 'test')
        schema = writer.register_schema('std_msgs/msg/String', 'ros2msg', b'string data')
        channel = writer.register_channel('/t', 'cdr', schema,
                                          metadata={'offered_qos_profiles': '[' * 1000})
        for i in range(10):
            writer.add_message(channel, log_time=10 ** 18 + i, publish_time=10 ** 18 + i,
                               data=encode_message({'data': 'a'}, 'std_msgs/msg/String'))
        writer.finish()
    part.write_bytes(part.read_bytes()[:-200])  # the summary and footer cut off
    result = recover_part(part)
    assert result.status == 'recovered', result.problem
    assert report_main(['recover', str(tmp_path)]) == 0


@pytest.mark.parametrize('kind, expected', [
    # Before: a ValueError traceback for a finished .mcap; "no such file" for a FIFO.
    ('finished', 'not a .mcap.part file, nor a directory of them'),
    ('fifo', 'not a regular file or directory'),
    ('missing', 'no such file or directory'),
])
def test_qfa_report_recover_refuses_what_it_cannot_recover_in_one_line(tmp_path, capsys, kind,
                                                                       expected):
    path = tmp_path / 'x.mcap'
    if kind == 'finished':
        path.write_bytes(b'\x89MCAP0\r\n')
    elif kind == 'fifo':
        os.mkfifo(path)
    assert report_main(['recover', str(path)]) == 1
    assert capsys.readouterr().err == f'qfa-report recover: {path}: {expected}\n'


CLI = textwrap.dedent("""
    import sys
    for name in ('matplotlib', 'dask', 'distributed', 'pyarrow'):
        sys.modules[name] = None  # as `make run` installs them: not at all
    from qfa_ros.cli.report import main
    sys.exit(main(['recover', *sys.argv[1:]]))
""")


def test_qfa_report_recover_runs_without_the_tools_and_says_what_it_did(tmp_path, killed,
                                                                        capsys):
    output = tmp_path / 'output'
    (output / 'recordings').mkdir(parents=True)
    bag = output / 'recordings' / killed.name
    shutil.copytree(killed, bag)
    (output / 'traces').mkdir()
    trace = output / 'traces' / 'qfa_reference_1767225600000000000.mcap.part'
    shutil.copy(next(killed.glob('*.part')), trace)

    def run():
        result = subprocess.run([sys.executable, '-c', CLI, str(output)], cwd=ROOT,
                                capture_output=True, text=True, timeout=120,
                                env={**os.environ, 'PYTHONPATH': str(ROOT)})
        assert result.returncode == 0, result.stderr
        return result.stdout.splitlines()

    lines = run()
    assert len(lines) == 2, lines
    assert lines[0].startswith(f'{bag}: recovered {killed.name}_3.mcap (')
    assert lines[0].endswith('metadata.yaml lists 4 files, 3500 messages'), lines[0]
    assert lines[1].startswith(f'{trace.with_suffix("")}: recovered ')
    part = next(killed.glob('*.part'))
    assert len(read_mcap(trace.with_suffix(''))) == len(_part_stamps(part)) == 500
    # Run again (in this process: the run above showed it needs none of the tools).
    assert report_main(['recover', str(output)]) == 0
    assert capsys.readouterr().out.splitlines() == [
        f'{output}: nothing to recover (complete bag directories: 1)']
