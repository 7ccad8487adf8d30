"""
Read a rosbag2 MCAP bag (a bag directory or a bare ``.mcap`` file) for playback.

:class:`BagSource` merges the messages of a bag's files in log-time order and keeps
each topic's type and the QoS its publishers offered (``offered_qos_profiles``). No
ROS: the replay publisher in :mod:`qfa_ros.ros.replay` puts the bytes on the wire.
"""

import contextlib
import dataclasses
import heapq
from pathlib import Path
import struct

from mcap.exceptions import EndOfFile, InvalidMagic, McapError, RecordLengthLimitExceeded
from mcap.reader import make_reader
import yaml
import zstandard

from qfa_ros.model.safe_files import open_regular_file, read_regular_file, UntrustedFileError


class BagError(RuntimeError):
    """The bag cannot be read: missing, not MCAP, or malformed."""


MAX_METADATA_BYTES = 64 << 20
"""Largest ``metadata.yaml`` read [bytes] (about 300 bytes a split file: 200 000 splits)."""
MCAP_READ_ERRORS = (McapError, zstandard.ZstdError, struct.error, EOFError, ValueError,
                    RuntimeError, OverflowError)
"""What reading a malformed MCAP file raises: mcap's own errors, a chunk that does not
decompress (zstd; lz4 raises RuntimeError), a record cut short (struct), a string that is
not UTF-8 (ValueError), a time beyond int64 (OverflowError)."""


def mcap_read_problem(error):
    """
    Return what is wrong with an MCAP file that raised ``error``, quoting none of it.

    mcap's messages quote the file (the first bytes for a bad magic, lengths read from
    it); a stranger's file is named, never quoted.
    """
    if isinstance(error, InvalidMagic):
        return 'not an MCAP file (no MCAP magic)'
    if isinstance(error, (EndOfFile, EOFError, struct.error)):
        return 'truncated (a record cut short)'
    if isinstance(error, RecordLengthLimitExceeded):
        return 'malformed (a record longer than the limit)'
    if isinstance(error, zstandard.ZstdError):
        return 'corrupt (a chunk that does not decompress)'
    return f'malformed ({type(error).__name__})'


@contextlib.contextmanager
def mcap_read_errors(path, *passing):
    """
    Raise what reading the MCAP file ``path`` raises as one ValueError naming it.

    :class:`UntrustedFileError` (a file not read) and the exception types ``passing`` go
    through as they are; an ``OSError`` or one of :data:`MCAP_READ_ERRORS` becomes
    ``ValueError('<path>: cannot read ...')``, quoting nothing of the file.
    """
    try:
        yield
    except (UntrustedFileError, *passing):
        raise
    except OSError as error:
        raise ValueError(f'{path}: cannot read: {error.strerror or error}') from None
    except MCAP_READ_ERRORS as error:
        raise ValueError(f'{path}: cannot read MCAP: {mcap_read_problem(error)}') from None


@dataclasses.dataclass
class BagTopic:
    """
    One recorded topic.

    Attributes
    ----------
    name : str
        Topic name as recorded.
    msgtype : str
        Type name like ``'sensor_msgs/msg/Imu'``.
    encoding : str
        MCAP message encoding; only ``'cdr'`` can be published.
    offered_qos : list of dict
        The recorded publishers' QoS profiles as rosbag2 stores them (may be empty).
    """

    name: str
    msgtype: str
    encoding: str = 'cdr'
    offered_qos: list = dataclasses.field(default_factory=list)


def _parse_offers(value):
    """Return rosbag2 ``offered_qos_profiles`` (YAML text or already a list) as a list."""
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value)
        except (yaml.YAMLError, RecursionError):
            return []
    if isinstance(value, dict):
        value = [value]
    return [offer for offer in value or [] if isinstance(offer, dict)]


def normalized_type(name):
    """Return ``pkg/msg/Name`` for ``pkg/Name`` (lenient: a bag may spell it either way)."""
    parts = [part for part in name.split('/') if part]
    if len(parts) == 2:
        parts.insert(1, 'msg')
    return '/'.join(parts)


class BagSource:
    """
    The messages of a rosbag2 MCAP bag, merged across its files in log-time order.

    Parameters
    ----------
    path : str or os.PathLike
        A bag directory (rosbag2 ``metadata.yaml`` naming its ``.mcap`` files, or
        just ``.mcap`` files) or a single ``.mcap`` file.

    Attributes
    ----------
    files : list of pathlib.Path
        The MCAP files in playback order.
    topics : dict of str to BagTopic
        Every recorded topic by name.
    warnings : list of str
        What could not be used (conflicting channel types, ...).
    """

    def __init__(self, path):
        self.path = Path(path)
        self.warnings = []
        metadata_topics = {}
        if self.path.is_dir():
            self.files, metadata_topics = self._directory_files(self.path)
        elif self.path.is_file():
            self.files = [self.path]
        else:
            raise BagError(f'no bag at {self.path}')
        self.topics = {}
        for file in self.files:
            for channel, schema_name in self._channels(file):
                self._add_channel(channel, schema_name, metadata_topics.get(channel.topic))

    @staticmethod
    def _directory_files(directory):
        metadata_file = directory / 'metadata.yaml'
        if not metadata_file.exists():
            files = sorted(directory.glob('*.mcap'))
            if not files:
                raise BagError(f'{directory} has neither metadata.yaml nor .mcap files')
            return files, {}
        # A stranger's file: read bounded, regular files only, and never quoted.
        try:
            document = yaml.safe_load(read_regular_file(metadata_file, MAX_METADATA_BYTES))
        except UntrustedFileError as error:
            raise BagError(str(error)) from None
        except (yaml.YAMLError, RecursionError):
            raise BagError(f'{metadata_file}: not YAML') from None
        info = document.get('rosbag2_bagfile_information') \
            if isinstance(document, dict) else None
        if not isinstance(info, dict):
            raise BagError(f'{metadata_file}: not rosbag2 metadata (no '
                           'rosbag2_bagfile_information mapping)')
        storage = info.get('storage_identifier', 'mcap')
        if storage != 'mcap':
            shown = repr(storage) if isinstance(storage, str) and len(storage) <= 40 \
                else 'other than mcap'
            raise BagError(f'{directory}: storage {shown} is not supported, only mcap '
                           '(convert with `ros2 bag convert` or rosbags-convert)')
        names = info.get('relative_file_paths') or []
        if not isinstance(names, list) or not all(
                isinstance(name, str) and name for name in names):
            raise BagError(f'{metadata_file}: relative_file_paths must be a list of file names')
        files = [directory / name for name in names]
        missing = [str(file) if str(file).isprintable() and len(str(file)) <= 1024
                   else 'an unprintable or overlong name' for file in files if not file.exists()]
        if missing or not files:
            raise BagError(f'{directory}: bag files missing: '
                           f'{", ".join(missing[:3]) or "none"}'
                           + (f' and {len(missing) - 3} more' if len(missing) > 3 else ''))
        entries = info.get('topics_with_message_count') or []
        metas = [entry.get('topic_metadata') for entry in entries
                 if isinstance(entry, dict)] if isinstance(entries, list) else []
        return files, {meta['name']: meta for meta in metas
                       if isinstance(meta, dict) and isinstance(meta.get('name'), str)}

    def _channels(self, file):
        """Yield ``(channel, schema name)`` of every channel in ``file``."""
        try:
            with open_regular_file(file) as stream:
                reader = make_reader(stream)
                summary = reader.get_summary()
                if summary is not None:
                    for channel in summary.channels.values():
                        schema = summary.schemas.get(channel.schema_id)
                        yield channel, schema.name if schema else ''
                    return
                # No summary (an interrupted recording): learn the channels by reading it.
                seen = set()
                for schema, channel, _ in reader.iter_messages(log_time_order=False):
                    if channel.id not in seen:
                        seen.add(channel.id)
                        yield channel, schema.name if schema else ''
        except UntrustedFileError as error:
            raise BagError(f'cannot read MCAP: {error}') from None
        except MCAP_READ_ERRORS as error:
            raise BagError(f'{file}: cannot read MCAP: {mcap_read_problem(error)}') from None

    def _add_channel(self, channel, schema_name, metadata):
        recorded_type = (metadata or {}).get('type', '')
        msgtype = normalized_type(schema_name or (
            recorded_type if isinstance(recorded_type, str) else ''))
        offers = _parse_offers(channel.metadata.get('offered_qos_profiles'))
        if not offers and metadata:
            offers = _parse_offers(metadata.get('offered_qos_profiles'))
        known = self.topics.get(channel.topic)
        if known is None:
            self.topics[channel.topic] = BagTopic(channel.topic, msgtype,
                                                  channel.message_encoding, offers)
        elif known.msgtype != msgtype:
            self.warnings.append(f'{channel.topic}: recorded as both {known.msgtype} and '
                                 f'{msgtype}; playing {known.msgtype} only')
        else:
            known.offered_qos.extend(offer for offer in offers
                                     if offer not in known.offered_qos)

    def messages(self, topics=None, start_ns=None):
        """
        Yield ``(topic, log_time_ns, cdr_bytes)`` in log-time order.

        Parameters
        ----------
        topics : collection of str, optional
            Only these topics (default all).
        start_ns : int, optional
            Skip messages logged before this time.
        """
        topics = None if topics is None else set(topics)
        streams = [self._file_messages(file, topics, start_ns) for file in self.files]
        # Split bags are usually sequential, but a merge keeps overlapping files in order.
        yield from heapq.merge(*streams, key=lambda item: item[1])

    def _file_messages(self, file, topics, start_ns):
        with open_regular_file(file) as stream:
            reader = make_reader(stream)
            try:
                for _, channel, message in reader.iter_messages(
                        topics=topics, starting_at=start_ns, log_time_order=True):
                    if channel.topic in self.topics:
                        yield channel.topic, message.log_time, bytes(message.data)
            except MCAP_READ_ERRORS as error:
                # A truncated file still plays up to its last complete chunk.
                self.warnings.append(f'{file}: stopped reading: {mcap_read_problem(error)}')
