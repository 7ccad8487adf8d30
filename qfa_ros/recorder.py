"""Write rosbag2-compatible MCAP files without ROS.

``McapBagWriter`` writes one MCAP file the way rosbag2's MCAP storage plugin does
(profile ``ros2``, ``ros2msg`` schemas with their dependent definitions, ``cdr``
messages, ``offered_qos_profiles`` and ``topic_type_hash`` channel metadata, a
``rosbag2`` metadata record, chunk and message indexes, summary), so
``ros2 bag play FILE.mcap``, ``ros2 bag info``, Foxglove, PlotJuggler and
``rosbags`` read it. ``FlightRecorder`` records already serialized messages into
a sequence of such files split by size or duration.

Durability rules, shared by both:

- A file is written as ``NAME.mcap.part``. Only ``finish()`` publishes it: the
  MCAP summary is written, the file is fsynced, linked to ``NAME.mcap`` without
  replacing anything, and the directory is fsynced. A file under its final name
  is therefore always complete.
- Data reaches the operating system one whole chunk at a time (the MCAP writer
  buffers a chunk in memory and this module writes with unbuffered ``os.write``),
  so after a crash the ``.part`` file holds every complete chunk and is readable
  with a streaming MCAP reader (or ``mcap recover``) up to the last one.
- Creation, write and finish failures raise ``OSError`` subclasses naming the
  file; the final name is never touched after a failure.

Times are integer nanoseconds (``int`` or numpy integers; floats are refused so
that seconds are never mistaken for nanoseconds).
"""

from collections.abc import Mapping
import dataclasses
import datetime
import errno
import operator
import os
from pathlib import Path
import re
import threading
import time

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, LIBRARY_IDENTIFIER, Writer
import mcap_ros2
from mcap_ros2._dynamic import serialize_dynamic
import yaml

from qfa_ros.msgdefs import MESSAGE_DEFINITIONS, TYPE_HASHES

__all__ = [
    'DEFAULT_CHUNK_SIZE',
    'FlightRecorder',
    'McapBagWriter',
    'QOS_DEFAULT',
    'QOS_LATCHED',
    'QOS_SENSOR_DATA',
    'QosProfile',
    'RecorderError',
    'iter_part_messages',
    'offered_qos_yaml',
    'register_message_definition',
    'stamp',
    'stamp_to_ns',
    'supported_types',
]

# rosbag2's MCAP plugin uses the mcap C++ default of 768 KiB per chunk.
DEFAULT_CHUNK_SIZE = 768 * 1024
BAG_METADATA_VERSION = 9
ROS_DISTRO = 'kilted'
LIBRARY = f'{LIBRARY_IDENTIFIER}; mcap-ros2-support {mcap_ros2.__version__}; qfa_ros recorder'
PART_SUFFIX = '.part'

_COMPRESSIONS = {
    'zstd': CompressionType.ZSTD,
    'lz4': CompressionType.LZ4,
    None: CompressionType.NONE,
    'none': CompressionType.NONE,
}
# RMW_DURATION_INFINITE as rmw reports it for a publisher's unset durations.
_INFINITE_SEC = 9223372036
_INFINITE_NSEC = 854775807
_PRIMITIVES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring',
})
# Message record framing (31 bytes) plus its message index entry (16 bytes).
_MESSAGE_OVERHEAD = 47
# Header, data end, statistics, summary offsets, footer, metadata index and the
# topic-independent part of the rosbag2 metadata YAML.
_BASE_FINISH_OVERHEAD = 1200
_TOPIC_RE = re.compile(r'^/?[A-Za-z_~][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$')


class RecorderError(OSError):
    """Writing or finishing an MCAP file failed; the ``.part`` file is left in place."""


@dataclasses.dataclass(frozen=True)
class QosProfile:
    """Offered QoS of a recorded publisher, as rosbag2 stores it.

    Parameters
    ----------
    history : str
        ``'keep_last'``, ``'keep_all'``, ``'system_default'`` or ``'unknown'``.
    depth : int
        History depth.
    reliability : str
        ``'reliable'``, ``'best_effort'``, ``'system_default'`` or ``'unknown'``.
    durability : str
        ``'volatile'``, ``'transient_local'``, ``'system_default'`` or ``'unknown'``.
    deadline_ns, lifespan_ns, liveliness_lease_duration_ns : int or None
        Durations in nanoseconds; None is infinite (what rmw reports when unset).
    liveliness : str
        ``'automatic'``, ``'manual_by_topic'``, ``'system_default'`` or ``'unknown'``.
    avoid_ros_namespace_conventions : bool
        As in ``rmw_qos_profile_t``.
    """

    history: str = 'keep_last'
    depth: int = 10
    reliability: str = 'reliable'
    durability: str = 'volatile'
    deadline_ns: int | None = None
    lifespan_ns: int | None = None
    liveliness: str = 'automatic'
    liveliness_lease_duration_ns: int | None = None
    avoid_ros_namespace_conventions: bool = False

    def as_dict(self):
        """Return the profile as the mapping rosbag2 (metadata version 9) serializes."""
        return {
            'history': self.history,
            'depth': int(self.depth),
            'reliability': self.reliability,
            'durability': self.durability,
            'deadline': _rmw_time(self.deadline_ns),
            'lifespan': _rmw_time(self.lifespan_ns),
            'liveliness': self.liveliness,
            'liveliness_lease_duration': _rmw_time(self.liveliness_lease_duration_ns),
            'avoid_ros_namespace_conventions': bool(self.avoid_ros_namespace_conventions),
        }


# Reliable + volatile is what rclpy offers by default and matches every subscriber.
QOS_DEFAULT = QosProfile()
QOS_SENSOR_DATA = QosProfile(depth=5, reliability='best_effort')
# For settings and results: late joiners of `ros2 bag play` still receive them.
QOS_LATCHED = QosProfile(depth=1, durability='transient_local')


def _rmw_time(duration_ns):
    if duration_ns is None:
        return {'sec': _INFINITE_SEC, 'nsec': _INFINITE_NSEC}
    sec, nsec = divmod(int(duration_ns), 1_000_000_000)
    return {'sec': sec, 'nsec': nsec}


def _dump_yaml(data):
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False).rstrip('\n')


def offered_qos_yaml(profiles):
    """Serialize QoS profiles into rosbag2's ``offered_qos_profiles`` YAML list.

    Parameters
    ----------
    profiles : QosProfile or iterable of QosProfile
        One profile per recorded publisher.

    Returns
    -------
    str
        The YAML text stored in the channel metadata.
    """
    return _dump_yaml([profile.as_dict() for profile in _qos_list(profiles)])


def _qos_list(qos):
    if qos is None:
        return [QOS_DEFAULT]
    if isinstance(qos, QosProfile):
        return [qos]
    profiles = list(qos)
    if not all(isinstance(profile, QosProfile) for profile in profiles):
        raise TypeError('qos must be a QosProfile or an iterable of QosProfile')
    return profiles


def stamp(time_ns):
    """Convert integer nanoseconds to a ``builtin_interfaces/Time`` mapping.

    Parameters
    ----------
    time_ns : int
        Nanoseconds since the epoch of the clock in use.

    Returns
    -------
    dict
        ``{'sec': ..., 'nanosec': ...}``.
    """
    sec, nanosec = divmod(_as_time_ns(time_ns, 'time_ns'), 1_000_000_000)
    return {'sec': sec, 'nanosec': nanosec}


def stamp_to_ns(time_msg):
    """Convert a ``builtin_interfaces/Time`` (mapping or object) to integer nanoseconds."""
    if isinstance(time_msg, Mapping):
        return int(time_msg['sec']) * 1_000_000_000 + int(time_msg['nanosec'])
    return int(time_msg.sec) * 1_000_000_000 + int(time_msg.nanosec)


def _as_time_ns(value, what):
    try:
        time_ns = operator.index(value)
    except TypeError:
        raise TypeError(
            f'{what} must be integer nanoseconds, got {type(value).__name__} {value!r}'
        ) from None
    if not 0 <= time_ns < 2**64:
        raise ValueError(f'{what} must be in [0, 2**64) nanoseconds, got {time_ns}')
    return time_ns


def _canonical_type(msgtype):
    parts = msgtype.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f'message type must look like pkg/msg/Name, got {msgtype!r}')
    return '/'.join(parts)


# --- message definitions -----------------------------------------------------------------

_DEFINITIONS = dict(MESSAGE_DEFINITIONS)
_HASHES = dict(TYPE_HASHES)
_ENCODERS = {}
_FIELDS = {}
_CACHE_LOCK = threading.Lock()


def supported_types():
    """Return the message types this module can write, sorted."""
    return sorted(_DEFINITIONS)


def register_message_definition(msgtype, definition, type_hash=''):
    """Add a message type the embedded definitions do not cover.

    Parameters
    ----------
    msgtype : str
        Type name like ``'geometry_msgs/msg/Twist'``.
    definition : str
        Full ``ros2msg`` text with dependent definitions concatenated the way
        rosbag2 writes them (separator line of 80 ``=``, ``MSG: pkg/Name``).
    type_hash : str
        ``RIHS01_...`` type description hash, or empty when unknown.
    """
    msgtype = _canonical_type(msgtype)
    with _CACHE_LOCK:
        _DEFINITIONS[msgtype] = definition
        _HASHES[msgtype] = type_hash
        _ENCODERS.pop(msgtype, None)
        _FIELDS.pop(msgtype, None)


def _definition(msgtype):
    try:
        return _DEFINITIONS[msgtype]
    except KeyError:
        raise ValueError(
            f'no message definition for {msgtype!r}; supported: {", ".join(supported_types())}'
            ' (add one with register_message_definition)'
        ) from None


def _encoder(msgtype):
    encoder = _ENCODERS.get(msgtype)
    if encoder is None:
        with _CACHE_LOCK:
            encoder = serialize_dynamic(msgtype, _definition(msgtype))[msgtype]
            _ENCODERS[msgtype] = encoder
            _FIELDS[msgtype] = _parse_fields(msgtype, _definition(msgtype))
    return encoder


def _parse_fields(root_type, definition):
    """Map each type in a concatenated definition to ``{field: (nested type or None, is_array)}``.

    Only field names and nesting are needed (to reject misspelt keys, which the
    CDR encoder would otherwise silently encode as zeros).
    """
    tables = {}
    current = _short_type(root_type)
    for section in re.split(r'^={3,}$', definition, flags=re.MULTILINE):
        lines = section.strip().splitlines()
        if lines and lines[0].startswith('MSG:'):
            current = _short_type(lines[0].split()[1])
            lines = lines[1:]
        package = current.split('/')[0]
        fields = {}
        for raw_line in lines:
            line = raw_line.split('#', 1)[0].strip()
            if not line:
                continue
            tokens = line.split()
            if len(tokens) < 2 or '=' in tokens[1] or (len(tokens) > 2 and tokens[2][0] == '='):
                continue  # constant, not a field
            base = re.sub(r'\[.*\]$', '', tokens[0])
            is_array = base != tokens[0]
            base = base.split('<=')[0]
            if base in _PRIMITIVES:
                fields[tokens[1]] = (None, is_array)
            else:
                nested = base if '/' in base else f'{package}/{base}'
                fields[tokens[1]] = (_short_type(nested), is_array)
        tables[current] = fields
    return tables


def _short_type(msgtype):
    parts = msgtype.split('/')
    return f'{parts[0]}/{parts[-1]}'


def _normalized(message, msgtype):
    """Return a copy of ``message`` checked against its definition, numpy arrays as lists."""
    tables = _FIELDS[msgtype]
    builtin_time = {'sec': (None, False), 'nanosec': (None, False)}

    def walk(value, short_type, where):
        if not isinstance(value, Mapping):
            return value  # attribute-style objects are encoded as given
        fields = tables.get(short_type, builtin_time if short_type.startswith(
            'builtin_interfaces/') else None)
        out = {}
        for key, item in value.items():
            if key not in fields:
                raise KeyError(
                    f'{where}: {short_type} has no field {key!r} (fields: {", ".join(fields)})'
                )
            nested, is_array = fields[key]
            if hasattr(item, 'tolist') and not isinstance(item, (str, bytes)):
                item = item.tolist()
            if nested is None and not is_array and isinstance(item, bytes) and len(item) == 1:
                item = item[0]  # rclpy spells byte fields (DiagnosticStatus.level) as b'\x00'
            elif nested is not None:
                if is_array:
                    item = [walk(element, nested, f'{where}.{key}[]') for element in item]
                else:
                    item = walk(item, nested, f'{where}.{key}')
            out[key] = item
        return out

    if not isinstance(message, Mapping):
        raise TypeError(f'{msgtype} message must be a mapping, got {type(message).__name__}')
    return walk(message, _short_type(msgtype), msgtype)


def _check_cdr(data, topic):
    view = memoryview(data)
    # Every CDR payload starts with a 4-byte encapsulation header whose first byte is 0.
    if view.nbytes < 4 or view[0] != 0:
        raise ValueError(f'{topic}: data is not CDR (missing encapsulation header)')
    return data if isinstance(data, bytes) else view.tobytes()


# --- the file ----------------------------------------------------------------------------

class _PartFile:
    """Unbuffered write-only file that the mcap ``Writer`` treats as its stream."""

    def __init__(self, path):
        self.path = path
        self.position = 0
        self._fd = None
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
        except OSError as error:
            raise _with_context(error, 'cannot create MCAP file', path) from None

    def write(self, data):
        view = memoryview(data)
        while view.nbytes:
            try:
                written = os.write(self._fd, view)
            except OSError as error:
                raise RecorderError(
                    error.errno, f'writing MCAP file failed: {error.strerror}', str(self.path)
                ) from error
            view = view[written:]
            self.position += written
        return len(data)

    def tell(self):
        return self.position

    def flush(self):
        """Do nothing: every write already went to the operating system."""

    def sync_and_close(self):
        try:
            os.fsync(self._fd)
        finally:
            self.close()

    def close(self):
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)

    def __del__(self):
        # An abandoned writer must not leak its descriptor; the .part file stays as is.
        self.close()


def _with_context(error, what, path):
    """Re-raise an ``OSError`` as its own subclass with a message that says what failed."""
    return type(error)(error.errno, f'{what}: {error.strerror}', str(path))


def fsync_directory(directory):
    """Make a rename in ``directory`` durable: fsync the directory entry itself."""
    fd = os.open(directory, os.O_RDONLY | getattr(os, 'O_DIRECTORY', 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _publish(part_path, final_path, overwrite):
    """Give a finished ``.part`` file its final name atomically."""
    if overwrite:
        os.replace(part_path, final_path)
        return
    try:
        # link() refuses to replace an existing file, unlike rename().
        os.link(part_path, final_path)
    except OSError as error:
        if error.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
            raise
        if final_path.exists():
            raise FileExistsError(errno.EEXIST, 'file exists', str(final_path)) from None
        os.replace(part_path, final_path)  # filesystem without hard links
        return
    os.unlink(part_path)


@dataclasses.dataclass
class _Topic:
    channel_id: int
    msgtype: str
    qos_yaml: str
    type_hash: str
    message_count: int = 0
    sequence: int = 0


class McapBagWriter:
    """Write one rosbag2-compatible MCAP file; a context manager.

    Parameters
    ----------
    path : str or os.PathLike
        Final file name, ending in ``.mcap``. Data goes to ``path + '.part'``
        until ``finish()``.
    compression : {'zstd', 'lz4', None}
        Chunk compression.
    chunk_size : int
        Uncompressed bytes buffered per chunk. Smaller chunks lose less in a
        crash and compress less well.
    storage_metadata : mapping of str to str, optional
        Written as rosbag2 ``custom_data`` (what ``ros2 bag record --custom-data``
        stores), e.g. node name, seed, git revision.
    overwrite : bool
        Replace an existing file at ``path`` on ``finish()``; by default an
        existing file is an error so earlier recordings are never lost.
    ros_distro : str
        Distribution recorded in the bag metadata; the embedded message
        definitions are Kilted's.

    Raises
    ------
    FileExistsError
        ``path`` exists (and not ``overwrite``) or a stale ``.part`` from a
        crashed recording is in the way (it is kept for recovery).
    OSError
        The directory is missing or unwritable (``FileNotFoundError``,
        ``PermissionError``, ``NotADirectoryError``, ...).

    Notes
    -----
    Methods are thread-safe. Leaving the ``with`` block by an exception aborts
    the recording: the ``.part`` file stays, nothing gets the final name.
    """

    def __init__(self, path, *, compression='zstd', chunk_size=DEFAULT_CHUNK_SIZE,
                 storage_metadata=None, overwrite=False, ros_distro=ROS_DISTRO):
        self.path = Path(path)
        if self.path.suffix != '.mcap':
            raise ValueError(f'MCAP file name must end in .mcap, got {str(self.path)!r}')
        if compression not in _COMPRESSIONS:
            raise ValueError(f'compression must be zstd, lz4 or None, got {compression!r}')
        if int(chunk_size) <= 0:
            raise ValueError(f'chunk_size must be positive, got {chunk_size!r}')
        self.part_path = self.path.with_name(self.path.name + PART_SUFFIX)
        self._overwrite = bool(overwrite)
        self._custom_data = {str(k): str(v) for k, v in (storage_metadata or {}).items()}
        self._ros_distro = str(ros_distro)
        self._compression_name = None if compression in (None, 'none') else compression
        self._topics = {}
        self._schema_ids = {}
        self._first_time_ns = None
        self._last_time_ns = None
        self._message_count = 0
        self._lock = threading.Lock()
        self._state = 'open'
        # For size_estimate(): bytes buffered in the chunk in progress, and what the
        # summary, indexes and rosbag2 metadata record will add at finish().
        self._position_seen = 0
        self._chunks_flushed = 0
        self._pending_bytes = 0
        self._finish_overhead = _BASE_FINISH_OVERHEAD
        if not overwrite and self.path.exists():
            raise FileExistsError(
                errno.EEXIST, 'MCAP file already exists (pass overwrite=True)', str(self.path)
            )
        self._file = _PartFile(self.part_path)
        try:
            self._writer = Writer(
                self._file,
                chunk_size=int(chunk_size),
                compression=_COMPRESSIONS[compression],
            )
            self._writer.start(profile='ros2', library=LIBRARY)
        except BaseException:
            self._file.close()
            self._state = 'failed'
            raise

    # context manager
    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, traceback):
        if exc_type is None:
            self.finish()
        else:
            self.abort()
        return False

    @property
    def finished(self):
        """Whether the file has been published under its final name."""
        return self._state == 'finished'

    @property
    def message_count(self):
        """Messages written so far."""
        return self._message_count

    def size_estimate(self, extra_message_bytes=0):
        """Return an upper estimate of the file size were it finished now.

        Parameters
        ----------
        extra_message_bytes : int
            Payload of a message about to be written, to include it.

        Returns
        -------
        int
            Bytes on disk, plus the chunk in progress uncompressed, plus the
            summary, indexes and metadata record ``finish()`` adds.
        """
        extra = 0 if not extra_message_bytes else extra_message_bytes + _MESSAGE_OVERHEAD
        chunk_indexes = (self._chunks_flushed + 1) * (100 + 10 * len(self._topics))
        return (self._file.position + self._pending_bytes + extra + chunk_indexes
                + self._finish_overhead)

    def _account(self, pending_bytes):
        if self._file.position != self._position_seen:
            # A chunk went to disk and took everything pending with it.
            self._position_seen = self._file.position
            self._chunks_flushed += 1
            self._pending_bytes = 0
        else:
            self._pending_bytes += pending_bytes

    @property
    def topics(self):
        """Registered topics mapped to their message types."""
        return {topic: entry.msgtype for topic, entry in self._topics.items()}

    @property
    def bytes_written(self):
        """Bytes handed to the operating system so far (the file grows one chunk at a time)."""
        return self._file.position

    def add_topic(self, topic, msgtype, qos=None):
        """Register a topic and return its MCAP channel id.

        Parameters
        ----------
        topic : str
            Topic name, e.g. ``'/imu/data_raw'``.
        msgtype : str
            Message type, e.g. ``'sensor_msgs/msg/Imu'``.
        qos : QosProfile or iterable of QosProfile, optional
            Offered QoS of the publisher(s); default reliable, volatile, keep last 10.

        Returns
        -------
        int
            The channel id. Registering the same topic and type again returns the
            same id; another type on the same topic is an error.
        """
        msgtype = _canonical_type(msgtype)
        if not _TOPIC_RE.match(topic):
            raise ValueError(f'invalid topic name {topic!r}')
        with self._lock:
            self._check_open('add a topic')
            known = self._topics.get(topic)
            if known is not None:
                if known.msgtype != msgtype:
                    raise ValueError(
                        f'topic {topic} already carries {known.msgtype}, not {msgtype}'
                    )
                return known.channel_id
            # Only a new topic pays for the YAML: FlightRecorder.record() comes here for
            # every message.
            qos_yaml = offered_qos_yaml(qos)
            definition = _definition(msgtype)
            new_schema = msgtype not in self._schema_ids
            schema_id = self._schema_id(msgtype, definition)
            type_hash = _HASHES.get(msgtype, '')
            channel_id = self._guarded(
                self._writer.register_channel,
                topic=topic,
                message_encoding=MessageEncoding.CDR,
                schema_id=schema_id,
                metadata={'offered_qos_profiles': qos_yaml, 'topic_type_hash': type_hash},
            )
            self._topics[topic] = _Topic(channel_id, msgtype, qos_yaml, type_hash)
            # Schema and channel records go into the chunk and again into the summary;
            # the topic also appears, QoS indented deeper, in the rosbag2 metadata YAML.
            records = (len(definition) + len(msgtype) + 20 if new_schema else 0) + (
                len(topic) + len(qos_yaml) + len(type_hash) + 80)
            self._account(records)
            self._finish_overhead += records + 2 * len(qos_yaml) + len(type_hash) + 300
            return channel_id

    def _schema_id(self, msgtype, definition):
        if msgtype not in self._schema_ids:
            self._schema_ids[msgtype] = self._guarded(
                self._writer.register_schema, msgtype, SchemaEncoding.ROS2, definition.encode()
            )
        return self._schema_ids[msgtype]

    def write(self, topic, message, log_time_ns, publish_time_ns=None):
        """Serialize a message given as a (nested) mapping and write it.

        Parameters
        ----------
        topic : str
            A topic registered with ``add_topic``.
        message : mapping
            Field names to values; nested messages as mappings, arrays as
            sequences or numpy arrays. Missing fields take their ROS defaults;
            unknown field names raise ``KeyError``.
        log_time_ns : int
            Receive time in nanoseconds (rosbag2's ``recv_timestamp``; what
            ``ros2 bag play`` replays by).
        publish_time_ns : int, optional
            Send time in nanoseconds; defaults to ``log_time_ns``.
        """
        entry = self._topic(topic)
        encoder = _encoder(entry.msgtype)
        data = encoder(_normalized(message, entry.msgtype))
        self._write_data(entry, data, log_time_ns, publish_time_ns)

    def write_serialized(self, topic, data, log_time_ns, publish_time_ns=None):
        """Write a message already serialized to CDR.

        Parameters
        ----------
        topic : str
            A topic registered with ``add_topic``.
        data : bytes-like
            CDR bytes with encapsulation header, e.g. from
            ``rclpy.serialization.serialize_message``.
        log_time_ns, publish_time_ns : int
            As for ``write``.
        """
        entry = self._topic(topic)
        self._write_data(entry, _check_cdr(data, topic), log_time_ns, publish_time_ns)

    def _topic(self, topic):
        try:
            return self._topics[topic]
        except KeyError:
            raise KeyError(f'topic {topic!r} is not registered; call add_topic first') from None

    def _write_data(self, entry, data, log_time_ns, publish_time_ns):
        log_time_ns = _as_time_ns(log_time_ns, 'log_time_ns')
        publish_time_ns = (log_time_ns if publish_time_ns is None
                           else _as_time_ns(publish_time_ns, 'publish_time_ns'))
        with self._lock:
            self._check_open()
            self._guarded(
                self._writer.add_message,
                channel_id=entry.channel_id,
                log_time=log_time_ns,
                data=data,
                publish_time=publish_time_ns,
                sequence=entry.sequence,
            )
            self._account(len(data) + _MESSAGE_OVERHEAD)
            entry.sequence = (entry.sequence + 1) & 0xFFFFFFFF
            entry.message_count += 1
            self._message_count += 1
            if self._first_time_ns is None or log_time_ns < self._first_time_ns:
                self._first_time_ns = log_time_ns
            if self._last_time_ns is None or log_time_ns > self._last_time_ns:
                self._last_time_ns = log_time_ns

    def _check_open(self, action='write'):
        if self._state != 'open':
            reason = {
                'failed': 'failed earlier (see the first error); nothing was published',
                'aborted': 'was aborted; nothing was published',
                'finished': 'is already finished',
            }[self._state]
            raise RecorderError(
                errno.EBADF, f'cannot {action}: the MCAP writer {reason}', str(self.part_path)
            )

    def _guarded(self, function, *args, **kwargs):
        try:
            return function(*args, **kwargs)
        except OSError:
            self._fail()
            raise

    def _fail(self):
        self._state = 'failed'
        self._file.close()

    def bag_metadata(self):
        """Return the rosbag2 ``BagMetadata`` mapping (version 9) for what is written so far."""
        start = self._first_time_ns or 0
        duration = 0 if self._first_time_ns is None else self._last_time_ns - start
        name = self.path.name
        return {
            'version': BAG_METADATA_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': self._message_count,
            'topics_with_message_count': [
                {
                    'topic_metadata': {
                        'name': topic,
                        'type': entry.msgtype,
                        'serialization_format': 'cdr',
                        'offered_qos_profiles': yaml.safe_load(entry.qos_yaml),
                        'type_description_hash': entry.type_hash,
                    },
                    'message_count': entry.message_count,
                }
                for topic, entry in self._topics.items()
            ],
            # Chunk compression is storage-internal; rosbag2 leaves these empty for it.
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [name],
            'files': [{
                'path': name,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': duration},
                'message_count': self._message_count,
            }],
            'custom_data': dict(self._custom_data) or None,
            'ros_distro': self._ros_distro,
        }

    def finish(self):
        """Complete the file and publish it under its final name; idempotent.

        Returns
        -------
        pathlib.Path
            The final path.

        Raises
        ------
        RecorderError
            The writer failed or was aborted earlier, or finishing failed; the
            ``.part`` file is left for inspection and the final name untouched.
        """
        with self._lock:
            if self._state == 'finished':
                return self.path
            self._check_open('finish')
            try:
                self._writer.add_metadata(
                    'rosbag2', {'serialized_metadata': _dump_yaml(self.bag_metadata())}
                )
                self._writer.finish()
                self._file.sync_and_close()
                _publish(self.part_path, self.path, self._overwrite)
                fsync_directory(self.path.parent)
            except OSError as error:
                self._fail()
                if isinstance(error, RecorderError):
                    raise
                raise RecorderError(
                    error.errno, f'finishing MCAP file failed: {error.strerror}',
                    str(self.part_path),
                ) from error
            self._state = 'finished'
            return self.path

    def abort(self):
        """Stop writing without publishing; the ``.part`` file keeps the complete chunks."""
        with self._lock:
            if self._state == 'open':
                self._state = 'aborted'
                self._file.close()


# --- continuous recording ----------------------------------------------------------------

class FlightRecorder:
    """Record serialized messages continuously into MCAP files split by size or duration.

    Files are named ``PREFIX_YYYYmmddTHHMMSS_NNNN.mcap`` with the session start
    (UTC wall clock) and a running index, so that a session's files sort in
    recording order. Each file is a complete, standalone rosbag2 MCAP file,
    written and published like ``McapBagWriter`` writes them. A file is opened
    on the first message after the previous one closed, so no empty files.

    Parameters
    ----------
    directory : str or os.PathLike
        Existing, writable directory.
    prefix : str
        File name prefix.
    max_bytes : int, optional
        Start a new file before a message would take the finished file past
        this size (estimated from the bytes on disk, the chunk in progress
        uncompressed and the summary to come, so files stay below it; a single
        message larger than the limit still gets a file of its own). A topic
        first seen in a file adds its definition and QoS to it, so leave room.
    max_duration_ns : int, optional
        Start a new file once a message's time is ``max_duration_ns`` or more
        after the first message of the current file.
    compression : {'zstd', 'lz4', None}
        Chunk compression.
    chunk_size : int, optional
        Chunk size; default ``DEFAULT_CHUNK_SIZE``, capped at a quarter of
        ``max_bytes``.
    qos : mapping of str to QosProfile, optional
        Offered QoS per topic (default ``QOS_DEFAULT``).
    storage_metadata : mapping of str to str, optional
        rosbag2 ``custom_data`` written into every file.
    session_time_ns : int, optional
        Wall-clock time used in the file names; default now.

    Raises
    ------
    OSError
        The directory does not exist or is not writable.
    """

    def __init__(self, directory, prefix='qfa', *, max_bytes=None, max_duration_ns=None,
                 compression='zstd', chunk_size=None, qos=None, storage_metadata=None,
                 session_time_ns=None):
        self.directory = Path(directory)
        if max_bytes is not None and int(max_bytes) < 1024:
            raise ValueError(f'max_bytes must be at least 1024, got {max_bytes!r}')
        if max_duration_ns is not None and _as_time_ns(max_duration_ns, 'max_duration_ns') <= 0:
            raise ValueError('max_duration_ns must be positive')
        if not re.match(r'^[A-Za-z0-9_.-]+$', prefix):
            raise ValueError(f'prefix must be a plain file name part, got {prefix!r}')
        if compression not in _COMPRESSIONS:
            raise ValueError(f'compression must be zstd, lz4 or None, got {compression!r}')
        self._max_bytes = None if max_bytes is None else int(max_bytes)
        self._max_duration_ns = max_duration_ns
        self._compression = compression
        if chunk_size is None:
            chunk_size = DEFAULT_CHUNK_SIZE
            if self._max_bytes is not None:
                chunk_size = max(256, min(chunk_size, self._max_bytes // 4))
        self._chunk_size = int(chunk_size)
        self._qos = dict(qos or {})
        self._storage_metadata = dict(storage_metadata or {})
        session_ns = time.time_ns() if session_time_ns is None else session_time_ns
        session = datetime.datetime.fromtimestamp(
            _as_time_ns(session_ns, 'session_time_ns') / 1e9, tz=datetime.timezone.utc
        )
        self._base_name = f'{prefix}_{session:%Y%m%dT%H%M%S}'
        self._check_directory()
        self._index = 0
        self._writer = None
        self._file_start_ns = None
        self._lock = threading.Lock()
        self._closed = False
        self.files = []

    def _check_directory(self):
        if not self.directory.is_dir():
            if self.directory.exists():
                raise NotADirectoryError(
                    errno.ENOTDIR, 'recording directory is not a directory', str(self.directory)
                )
            raise FileNotFoundError(
                errno.ENOENT, 'recording directory does not exist', str(self.directory)
            )
        probe = self.directory / f'.{self._base_name}.probe{os.getpid()}'
        try:
            os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            os.unlink(probe)
        except OSError as error:
            raise _with_context(error, 'recording directory is not writable',
                                self.directory) from None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, traceback):
        # Unlike a single trace, a continuous recording is valid up to any point: keep it.
        self.close()
        return False

    @property
    def current_path(self):
        """Final path of the file being written, or None between files."""
        return None if self._writer is None else self._writer.path

    def record(self, topic, msgtype, data, time_ns):
        """Record one serialized message, starting a new file first if a limit is reached.

        Parameters
        ----------
        topic : str
            Topic name.
        msgtype : str
            Message type, e.g. ``'sensor_msgs/msg/Imu'``; fixed per topic.
        data : bytes-like
            CDR bytes (``rclpy.serialization.serialize_message`` output).
        time_ns : int
            Receive time in nanoseconds.
        """
        time_ns = _as_time_ns(time_ns, 'time_ns')
        with self._lock:
            if self._closed:
                raise RecorderError(errno.EBADF, 'flight recorder is closed', str(self.directory))
            if self._writer is not None and self._limit_reached(
                    topic, msgtype, len(data), time_ns):
                self._finish_current()
            if self._writer is None:
                self._open_next(time_ns)
            self._writer.add_topic(topic, msgtype, self._qos.get(topic))
            self._writer.write_serialized(topic, data, time_ns)

    def _limit_reached(self, topic, msgtype, size, time_ns):
        if (self._max_duration_ns is not None
                and time_ns - self._file_start_ns >= self._max_duration_ns):
            return True
        if self._max_bytes is not None and self._writer.message_count:
            estimate = self._writer.size_estimate(size)
            if topic not in self._writer.topics:
                # Its schema, channel and metadata entry: definition twice, QoS thrice.
                estimate += 2 * len(_definition(_canonical_type(msgtype))) + 1500
            return estimate > self._max_bytes
        return False

    def _open_next(self, time_ns):
        path = self.directory / f'{self._base_name}_{self._index:04d}.mcap'
        self._writer = McapBagWriter(
            path, compression=self._compression, chunk_size=self._chunk_size,
            storage_metadata=self._storage_metadata,
        )
        self._index += 1
        self._file_start_ns = time_ns

    def _finish_current(self):
        writer, self._writer = self._writer, None
        self.files.append(writer.finish())

    def close(self):
        """Finish the current file; idempotent.

        Returns
        -------
        list of pathlib.Path
            Every file this recorder published, in order.
        """
        with self._lock:
            if not self._closed:
                self._closed = True
                if self._writer is not None:
                    self._finish_current()
            return list(self.files)


def iter_part_messages(path):
    """Yield ``(channel, message)`` from the complete chunks of an unfinished MCAP file.

    Reads sequentially, checking chunk CRCs, and stops quietly at the first
    record it cannot read, so it recovers what a crashed recording left in its
    ``.part`` file. Use it for salvage only: it cannot tell truncation from
    corruption.

    Parameters
    ----------
    path : str or os.PathLike
        An MCAP file, finished or not.

    Yields
    ------
    tuple
        ``(mcap.records.Channel, mcap.records.Message)``.
    """
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    channels = {}
    with open(path, 'rb') as stream:
        records = StreamReader(stream, validate_crcs=True).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except OSError:
                raise
            except Exception:
                # A truncated record fails in the MCAP parser, struct, zstd, lz4 or the
                # CRC check depending on where the cut is; each marks the end of the data.
                return
            if isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                yield channels[record.channel_id], record
