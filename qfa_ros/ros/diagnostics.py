"""Diagnostics: the node's health on ``/diagnostics`` at about 1 Hz, not at the IMU rate."""

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from qfa_ros.ros.topic_table import create_publisher

DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'


def temperature_status(triad, keeper, last_reading_c):
    """Return ``(level, message, key values)`` for the ``temperature`` diagnostic."""
    thermal = triad.thermal
    rom = 'stored' if keeper.state.temperature else 'none'
    compensating = 'on' if triad.temperature_compensation else 'off'
    values = [('thermal model', 'on' if thermal else 'off'),
              ('temperature compensation', compensating), ('temperature ROM', rom)]
    if last_reading_c is not None:
        values.append(('reading [degC]', f'{last_reading_c:.3f}'))
    if thermal is None:
        values.append(('sensor temperature [degC]', f'{triad.temperature:.2f}'))
        return DiagnosticStatus.OK, 'no thermal model: constant temperature', values
    values += [('ambient profile', thermal.config.ambient_profile),
               ('body temperature [degC]', f'{thermal.sensor_c:.3f}')]
    if compensating == 'on':
        return DiagnosticStatus.OK, 'zero bias compensated (fixed-point CORDIC)', values
    return DiagnosticStatus.OK, 'uncompensated: call calibrate_temperature', values


class Diagnostics:
    """
    Publish the ``stream``, ``calibration``, ``temperature`` and ``input`` statuses.

    Creates the ``/diagnostics`` publisher (its row in the topic table) and the timer at
    ``diagnostics_rate_hz`` that publishes and records them.

    Parameters
    ----------
    node
        The node (publisher, timer, name, clock).
    lock
        The node lock (every status is read under it).
    values
        The node's live parameter values (``hardware_id``, ``diagnostics_rate_hz``; read only).
    recording
        :class:`~qfa_ros.ros.recording.StreamRecording` (publishes and records).
    sources
        ``(topic, callable returning (level, message, key values))`` pairs.
    """

    def __init__(self, node, lock, values, recording, sources):
        self._node = node
        self._lock = lock  # the node lock: every status is read under it
        self._values = values
        self._recording = recording
        self._sources = sources
        self._publisher = create_publisher(node, '/diagnostics')
        self.timer = node.create_timer(1.0 / values['diagnostics_rate_hz'], self.timer_callback)

    def array(self):
        """Return a :class:`DiagnosticArray` of every status (call with the node lock held)."""
        array = DiagnosticArray()
        array.header.stamp = self._node.get_clock().now().to_msg()
        # As diagnostic_updater names them: 'node_name: task', no namespace, no slash;
        # hardware_id tells two units apart.
        prefix = self._node.get_name()
        for topic, source in self._sources:
            level, message, values = source()
            array.status.append(DiagnosticStatus(
                level=level, name=f'{prefix}: {topic}', message=message,
                hardware_id=self._values['hardware_id'],
                values=[KeyValue(key=k, value=str(v)) for k, v in values]))
        return array

    def timer_callback(self):
        """Publish the stream, calibration, temperature and input status (about 1 Hz)."""
        with self._lock:
            array = self.array()
        # Published and recorded outside the node lock: the recording's lock may wait for
        # the disk, and the sensor thread must not wait behind it.
        self._recording.publish(self._publisher, array, DIAGNOSTICS_TYPE)
