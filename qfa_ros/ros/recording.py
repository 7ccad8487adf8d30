"""The flight recorder hook: what the node publishes, recorded as published, within limits."""

import shutil
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.serialization import serialize_message

from qfa_ros.bag.part_files import make_durable, RecorderError
from qfa_ros.model.safe_files import system_reason
from qfa_ros.model.triad import NS_PER_S
from qfa_ros.ros.bounds import confined_directory
from qfa_ros.ros.pacing import lower_thread_priority

FREE_SPACE_CHECK_S = 1.0
"""Wall time between two free-space checks of a running recording [s]."""

GUARD_BAND_BYTES = 16 << 20
"""Margin above ``min_free_bytes`` at which writing stops [bytes]: more than the node
writes between two checks (about 0.4 MB/s at 10 kHz), so the floor itself is never crossed."""

MIB = float(1 << 20)
GIB = float(1 << 30)

RETENTION_NICE = 19
"""Niceness added to a retention pass's thread (Linux): the least of the node's threads, as
the start-up recovery's. Deleting old files may wait on the disk; nothing waits for it."""


class FreeSpaceGuard:
    """
    Say when writing under a directory would take its file system under a free-space floor.

    Parameters
    ----------
    floor_bytes
        Free space to leave (``min_free_bytes``) [bytes].
    usage
        ``shutil.disk_usage`` or a stand-in with the same result (tests).
    """

    def __init__(self, floor_bytes, usage=shutil.disk_usage):
        self.floor_bytes = int(floor_bytes)
        self._usage = usage

    def shortfall(self, directory, name):
        """
        Return why nothing more may be written under ``directory``, or None.

        ``name``: the parameter that set ``directory``, what the reason names (a
        participant reads it: never the resolved path, as long as the value).
        """
        try:
            free = self._usage(directory).free
        except OSError as error:
            return f'free space of {name} unknown ({system_reason(error)})'
        if free < self.floor_bytes + GUARD_BAND_BYTES:
            return (f'only {free / MIB:.0f} MiB free on the file system of {name}; '
                    f'min_free_bytes keeps {self.floor_bytes / MIB:.0f} MiB free')
        return None


class StreamRecording:
    """
    Record the node's own output (``recorder.*`` parameters) into a rosbag2 bag directory.

    The recording goes to ``recorder.directory`` confined to ``output_dir``, split by
    the (finite, positive) ``recorder.max_bytes`` and ``recorder.max_duration_s``. The
    free space is checked when a recording or a file starts and every
    :data:`FREE_SPACE_CHECK_S`; before it falls under ``min_free_bytes`` the recording
    stops (the current file finished under its final name) with an ERROR diagnostic.
    A failed write stops the recording, never the stream; :attr:`problem` says why.

    Retention (``recorder.keep_s``, ``recorder.keep_bytes``, :mod:`qfa_ros.bag.retention`)
    deletes the oldest finished files of the node's bags in the directory beyond the
    limits: a pass when a recording starts and after each file finished, on a thread of its
    own at low priority, and at once before the free space would stop the recording (the
    floor is the last resort). It applies only in the ``recorder.directory`` the node
    started with (``operator_values``): a participant who moves the recording elsewhere
    cannot have files deleted there.

    Thread-safe on its own lock, not the node's: a write the disk holds up (page-cache
    writeback stalls ``write`` for 100 ms and more) must not hold up the sensor thread.

    Parameters
    ----------
    node
        The node (its name prefixes the files; its logger reports).
    values
        The node's live parameter values.
    qos
        Offered QoS per recorded topic name.
    guard
        :class:`FreeSpaceGuard` (default: ``min_free_bytes`` of ``values``).
    operator_values
        The parameter values the node started with (default: ``values`` as they are now): retention
        applies only in their ``recorder.directory``.
    """

    def __init__(self, node, values, qos, guard=None, operator_values=None):
        self._node = node
        self._values = values
        self._qos = qos
        self._guard = guard or FreeSpaceGuard(values['min_free_bytes'])
        self._operator_values = dict(operator_values or values)
        # The Retention of the directory recorded into (None: no limit set, or not the
        # operator's directory; retention_note says which); kept over restarts in the same
        # directory, so that what it deleted adds up since start.
        self.retention = None
        self.retention_note = 'off'
        # Whether a retention pass is wanted, and the thread running passes (None: none).
        self._retention_due = False
        self._retention_thread = None
        self.recorder = None
        self.directory = None
        self.problem = None
        # Level of the stream diagnostic while there is a problem: WARN for a write
        # error, ERROR when the recording stopped for lack of free space.
        self.problem_level = DiagnosticStatus.OK
        self._next_check = 0.0
        self._checked_path = None
        # Called with the problem (the recording's lock held, any thread; it must not block)
        # when the recording stops for lack of free space: a managed node's fault.
        self.on_free_space_floor = None
        # Protects the writer, its files and the fields above (retention's included; a
        # pass itself runs without it, on Retention's own lock); re-entrant because a
        # failed write stops (closes) the recording from inside record, and a caller may
        # hold it around several calls (drain a queue, then restart).
        self.lock = threading.RLock()

    @property
    def active(self):
        """Return True while a recording is open."""
        return self.recorder is not None

    @property
    def current_path(self):
        """Return the file being written, or None between files."""
        return None if self.recorder is None else self.recorder.current_path

    def offer(self, qos):
        """Add the offered QoS of more topics (``{topic: QosProfile}``), from the next file on."""
        with self.lock:
            self._qos = {**self._qos, **qos}

    def _stop(self, problem, level):
        self.problem, self.problem_level = problem, level
        self._node.get_logger().error(problem)
        self.close()
        if level == DiagnosticStatus.ERROR and self.on_free_space_floor is not None:
            self.on_free_space_floor(problem)

    def restart(self):
        """Close the current recording and open one with the present parameters."""
        with self.lock:
            self._restart()

    def _restart(self):
        self.close()
        self.problem, self.problem_level = None, DiagnosticStatus.OK
        values = self._values
        if not values['recorder.enabled']:
            return
        try:
            directory = confined_directory(values, 'recorder.directory')
            directory.mkdir(parents=True, exist_ok=True)
            self._choose_retention(directory)
            shortfall = self._floor_reached(directory, None)
            if shortfall:
                self._stop(f'recorder not started: {shortfall}', DiagnosticStatus.ERROR)
                return
            # Imported here: the MCAP writer's packages load only when a recording starts.
            from qfa_ros.bag.flight_recorder import FlightRecorder
            self.recorder = FlightRecorder(
                directory, prefix=self._node.get_name(), max_bytes=values['recorder.max_bytes'],
                max_duration_ns=int(values['recorder.max_duration_s'] * NS_PER_S),
                qos=self._qos)
            self.directory = directory
            self._next_check = time.monotonic() + FREE_SPACE_CHECK_S
            self._checked_path = None
            self._retain_soon()
        except (OSError, ValueError) as error:
            # What a participant reads (a refused change, /rosout): the rule or the
            # system's words, never the path (resolved, and as long as the value).
            reason = f'recorder.directory: {system_reason(error)}' \
                if isinstance(error, OSError) else error
            self._stop(f'recorder not started: {reason}', DiagnosticStatus.WARN)

    def split(self):
        """Finish the current file now (readable as it is); the next message starts the next."""
        with self.lock:
            if self.recorder is None:
                return
            try:
                path = self.recorder.split()
            except (OSError, RecorderError) as error:
                self._stop(f'recording stopped: {error}', DiagnosticStatus.WARN)
                return
            if path is not None:
                self._node.get_logger().info(f'recording file finished: {path}')
                self._retain_soon()

    def close(self):
        """Finish the current file, if any; idempotent."""
        with self.lock:
            recorder, self.recorder = self.recorder, None
            if recorder is None:
                return
            try:
                files = recorder.close()
            except (OSError, RecorderError) as error:
                self.problem = f'recording not closed cleanly: {error}'
                self.problem_level = DiagnosticStatus.WARN
                return
            if files:
                self._node.get_logger().info(
                    f'recorded bag {recorder.bag_directory} ({len(files)} file(s))')

    def checkpoint(self):
        """
        End the chunk in progress and fsync the recording (the recording thread, periodically).

        The fsync runs outside every lock: a disk that holds it up delays only the
        recording thread, never a ``record`` call from the executor. A failure stops the
        recording with a WARN, as a failed write does.
        """
        with self.lock:
            if self.recorder is None:
                return
            recorder = self.recorder
            try:
                paths = recorder.flush()
            except (OSError, ValueError) as error:
                self._stop(f'recording stopped: {error}', DiagnosticStatus.WARN)
                return
        try:
            make_durable(paths)
        except OSError as error:
            with self.lock:
                if self.recorder is recorder:
                    self._stop(f'recording stopped: fsync failed: {error}',
                               DiagnosticStatus.WARN)

    def record(self, topic, msgtype, data, now_ns):
        """Record serialized ``data``; on failure or low free space stop recording and say why."""
        with self.lock:
            if self.recorder is not None:
                self._record(topic, msgtype, [data], [now_ns])

    def record_runs(self, runs):
        """
        Record ``(topic, msgtype, datas, times_ns)`` runs in order, under one lock round.

        A run is consecutive messages of one topic; each is written with one call.
        """
        with self.lock:
            for topic, msgtype, datas, times_ns in runs:
                if self.recorder is None:
                    return
                self._record(topic, msgtype, datas, times_ns)

    def _record(self, topic, msgtype, datas, times_ns):
        try:
            self.recorder.record_many(topic, msgtype, datas, times_ns)
        except (OSError, ValueError) as error:
            self._stop(f'recording stopped: {error}', DiagnosticStatus.WARN)
            return
        path = self.recorder.current_path
        now = time.monotonic()
        if now >= self._next_check or path != self._checked_path:
            # Each new file and every FREE_SPACE_CHECK_S: one statvfs call.
            if path != self._checked_path and self._checked_path is not None:
                self._retain_soon()  # a file finished
            self._next_check, self._checked_path = now + FREE_SPACE_CHECK_S, path
            shortfall = self._floor_reached(self.directory, self.recorder)
            if shortfall:
                self._stop(f'recording stopped: {shortfall}', DiagnosticStatus.ERROR)

    # Retention ------------------------------------------------------------------------
    def _choose_retention(self, directory):
        """Keep, make or drop the Retention for ``directory`` (the lock held)."""
        values = self._values
        keep_ns = int(round(values['recorder.keep_s'] * NS_PER_S))
        keep_bytes = int(values['recorder.keep_bytes'])
        try:
            operator = confined_directory(self._operator_values, 'recorder.directory')
        except ValueError:
            operator = None
        if not (keep_ns or keep_bytes):
            self.retention, self.retention_note = None, 'off (recorder.keep_s and ' \
                'recorder.keep_bytes are 0: no limit)'
        elif directory != operator:
            self.retention, self.retention_note = None, 'off: recorder.directory is not ' \
                'the one the node started with'
        elif self.retention is None or self.retention.directory != directory:
            # Imported here: the MCAP packages load only when a recording starts.
            from qfa_ros.bag.retention import Retention
            self.retention = Retention(directory, self._node.get_name(), keep_ns, keep_bytes)
            self.retention_note = (f'keeps {_duration(keep_ns)} of recording'
                                   if keep_ns else 'no duration limit') + \
                (f', at most {keep_bytes / GIB:.3g} GiB' if keep_bytes else ', no size limit')

    def _floor_reached(self, directory, recorder):
        """
        Return why the free space stops the recording, or None (the lock held).

        Retention goes first: short of the floor, a pass runs at once (the file being
        written is never deleted), then the free space is looked at again.
        """
        shortfall = self._guard.shortfall(directory, 'recorder.directory')
        if shortfall and self.retention is not None:
            self._retain(self.retention, recorder)
            shortfall = self._guard.shortfall(directory, 'recorder.directory')
        return shortfall

    def retain(self):
        """Have a retention pass run soon (a recording finished elsewhere: a recovered one)."""
        with self.lock:
            self._retain_soon()

    def _retain_soon(self):
        """Have a pass run on the retention thread (started if none runs; the lock held)."""
        if self.retention is None:
            return
        self._retention_due = True
        if self._retention_thread is None:
            self._retention_thread = threading.Thread(
                target=self._retention_passes, name='qfa_retention', daemon=True)
            self._retention_thread.start()

    def _retention_passes(self):
        """Run passes while one is due, then end (the retention thread)."""
        lower_thread_priority(RETENTION_NICE)
        while True:
            with self.lock:
                if not self._retention_due or self.retention is None:
                    self._retention_thread = None
                    return
                self._retention_due = False
                retention, recorder = self.retention, self.recorder
            self._retain(retention, recorder)

    def _retain(self, retention, recorder):
        """Run one retention pass; log what it deleted (never raises)."""
        before = retention.summary.deleted
        try:
            summary = retention.apply(recorder)
        except Exception as error:  # a thread of the node never raises; it says why
            retention.summary.problem = f'{type(error).__name__}: {error}'
            self._node.get_logger().error(f'retention pass failed: {retention.summary.problem}')
            return
        if summary.deleted > before:
            self._node.get_logger().info(
                f'retention deleted {summary.deleted - before} recording file(s) in '
                f'{retention.directory}: {_kept(summary)}')

    def retention_values(self):
        """Return the ``stream`` diagnostic's retention key values: what it deleted and kept."""
        # Without the lock: a pass before the floor may hold it for long; each attribute is
        # replaced whole.
        retention, note = self.retention, self.retention_note
        if not self.active and retention is None:
            return []
        values = [('retention', note)]
        if retention is not None:
            summary = retention.summary
            values += [('retention deleted', f'{summary.deleted} file(s), '
                        f'{summary.deleted_bytes / MIB:.1f} MiB since start'),
                       ('retention kept', _kept(summary))]
            if summary.problem:
                values.append(('retention problem', summary.problem))
        return values

    def publish(self, publisher, message, msgtype, now_ns=None):
        """Publish ``message`` and record the published bytes when recording."""
        if self.recorder is None:
            publisher.publish(message)
            return
        data = serialize_message(message)
        publisher.publish(data)
        self.record(publisher.topic_name, msgtype, data,
                    self._node.get_clock().now().nanoseconds if now_ns is None else now_ns)


def _duration(ns):
    """Return a duration [ns] in the unit that reads best: s, min or h."""
    seconds = ns / NS_PER_S
    if seconds >= 3600.0:
        return f'{seconds / 3600.0:.4g} h'
    return f'{seconds / 60.0:.4g} min' if seconds >= 60.0 else f'{seconds:.4g} s'


def _kept(summary):
    """Return what a retention pass kept: files, size, time covered and since when."""
    if not summary.kept:
        return 'no finished file'
    # Imported here: the MCAP packages load only when a recording starts.
    from qfa_ros.bag.part_repair import utc_text
    return (f'{summary.kept} finished file(s), {summary.kept_bytes / MIB:.1f} MiB, '
            f'{_duration(summary.kept_ns)} of recording since '
            f'{utc_text(summary.oldest_kept_ns)}')
