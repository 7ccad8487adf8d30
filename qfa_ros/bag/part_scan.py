"""
Read a ``.part`` a killed writer left: what its complete records hold, checked.

:func:`scan_part` reads the file once from its start: the magic and header, then every
record, each chunk decompressed (bounded) with its size and CRC checked, its message indexes
trusted when a valid record follows them and rebuilt from the chunk otherwise (the kill
may have cut them), metadata records kept where they stand or carried after the data.
It stops at the first record it cannot take (cut short, malformed, too large, a summary
record) and says why. The :class:`PartScan` it returns is what
:mod:`qfa_ros.bag.part_repair` needs to append a summary: schemas, channels, chunk
indexes, message counts per channel, the time span, and where the kept data ends. One
chunk at a time is held in memory; messages name counts, sizes and why a scan stopped,
never what the file contains.
"""

import collections
import dataclasses
import io
import struct
import zlib

import lz4.frame
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    Header,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
)
import zstandard

from qfa_ros.bag.writer import LIBRARY

__all__ = [
    'find_missing_definitions',
    'MAGIC',
    'MAX_RECORD_BYTES',
    'NotRecoverableError',
    'PartScan',
    'RecoveryStoppedError',
    'scan_part',
]

MAGIC = b'\x89MCAP0\r\n'
MAX_RECORD_BYTES = 32 << 20
"""Largest record (and chunk, decompressed) recovery reads [bytes]: the memory one file may
cost; the recorder's are under 1 MiB. A larger one ends the scan there, as a cut would."""
RECORD_HEAD = struct.Struct('<BQ')
MESSAGE_INDEX_HEAD = struct.Struct('<HI')
MESSAGE_HEAD = struct.Struct('<HIQ')
"""channel id, sequence, log time: the start of a Message record's body."""
_RECORDS = {Opcode.METADATA: Metadata, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel}
"""The records outside chunks the scan reads with mcap's parser."""


class RecoveryStoppedError(Exception):
    """The caller asked recovery to stop; nothing was changed."""


class NotRecoverableError(ValueError):
    """The file is not a ``.part`` this module can finish; the message says why."""


@dataclasses.dataclass
class _Group:
    """A chunk and the message index records after it."""

    index: ChunkIndex
    data: bytes
    """The chunk's records, decompressed; dropped once the group is taken."""
    counts: dict = dataclasses.field(default_factory=dict)
    end: int = 0


@dataclasses.dataclass
class PartScan:
    """What the complete records of a ``.part`` hold: what its summary must list."""

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
    prefix: bytes = b''
    """A new start of the file (magic and header) when it was cut inside its own; else empty."""


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
        if opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            _take_definition(scan, opcode, _read_body(_RECORDS[opcode], body))


def _take_definition(scan, opcode, record):
    """Keep the first schema or channel record of its id."""
    (scan.schemas if opcode == Opcode.SCHEMA else scan.channels).setdefault(record.id, record)


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
        MessageIndex(channel_id, records).write(builder)
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


def scan_part(stream, should_stop=None):
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
        scan = PartScan(prefix=_start_of_file(), stopped='cut inside its header')
        scan.data_end = len(scan.prefix)
        return scan
    if opcode != Opcode.HEADER:
        raise NotRecoverableError('not an MCAP file (no header record after the magic)')
    position = len(MAGIC) + 9 + len(body)
    scan = PartScan(data_end=position)
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
            group = _open_group(scan, record, start, position)
        elif opcode == Opcode.METADATA:
            scan.trailing_metadata.append((start, 9 + len(body), record))
        else:  # a schema or channel outside chunks
            _take_definition(scan, opcode, record)
            scan.data_end = position
    if group is not None:
        # Cut by the kill: the chunk is whole (checked), its message indexes perhaps not.
        _take(scan, group, rebuild=True)
    return scan


def _open_group(scan, record, start, end):
    """
    Return the group a chunk record opens; the metadata before it stays where it is.

    Parameters
    ----------
    scan : PartScan
        The scan so far.
    record : tuple
        The chunk as :func:`_parse` returns it: ``(Chunk, decompressed records)``.
    start, end : int
        The chunk record's first byte and the byte after it in the file.

    Returns
    -------
    _Group
    """
    chunk, data = record
    scan.kept_metadata += [MetadataIndex(offset, length, metadata.name)
                           for offset, length, metadata in scan.trailing_metadata]
    scan.trailing_metadata = []
    return _Group(ChunkIndex(
        message_start_time=chunk.message_start_time,
        message_end_time=chunk.message_end_time,
        chunk_start_offset=start, chunk_length=end - start,
        message_index_offsets={}, message_index_length=0,
        compression=chunk.compression, compressed_size=len(chunk.data),
        uncompressed_size=chunk.uncompressed_size), data, end=end)


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
    return _read_body(_RECORDS[opcode], body) if opcode in _RECORDS else None


def find_missing_definitions(scan, stream):
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
