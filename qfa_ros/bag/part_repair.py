"""
Finish a ``.part`` file a killed writer left: complete MCAP, in place, under its final name.

A recording or trace cut short by ``kill -9`` or a power cut leaves ``NAME.mcap.part``:
the MCAP magic, the header and complete chunks up to the last one written (the flight
recorder ends a chunk every 0.25 s), then perhaps a chunk cut short. No standard reader
opens it: the seeking readers want the summary and the footer. :func:`recover_part`
makes it a finished MCAP under ``NAME.mcap``, **in place**: it reads the file once,
checking every chunk (framing, size, CRC), cuts the file after the last complete one and
appends what ``finish()`` would have written (that chunk's message indexes if they are
missing, a ``rosbag2`` metadata record, the summary with schemas, channels, statistics
and chunk indexes, the footer), fsyncs it and links it to its final name. Nothing
already written is copied and one chunk at a time is held in memory: recovering a
1 GiB part costs one sequential read of it.

**Never under a live writer**: a writer holds an exclusive ``flock`` on its ``.part``
(:class:`~qfa_ros.bag.files.PartFile`); recovery takes it without waiting and leaves a
locked file alone. **Crash-safe and idempotent**: a recovery killed half way leaves the
good prefix plus part of a tail, which the next run cuts off again; the final name
appears only once the file is complete and fsynced (``link``, as ``finish()``
publishes). **Bounded**: no symlink followed (``O_NOFOLLOW``), regular files only, no
record larger than :data:`MAX_RECORD_BYTES` nor a chunk larger decompressed; messages
name counts, sizes and why a scan stopped, never what the file contains.

The module is one cohesive thing, longer than 500 lines: the scan of a cut file finds
exactly what the summary it appends must list.
"""

import collections
import dataclasses
import datetime
import errno
import io
import os
from pathlib import Path
import stat
import struct
import zlib

import lz4.frame
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
import yaml
import zstandard

from qfa_ros.bag.files import lock_exclusively, PART_SUFFIX, publish_part
from qfa_ros.bag.qos import dump_yaml
from qfa_ros.bag.writer import file_bag_metadata, LIBRARY
from qfa_ros.model.files import fsync_directory

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

MAGIC = b'\x89MCAP0\r\n'
MAX_RECORD_BYTES = 32 << 20
"""Largest record (and chunk, decompressed) recovery reads [bytes]: the memory one file may
cost; the recorder's are under 1 MiB. A larger one ends the scan there, as a cut would."""
MAX_QOS_YAML = 1 << 16
"""Longest offered-QoS YAML of a channel that is parsed [characters] (the recorder's: ~1 KiB)."""
UNREADABLE_SUFFIX = '.unreadable'
"""What a ``.part`` that is no MCAP file is renamed to (``NAME.mcap.unreadable``), kept as it
is and out of the way of the next recovery."""
RECORD_HEAD = struct.Struct('<BQ')
MESSAGE_INDEX_HEAD = struct.Struct('<HI')
MESSAGE_HEAD = struct.Struct('<HIQ')
"""channel id, sequence, log time: the start of a Message record's body."""


class RecoveryStoppedError(Exception):
    """The caller asked recovery to stop; nothing was changed."""


class NotRecoverableError(ValueError):
    """The file is not a ``.part`` this module can finish; the message says why."""


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


# --- scanning a .part --------------------------------------------------------------------

@dataclasses.dataclass
class _Group:
    """A chunk and the message index records after it."""

    index: ChunkIndex
    data: bytes
    """The chunk's records, decompressed; dropped once the group is taken."""
    counts: dict = dataclasses.field(default_factory=dict)
    end: int = 0


@dataclasses.dataclass
class _Scan:
    schemas: dict = dataclasses.field(default_factory=dict)
    channels: dict = dataclasses.field(default_factory=dict)
    chunk_indexes: list = dataclasses.field(default_factory=list)
    counts: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    kept_metadata: list = dataclasses.field(default_factory=list)
    """MetadataIndex of metadata records kept in place (between chunks)."""
    trailing_metadata: list = dataclasses.field(default_factory=list)
    """(offset, length, Metadata) after the last chunk: written again after the data."""
    data_end: int = 0
    """Where the kept data ends: the file is cut here."""
    tail: bytes = b''
    """Message indexes of the last chunk rebuilt from it, written at ``data_end``."""
    first_ns: int = None
    last_ns: int = None
    stopped: str = 'end of file'
    unsearched: list = dataclasses.field(default_factory=list)
    """Chunk offsets not yet searched for schema and channel records."""
    prefix: bytes = None
    """A new start of the file (magic and header) when it was cut inside its own."""


def _whole_header(body):
    """Return whether a header record's body is whole (no zeros where text should be)."""
    try:
        header = _read_body(Header, body)
    except Exception:  # the mcap parser raises several kinds on a cut string
        return False
    return '\0' not in header.profile + header.library


def _start_of_file():
    """Return the magic and header record ``McapBagWriter`` starts a file with."""
    builder = RecordBuilder()
    Header(profile='ros2', library=LIBRARY).write(builder)
    return MAGIC + builder.end()


def _record_parts(data):
    """Yield ``(offset, opcode, body)`` of the records in a chunk's decompressed data."""
    view = memoryview(data)
    offset = 0
    while offset + 9 <= len(view):
        opcode, length = RECORD_HEAD.unpack_from(view, offset)
        end = offset + 9 + length
        if end > len(view):
            raise NotRecoverableError('a record inside a chunk overruns it')
        yield offset, opcode, view[offset + 9:end]
        offset = end
    if offset != len(view):
        raise NotRecoverableError('a chunk ends inside a record')


def _read_body(record_class, body):
    return record_class.read(ReadDataStream(io.BytesIO(body)))


def _decompress(chunk):
    """Return the chunk's records, checked for size and CRC; raise ``NotRecoverableError``."""
    size = chunk.uncompressed_size
    if size > MAX_RECORD_BYTES:
        raise NotRecoverableError(f'a chunk of {size} bytes decompressed, more than recovery '
                                  'reads')
    try:
        if chunk.compression == 'zstd':
            with zstandard.ZstdDecompressor().stream_reader(chunk.data) as reader:
                data = reader.read(size + 1)
        elif chunk.compression == 'lz4':
            data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=size + 1)
        elif chunk.compression == '':
            data = chunk.data
        else:
            raise NotRecoverableError('a chunk of an unknown compression')
    except (zstandard.ZstdError, RuntimeError, OSError, ValueError) as error:
        raise NotRecoverableError(f'a chunk that does not decompress ({type(error).__name__})') \
            from None
    if len(data) != size:
        raise NotRecoverableError('a chunk whose size is not the one it states')
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise NotRecoverableError('a chunk whose CRC does not match')
    return data


def _search_definitions(scan, data):
    """Take the schema and channel records of a chunk's data."""
    for _, opcode, body in _record_parts(data):
        if opcode == Opcode.SCHEMA:
            schema = _read_body(Schema, body)
            scan.schemas.setdefault(schema.id, schema)
        elif opcode == Opcode.CHANNEL:
            channel = _read_body(Channel, body)
            scan.channels.setdefault(channel.id, channel)


def _rebuild_indexes(group, position):
    """Rebuild the message index records of ``group``'s chunk, written at ``position``."""
    entries = collections.defaultdict(list)
    for offset, opcode, body in _record_parts(group.data):
        if opcode == Opcode.MESSAGE:
            channel_id, _, log_time = MESSAGE_HEAD.unpack_from(body)
            entries[channel_id].append((log_time, offset))
    builder = RecordBuilder()
    group.index.message_index_offsets = {}
    for channel_id, records in entries.items():
        group.index.message_index_offsets[channel_id] = position + builder.count
        # The Writer's MessageIndex record, written directly: its entries are a list here.
        builder.start_record(Opcode.MESSAGE_INDEX)
        builder.write2(channel_id)
        builder.write4(16 * len(records))
        for log_time, offset in records:
            builder.write8(log_time)
            builder.write8(offset)
        builder.finish_record()
    group.counts = {channel_id: len(records) for channel_id, records in entries.items()}
    tail = builder.end()
    group.index.message_index_length = len(tail)
    return tail


def _take(scan, group, rebuild):
    """Add a complete group to the scan (``rebuild``: its message indexes were cut)."""
    chunk_end = group.index.chunk_start_offset + group.index.chunk_length
    if rebuild:
        scan.tail = _rebuild_indexes(group, chunk_end)
        scan.data_end = chunk_end
    else:
        scan.data_end = group.end
    if any(channel not in scan.channels for channel in group.counts):
        _search_definitions(scan, group.data)
    else:
        scan.unsearched.append(group.index.chunk_start_offset)
    group.data = None
    scan.chunk_indexes.append(group.index)
    scan.counts.update(group.counts)
    if group.counts:
        first, last = group.index.message_start_time, group.index.message_end_time
        scan.first_ns = first if scan.first_ns is None else min(scan.first_ns, first)
        scan.last_ns = last if scan.last_ns is None else max(scan.last_ns, last)


def _read_record(stream):
    """Return ``(opcode, body)`` of the next record, or ``(None, why not)``."""
    head = stream.read(9)
    if len(head) < 9:
        return None, 'end of file' if not head else 'record cut short'
    opcode, length = RECORD_HEAD.unpack(head)
    if length > MAX_RECORD_BYTES:
        return None, f'a record of {length} bytes, more than recovery reads'
    body = stream.read(length)
    if len(body) < length:
        return None, 'chunk cut short' if opcode == Opcode.CHUNK else 'record cut short'
    return opcode, body


def _scan(stream, should_stop=None):
    """
    Read a ``.part`` from its start; return what its complete records hold.

    A chunk's message indexes are trusted when a valid record follows them (the next
    chunk, checked; metadata; the data end): the writer wrote them before it. The last
    chunk's, followed by nothing valid, are rebuilt from the chunk itself.
    """
    magic = stream.read(len(MAGIC))
    landed = magic.rstrip(b'\0')  # a power cut leaves zeros where nothing landed
    if landed != MAGIC[:len(landed)]:
        raise NotRecoverableError('not an MCAP file (no MCAP magic at its start)')
    opcode, body = _read_record(stream) if magic == MAGIC else (None, 'end of file')
    if opcode in (None, 0) or (opcode == Opcode.HEADER and not _whole_header(body)):
        # Cut before its header was whole (the writer writes magic and header apart):
        # nothing in it yet, it starts again as an empty MCAP file.
        scan = _Scan(prefix=_start_of_file(), stopped='cut inside its header')
        scan.data_end = len(scan.prefix)
        return scan
    if opcode != Opcode.HEADER:
        raise NotRecoverableError('not an MCAP file (no header record after the magic)')
    position = len(MAGIC) + 9 + len(body)
    scan = _Scan(data_end=position)
    group = None
    while True:
        if should_stop is not None and should_stop():
            raise RecoveryStoppedError()
        start = position
        opcode, body = _read_record(stream)
        if opcode is None:
            scan.stopped = body
            break
        position = start + 9 + len(body)
        try:
            record = _parse(opcode, body, group is not None)
        except NotRecoverableError as error:
            scan.stopped = str(error)
            break
        except Exception as error:  # the mcap parsers raise several kinds on a bad record
            scan.stopped = f'a malformed record ({type(error).__name__})'
            break
        if record is None:
            scan.stopped = ('the end of the data section' if opcode == Opcode.DATA_END
                            else f'a record of opcode {opcode:#04x}')
            if opcode == Opcode.DATA_END and group is not None:
                _take(scan, group, rebuild=False)
                group = None
            break
        if opcode == Opcode.MESSAGE_INDEX:
            channel_id, count = record
            group.index.message_index_offsets[channel_id] = start
            group.index.message_index_length = position - (
                group.index.chunk_start_offset + group.index.chunk_length)
            group.counts[channel_id] = count
            group.end = position
            continue
        if group is not None:
            # A valid record after the group: its message indexes are all there.
            _take(scan, group, rebuild=False)
            group = None
        if opcode == Opcode.CHUNK:
            chunk, data = record
            # Metadata between chunks stays where it is.
            scan.kept_metadata += [MetadataIndex(offset, length, metadata.name)
                                   for offset, length, metadata in scan.trailing_metadata]
            scan.trailing_metadata = []
            group = _Group(ChunkIndex(
                message_start_time=chunk.message_start_time,
                message_end_time=chunk.message_end_time,
                chunk_start_offset=start, chunk_length=9 + len(body),
                message_index_offsets={}, message_index_length=0,
                compression=chunk.compression, compressed_size=len(chunk.data),
                uncompressed_size=chunk.uncompressed_size), data, end=position)
        elif opcode == Opcode.METADATA:
            scan.trailing_metadata.append((start, 9 + len(body), record))
        else:  # a schema or channel outside chunks
            (scan.schemas if opcode == Opcode.SCHEMA else scan.channels).setdefault(
                record.id, record)
            scan.data_end = position
    if group is not None:
        # Cut by the kill: the chunk is whole (checked), its message indexes perhaps not.
        _take(scan, group, rebuild=True)
    return scan


def _parse(opcode, body, in_group):
    """
    Return the record ``opcode`` with ``body`` as the scan takes it, or None to stop there.

    A chunk comes as ``(Chunk, decompressed records)``, a message index (only right after
    a chunk) as ``(channel id, message count)``.
    """
    if opcode == Opcode.CHUNK:
        chunk = _read_body(Chunk, body)
        return chunk, _decompress(chunk)
    if opcode == Opcode.MESSAGE_INDEX and in_group:
        channel_id, length = MESSAGE_INDEX_HEAD.unpack_from(body)
        if length % 16 or MESSAGE_INDEX_HEAD.size + length != len(body):
            raise NotRecoverableError('a malformed message index')
        return channel_id, length // 16
    if opcode == Opcode.METADATA:
        return _read_body(Metadata, body)
    if opcode == Opcode.SCHEMA:
        return _read_body(Schema, body)
    if opcode == Opcode.CHANNEL:
        return _read_body(Channel, body)
    return None


def _find_missing_definitions(scan, stream):
    """Search the chunks not searched yet for channels and schemas still missing."""
    for offset in scan.unsearched:
        if all(channel in scan.channels for channel in scan.counts) and all(
                channel.schema_id in scan.schemas or channel.schema_id == 0
                for channel in scan.channels.values()):
            return
        stream.seek(offset)
        _, body = _read_record(stream)  # read once already: complete
        _search_definitions(scan, _decompress(_read_body(Chunk, body)))
    missing = sorted(set(scan.counts) - set(scan.channels))
    if missing:
        raise NotRecoverableError(f'no channel record for channel ids {missing}')


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
    except yaml.YAMLError:
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
    # The summary CRC covers the summary and the footer up to the CRC (as Writer.finish).
    crc = zlib.crc32(struct.pack('<BQQQ', Opcode.FOOTER, 8 + 8 + 4, summary_start,
                                 summary_offset_start), zlib.crc32(summary))
    out += summary
    Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
           summary_crc=crc).write(builder)
    out += builder.end() + MAGIC
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
            scan = _scan(stream, should_stop)
            _find_missing_definitions(scan, stream)
        tail, result.metadata = _tail(scan, final.name)
        if scan.prefix is not None:
            tail = scan.prefix + tail
        os.ftruncate(descriptor, scan.data_end - len(scan.prefix or b''))
        _write_all(descriptor, tail, scan.data_end - len(scan.prefix or b''))
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


def finished_file_metadata(path):
    """Return the rosbag2 metadata of a finished MCAP file, from its summary."""
    descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
    with os.fdopen(descriptor, 'rb') as stream:
        if not stat.S_ISREG(os.fstat(stream.fileno()).st_mode):
            raise NotRecoverableError('not a regular file')
        try:
            summary = SeekingReader(stream, record_size_limit=MAX_RECORD_BYTES).get_summary()
        except Exception as error:  # mcap raises several kinds on a file it cannot read
            raise NotRecoverableError(f'its summary cannot be read ({type(error).__name__})') \
                from None
    if summary is None or summary.statistics is None:
        raise NotRecoverableError('it has no summary statistics')
    scan = _Scan(schemas=summary.schemas, channels=summary.channels,
                 counts=collections.Counter(summary.statistics.channel_message_counts))
    if summary.statistics.message_count:
        scan.first_ns = summary.statistics.message_start_time
        scan.last_ns = summary.statistics.message_end_time
    return file_bag_metadata(Path(path).name, _topics(scan), scan.first_ns, scan.last_ns)
