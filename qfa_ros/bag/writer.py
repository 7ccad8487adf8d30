"""Write rosbag2-compatible MCAP files without ROS.

``McapBagWriter`` writes one MCAP file the way rosbag2's MCAP storage plugin does
(profile ``ros2``, ``ros2msg`` schemas with their dependent definitions, ``cdr``
messages, ``offered_qos_profiles`` and ``topic_type_hash`` channel metadata, a
``rosbag2`` metadata record, chunk and message indexes, summary), so
``ros2 bag play FILE.mcap``, ``ros2 bag info``, Foxglove, PlotJuggler and
``rosbags`` read it; :mod:`qfa_ros.bag.flight_recorder` records into a sequence of
such files.

Durability rules (:mod:`qfa_ros.bag.part_files`):

- A file is written as ``NAME.mcap.part``. Only ``finish()`` publishes it: the
  MCAP summary is written, the file is fsynced, linked to ``NAME.mcap`` without
  replacing anything, and the directory is fsynced. A file under its final name
  is therefore always complete.
- Data reaches the operating system one whole chunk at a time (the MCAP writer
  buffers a chunk in memory and this module writes with unbuffered ``os.write``),
  so after a crash the ``.part`` file holds every complete chunk and is readable
  with a streaming MCAP reader up to the last one; ``qfa-report recover``
  (:mod:`qfa_ros.bag.recovery`) makes it a finished file. A chunk ends at
  ``chunk_size`` or at ``flush()``, which a continuous recording calls every fraction
  of a second so that a crash loses no more than that.
- The ``.part`` file is ``flock``-ed while it is written: a recovery never touches
  a file in use.
- Creation, write and finish failures raise ``OSError`` subclasses naming the
  file; the final name is never touched after a failure.

Times are integer nanoseconds (``int`` or numpy integers; floats are refused so
that seconds are never mistaken for nanoseconds).

The module is one cohesive thing: one writer class, whose records, durability and size
accounting (which the flight recorder splits files by) cannot be understood apart.
"""

import dataclasses
import errno
from pathlib import Path
import re
import threading

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, LIBRARY_IDENTIFIER, Writer
import mcap_ros2
import yaml

from qfa_ros.bag.part_files import (
    PART_SUFFIX,
    PartFile,
    publish_part,
    RecorderError,
)
from qfa_ros.bag.qos import dump_yaml, offered_qos_yaml
from qfa_ros.bag.types import (
    as_time_ns,
    canonical_type,
    check_cdr,
    definition_of,
    encode_message,
    type_hash_of,
)
from qfa_ros.model.safe_files import fsync_directory

__all__ = [
    'bag_metadata_head',
    'DEFAULT_CHUNK_SIZE',
    'file_bag_metadata',
    'file_entry',
    'McapBagWriter',
]

# rosbag2's MCAP plugin uses the mcap C++ default of 768 KiB per chunk.
DEFAULT_CHUNK_SIZE = 768 * 1024
BAG_METADATA_VERSION = 9
ROS_DISTRO = 'kilted'
LIBRARY = f'{LIBRARY_IDENTIFIER}; mcap-ros2-support {mcap_ros2.__version__}; qfa_ros recorder'

COMPRESSIONS = {
    'zstd': CompressionType.ZSTD,
    'lz4': CompressionType.LZ4,
    None: CompressionType.NONE,
    'none': CompressionType.NONE,
}
# Message record framing (31 bytes) plus its message index entry (16 bytes).
MESSAGE_OVERHEAD = 47
# Header, data end, statistics, summary offsets, footer, metadata index and the
# topic-independent part of the rosbag2 metadata YAML.
_BASE_FINISH_OVERHEAD = 1200
_TOPIC_RE = re.compile(r'^/?[A-Za-z_~][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$')


def file_bag_metadata(name, topics, first_time_ns, last_time_ns, custom_data=None,
                      ros_distro=ROS_DISTRO):
    """
    Return the rosbag2 ``BagMetadata`` mapping (version 9) of one MCAP file.

    Parameters
    ----------
    name : str
        The file name (``relative_file_paths``).
    topics : list of tuple
        ``(topic, msgtype, offered QoS YAML, type hash, message count)`` per topic.
    first_time_ns, last_time_ns : int or None
        Log times of the first and last message [ns]; None without messages.
    custom_data : mapping, optional
        rosbag2 ``custom_data``.
    ros_distro : str
        Distribution the bag says it was recorded with.
    """
    start = first_time_ns or 0
    duration = 0 if first_time_ns is None else last_time_ns - start
    message_count = sum(topic[4] for topic in topics)
    return {
        **bag_metadata_head(start, duration, message_count, [
            {
                'topic_metadata': {
                    'name': topic,
                    'type': msgtype,
                    'serialization_format': 'cdr',
                    'offered_qos_profiles': yaml.safe_load(qos_yaml) if qos_yaml else [],
                    'type_description_hash': type_hash,
                },
                'message_count': count,
            }
            for topic, msgtype, qos_yaml, type_hash, count in topics
        ]),
        'relative_file_paths': [name],
        'files': [file_entry(name, start, duration, message_count)],
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': ros_distro,
    }


def bag_metadata_head(start, duration, message_count, topics):
    """Return what begins rosbag2's ``BagMetadata`` mapping: counts, time span [ns], topics."""
    return {
        'version': BAG_METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': message_count,
        'topics_with_message_count': topics,
        # Chunk compression is storage-internal; rosbag2 leaves these empty for it.
        'compression_format': '',
        'compression_mode': '',
    }


def file_entry(path, start, duration, message_count):
    """Return a ``files`` entry of rosbag2's ``BagMetadata`` (times [ns])."""
    return {'path': path, 'starting_time': {'nanoseconds_since_epoch': start},
            'duration': {'nanoseconds': duration}, 'message_count': message_count}


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
        if compression not in COMPRESSIONS:
            raise ValueError(f'compression must be zstd, lz4 or None, got {compression!r}')
        if int(chunk_size) <= 0:
            raise ValueError(f'chunk_size must be positive, got {chunk_size!r}')
        self.part_path = self.path.with_name(self.path.name + PART_SUFFIX)
        self._overwrite = bool(overwrite)
        self._custom_data = {str(k): str(v) for k, v in (storage_metadata or {}).items()}
        self._extra_metadata = {}
        self._ros_distro = str(ros_distro)
        self._topics = {}
        self._schema_ids = {}
        self._first_time_ns = None
        self._last_time_ns = None
        self._message_count = 0
        # Protects the MCAP writer, the topics and schema ids, the message count and times,
        # the size accounting and _state: adding, finishing and aborting may come from
        # several threads.
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
        self._file = PartFile(self.part_path)
        try:
            self._writer = Writer(
                self._file,
                chunk_size=int(chunk_size),
                compression=COMPRESSIONS[compression],
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
        extra = 0 if not extra_message_bytes else extra_message_bytes + MESSAGE_OVERHEAD
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
        msgtype = canonical_type(msgtype)
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
            definition = definition_of(msgtype)
            new_schema = msgtype not in self._schema_ids
            if new_schema:
                self._schema_ids[msgtype] = self._guarded(
                    self._writer.register_schema, msgtype, SchemaEncoding.ROS2,
                    definition.encode())
            type_hash = type_hash_of(msgtype)
            channel_id = self._guarded(
                self._writer.register_channel,
                topic=topic,
                message_encoding=MessageEncoding.CDR,
                schema_id=self._schema_ids[msgtype],
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
        data = encode_message(message, entry.msgtype)
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
        self._write_data(entry, check_cdr(data, topic), log_time_ns, publish_time_ns)

    def write_serialized_many(self, topic, datas, log_times_ns, *, max_bytes=None,
                              before_ns=None):
        """Write messages of one topic already serialized to CDR, in order, while they fit.

        The same as ``write_serialized`` for each (publish time = log time),
        with the checks and the lock paid once per call: a recorder keeping
        up with a kHz stream spends its time in the MCAP records, not here.
        Every message is checked before any is written.

        Parameters
        ----------
        topic : str
            A topic registered with ``add_topic``.
        datas : sequence of bytes-like
            CDR bytes with encapsulation header, one per message.
        log_times_ns : sequence of int
            Receive time of each message [ns].
        max_bytes : int, optional
            Stop before a message that would take ``size_estimate`` past this
            (never before the file's first message).
        before_ns : int, optional
            Stop at the first message logged at or after this time [ns].

        Returns
        -------
        int
            How many messages were written, from the first.
        """
        if len(datas) != len(log_times_ns):
            raise ValueError(f'{topic}: {len(datas)} messages but {len(log_times_ns)} times')
        times = [as_time_ns(t, 'log_time_ns') for t in log_times_ns]
        return self._add_messages(self._topic(topic), [check_cdr(d, topic) for d in datas],
                                  times, times, max_bytes, before_ns)

    def _topic(self, topic):
        try:
            return self._topics[topic]
        except KeyError:
            raise KeyError(f'topic {topic!r} is not registered; call add_topic first') from None

    def _write_data(self, entry, data, log_time_ns, publish_time_ns):
        log_time_ns = as_time_ns(log_time_ns, 'log_time_ns')
        publish_time_ns = (log_time_ns if publish_time_ns is None
                           else as_time_ns(publish_time_ns, 'publish_time_ns'))
        self._add_messages(entry, [data], [log_time_ns], [publish_time_ns])

    def _add_messages(self, entry, datas, log_times, publish_times, max_bytes=None,
                      before_ns=None):
        """Add checked messages of one channel while they fit; return how many."""
        with self._lock:
            self._check_open()
            add_message, channel_id = self._writer.add_message, entry.channel_id
            sequence, written = entry.sequence, 0
            try:
                for data, log_time, publish_time in zip(datas, log_times, publish_times):
                    if before_ns is not None and log_time >= before_ns:
                        break
                    if (max_bytes is not None and self._message_count
                            and self.size_estimate(len(data)) > max_bytes):
                        break
                    add_message(channel_id=channel_id, log_time=log_time, data=data,
                                publish_time=publish_time, sequence=sequence)
                    self._account(len(data) + MESSAGE_OVERHEAD)
                    sequence = (sequence + 1) & 0xFFFFFFFF
                    written += 1
                    self._message_count += 1
            except OSError:
                self._fail()
                raise
            finally:
                entry.sequence = sequence
                entry.message_count += written
                if written:
                    first, last = min(log_times[:written]), max(log_times[:written])
                    if self._first_time_ns is None or first < self._first_time_ns:
                        self._first_time_ns = first
                    if self._last_time_ns is None or last > self._last_time_ns:
                        self._last_time_ns = last
        return written

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
        return file_bag_metadata(
            self.path.name,
            [(topic, entry.msgtype, entry.qos_yaml, entry.type_hash, entry.message_count)
             for topic, entry in self._topics.items()],
            self._first_time_ns, self._last_time_ns, self._custom_data, self._ros_distro)

    def add_metadata(self, name, record):
        """
        Add an MCAP metadata record ``name`` (str to str) written at ``finish()``.

        After the ``rosbag2`` record, in the order added; a second record of one name
        replaces the first.
        """
        if name == 'rosbag2':
            raise ValueError('metadata name rosbag2 is the bag metadata record')
        record = {str(k): str(v) for k, v in record.items()}
        with self._lock:
            self._check_open('add metadata to')
            self._extra_metadata[str(name)] = record
            self._finish_overhead += 64 + sum(len(k) + len(v) + 8 for k, v in record.items())

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
                    'rosbag2', {'serialized_metadata': dump_yaml(self.bag_metadata())}
                )
                for name, record in self._extra_metadata.items():
                    self._writer.add_metadata(name, record)
                self._writer.finish()
                self._file.sync_and_close()
                publish_part(self.part_path, self.path, self._overwrite)
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

    def flush(self):
        """
        Write the chunk in progress to the file now, compressed and indexed like any other.

        Called every fraction of a second, it bounds what a crash can lose to what came
        after the last call: the ``.part`` file then holds complete chunks up to it
        (:mod:`qfa_ros.bag.recovery` makes them a finished file). Without a message since
        the last chunk, nothing is written.

        Returns
        -------
        pathlib.Path
            The ``.part`` file, to hand to :func:`~qfa_ros.bag.part_files.make_durable` once no
            lock is held (an fsync may take long).
        """
        with self._lock:
            self._check_open('flush')
            self._guarded(self._writer.flush)
            self._account(0)
        return self.part_path

    def abort(self):
        """Stop writing without publishing; the ``.part`` file keeps the complete chunks."""
        with self._lock:
            if self._state == 'open':
                self._state = 'aborted'
                self._file.close()


