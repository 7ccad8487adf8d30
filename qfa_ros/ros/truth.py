"""
Publish the truth INS developers need, and the calibration events of the node.

Topics: ``truth/odometry``, ``truth/origin``, ``truth/imu_errors`` and
``~/calibration_events`` (``docs/ins.md`` has the layouts).

A timer on the executor at ``truth.rate_hz`` reads, under the node lock, the last sample
the sensor thread computed (its stamp and the model's sensor time at its end) and
publishes what the model holds then: the pose on the input trajectory, its origin
(again whenever the input changes), and the sensor's errors
(:func:`qfa_ros.model.error_truth.error_truth`). Nothing runs on the per-sample path.

A correction applied in place (a schedule's result, ``~/set_compensation``) changes the
loop words, the temperature compensation or the gyro bias correction. Where the node
applies one, :meth:`TruthPublisher.mark` records the words and the errors right after it
and the first sample computed with it, under the kind of the service that applied it
(its row in :data:`~qfa_ros.ros.service_table.SERVICES`); the next tick publishes one
``diagnostic_msgs/DiagnosticStatus`` on ``~/calibration_events`` (transient local) per
marked correction that changed something, each against the one before it, so two
corrections within one tick give two events. Every correction the node applies is marked;
a change seen between two ticks that nobody marked would be published under the schedule
seen running, or as :data:`UNATTRIBUTED` with a warning in the log.
"""

import math

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

from qfa_ros.model.constants import DEG_PER_HOUR, MICRO_G, PPM
from qfa_ros.model.error_truth import error_truth
from qfa_ros.model.loop_response import CORRECTION_SETTLE_BAND, feedback_step_transient
from qfa_ros.model.triad import NS_PER_S
from qfa_ros.ros.topic_table import create_publisher, TOPIC, TRUTH_FRAME_ID

POSE_MODES = ('static', 'trajectory')
"""Input modes with a pose on the Earth (``profile`` scripts a specific force only)."""
UNATTRIBUTED = 'unattributed'
"""The kind of an event whose correction no service marked (none is known to)."""
TRUTH_TOPICS = {'events': '~/calibration_events', 'odometry': 'truth/odometry',
                'origin': 'truth/origin', 'errors': 'truth/imu_errors'}
"""The row in the topic table of each truth publisher."""
TYPES = {key: TOPIC[name].type_name for key, name in TRUTH_TOPICS.items()}
"""The message type of each truth publisher, as the flight recorder writes it."""


def _stamp(message_stamp, time_ns):
    message_stamp.sec, message_stamp.nanosec = divmod(int(time_ns), NS_PER_S)


def imu_errors_message(truth, stamp_ns, frame_id):
    """
    Return the ``truth/imu_errors`` :class:`sensor_msgs.msg.Imu` of an :class:`ErrorTruth`.

    ``linear_acceleration``: accelerometer bias [m/s^2]; ``angular_velocity``: gyro bias
    [rad/s]; ``linear_acceleration_covariance`` and ``angular_velocity_covariance``: the
    matrices ``N_a``, ``N_g`` row-major (diagonal scale-factor errors, off-diagonal
    misalignment) [1]; ``orientation_covariance``: accelerometer K2 x, y, z
    [1/(m/s^2)], gyro asymmetry x, y, z [1], body temperature [degC], 0, 0;
    ``orientation`` the identity.
    """
    message = Imu()
    _stamp(message.header.stamp, stamp_ns)
    message.header.frame_id = frame_id
    message.orientation.w = 1.0
    fields = truth.imu_fields()
    for name in ('linear_acceleration', 'angular_velocity'):
        vector = getattr(message, name)
        vector.x, vector.y, vector.z = fields[name]
    for name in ('linear_acceleration_covariance', 'angular_velocity_covariance',
                 'orientation_covariance'):
        setattr(message, name, fields[name])
    return message


class TruthPublisher:
    """
    Publish the truth topics and the calibration events of the node.

    Parameters
    ----------
    node
        The node (publishers, timer, clock).
    lock
        The node lock (the model and the stream are read under it).
    triad
        The model.
    values
        The node's live parameter values (``truth.*``, ``frame_id``, ``input.mode``,
        ``hardware_id``).
    stream
        The :class:`~qfa_ros.ros.stream.SampleStream` (its grid and schedule).
    recording
        The :class:`~qfa_ros.ros.recording.StreamRecording`: what is published is recorded too,
        while a flight recording runs (:meth:`offered_qos` gives it the topics' QoS).
    """

    def __init__(self, node, lock, triad, values, stream, recording):
        self._node = node
        self._recording = recording
        self._lock = lock  # the node lock: the model and the stream's grid are read under it
        self._triad = triad
        self._values = values
        self._stream = stream
        self.enabled = bool(values['truth.enabled'])
        # The QoS of each is its row's in the topic table (the bags' too: qfa_ros.bag.qos).
        self.events = create_publisher(node, TRUTH_TOPICS['events'])
        self.odometry = self.origin = self.errors = None
        if self.enabled:
            self.odometry = create_publisher(node, TRUTH_TOPICS['odometry'])
            self.origin = create_publisher(node, TRUTH_TOPICS['origin'])
            self.errors = create_publisher(node, TRUTH_TOPICS['errors'])
        self._profile = None
        self._fingerprint = None
        self._before = None
        self._marks = []  # (sample index, kind, words, ErrorTruth) per correction since the tick
        self._last_kind = None
        self._position = None
        self.published = 0
        self.event_count = 0
        self.timer = node.create_timer(1.0 / values['truth.rate_hz'], self.tick)

    def chain(self, callback):
        """Return ``callback`` preceded by :meth:`mark` (the stream's schedule-end hook)."""
        def marked(kind):
            self.mark(kind)
            callback()
        return marked

    def mark(self, kind):
        """
        Note that a correction ``kind`` may have been applied now: the next sample has it.

        ``kind`` is the kind of the service that applied it (its row's ``kind`` in
        :data:`~qfa_ros.ros.service_table.SERVICES`).

        Records the words and the errors the model holds now, so that each correction
        gets its own event even when several come within one tick. Called with the node
        lock held (by the sensor thread at a schedule's end, by the ``~/set_compensation``
        callback); takes no lock.
        """
        if self._fingerprint is None:
            return  # before the first tick: nothing to compare the correction with
        self._marks.append((self._stream.grid.next_index, kind, self._words(),
                            self._error_truth()[0]))

    def _unmarked_kind(self):
        """Return the kind of a change nobody marked: the schedule seen running, or none."""
        if self._last_kind is not None:
            return self._last_kind
        self._node.get_logger().warning(
            'a correction no service marked: published on ~/calibration_events as '
            f'{UNATTRIBUTED}')
        return UNATTRIBUTED

    def _error_truth(self):
        """Return the :class:`ErrorTruth` of the model now, and whether the input has a pose."""
        triad = self._triad
        profile = triad.profile
        pose_input = self._values['input.mode'] in POSE_MODES \
            and hasattr(profile, 'local_pose') and triad.fixture is None
        force = profile.evaluate(np.array([triad.time]))[0] if pose_input else None
        return error_truth(triad, force), pose_input

    def _words(self):
        triad = self._triad
        loops = tuple((loop.n_fpga, loop.n_vref, loop.controller.gain) for loop in triad.axes)
        return loops, (triad.temperature_compensation, id(triad.temperature_compensator),
                       tuple(np.asarray(triad.gyro_bias_correction).tolist()))

    def tick(self):
        """Publish the truth of the last computed sample; detect applied corrections."""
        messages = []
        with self._lock:
            grid, triad = self._stream.grid, self._triad
            position = (grid.next_index, triad.sample_index)
            previous, self._position = self._position, position
            schedule = self._stream.schedule
            if schedule is not None:
                self._last_kind = schedule.kind
            if grid.start_ns is None or grid.next_index == 0 or previous is None:
                return
            # No sample computed since the last tick (the sensor thread computes a batch
            # every stream.batch_s, the timer runs on its own): the last one has had its
            # truth already; a second message would repeat its stamp and state.
            if position[0] == previous[0]:
                return
            # The grid and the model advanced together since the last tick (no fast
            # schedule, no skip between): the last computed sample ends at triad.time.
            in_step = position[0] - previous[0] == position[1] - previous[1]
            if schedule is not None or not in_step or any(
                    loop.open_loop for loop in triad.axes):
                return
            stamp_ns = int(grid.stamp_ns(grid.next_index - 1))
            t = triad.time
            profile = triad.profile
            truth, pose_input = self._error_truth()
            words = self._words()
            marks, self._marks = self._marks, []
            for index, kind, marked_words, marked_truth in marks:
                if marked_words != self._fingerprint:
                    messages.append(('events', self._event(
                        kind or self._unmarked_kind(), marked_words, marked_truth, index)))
                self._fingerprint, self._before = marked_words, marked_truth
            if self._fingerprint is not None and words != self._fingerprint:
                messages.append(('events', self._event(
                    self._unmarked_kind(), words, truth, grid.next_index - 1)))
            self._fingerprint, self._before = words, truth
            self._last_kind = None
            if self.enabled:
                frame_id = self._values['frame_id']
                messages.append(('errors', imu_errors_message(truth, stamp_ns, frame_id)))
                if pose_input:
                    if profile is not self._profile:
                        self._profile = profile
                        messages.append(('origin', self._origin_message(profile, stamp_ns)))
                    messages.append(('odometry', self._odometry_message(
                        profile, t, stamp_ns, frame_id)))
        # Published outside the lock: the middleware must not hold up the sensor thread.
        for kind, message in messages:
            self._recording.publish(getattr(self, kind), message, TYPES[kind])
            if kind == 'events':
                self.event_count += 1
            else:
                self.published += 1

    def offered_qos(self):
        """Return the QoS (:class:`~qfa_ros.bag.qos.QosProfile`) of each truth topic."""
        return {getattr(self, key).topic_name: TOPIC[name].qos
                for key, name in TRUTH_TOPICS.items() if getattr(self, key) is not None}

    def _event(self, kind, words, truth, index):
        """
        Return the event of the correction ``kind`` to ``words``, against the one before.

        ``index`` is the grid index of the first sample with the correction.
        """
        before = self._before
        grid = self._stream.grid
        stamp_ns = int(grid.stamp_ns(index))
        scale = (np.diag(truth.accel_matrix) - np.diag(before.accel_matrix)) / PPM
        bias = (truth.accel_bias - before.accel_bias) / MICRO_G
        gyro = np.nan_to_num(truth.gyro_bias - before.gyro_bias) / DEG_PER_HOUR
        first, peak, settled = self._transient(words)
        settled_ns = int(grid.stamp_ns(index + settled))
        values = [('kind', kind), ('stamp_ns', str(stamp_ns)),
                  ('settled_stamp_ns', str(settled_ns)),
                  ('transient_first_fraction', f'{first:.3f}'),
                  ('transient_peak_fraction', f'{peak:.3f}'),
                  ('settle_band', f'{CORRECTION_SETTLE_BAND:g}'),
                  ('temperature_compensation', 'on' if words[1][0] else 'off')]
        for i, axis in enumerate('xyz'):
            values += [(f'accel_scale_change_ppm_{axis}', f'{scale[i]:.3f}'),
                       (f'accel_bias_change_ug_{axis}', f'{bias[i]:.3f}'),
                       (f'gyro_bias_change_deg_per_h_{axis}', f'{gyro[i]:.6f}')]
        return DiagnosticStatus(
            level=DiagnosticStatus.OK, name=f'{self._node.get_name()}: calibration event',
            message=f'{kind} applied in place from stamp {stamp_ns}, output settled from '
                    f'stamp {settled_ns}',
            hardware_id=self._values['hardware_id'],
            values=[KeyValue(key=k, value=v) for k, v in values])

    def _transient(self, words):
        """
        Return (first fraction, peak fraction, settled samples) of a correction's output.

        A new feedback word (N_VREF) makes the loop answer as to a step of its input
        (:func:`~qfa_ros.model.loop_response.feedback_step_transient`, the changed axes'
        worst); the forward gain moves no settled output (a loop at rest, no transient
        above its quantization), and the temperature compensation and the gyro bias
        correction are digital: a step at the first sample.
        """
        changed = [axis for axis, (after, before) in enumerate(zip(words[0],
                                                                   self._fingerprint[0]))
                   if after[1] != before[1]]
        if not changed:
            return 1.0, 1.0, 0
        transients = [feedback_step_transient(self._triad.config,
                                              self._triad.axes[axis].controller)
                      for axis in changed]
        return (min(t.first_fraction for t in transients),
                max(t.peak_fraction for t in transients),
                max(t.settled_samples for t in transients))

    def _origin_message(self, profile, stamp_ns):
        k = profile.kinematics(np.array([profile.start]))
        message = NavSatFix()
        _stamp(message.header.stamp, stamp_ns)
        message.header.frame_id = TRUTH_FRAME_ID
        message.status.status = NavSatStatus.STATUS_FIX
        message.latitude = math.degrees(float(k['latitude'][0]))
        message.longitude = math.degrees(float(k['longitude'][0]))
        message.altitude = float(k['height'][0])
        message.position_covariance_type = NavSatFix.COVARIANCE_TYPE_KNOWN
        return message

    def _odometry_message(self, profile, t, stamp_ns, frame_id):
        position, orientation, velocity, rate = (a[0] for a in profile.local_pose(
            np.array([t])))
        message = Odometry()
        _stamp(message.header.stamp, stamp_ns)
        message.header.frame_id = TRUTH_FRAME_ID
        message.child_frame_id = frame_id
        pose, twist = message.pose.pose, message.twist.twist
        pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
        q = [float(v) for v in orientation]
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = q
        twist.linear.x, twist.linear.y, twist.linear.z = (float(v) for v in velocity)
        twist.angular.x, twist.angular.y, twist.angular.z = (float(v) for v in rate)
        return message

