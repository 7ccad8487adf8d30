"""The flight recorder hook: what the node publishes, recorded as published."""

import os
from pathlib import Path

from rclpy.serialization import serialize_message

from qfa_ros.bag.files import RecorderError
from qfa_ros.bag.flight_recorder import FlightRecorder
from qfa_ros.model.triad import NS_PER_S

RECORDER_PARAMETERS = frozenset({'recorder.enabled', 'recorder.directory', 'recorder.max_bytes',
                                 'recorder.max_duration_s'})


class StreamRecording:
    """
    Record the node's own output (``recorder.*`` parameters) into a rosbag2 bag directory.

    A failed write stops the recording, never the stream; :attr:`problem` says why.
    The caller holds the node lock around every method.

    :param node: The node (its name prefixes the files; its logger reports).
    :param values: The node's live parameter values.
    :param qos: Offered QoS per recorded topic name.
    """

    def __init__(self, node, values, qos):
        self._node = node
        self._values = values
        self._qos = qos
        self.recorder = None
        self.problem = None

    @property
    def active(self):
        """Return True while a recording is open."""
        return self.recorder is not None

    @property
    def current_path(self):
        """Return the file being written, or None between files."""
        return None if self.recorder is None else self.recorder.current_path

    def restart(self):
        """Close the current recording and open one with the present parameters."""
        self.close()
        values = self._values
        if not values['recorder.enabled']:
            return
        max_bytes = values['recorder.max_bytes'] or None
        max_duration = values['recorder.max_duration_s']
        directory = Path(os.path.expanduser(values['recorder.directory']))
        try:
            directory.mkdir(parents=True, exist_ok=True)
            self.recorder = FlightRecorder(
                directory,
                prefix=self._node.get_name(), max_bytes=max_bytes,
                max_duration_ns=int(max_duration * NS_PER_S) if max_duration else None,
                qos=self._qos)
            self.problem = None
        except (OSError, ValueError) as error:
            self.problem = f'recorder not started: {error}'
            self._node.get_logger().error(self.problem)

    def close(self):
        """Finish the current file, if any; idempotent."""
        recorder, self.recorder = self.recorder, None
        if recorder is not None:
            try:
                files = recorder.close()
            except (OSError, RecorderError) as error:
                self.problem = f'recording not closed cleanly: {error}'
                return
            if files:
                self._node.get_logger().info(
                    f'recorded bag {recorder.bag_directory} ({len(files)} file(s))')

    def record(self, topic, msgtype, data, now_ns):
        """Record serialized ``data``; on failure stop recording and say why."""
        try:
            self.recorder.record(topic, msgtype, data, now_ns)
        except (OSError, ValueError) as error:
            self.problem = f'recording stopped: {error}'
            self._node.get_logger().error(self.problem)
            self.close()

    def publish(self, publisher, message, msgtype, now_ns=None):
        """Publish ``message`` and record the published bytes when recording."""
        if self.recorder is None:
            publisher.publish(message)
            return
        data = serialize_message(message)
        publisher.publish(data)
        self.record(publisher.topic_name, msgtype, data,
                    self._node.get_clock().now().nanoseconds if now_ns is None else now_ns)
