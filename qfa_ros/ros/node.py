"""
ROS 2 node of the emulated QFA triad: maps parameters, topics and services onto the model.

Run it with ``qfa_node`` (``ros2 run qfa_ros qfa_node``) or
``python -m qfa_ros.cli.node --ros-args --params-file config/qfa.yaml``. The interface is
described in ``docs/node.md``.
"""

import collections
import threading

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import InvalidParameterTypeException, ParameterException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from qfa_ros.bag.qos import QOS_LATCHED, QosProfile
from qfa_ros.calibration.estimation import (
    capture_reference,
    feedback_schedule,
    forward_schedule,
    self_calibrate,
)
from qfa_ros.calibration.gyro_bias import gyro_bias_schedule
from qfa_ros.calibration.temperature import temperature_calibration
from qfa_ros.model.design import published_acceleration_variance
from qfa_ros.model.triad import AXES, NS_PER_S
from qfa_ros.model.units import PPM
from qfa_ros.ros.bounds import output_directory
from qfa_ros.ros.calibration import CalibrationKeeper
from qfa_ros.ros.diagnostics import Diagnostics, DIAGNOSTICS_TYPE, temperature_status
from qfa_ros.ros.ground_truth import GroundTruthInput
from qfa_ros.ros.params import (
    ambient_settings,
    as_declared_type,
    check_all,
    descriptor,
    EFFECT_OF,
    FEEDBACK_COMPONENT,
    FORWARD_COMPONENT,
    gyro_bias_settings,
    input_profile,
    load_trajectory_file,
    make_triad,
    PARAMETERS,
    RUNTIME_EFFECTS,
    temperature_settings,
    THERMAL_RUNTIME_PARAMETERS,
)
from qfa_ros.ros.recording import StreamRecording
from qfa_ros.ros.schedules import ScheduleService
from qfa_ros.ros.stream import offered_qos, SampleStream
from qfa_ros.ros.truth import TruthPublisher


class QfaNode(Node):
    """
    Emulated self-calibrating IMU of three digital closed-loop QFA.

    Publishes ``imu/data_raw``, ``imu/temperature``, ``/diagnostics`` and
    ``~/is_calibrated``; serves ``~/capture_reference``, ``~/estimate_forward_gain``,
    ``~/estimate_feedback_gain``, ``~/self_calibrate``, ``~/calibrate_temperature``,
    ``~/calibrate_gyros``, ``~/set_compensation`` and ``~/cancel``.

    The node wires small collaborators: :class:`SampleStream` (the sensor thread that
    advances the model and publishes), :class:`ScheduleService` (schedules behind the
    services), :class:`CalibrationKeeper` (state and state file),
    :class:`GroundTruthInput`, :class:`StreamRecording` and :class:`Diagnostics`. The
    executor thread serves parameters, services, diagnostics and the ground-truth input.

    :param node_name: Node name.
    :param kwargs: Passed to :class:`rclpy.node.Node` (e.g. ``context``,
        ``parameter_overrides``).
    :raises ValueError: A parameter is invalid; the message names it.
    """

    def __init__(self, node_name='qfa_node', **kwargs):
        super().__init__(node_name, **kwargs)
        # Integers typed for doubles ([1, 2, 3], 2000) become doubles: in every change
        # (pre-set callback) and at start, where declaration runs no pre-set callback.
        self.add_pre_set_parameters_callback(
            lambda parameters: [as_declared_type(p) for p in parameters])
        for spec in PARAMETERS:
            try:
                try:
                    self.declare_parameter(spec.name, spec.default, descriptor(spec))
                except InvalidParameterTypeException:
                    # Read the start value untyped; declare the double it means, if any.
                    given = self.declare_parameter(spec.name, spec.default,
                                                   ParameterDescriptor(dynamic_typing=True))
                    typed = as_declared_type(given)
                    self.undeclare_parameter(spec.name)
                    if typed is given:
                        raise
                    self.declare_parameter(spec.name, typed.value, descriptor(spec),
                                           ignore_override=True)
            except ParameterException as error:
                raise ValueError(str(error)) from None
        # The live parameter values, shared (read-only) by every collaborator.
        self._values = {spec.name: self.get_parameter(spec.name).value for spec in PARAMETERS}
        values = self._values
        # The step that applies each runtime effect of params.RUNTIME_EFFECTS, and how
        # often each ran (read by the tests; under _lock).
        self.runtime_effects = {
            'live': lambda: None, 'drift': self._apply_drift, 'input': self._apply_input,
            'frame': self._apply_frame_id, 'ambient': self._apply_ambient,
            'recorder': self._restart_recording}
        self.applied_effects = collections.Counter()
        # The trajectory file is read once here, before any service answers (the parameter
        # is read-only); the state file below, also only at start.
        self._trajectory_file = load_trajectory_file(values)
        reason = check_all(values, self._trajectory_file)
        if reason:
            raise ValueError(reason)
        self._triad = make_triad(values, input_profile(values,
                                                       trajectory_file=self._trajectory_file))
        self._apply_ambient()
        self._keeper = CalibrationKeeper(self._triad, values['state_file'], self.get_logger())
        self._apply_drift()

        # The sensor thread and the executor thread share the model, the sample grid,
        # the running schedule, the ground-truth input queue, the
        # calibration state and the counters of the collaborators; _lock makes each
        # tick and each callback's use of them atomic.
        self._lock = threading.Lock()
        self._keeper.load(fresh=values['state.fresh'])

        # REP-2003: a sensor driver offers the system-default (reliable) QoS; a depth of
        # 100 lets a reliable subscriber be briefly late. Users override it the ROS way:
        # qos_overrides./<namespace>/imu/data_raw.publisher.{history,depth,reliability}.
        stream_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        imu_publisher = self.create_publisher(
            Imu, 'imu/data_raw', stream_qos,
            qos_overriding_options=QoSOverridingOptions.with_default_policies())
        temperature_publisher = self.create_publisher(
            Temperature, 'imu/temperature', QoSProfile(
                history=stream_qos.history, depth=stream_qos.depth,
                reliability=stream_qos.reliability),
            qos_overriding_options=QoSOverridingOptions.with_default_policies())
        self._diagnostics_publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', 10)
        self._calibrated_publisher = self.create_publisher(Bool, '~/is_calibrated', latched)

        # The recording states the QoS the publishers really offer (overrides applied).
        self._recording = StreamRecording(self, values, {
            imu_publisher.topic_name: offered_qos(imu_publisher.qos_profile),
            temperature_publisher.topic_name: offered_qos(temperature_publisher.qos_profile),
            '/diagnostics': QosProfile(depth=10),
            self._calibrated_publisher.topic_name: QOS_LATCHED})
        self._recording.restart()

        self._ground_truth = GroundTruthInput(values)
        input_qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        if values['input.topic_type'] == 'imu':
            self.create_subscription(Imu, 'input/imu', self.input_imu_callback, input_qos)
        elif values['input.topic_type'] == 'odometry':
            self.create_subscription(Odometry, 'input/odometry', self.input_odometry_callback,
                                     input_qos)
        else:
            self.create_subscription(AccelStamped, 'input/accel', self.input_accel_callback,
                                     input_qos)

        config = self._triad.config
        variance = published_acceleration_variance(config)
        self._stream = SampleStream(
            self, self._lock, self._triad, values, self._ground_truth, self._recording,
            imu_publisher, temperature_publisher,
            [variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, variance])
        if self._triad.gyro is not None:
            rate_variance = self._triad.gyro.variance()
            self._stream.set_rate_covariance(
                [rate_variance, 0.0, 0.0, 0.0, rate_variance, 0.0, 0.0, 0.0, rate_variance])
        self._schedules = ScheduleService(self, self._lock, values, self._stream, self._keeper)
        self._diagnostics = Diagnostics(self, values, [
            ('stream', self._stream.status),
            ('calibration', self._schedules.status),
            ('temperature', lambda: temperature_status(self._triad, self._keeper,
                                                       self._stream.last_temperature)),
            ('input', lambda: self._ground_truth.status(self.get_clock().now().nanoseconds)),
        ])

        # A schedule service awaits the schedule the sensor thread drives. In the default
        # mutually exclusive group the pending coroutine would keep the other services
        # from answering 'busy'; the reentrant group lets them run meanwhile.
        services = ReentrantCallbackGroup()
        for srv_type, name, callback in (
                (Trigger, '~/capture_reference', self.capture_reference_callback),
                (Trigger, '~/estimate_forward_gain', self.estimate_forward_gain_callback),
                (Trigger, '~/estimate_feedback_gain', self.estimate_feedback_gain_callback),
                (Trigger, '~/self_calibrate', self.self_calibrate_callback),
                (Trigger, '~/calibrate_temperature', self.calibrate_temperature_callback),
                (Trigger, '~/calibrate_gyros', self.calibrate_gyros_callback),
                (SetBool, '~/set_compensation', self.set_compensation_callback),
                (Trigger, '~/cancel', self.cancel_callback)):
            self.create_service(srv_type, name, callback, callback_group=services)
        # Triggered by the sensor thread when a schedule ends, so that the executor wakes
        # and resumes the service coroutine awaiting it.
        schedule_done = self.create_guard_condition(self.schedule_done_callback)
        self._truth = TruthPublisher(self, self._lock, self._triad, values, self._stream)
        self._stream.on_schedule_end = self._truth.chain(schedule_done.trigger)
        self.add_on_set_parameters_callback(self.validate_parameters_callback)
        self.add_post_set_parameters_callback(self.parameters_set_callback)

        self.create_timer(1.0 / values['diagnostics_rate_hz'], self.diagnostics_callback)
        self.publish_calibrated()
        self._stream.start()
        thermal = self._triad.thermal
        self.get_logger().info(
            f'{values["sample_rate_hz"]:g} Hz on imu/data_raw (frame {values["frame_id"]}), '
            f'loop {values["loop_rate_hz"]:g} Hz, input {values["input.mode"]}, thermal '
            f'{values["thermal.ambient_profile"] if thermal else "off"}, '
            f'calibration state {self._keeper.store.path or "in memory only"}, files only '
            f'under {output_directory(values)}')
        unit = values['unit.seed'] if values['unit.seed'] >= 0 else values['seed']
        self.get_logger().info(
            f'{self._keeper.startup_summary()}; unit '
            f'{f"drawn, seed {unit}" if values["unit.draw"] else "nominal"}; to start fresh '
            f'(uncompensated): -p state.fresh:=true')

    # Parameters ------------------------------------------------------------------------
    def validate_parameters_callback(self, parameters):
        """Accept a parameter change only if the whole set stays consistent."""
        try:
            merged = dict(self._values)
            for parameter in parameters:
                merged[parameter.name] = parameter.value
            reason = check_all(merged, self._trajectory_file)
            names = {parameter.name for parameter in parameters}
            if not reason and self._schedules.busy_kind == 'temperature' \
                    and names & THERMAL_RUNTIME_PARAMETERS:
                reason = 'busy: the temperature calibration controls the ambient until it ends'
        except Exception as error:
            # A parameter callback must never raise: it would kill the set_parameters call.
            reason = f'cannot check the change: {error}'
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def parameters_set_callback(self, parameters):
        """Apply accepted parameter changes to the running sensor at once."""
        names = {parameter.name for parameter in parameters}
        # One step per effect, each once, in the order of params.RUNTIME_EFFECTS.
        wanted = {EFFECT_OF[name] for name in names}
        effects = [effect for effect in RUNTIME_EFFECTS if effect in wanted]
        with self._lock:
            for parameter in parameters:
                self._values[parameter.name] = parameter.value
            try:
                for effect in effects:
                    self.runtime_effects[effect]()
                    self.applied_effects[effect] += 1
            except (ValueError, OSError) as error:
                self._schedules.last_error = f'applying {", ".join(sorted(names))}: {error}'
                self.get_logger().error(self._schedules.last_error)

    def _apply_frame_id(self):
        self._stream.set_frame_id(self._values['frame_id'])

    def _apply_input(self):
        self._triad.profile = input_profile(self._values, self._triad.time,
                                            self._trajectory_file)

    def _restart_recording(self):
        # What was published before the change goes to the recording it was in.
        with self._recording.lock:
            self._stream.flush_recording()
            self._recording.restart()

    def _apply_drift(self):
        values = self._values
        drift = self._triad.drift
        for axis in range(len(AXES)):
            drift.set_step(axis, FORWARD_COMPONENT, values['drift.forward_ppm'][axis] * PPM)
            drift.set_step(axis, FEEDBACK_COMPONENT, values['drift.feedback_ppm'][axis] * PPM)
            drift.set_aging(axis, FORWARD_COMPONENT,
                            values['drift.aging_forward_ppm_per_year'][axis])
            drift.set_aging(axis, FEEDBACK_COMPONENT,
                            values['drift.aging_feedback_ppm_per_year'][axis])
        drift.set_time_acceleration(values['drift.time_acceleration'])

    def _apply_ambient(self):
        if self._triad.thermal is None:
            self._triad.set_temperature(self._values['temperature_c'])
        else:
            self._triad.thermal.set_ambient(**ambient_settings(self._values))

    @property
    def is_calibrated(self):
        """Return True when references exist and the stored corrections are applied."""
        return self._keeper.is_calibrated

    def publish_calibrated(self):
        """Publish ``~/is_calibrated`` (transient local: late subscribers get it too)."""
        self._calibrated_publisher.publish(Bool(data=self.is_calibrated))

    # Ground-truth input -----------------------------------------------------------------
    def input_imu_callback(self, message):
        """Take the specific force (and angular rate, if given) of a ground-truth Imu."""
        rate = None
        if message.angular_velocity_covariance[0] != -1.0:
            w = message.angular_velocity
            rate = (w.x, w.y, w.z)
        self._accept_input(message.header.stamp, message.linear_acceleration, rate)

    def input_odometry_callback(self, message):
        """Take the specific force and rate implied by a ground-truth ``nav_msgs/Odometry``."""
        pose, twist = message.pose.pose, message.twist.twist
        now_ns = self.get_clock().now().nanoseconds
        with self._lock:
            self._ground_truth.accept_odometry(
                self._input_time_ns(message.header.stamp, now_ns),
                (pose.position.x, pose.position.y, pose.position.z),
                (pose.orientation.x, pose.orientation.y, pose.orientation.z,
                 pose.orientation.w),
                (twist.linear.x, twist.linear.y, twist.linear.z),
                (twist.angular.x, twist.angular.y, twist.angular.z), now_ns)
        self._stream.input_arrived()

    def input_accel_callback(self, message):
        """Take the specific force of a ground-truth ``geometry_msgs/AccelStamped``."""
        self._accept_input(message.header.stamp, message.accel.linear)

    @staticmethod
    def _input_time_ns(stamp, now_ns):
        time_ns = stamp.sec * NS_PER_S + stamp.nanosec
        return time_ns if time_ns else now_ns

    def _accept_input(self, stamp, vector, rate=None):
        now_ns = self.get_clock().now().nanoseconds
        with self._lock:
            self._ground_truth.accept(self._input_time_ns(stamp, now_ns),
                                      (vector.x, vector.y, vector.z), rate, now_ns)
        self._stream.input_arrived()

    # Services ---------------------------------------------------------------------------
    async def capture_reference_callback(self, request, response):
        """Measure and persist the forward and feedback reference gains."""
        return await self._schedules.run(response, 'reference', lambda f, b: capture_reference(
            self._triad, self._keeper.state, f, b))

    async def estimate_forward_gain_callback(self, request, response):
        """Run the forward schedule and apply the correction in place."""
        return await self._schedules.run(response, 'forward', lambda f, b: forward_schedule(
            self._triad, self._keeper.state, f))

    async def estimate_feedback_gain_callback(self, request, response):
        """Run the feedback schedule and apply the correction in place."""
        return await self._schedules.run(response, 'feedback', lambda f, b: feedback_schedule(
            self._triad, self._keeper.state, b))

    async def self_calibrate_callback(self, request, response):
        """Run the forward, then the feedback schedule and apply both corrections."""
        return await self._schedules.run(response, 'self_calibrate', lambda f, b: self_calibrate(
            self._triad, self._keeper.state, f, b))

    async def calibrate_temperature_callback(self, request, response):
        """
        Run an accelerated chamber cycle, fit bias and scale factor, switch compensation on.

        With ``temperature_calibration.reference_steps`` the I_ref step is measured at every
        plateau and its temperature coefficient stored in the calibration state.
        """
        return await self._schedules.run(
            response, 'temperature', lambda f, b: temperature_calibration(
                self._triad, self._keeper.state, temperature_settings(self._values)),
            fast=True)

    async def calibrate_gyros_callback(self, request, response):
        """Average the gyros at rest, remove the Earth rate and correct their bias."""
        return await self._schedules.run(
            response, 'gyro_bias', lambda f, b: gyro_bias_schedule(
                self._triad, self._keeper.state, gyro_bias_settings(self._values)))

    def set_compensation_callback(self, request, response):
        """Apply (true) the stored corrections or restore the nominal words (false)."""
        busy = self._schedules.busy_answer()
        if busy:
            response.success, response.message = False, busy
            return response
        with self._lock:
            response.success, response.message = self._keeper.set_compensation(request.data)
            self._truth.mark('set_compensation')
        if response.success:
            problem = self._keeper.save()
            if problem:
                response.success = False
                response.message += f'; {problem}'
            self.publish_calibrated()
        return response

    def cancel_callback(self, request, response):
        """Abort the running schedule, restore the sensor and let the stream resume."""
        with self._lock:
            try:
                response.success, response.message = self._schedules.cancel()
            except Exception as error:
                # Restoring a word the model refuses: say so instead of killing the call.
                response.success, response.message = False, f'cancel failed: {error}'
        self.get_logger().info(f'~/cancel: {response.message}')
        return response

    def schedule_done_callback(self):
        """Do nothing: the wake-up itself lets the executor resume the service coroutine."""

    # Diagnostics ----------------------------------------------------------------------
    def diagnostics_callback(self):
        """Publish the stream, calibration, temperature and input status (about 1 Hz)."""
        with self._lock:
            array = self._diagnostics.array()
        # Published and recorded outside the node lock: the recording's lock may wait for
        # the disk, and the sensor thread must not wait behind it.
        self._recording.publish(self._diagnostics_publisher, array, DIAGNOSTICS_TYPE)

    # Shutdown -------------------------------------------------------------------------
    def close(self, timeout_s=10.0):
        """
        Stop the sensor thread and a running schedule, save the state, close the recording.

        Idempotent. Bounded: if the sensor thread does not stop within ``timeout_s`` (stuck
        in the middleware, holding the lock), the state and the recording are written
        without the lock; nothing else touches them once the stream has stopped ticking.
        """
        self._stream.stop(timeout_s)
        locked = self._lock.acquire(timeout=timeout_s)
        if not locked:
            self.get_logger().error(
                f'sensor thread still busy after {timeout_s:g} s; saving without the lock')
        try:
            if self._stream.schedule is not None:
                self._stream.schedule.abort()
                self._stream.end_schedule()
            if self._keeper.unsaved:
                self._keeper.save()
            self._recording.close()
        finally:
            if locked:
                self._lock.release()
