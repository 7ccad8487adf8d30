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

FREE_SPACE_CHECK_S = 1.0
"""Wall time between two free-space checks of a running recording [s]."""

GUARD_BAND_BYTES = 16 << 20
"""Margin above ``min_free_bytes`` at which writing stops [bytes]: more than the node
writes between two checks (about 0.4 MB/s at 10 kHz), so the floor itself is never crossed."""

MIB = float(1 << 20)


class FreeSpaceGuard:
    """
    Say when writing under a directory would take its file system under a free-space floor.

    :param floor_bytes: Free space to leave (``min_free_bytes``) [bytes].
    :param usage: ``shutil.disk_usage`` or a stand-in with the same result (tests).
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
    Thread-safe on its own lock, not the node's: a write the disk holds up (page-cache
    writeback stalls ``write`` for 100 ms and more) must not hold up the sensor thread.

    :param node: The node (its name prefixes the files; its logger reports).
    :param values: The node's live parameter values.
    :param qos: Offered QoS per recorded topic name.
    :param guard: :class:`FreeSpaceGuard` (default: ``min_free_bytes`` of ``values``).
    """

    def __init__(self, node, values, qos, guard=None):
        self._node = node
        self._values = values
        self._qos = qos
        self._guard = guard or FreeSpaceGuard(values['min_free_bytes'])
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
        # Protects the writer, its files and the fields above; re-entrant because a
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
            shortfall = self._guard.shortfall(directory, 'recorder.directory')
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
            self._next_check, self._checked_path = now + FREE_SPACE_CHECK_S, path
            shortfall = self._guard.shortfall(self.directory, 'recorder.directory')
            if shortfall:
                self._stop(f'recording stopped: {shortfall}', DiagnosticStatus.ERROR)

    def publish(self, publisher, message, msgtype, now_ns=None):
        """Publish ``message`` and record the published bytes when recording."""
        if self.recorder is None:
            publisher.publish(message)
            return
        data = serialize_message(message)
        publisher.publish(data)
        self.record(publisher.topic_name, msgtype, data,
                    self._node.get_clock().now().nanoseconds if now_ns is None else now_ns)
