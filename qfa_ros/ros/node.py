"""
ROS 2 node of the emulated QFA triad: maps parameters, topics and services onto the model.

Run it with ``qfa_node`` (``ros2 run qfa_ros qfa_node``) or
``python -m qfa_ros.cli.node --ros-args --params-file config/qfa.yaml``. The interface is
described in ``docs/node.md``.
"""

import threading

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_msgs.msg import Bool

from qfa_ros.model.design import published_acceleration_variance
from qfa_ros.ros.bounds import output_directory
from qfa_ros.ros.calibration_keeper import CalibrationKeeper
from qfa_ros.ros.diagnostics import Diagnostics, temperature_status
from qfa_ros.ros.input_queue import GroundTruthInput
from qfa_ros.ros.input_topic import InputSubscription
from qfa_ros.ros.model_settings import (
    input_profile,
    load_imu_noise,
    load_trajectory_file,
    make_triad,
)
from qfa_ros.ros.parameter_checks import check_all
from qfa_ros.ros.recording import StreamRecording
from qfa_ros.ros.runtime_parameters import (
    apply_ambient,
    apply_drift,
    declare_parameters,
    RuntimeParameters,
)
from qfa_ros.ros.schedule_service import ScheduleService
from qfa_ros.ros.services import CalibrationServices
from qfa_ros.ros.startup_recovery import StartupRecovery
from qfa_ros.ros.stream import offered_qos, SampleStream
from qfa_ros.ros.topic_table import create_publisher, TOPIC
from qfa_ros.ros.truth import TruthPublisher

ANNOUNCE_AFTER_S = 1.0
"""The start-up lines are logged at the latest this long after construction [s, steady]."""


class SensorWiring:
    """
    The emulated unit on a node: the model and its collaborators, wired in one place.

    Mixed into both nodes, so that there is one wiring: :class:`QfaNode` wires and starts
    it at construction, :class:`~qfa_ros.ros.lifecycle_node.QfaLifecycleNode` at its
    ``configure`` transition. :meth:`wire_sensor` creates every publisher, service, timer
    and subscription of the unit on the node it is mixed into.

    The node wires small collaborators: :class:`SampleStream` (the sensor thread that
    advances the model and publishes), :class:`ScheduleService` (schedules behind the
    services), :class:`CalibrationServices` (the services), :class:`CalibrationKeeper`
    (state and state file), :class:`RuntimeParameters` (parameter changes),
    :class:`GroundTruthInput` with :class:`InputSubscription` (the input topic),
    :class:`TruthPublisher`, :class:`StreamRecording`, :class:`Diagnostics` and
    :class:`StartupRecovery` (what a killed earlier run left unfinished). The
    executor thread serves parameters, services, diagnostics and the ground-truth input.
    """

    _stream = None
    """The :class:`SampleStream` once :meth:`wire_sensor` made it (None before)."""
    _start_values = None
    """The parameter values the node was started with, if :meth:`wire_sensor` runs later
    (the managed node's ``configure``): the recording's retention applies in their
    ``recorder.directory`` only."""

    def wire_sensor(self, values, process_tuning=None):
        """
        Build the model from ``values`` and wire the collaborators; the stream is not started.

        Parameters
        ----------
        values
            Every parameter's value by name (``declare_parameters``); kept as the live values.
        process_tuning
            The process's interpreter settings, applied by the sensor thread (see
            :class:`SampleStream`); only a process that runs this node alone passes them.

        Raises
        ------
        ValueError
            A parameter is invalid or the trajectory file cannot be used; the message names the
            parameter.
        """
        # The live parameter values, shared (read-only) by every collaborator; written
        # only by RuntimeParameters, under _lock.
        self._values = values
        # Protects what the sensor thread and the executor thread share: the model, the
        # live values, the sample grid and the running schedule (SampleStream), the
        # ground-truth input queue, the calibration state (CalibrationKeeper) and the
        # counters of the collaborators. Each tick and each callback's use of them holds it.
        self._lock = threading.Lock()
        trajectory_file = self._build_model(values)
        publishers = self._create_publishers(values)
        self._wire_collaborators(values, trajectory_file, publishers, process_tuning)
        self.publish_calibrated()
        self._start_lines = self._start_summary(values)
        # What an earlier run left unfinished (a kill, a power cut), recovered in the
        # background once the first samples are out (QfaNode.announce_start) or at
        # configure (QfaLifecycleNode).
        self._startup_recovery = StartupRecovery(
            self, values, on_recovered=self._recording.retain)

    def _build_model(self, values):
        """Build the model and its state from ``values``; return the trajectory file read."""
        # The trajectory file and the imu.yaml are read once here, before any service
        # answers (the parameters are read-only); the state file below, also only at start
        # (a managed node's start is its configure).
        trajectory_file = load_trajectory_file(values)
        imu_noise = load_imu_noise(values)
        reason = check_all(values, trajectory_file, imu_noise)
        if reason:
            raise ValueError(reason)
        self._triad = make_triad(values, input_profile(values, trajectory_file=trajectory_file),
                                 imu_noise)
        apply_ambient(self._triad, values)
        self._keeper = CalibrationKeeper(self._triad, values['state_file'], self.get_logger())
        apply_drift(self._triad, values)
        self._keeper.load(fresh=values['state.fresh'])
        return trajectory_file

    def _create_publishers(self, values):
        """Create the publishers and their recording; return the imu and temperature ones."""
        # A profile each (topic_table): an override applied to one is not the other's.
        imu_publisher = create_publisher(self, 'imu/data_raw')
        temperature_publisher = create_publisher(self, 'imu/temperature')
        self._calibrated_publisher = create_publisher(self, '~/is_calibrated')

        # The recording states the QoS the publishers really offer (overrides applied).
        self._recording = StreamRecording(self, values, {
            imu_publisher.topic_name: offered_qos(imu_publisher.qos_profile),
            temperature_publisher.topic_name: offered_qos(temperature_publisher.qos_profile),
            '/diagnostics': TOPIC['/diagnostics'].qos,
            self._calibrated_publisher.topic_name: TOPIC['~/is_calibrated'].qos},
            operator_values=self._start_values or values)
        return imu_publisher, temperature_publisher

    def _wire_collaborators(self, values, trajectory_file, publishers, process_tuning):
        """Wire the stream, the input, the schedules and services, diagnostics and the truth."""
        self._ground_truth = GroundTruthInput(values)
        variance = published_acceleration_variance(self._triad.config)
        self._stream = SampleStream(
            self, self._lock, self._triad, values, self._ground_truth, self._recording,
            *publishers, [variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, variance],
            process_tuning)
        if self._triad.gyro is not None:
            rate_variance = self._triad.gyro.variance()
            self._stream.set_rate_covariance(
                [rate_variance, 0.0, 0.0, 0.0, rate_variance, 0.0, 0.0, 0.0, rate_variance])
        self._input_topic = InputSubscription(self, self._lock, values, self._ground_truth,
                                              self._stream)
        self._schedules = ScheduleService(self, self._lock, values, self._stream, self._keeper)
        self._diagnostics = Diagnostics(self, self._lock, values, self._recording, [
            ('stream', self._stream.status),
            ('calibration', self._schedules.status),
            ('temperature', lambda: temperature_status(self._triad, self._keeper,
                                                       self._stream.last_temperature)),
            ('input', lambda: self._ground_truth.status(self.get_clock().now().nanoseconds)),
        ])
        self._truth = TruthPublisher(self, self._lock, self._triad, values, self._stream,
                                     self._recording)
        # Opened once every recorded topic is known (the truth's too).
        self._recording.offer(self._truth.offered_qos())
        self._recording.restart()
        services = CalibrationServices(self, self._lock, values, self._schedules, self._keeper,
                                       self._truth, self.publish_calibrated)
        self._stream.on_schedule_end = self._truth.chain(services.schedule_done.trigger)
        self._calibration_services = services
        self._parameter_changes = RuntimeParameters(
            self, self._lock, values, trajectory_file, self._triad, self._stream,
            self._recording, self._schedules)
        # The step applying each runtime effect and how often each ran (read by the tests).
        self.runtime_effects = self._parameter_changes.steps
        self.applied_effects = self._parameter_changes.applied

    def _start_summary(self, values):
        """Return the two start-up lines: what the node runs, and the state it loaded."""
        thermal = self._triad.thermal
        unit = values['unit.seed'] if values['unit.seed'] >= 0 else values['seed']
        return [
            f'{values["sample_rate_hz"]:g} Hz on imu/data_raw (frame {values["frame_id"]}), '
            f'loop {values["loop_rate_hz"]:g} Hz, input {values["input.mode"]}, thermal '
            f'{values["thermal.ambient_profile"] if thermal else "off"}, '
            f'calibration state {self._keeper.store.path or "in memory only"}, files only '
            f'under {output_directory(values)}',
            f'{self._keeper.startup_summary()}; unit '
            f'{f"drawn, seed {unit}" if values["unit.draw"] else "nominal"}; to start fresh '
            f'(uncompensated): -p state.fresh:=true']

    @property
    def is_calibrated(self):
        """Return True when references exist and the stored corrections are applied."""
        return self._keeper.is_calibrated

    def publish_calibrated(self):
        """Publish ``~/is_calibrated`` (transient local: late subscribers get it too), recorded."""
        self._recording.publish(self._calibrated_publisher, Bool(data=self.is_calibrated),
                                TOPIC['~/is_calibrated'].type_name)

    # Shutdown -------------------------------------------------------------------------
    def close(self, timeout_s=10.0):
        """
        Stop the sensor thread and a running schedule, save the state, close the recording.

        Idempotent. Bounded: if the sensor thread does not stop within ``timeout_s`` (stuck
        in the middleware, holding the lock), the state and the recording are written
        without the lock; nothing else touches them once the stream has stopped ticking.
        """
        if self._stream is None:
            return
        self._startup_recovery.stop(timeout_s)
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


class QfaNode(SensorWiring, Node):
    """
    Emulated self-calibrating IMU of three digital closed-loop QFA.

    Publishes and subscribes to the topics of
    :data:`~qfa_ros.ros.topic_table.TOPICS` and serves the services of
    :data:`~qfa_ros.ros.service_table.SERVICES`. The unit
    (:class:`SensorWiring`) is wired and started at construction, and runs until :meth:`close`.

    Parameters
    ----------
    node_name
        Node name.
    process_tuning
        The process's interpreter settings, applied by the sensor thread (see
        :class:`SampleStream`); only a process that runs this node alone passes them.
    kwargs
        Passed to :class:`rclpy.node.Node` (e.g. ``context``, ``parameter_overrides``).

    Raises
    ------
    ValueError
        A parameter is invalid; the message names it.
    """

    def __init__(self, node_name='qfa_node', *, process_tuning=None, **kwargs):
        super().__init__(node_name, **kwargs)
        self.wire_sensor(declare_parameters(self), process_tuning)
        # The start-up lines are logged (executor thread) once the first samples are out,
        # or ANNOUNCE_AFTER_S of steady time after construction should none come (a topic
        # input not yet arrived, no /clock): rclpy's logger finds its caller through
        # inspect, whose first call resolves the path of every loaded module, ~70 ms that
        # would otherwise delay the first sample.
        self._stream.on_publishing = self.create_guard_condition(self.announce_start).trigger
        self._announce_timer = self.create_timer(
            ANNOUNCE_AFTER_S, self.announce_start, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._stream.start()

    def announce_start(self):
        """Log what the node runs and which state it loaded; start the recovery (once)."""
        lines, self._start_lines = self._start_lines, []
        self._announce_timer.cancel()
        self._startup_recovery.start()
        for line in lines:
            self.get_logger().info(line)
