"""
Finish a ``.part`` file a killed writer left: complete MCAP, in place, under its final name.

A recording or trace cut short by ``kill -9`` or a power cut leaves ``NAME.mcap.part``:
the MCAP magic, the header and complete chunks up to the last one written (the flight
recorder ends a chunk every 0.25 s), then perhaps a chunk cut short. No standard reader
opens it: the seeking readers want the summary and the footer. :func:`recover_part`
makes it a finished MCAP under ``NAME.mcap``, **in place**: it reads the file once,
checking every chunk (framing, size, CRC: :mod:`qfa_ros.bag.part_scan`), cuts the file
after the last complete one and appends what ``finish()`` would have written (that
chunk's message indexes if they are missing, a ``rosbag2`` metadata record, the summary
with schemas, channels, statistics and chunk indexes, the footer), fsyncs it and links it
to its final name. Nothing already written is copied and one chunk at a time is held in
memory: recovering a 1 GiB part costs one sequential read of it. (mcap's ``Writer``
cannot write the summary of chunks it did not write; rewriting the file through it costs
what ``bench/results/bag_alternatives.md`` measures.)

**Never under a live writer**: a writer holds an exclusive ``flock`` on its ``.part``
(:class:`~qfa_ros.bag.part_files.PartFile`); recovery takes it without waiting and leaves a
locked file alone. **Crash-safe and idempotent**: a recovery killed half way leaves the
good prefix plus part of a tail, which the next run cuts off again; the final name
appears only once the file is complete and fsynced (``link``, as ``finish()``
publishes). **Bounded**: no symlink followed (``O_NOFOLLOW``), regular files only, no
record larger than :data:`MAX_RECORD_BYTES` nor a chunk larger decompressed; messages
name counts, sizes and why a scan stopped, never what the file contains.
"""

import dataclasses
import datetime
import errno
import os
from pathlib import Path
import stat
import zlib

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import (
    DataEnd,
    Footer,
    Metadata,
    MetadataIndex,
    Statistics,
    SummaryOffset,
)
import yaml

from qfa_ros.bag.part_files import lock_exclusively, PART_SUFFIX, publish_part
from qfa_ros.bag.part_scan import (
    find_missing_definitions,
    MAGIC,
    MAX_RECORD_BYTES,
    NotRecoverableError,
    PartScan,
    RecoveryStoppedError,
    scan_part,
)
from qfa_ros.bag.qos import dump_yaml
from qfa_ros.bag.writer import file_bag_metadata, LIBRARY
from qfa_ros.model.safe_files import fsync_directory

__all__ = [
    'final_path',
    'finished_file_metadata',
    'MAX_RECORD_BYTES',
    'NotRecoverableError',
    'recover_part',
    'RecoveredFile',
    'RecoveryStoppedError',
    'utc_text',
]

MAX_QOS_YAML = 1 << 16
"""Longest offered-QoS YAML of a channel that is parsed [characters] (the recorder's: ~1 KiB)."""
UNREADABLE_SUFFIX = '.unreadable'
"""What a ``.part`` that is no MCAP file is renamed to (``NAME.mcap.unreadable``), kept as it
is and out of the way of the next recovery."""


@dataclasses.dataclass
class RecoveredFile:
    """What became of one ``.part`` file."""

    path: Path
    """The final ``.mcap`` name."""
    status: str
    """``recovered``, ``finished`` (already complete: only the ``.part`` name was left),
    ``in use`` (locked by a live writer), ``skipped`` (finished meanwhile) or ``failed``."""
    messages: int = 0
    first_ns: int = None
    last_ns: int = None
    dropped_bytes: int = 0
    """Bytes cut off the end: a chunk or record the kill cut short."""
    stopped: str = ''
    """Why the scan stopped where it did (``end of file``, ``chunk cut short`` ...)."""
    problem: str = ''
    metadata: dict = None
    """The file's rosbag2 metadata (:func:`~qfa_ros.bag.writer.file_bag_metadata`)."""

    def describe(self):
        """Return one line: what was done and how much it holds."""
        if self.status == 'failed':
            return f'{self.path.name}: not recovered: {self.problem}'
        if self.status != 'recovered':
            return f'{self.path.name}: {self.status}'
        text = f'recovered {self.path.name} ({self.messages} messages'
        if self.last_ns is not None:
            text += f', the last at {utc_text(self.last_ns)}'
        if self.dropped_bytes:
            text += f'; {self.dropped_bytes} bytes cut short dropped ({self.stopped})'
        return text + ')'


def utc_text(time_ns):
    """Return ``time_ns`` as an ISO 8601 UTC time to the millisecond."""
    moment = datetime.datetime.fromtimestamp(time_ns / 1e9, tz=datetime.timezone.utc)
    return moment.isoformat(timespec='milliseconds').replace('+00:00', 'Z')



# --- writing the summary -----------------------------------------------------------------

def _topics(scan):
    """Return ``file_bag_metadata`` topics of the scan's channels."""
    topics = []
    for channel_id, channel in sorted(scan.channels.items()):
        schema = scan.schemas.get(channel.schema_id)
        topics.append((channel.topic, schema.name if schema else '',
                       _qos_yaml(channel.metadata.get('offered_qos_profiles', '')),
                       channel.metadata.get('topic_type_hash', ''),
                       scan.counts.get(channel_id, 0)))
    return topics


def _qos_yaml(text):
    """Return the channel's offered-QoS YAML if it is short and parses as a list, else ''."""
    if len(text) > MAX_QOS_YAML:
        return ''
    try:
        return text if isinstance(yaml.safe_load(text), list) else ''
    except (yaml.YAMLError, RecursionError):  # nested deeper than PyYAML recurses
        return ''


def _tail(scan, name):
    """Return what goes after ``scan.data_end``: indexes, metadata, summary, footer."""
    out = bytearray(scan.tail)
    builder = RecordBuilder()
    metadata = file_bag_metadata(name, _topics(scan), scan.first_ns, scan.last_ns)
    records = [Metadata('rosbag2', {'serialized_metadata': dump_yaml(metadata)})]
    records += [record for _, _, record in scan.trailing_metadata if record.name != 'rosbag2']
    metadata_indexes = list(scan.kept_metadata)
    for record in records:
        record.write(builder)
        data = builder.end()
        metadata_indexes.append(MetadataIndex(scan.data_end + len(out), len(data), record.name))
        out += data
    DataEnd(0).write(builder)
    out += builder.end()

    summary_start = scan.data_end + len(out)
    statistics = Statistics(
        message_count=sum(scan.counts.values()), schema_count=len(scan.schemas),
        channel_count=len(scan.channels), attachment_count=0,
        metadata_count=len(metadata_indexes), chunk_count=len(scan.chunk_indexes),
        message_start_time=scan.first_ns or 0, message_end_time=scan.last_ns or 0,
        channel_message_counts=dict(sorted(scan.counts.items())))
    groups = [(Opcode.SCHEMA, [scan.schemas[k] for k in sorted(scan.schemas)]),
              (Opcode.CHANNEL, [scan.channels[k] for k in sorted(scan.channels)]),
              (Opcode.STATISTICS, [statistics]),
              (Opcode.CHUNK_INDEX, scan.chunk_indexes),
              (Opcode.METADATA_INDEX, metadata_indexes)]
    offsets = []
    for opcode, group in groups:
        group_start = builder.count
        for record in group:
            record.write(builder)
        if group:
            offsets.append(SummaryOffset(group_opcode=opcode,
                                         group_start=summary_start + group_start,
                                         group_length=builder.count - group_start))
    summary_offset_start = summary_start + builder.count
    for offset in offsets:
        offset.write(builder)
    summary = builder.end()
    footer = Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                    summary_crc=0)
    footer.write(builder)
    # The summary CRC covers the summary and the footer up to the CRC (as Writer.finish).
    footer.summary_crc = zlib.crc32(builder.end()[:-4], zlib.crc32(summary))
    footer.write(builder)
    out += summary + builder.end() + MAGIC
    return bytes(out), metadata


# --- one .part ---------------------------------------------------------------------------

def final_path(part):
    """Return the final name of ``NAME.mcap.part``: ``NAME.mcap``."""
    part = Path(part)
    if not part.name.endswith('.mcap' + PART_SUFFIX):
        raise ValueError(f'{part}: not a .mcap.part file')
    return part.with_name(part.name[:-len(PART_SUFFIX)])


def _same_file(a, b):
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _lstat(path):
    try:
        return os.lstat(path)
    except FileNotFoundError:
        return None


def _set_aside(part, final):
    """Rename a ``.part`` recovery cannot finish out of the way; say where it went."""
    aside = final.with_name(final.name + UNREADABLE_SUFFIX)
    if _lstat(aside) is not None:
        return 'left as it is'
    os.rename(part, aside)
    fsync_directory(part.parent)
    return f'kept as {aside.name}'


def _write_all(descriptor, data, offset):
    view = memoryview(data)
    while view.nbytes:
        written = os.pwrite(descriptor, view, offset)
        view, offset = view[written:], offset + written


def recover_part(part, should_stop=None):
    """
    Finish ``NAME.mcap.part`` in place and publish it as ``NAME.mcap``.

    Parameters
    ----------
    part : str or os.PathLike
        The ``.part`` file (no symlink).
    should_stop : callable, optional
        Polled between chunks; when it returns true the scan ends with
        :class:`RecoveryStoppedError` before anything was changed.

    Returns
    -------
    RecoveredFile
        Its ``status`` says what was done; ``failed`` with ``problem`` when the file is
        not one recovery can finish (left as it is).
    """
    part = Path(part)
    final = final_path(part)
    result = RecoveredFile(final, 'failed')
    try:
        descriptor = os.open(part, os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
    except FileNotFoundError:
        result.status = 'skipped'
        return result
    except OSError as error:
        result.problem = ('a symlink, not followed' if error.errno == errno.ELOOP
                          else f'cannot open it: {error.strerror}')
        return result
    try:
        info = os.fstat(descriptor)
        if not stat.S_ISREG(info.st_mode):
            result.problem = 'not a regular file'
            return result
        if not lock_exclusively(descriptor, wait=False):
            result.status = 'in use'
            return result
        current = _lstat(part)
        if current is None or not _same_file(current, info):
            result.status = 'skipped'  # finished (renamed) by its writer meanwhile
            return result
        existing = _lstat(final)
        if existing is not None:
            if _same_file(existing, info):
                # Killed between finish()'s link and unlink: the file is complete.
                os.unlink(part)
                fsync_directory(part.parent)
                result.status = 'finished'
            else:
                result.problem = f'{final.name} exists too: both left as they are'
            return result
        with os.fdopen(os.dup(descriptor), 'rb', buffering=1 << 20) as stream:
            scan = scan_part(stream, should_stop)
            find_missing_definitions(scan, stream)
        tail, result.metadata = _tail(scan, final.name)
        os.ftruncate(descriptor, scan.data_end - len(scan.prefix))
        _write_all(descriptor, scan.prefix + tail, scan.data_end - len(scan.prefix))
        os.fsync(descriptor)
        publish_part(part, final, overwrite=False)
        fsync_directory(part.parent)
    except NotRecoverableError as error:
        result.problem = f'{error}: {_set_aside(part, final)}'
        return result
    except OSError as error:
        result.problem = f'{type(error).__name__}: {error.strerror or error}'
        return result
    finally:
        os.close(descriptor)
    result.status = 'recovered'
    result.messages = sum(scan.counts.values())
    result.first_ns, result.last_ns = scan.first_ns, scan.last_ns
    # Rebuilt message indexes stand for what the file held of them.
    result.dropped_bytes = max(0, info.st_size - scan.data_end - len(scan.tail))
    result.stopped = scan.stopped
    return result


def finished_file_metadata(path, recorder_only=False):
    """
    Return the rosbag2 metadata of a finished MCAP file, from its summary.

    Parameters
    ----------
    path : pathlib.Path
        The file (a symlink is not followed).
    recorder_only : bool
        Refuse a file whose MCAP header does not name this package's writer
        (``McapBagWriter``: its library ends in ``qfa_ros recorder``).

    Returns
    -------
    dict
        ``file_bag_metadata`` of the file: its topics, counts and time span.

    Raises
    ------
    NotRecoverableError
        Not a regular file, no readable summary, or (``recorder_only``) another writer's.
    OSError
        It cannot be opened.
    """
    descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
    with os.fdopen(descriptor, 'rb') as stream:
        if not stat.S_ISREG(os.fstat(stream.fileno()).st_mode):
            raise NotRecoverableError('not a regular file')
        try:
            reader = SeekingReader(stream, record_size_limit=MAX_RECORD_BYTES)
            library = reader.get_header().library
            summary = reader.get_summary()
        except Exception as error:  # mcap raises several kinds on a file it cannot read
            raise NotRecoverableError(f'its summary cannot be read ({type(error).__name__})') \
                from None
    # The writer's own name ends the library (the versions before it may change).
    if recorder_only and not library.endswith(LIBRARY.rpartition('; ')[2]):
        raise NotRecoverableError('not written by the qfa_ros recorder')
    if summary is None or summary.statistics is None:
        raise NotRecoverableError('it has no summary statistics')
    statistics = summary.statistics
    scan = PartScan(schemas=summary.schemas, channels=summary.channels,
                    counts=statistics.channel_message_counts)
    span = (statistics.message_start_time, statistics.message_end_time) \
        if statistics.message_count else (None, None)
    return file_bag_metadata(Path(path).name, _topics(scan), *span)
