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
loop words, the temperature compensation or the gyro bias correction; the timer sees the
change between two ticks without a schedule running and publishes one
``diagnostic_msgs/DiagnosticStatus`` on ``~/calibration_events`` (transient local), stamped
with the first sample computed after the change (:meth:`TruthPublisher.mark` records it
exactly where the node knows it).
"""

import math

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

from qfa_ros.bag.qos import QOS_LATCHED, QosProfile
from qfa_ros.model.error_truth import error_truth
from qfa_ros.model.triad import NS_PER_S
from qfa_ros.model.units import DEG_PER_HOUR, MICRO_G, PPM

TRUTH_FRAME_ID = 'enu_origin'
"""Frame of ``truth/odometry``: the ENU tangent plane at ``truth/origin``."""
POSE_MODES = ('static', 'trajectory')
"""Input modes with a pose on the Earth (``profile`` scripts a specific force only)."""
EVENT_DEPTH = 20
"""Calibration events a late subscriber still gets (transient local)."""
TYPES = {'events': 'diagnostic_msgs/msg/DiagnosticStatus', 'odometry': 'nav_msgs/msg/Odometry',
         'origin': 'sensor_msgs/msg/NavSatFix', 'errors': 'sensor_msgs/msg/Imu'}
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

    :param node: The node (publishers, timer, clock).
    :param lock: The node lock (the model and the stream are read under it).
    :param triad: The model.
    :param values: The node's live parameter values (``truth.*``, ``frame_id``,
        ``input.mode``, ``hardware_id``).
    :param stream: The :class:`~qfa_ros.ros.stream.SampleStream` (its grid and schedule).
    :param recording: The :class:`~qfa_ros.ros.recording.StreamRecording`: what is published
        is recorded too, while a flight recording runs (:meth:`offered_qos` gives it the
        topics' QoS).
    """

    def __init__(self, node, lock, triad, values, stream, recording):
        self._node = node
        self._recording = recording
        self._lock = lock  # the node lock: the model and the stream's grid are read under it
        self._triad = triad
        self._values = values
        self._stream = stream
        self.enabled = bool(values['truth.enabled'])
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        self.events = node.create_publisher(
            DiagnosticStatus, '~/calibration_events',
            QoSProfile(depth=EVENT_DEPTH, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                       reliability=ReliabilityPolicy.RELIABLE))
        self.odometry = self.origin = self.errors = None
        if self.enabled:
            self.odometry = node.create_publisher(Odometry, 'truth/odometry', reliable)
            self.origin = node.create_publisher(NavSatFix, 'truth/origin', latched)
            self.errors = node.create_publisher(Imu, 'truth/imu_errors', reliable)
        self._profile = None
        self._fingerprint = None
        self._before = None
        self._marked = None
        self._last_kind = None
        self._position = None
        self.published = 0
        self.event_count = 0
        self.timer = node.create_timer(1.0 / values['truth.rate_hz'], self.tick)

    def chain(self, callback):
        """Return ``callback`` preceded by :meth:`mark` (the stream's schedule-end hook)."""
        def marked():
            self.mark()
            callback()
        return marked

    def mark(self, kind=None):
        """
        Note that a correction may have been applied now: the next sample has it.

        Called with the node lock held (by the sensor thread at a schedule's end, by the
        ``~/set_compensation`` callback); takes no lock.
        """
        self._marked = (self._stream.grid.next_index, kind)

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
            # The grid and the model advanced together since the last tick (no fast
            # schedule, no skip between): the last computed sample ends at triad.time.
            in_step = position[0] - previous[0] == position[1] - previous[1]
            if schedule is not None or not in_step or any(
                    loop.open_loop for loop in triad.axes):
                return
            stamp_ns = int(grid.stamp_ns(grid.next_index - 1))
            t = triad.time
            profile = triad.profile
            pose_input = self._values['input.mode'] in POSE_MODES \
                and hasattr(profile, 'local_pose') and triad.fixture is None
            force = profile.evaluate(np.array([t]))[0] if pose_input else None
            truth = error_truth(triad, force)
            words = self._words()
            if self._fingerprint is not None and words != self._fingerprint:
                messages.append(('event', self._event(words, truth, stamp_ns)))
            self._fingerprint, self._before = words, truth
            self._marked = self._last_kind = None
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
            kind = 'events' if kind == 'event' else kind
            self._recording.publish(getattr(self, kind), message, TYPES[kind])
            if kind == 'events':
                self.event_count += 1
            else:
                self.published += 1

    def offered_qos(self):
        """Return the QoS (:class:`~qfa_ros.bag.qos.QosProfile`) of each truth topic."""
        topics = {self.events.topic_name: QosProfile(depth=EVENT_DEPTH,
                                                     durability='transient_local')}
        if self.enabled:
            topics[self.odometry.topic_name] = QosProfile(depth=10)
            topics[self.errors.topic_name] = QosProfile(depth=10)
            topics[self.origin.topic_name] = QOS_LATCHED
        return topics

    def _event(self, words, truth, stamp_ns):
        before = self._before
        index, marked_kind = self._marked if self._marked is not None else (None, None)
        if index is not None:
            stamp_ns = int(self._stream.grid.stamp_ns(index))
        kind = marked_kind or self._last_kind or _changed(self._fingerprint, words)
        scale = (np.diag(truth.accel_matrix) - np.diag(before.accel_matrix)) / PPM
        bias = (truth.accel_bias - before.accel_bias) / MICRO_G
        gyro = np.nan_to_num(truth.gyro_bias - before.gyro_bias) / DEG_PER_HOUR
        values = [('kind', kind), ('stamp_ns', str(stamp_ns)),
                  ('temperature_compensation', 'on' if words[1][0] else 'off')]
        for i, axis in enumerate('xyz'):
            values += [(f'accel_scale_change_ppm_{axis}', f'{scale[i]:.3f}'),
                       (f'accel_bias_change_ug_{axis}', f'{bias[i]:.3f}'),
                       (f'gyro_bias_change_deg_per_h_{axis}', f'{gyro[i]:.6f}')]
        return DiagnosticStatus(
            level=DiagnosticStatus.OK, name=f'{self._node.get_name()}: calibration event',
            message=f'{kind} applied in place from stamp {stamp_ns}',
            hardware_id=self._values['hardware_id'],
            values=[KeyValue(key=k, value=v) for k, v in values])

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


def _changed(before, after):
    """Return the kind of correction a change of the loop words and switches implies."""
    loops_before, rest_before = before
    loops_after, rest_after = after
    forward = any(a[0] != b[0] or a[2] != b[2] for a, b in zip(loops_after, loops_before))
    feedback = any(a[1] != b[1] for a, b in zip(loops_after, loops_before))
    if forward and feedback:
        return 'self_calibrate'
    if forward or feedback:
        return 'forward' if forward else 'feedback'
    if rest_after[:2] != rest_before[:2]:
        return 'temperature'
    return 'gyro_bias'
