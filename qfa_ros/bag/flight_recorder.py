"""Record serialized messages continuously into a rosbag2 bag directory split by size or time."""

import errno
import os
from pathlib import Path
import re
import threading
import time

from qfa_ros.bag.bag_directory import BagMetadata, default_bag_name, split_file_name
from qfa_ros.bag.part_files import (
    delete_finished_file,
    lock_exclusively,
    os_error_with_context,
    RecorderError,
)
from qfa_ros.bag.types import as_time_ns, canonical_type, definition_of
from qfa_ros.bag.writer import COMPRESSIONS, DEFAULT_CHUNK_SIZE, McapBagWriter
from qfa_ros.model.safe_files import fsync_directory


class FlightRecorder:
    """Record serialized messages continuously into a rosbag2 bag directory, split.

    The bag is a directory ``DIRECTORY/PREFIX_YYYY_MM_DD-HH_MM_SS`` (rosbag2's default
    name pattern, session start in UTC; ``_2``, ``_3``... if taken) holding
    ``NAME_0.mcap``, ``NAME_1.mcap``... and rosbag2's ``metadata.yaml`` (version 9), as
    ``ros2 bag record -s mcap --max-bag-size/--max-bag-duration`` writes it; ``ros2 bag
    play/info``, ``rosbags.rosbag2.Reader`` and ``qfa-replay`` open it. Each file is a
    complete, standalone rosbag2 MCAP file, written and published like ``McapBagWriter``
    writes them (``NAME_i.mcap.part`` until finished). Every time a file is finished,
    ``metadata.yaml`` is replaced atomically by one listing every finished file, so the
    directory is a valid bag of all finished files at any moment. A file is opened on the
    first message after the previous one closed, so no empty files; a session without
    messages leaves no directory.

    Crash safety: whoever records calls :meth:`flush` every fraction of a second (the
    node: every 0.25 s), which writes the chunk in progress and names what to fsync, so
    after a kill or a power cut the ``.part`` holds every message up to the last flush
    (the last fsync). ``qfa-report recover DIR`` (:mod:`qfa_ros.bag.recovery`) then
    finishes it and rewrites ``metadata.yaml``. The bag directory is ``flock``-ed from its
    creation to :meth:`close`, so that no recovery touches a recording in progress.

    Parameters
    ----------
    directory : str or os.PathLike
        Existing, writable directory.
    prefix : str
        Bag name prefix.
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
        Wall-clock time used in the bag name; default now.
    bag_name : str, optional
        The bag (directory) name instead of ``PREFIX_YYYY_MM_DD-HH_MM_SS``.

    Raises
    ------
    OSError
        The directory does not exist or is not writable.
    """

    def __init__(self, directory, prefix='qfa', *, max_bytes=None, max_duration_ns=None,
                 compression='zstd', chunk_size=None, qos=None, storage_metadata=None,
                 session_time_ns=None, bag_name=None):
        self.directory = Path(directory)
        if max_bytes is not None and int(max_bytes) < 1024:
            raise ValueError(f'max_bytes must be at least 1024, got {max_bytes!r}')
        if max_duration_ns is not None and as_time_ns(max_duration_ns, 'max_duration_ns') <= 0:
            raise ValueError('max_duration_ns must be positive')
        if not re.match(r'^[A-Za-z0-9_.-]+$', prefix):
            raise ValueError(f'prefix must be a plain file name part, got {prefix!r}')
        if compression not in COMPRESSIONS:
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
        base = bag_name or default_bag_name(prefix, as_time_ns(session_ns, 'session_time_ns'))
        if not re.match(r'^[A-Za-z0-9_.-]+$', base) or base.startswith('.'):
            raise ValueError(f'bag_name must be a plain directory name, got {base!r}')
        self._base_name = base
        self._check_directory()
        self.bag_directory = None
        # metadata.yaml: each finished file is added as it finishes, so a recording that
        # splits for days keeps a few hundred bytes per file (its whole metadata, the
        # topics' QoS parsed, was ~16 kB) and renders only the new file's entry.
        self._metadata = BagMetadata(self._storage_metadata)
        self._index = 0
        self._writer = None
        # (topic, msgtype) pairs registered in the current file: add_topic once per file.
        self._registered = set()
        self._file_start_ns = None
        # Protects the current writer and file, _registered, _file_start_ns, _index, the
        # file list, the metadata, _unsynced_directory, _flushed_bytes, _directory_lock and
        # _closed: record, flush and close may come from several threads.
        self._lock = threading.Lock()
        # The locked bag directory's descriptor (held from its creation to close()).
        self._directory_lock = None
        # Whether a file was created since the last flush(): its directory entry is synced.
        self._unsynced_directory = False
        # Bytes of the current file at the last flush(): an unchanged file needs no fsync.
        self._flushed_bytes = 0
        self._closed = False

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
            raise os_error_with_context(error, 'recording directory is not writable',
                                self.directory) from None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, traceback):
        # Unlike a single trace, a continuous recording is valid up to any point: keep it.
        self.close()
        return False

    @property
    def files(self):
        """Every file this recorder published so far, in order (in :attr:`bag_directory`)."""
        return [self.bag_directory / name for name in self._metadata.file_names]

    @property
    def current_path(self):
        """Final path of the file being written, or None between files."""
        return None if self._writer is None else self._writer.path

    def finished_entries(self):
        """
        Return what retention counts of this recording: its finished files, oldest first.

        Returns
        -------
        tuple
            The bag directory's name (None before the first file), ``(name, start [ns],
            duration [ns], message count)`` of each finished file, and the first message
            of the file being written [ns] (None between files).
        """
        with self._lock:
            name = None if self.bag_directory is None else self.bag_directory.name
            start = None if self._writer is None else self._file_start_ns
            return name, self._metadata.files, start

    def delete_finished(self, name):
        """
        Delete the finished file ``name`` crash-safely (retention); never the file being written.

        Its summary is read first (its topics' counts leave ``metadata.yaml``), then
        :func:`~qfa_ros.bag.part_files.delete_finished_file` marks, unlists and unlinks it.

        Parameters
        ----------
        name : str
            A finished file of this recording.

        Returns
        -------
        bool
            Whether it was deleted: False once the recorder is closed (its bag is then an
            earlier session's) or ``name`` is not a finished file of it.

        Raises
        ------
        OSError
            The deletion failed half way; what is on disk is a bag a recovery completes.
        """
        # Imported here: the recorder's own writing needs no summary reader.
        from qfa_ros.bag.part_repair import finished_file_metadata

        with self._lock:
            if self._closed or name not in self._metadata.file_names:
                return False
            path = self.bag_directory / name
        own = finished_file_metadata(path, recorder_only=True)
        with self._lock:
            if self._closed or name not in self._metadata.file_names:
                return False

            def unlist():
                self._metadata.remove(name, own)
                self._metadata.write(self.bag_directory)
            delete_finished_file(self._directory_lock, name, unlist)
            return True

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
        self.record_many(topic, msgtype, [data], [time_ns])

    def record_many(self, topic, msgtype, datas, times_ns):
        """Record serialized messages of one topic in order, as ``record`` each, faster.

        The files are split exactly where ``record`` would split them; the
        lock and the checks are paid once per file the messages go to.

        Parameters
        ----------
        topic, msgtype : str
            As for ``record``.
        datas : sequence of bytes-like
            CDR bytes, one per message.
        times_ns : sequence of int
            Receive time of each message [ns].
        """
        if len(datas) != len(times_ns):
            raise ValueError(f'{topic}: {len(datas)} messages but {len(times_ns)} times')
        times = [as_time_ns(t, 'time_ns') for t in times_ns]
        with self._lock:
            if self._closed:
                raise RecorderError(errno.EBADF, 'flight recorder is closed', str(self.directory))
            start = 0
            while start < len(datas):
                if self._writer is not None and self._limit_reached(
                        topic, msgtype, len(datas[start]), times[start]):
                    self._finish_current()
                if self._writer is None:
                    self._open_next(times[start])
                if (topic, msgtype) not in self._registered:
                    self._writer.add_topic(topic, msgtype, self._qos.get(topic))
                    self._registered.add((topic, msgtype))
                written = self._writer.write_serialized_many(
                    topic, datas[start:], times[start:], max_bytes=self._max_bytes,
                    before_ns=None if self._max_duration_ns is None
                    else self._file_start_ns + self._max_duration_ns)
                if not written:
                    # The topic's registration took the file to its limit: next file.
                    self._finish_current()
                start += written

    def _limit_reached(self, topic, msgtype, size, time_ns):
        if (self._max_duration_ns is not None
                and time_ns - self._file_start_ns >= self._max_duration_ns):
            return True
        if self._max_bytes is not None and self._writer.message_count:
            estimate = self._writer.size_estimate(size)
            if (topic, msgtype) not in self._registered:
                # Its schema, channel and metadata entry: definition twice, QoS thrice.
                estimate += 2 * len(definition_of(canonical_type(msgtype))) + 1500
            return estimate > self._max_bytes
        return False

    def _create_bag_directory(self):
        for attempt in range(1, 1000):
            name = self._base_name if attempt == 1 else f'{self._base_name}_{attempt}'
            path = self.directory / name
            try:
                path.mkdir()
            except FileExistsError:
                continue
            except OSError as error:
                raise os_error_with_context(error, 'cannot create bag directory', path) from None
            # Locked before any file is in it: a recovery that finds it unlocked finds it
            # empty (and leaves it so); retention may have removed it meanwhile, as a bag
            # left without a file (then the next name).
            try:
                descriptor = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW
                                     | os.O_CLOEXEC)
            except FileNotFoundError:
                continue
            try:
                lock_exclusively(descriptor, wait=True)
                removed = os.fstat(descriptor).st_nlink == 0
            except BaseException:
                os.close(descriptor)
                raise
            if removed:
                os.close(descriptor)
                continue
            self._directory_lock = descriptor
            fsync_directory(self.directory)
            self.bag_directory = path
            return
        raise FileExistsError(errno.EEXIST, 'no free bag directory name',
                              str(self.directory / self._base_name))

    def _open_next(self, time_ns):
        if self.bag_directory is None:
            self._create_bag_directory()
        path = self.bag_directory / split_file_name(self.bag_directory.name, self._index)
        self._writer = McapBagWriter(
            path, compression=self._compression, chunk_size=self._chunk_size,
            storage_metadata=self._storage_metadata,
        )
        self._index += 1
        self._registered = set()
        self._file_start_ns = time_ns
        self._unsynced_directory = True
        self._flushed_bytes = 0

    def _finish_current(self):
        writer, self._writer = self._writer, None
        writer.finish()
        self._metadata.add(writer.bag_metadata())
        self._metadata.write(self.bag_directory)

    def flush(self):
        """
        Write the chunk in progress of the current file; return what to fsync.

        Returns
        -------
        list of pathlib.Path
            The ``.part`` file if anything was written to it since the last call (and the
            bag directory after a new file appeared in it), for
            :func:`~qfa_ros.bag.part_files.make_durable`, called once no lock is held; empty
            between files.
        """
        with self._lock:
            if self._writer is None:
                return []
            part = self._writer.flush()
            # Nothing written since the last flush (the stream withheld): nothing to sync.
            paths = [] if self._writer.bytes_written == self._flushed_bytes else [part]
            self._flushed_bytes = self._writer.bytes_written
            if self._unsynced_directory:
                self._unsynced_directory = False
                paths.append(self.bag_directory)
            return paths

    def split(self):
        """Finish the current file now, if one is open; the next message starts the next.

        Returns
        -------
        pathlib.Path or None
            The file finished (listed in ``metadata.yaml``), or None.
        """
        with self._lock:
            if self._closed or self._writer is None:
                return None
            self._finish_current()
            return self.files[-1]

    def close(self):
        """Finish the current file and the bag's ``metadata.yaml``; idempotent.

        Returns
        -------
        list of pathlib.Path
            Every file this recorder published, in order (in :attr:`bag_directory`).
        """
        with self._lock:
            if not self._closed:
                self._closed = True
                try:
                    if self._writer is not None:
                        self._finish_current()
                finally:
                    if self._directory_lock is not None:
                        descriptor, self._directory_lock = self._directory_lock, None
                        os.close(descriptor)
            return list(self.files)
