"""
ROS 2 node of the emulated QFA triad: maps parameters, topics and services onto the model.

Run it with ``qfa-node`` (``ros2 run qfa_ros qfa_node``) or
``python -m qfa_ros.node --ros-args --params-file config/qfa.yaml``. The interface is
described in ``docs/node.md``.
"""

import math
import os
from pathlib import Path
import signal
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import AccelStamped
import numpy as np
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from qfa_ros.estimation import (
    CalibrationState,
    capture_reference,
    EstimationError,
    feedback_schedule,
    forward_schedule,
    self_calibrate,
)
from qfa_ros.fastdds import use_shipped_fastdds_profile
from qfa_ros.imu_cdr import ImuEncoder
from qfa_ros.model import AXES, concatenate, NS_PER_S, QfaTriad, SampleGrid
from qfa_ros.node_params import (
    ambient_settings,
    check_all,
    descriptor,
    FEEDBACK_COMPONENT,
    feedback_settings,
    FORWARD_COMPONENT,
    forward_settings,
    input_profile,
    PARAMETERS,
    static_profile,
    temperature_settings,
    THERMAL_RUNTIME_PARAMETERS,
    triad_config,
)
from qfa_ros.noise import acceleration_variance
from qfa_ros.recorder import FlightRecorder, QOS_LATCHED, QosProfile, RecorderError
from qfa_ros.state_store import StateFileError, StateStore
from qfa_ros.temperature import temperature_schedule
from qfa_ros.traces import trace_path, write_estimation_trace

PPM = 1e-6
FAST_CHUNK_SAMPLES = 1000
FAST_SLICE_S = 0.02
"""CPU time a fast schedule may hold the model before the executor gets a turn [s]."""

MAX_CATCH_UP_S = 1.0
"""A tick later than this skips ahead instead of computing the backlog (e.g. a debugger stop)."""

MAX_PENDING_INPUTS = 10000
IMU_TYPE = 'sensor_msgs/msg/Imu'
TEMPERATURE_TYPE = 'sensor_msgs/msg/Temperature'
DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'

DRIFT_PARAMETERS = frozenset({'drift.forward_ppm', 'drift.feedback_ppm',
                              'drift.aging_forward_ppm_per_year',
                              'drift.aging_feedback_ppm_per_year', 'drift.time_acceleration'})
RECORDER_PARAMETERS = frozenset({'recorder.enabled', 'recorder.directory', 'recorder.max_bytes',
                                 'recorder.max_duration_s'})

_SCHEDULE_PAUSE = {
    'reference': 'reference capture running (open loop, then I_ref steps)',
    'forward': 'forward-gain schedule running: loops open, no valid output',
    'feedback': 'feedback-gain schedule running: I_ref steps of about 0.6 g on the output',
    'self_calibrate': 'self-calibration running (open loop, then I_ref steps)',
    'temperature': 'temperature calibration running: accelerated chamber cycle',
}


class ScheduleRun:
    """
    A self-estimation or calibration schedule driven by the sensor thread.

    The schedule generator yields how many samples it needs; the sensor thread feeds
    it the model output (as the samples become due, or as fast as the CPU allows when
    ``fast``) and sends the concatenated block back. ``future`` gets the result.

    :param kind: Schedule name.
    :param generator: Schedule generator of :mod:`qfa_ros.estimation` or
        :mod:`qfa_ros.temperature`.
    :param fast: Run as fast as the CPU allows instead of at the node clock.
    :raises EstimationError: The schedule refuses to start (e.g. no reference).
    """

    def __init__(self, kind, generator, fast):
        self.kind = kind
        self.generator = generator
        self.fast = fast
        self.future = Future()
        self.parts = []
        self.remaining = next(generator)

    def feed(self, output):
        """Hand over ``output``; return True once the schedule has finished."""
        self.parts.append(output)
        self.remaining -= len(output.stamps_ns)
        if self.remaining > 0:
            return False
        block, self.parts = concatenate(self.parts), []
        try:
            self.remaining = self.generator.send(block)
        except StopIteration as stop:
            self.future.set_result(stop.value)
            return True
        except Exception as error:
            # Whatever stopped the schedule, the waiting service call reports it.
            self.future.set_exception(error)
            return True
        return False

    def abort(self):
        """Stop the schedule: its ``finally`` blocks re-close the loops."""
        self.generator.close()
        if not self.future.done():
            self.future.set_exception(EstimationError('node shutting down'))


class QfaNode(Node):
    """
    Emulated self-calibrating IMU of three digital closed-loop QFA.

    Publishes ``imu/data_raw``, ``imu/temperature``, ``/diagnostics`` and
    ``~/is_calibrated``; serves ``~/capture_reference``, ``~/estimate_forward_gain``,
    ``~/estimate_feedback_gain``, ``~/self_calibrate``, ``~/calibrate_temperature`` and
    ``~/set_compensation``.

    A sensor thread plays the part of the sensor's own electronics: every
    1/``tick_rate_hz`` it advances the model to the node clock and publishes every
    sample that has become due, and it drives the running schedule. The executor
    thread serves parameters, services, diagnostics and the ground-truth input; a
    schedule service is a coroutine that awaits the schedule the sensor thread runs.

    :param node_name: Node name.
    :param kwargs: Passed to :class:`rclpy.node.Node` (e.g. ``context``,
        ``parameter_overrides``).
    :raises ValueError: A parameter is invalid; the message names it.
    """

    def __init__(self, node_name='qfa_node', **kwargs):
        super().__init__(node_name, **kwargs)
        for spec in PARAMETERS:
            try:
                self.declare_parameter(spec.name, spec.default, descriptor(spec))
            except ParameterException as error:
                raise ValueError(str(error)) from None
        self._values = {spec.name: self.get_parameter(spec.name).value for spec in PARAMETERS}
        reason = check_all(self._values)
        if reason:
            raise ValueError(reason)
        values = self._values
        config = triad_config(values)
        self._triad = QfaTriad(config, rng=values['seed'], profile=input_profile(values))
        self._apply_ambient()
        self._nominal_gains = [loop.controller.gain for loop in self._triad.axes]
        self._nominal_n_vref = [loop.n_vref for loop in self._triad.axes]
        self._apply_drift()

        # The sensor thread and the executor thread share the model, the sample grid,
        # the running schedule, the ground-truth input queue, the recorder and the
        # counters below; _lock makes each tick and each callback's use of them atomic.
        # The calibration state is changed by a schedule (sensor thread, under the lock)
        # or by a service (executor thread, under the lock while a schedule cannot run).
        self._lock = threading.Lock()
        self._stop = threading.Event()

        self._state = CalibrationState()
        self._compensation = True
        self._state_problem = None
        self._state_unsaved = False
        self._state_store = StateStore(values['state_file'])
        self._load_state()

        self._grid = SampleGrid(values['sample_rate_hz'])
        self._temperature_every = max(1, round(values['sample_rate_hz']
                                               / values['temperature_rate_hz']))
        self._schedule = None
        self._busy_kind = None
        self._published = 0
        self._withheld = 0
        self._skipped = 0
        self._max_batch = 0
        self._pause_reason = None
        self._sensor_error = None
        self._saturated = np.zeros(len(AXES), dtype=np.int64)
        self._last_results = {}
        self._last_trace = None
        self._last_error = None
        self._clock_note = None
        self._inputs = []
        self._held_input = None
        self._input_rejected = 0
        self._input_problem = None
        self._last_temperature = None

        variance = acceleration_variance(config.noise, config.sample_rate_hz)
        self._acceleration_covariance = [variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0,
                                         variance]
        self._temperature = Temperature()
        thermal = self._triad.thermal
        if thermal is not None:
            self._temperature.variance = thermal.reading_variance_c2
        self._set_frame_id(values['frame_id'])

        stream_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=values['qos.depth'],
            reliability=ReliabilityPolicy.RELIABLE if values['qos.reliability'] == 'reliable'
            else ReliabilityPolicy.BEST_EFFORT)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        self._imu_publisher = self.create_publisher(Imu, 'imu/data_raw', stream_qos)
        self._temperature_publisher = self.create_publisher(Temperature, 'imu/temperature',
                                                            stream_qos)
        self._diagnostics_publisher = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._calibrated_publisher = self.create_publisher(Bool, '~/is_calibrated', latched)
        input_qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        if values['input.topic_type'] == 'imu':
            self._input_subscription = self.create_subscription(
                Imu, 'input/imu', self.input_imu_callback, input_qos)
        else:
            self._input_subscription = self.create_subscription(
                AccelStamped, 'input/accel', self.input_accel_callback, input_qos)
        recorder_qos = QosProfile(depth=values['qos.depth'],
                                  reliability=values['qos.reliability'])
        self._recorder_qos = {self._imu_publisher.topic_name: recorder_qos,
                              self._temperature_publisher.topic_name: recorder_qos}
        self._recorder = None
        self._recorder_problem = None
        self._restart_recorder()

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
                (SetBool, '~/set_compensation', self.set_compensation_callback)):
            self.create_service(srv_type, name, callback, callback_group=services)
        # Triggered by the sensor thread when a schedule ends, so that the executor wakes
        # and resumes the service coroutine awaiting it.
        self._schedule_done = self.create_guard_condition(self.schedule_done_callback)
        self.add_on_set_parameters_callback(self.validate_parameters_callback)
        self.add_post_set_parameters_callback(self.parameters_set_callback)

        self._diagnostics_timer = self.create_timer(1.0 / values['diagnostics_rate_hz'],
                                                    self.diagnostics_callback)
        self._publish_calibrated()
        self._sensor_thread = threading.Thread(target=self._sensor_loop, name='qfa_sensor',
                                               daemon=True)
        self._sensor_thread.start()
        self.get_logger().info(
            f'{values["sample_rate_hz"]:g} Hz on imu/data_raw (frame {values["frame_id"]}), '
            f'loop {values["loop_rate_hz"]:g} Hz, input {values["input.mode"]}, thermal '
            f'{values["thermal.ambient_profile"] if thermal else "off"}, '
            f'calibration state {self._state_store.path or "in memory only"}')

    # Parameters ------------------------------------------------------------------------
    def validate_parameters_callback(self, parameters):
        """Accept a parameter change only if the whole set stays consistent."""
        try:
            merged = dict(self._values)
            for parameter in parameters:
                merged[parameter.name] = parameter.value
            reason = check_all(merged)
            names = {parameter.name for parameter in parameters}
            if not reason and self._busy_kind == 'temperature' \
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
        with self._lock:
            for parameter in parameters:
                self._values[parameter.name] = parameter.value
            try:
                if names & DRIFT_PARAMETERS:
                    self._apply_drift()
                if any(name.startswith('input.') for name in names):
                    self._triad.profile = input_profile(self._values)
                if 'frame_id' in names:
                    self._set_frame_id(self._values['frame_id'])
                if names & THERMAL_RUNTIME_PARAMETERS:
                    self._apply_ambient()
                if names & RECORDER_PARAMETERS:
                    self._restart_recorder()
            except (ValueError, OSError) as error:
                self._last_error = f'applying {", ".join(sorted(names))}: {error}'
                self.get_logger().error(self._last_error)

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

    def _set_frame_id(self, frame_id):
        self._imu_encoder = ImuEncoder(frame_id, self._acceleration_covariance)
        self._temperature.header.frame_id = frame_id

    # Calibration state ------------------------------------------------------------------
    def _load_state(self):
        store = self._state_store
        try:
            state, compensation = store.load()
        except StateFileError as error:
            where = f'kept as {error.kept_as}' if error.kept_as else 'could not be set aside'
            self._state_problem = f'{error}; {where}; starting uncalibrated'
            self.get_logger().error(self._state_problem)
            return
        if state is None:
            return
        try:
            if compensation:
                state.apply_to(self._triad)
        except ValueError as error:
            self._restore_nominal_words()
            kept = store.set_aside()
            where = f'kept as {kept}' if kept else 'could not be set aside'
            self._state_problem = (f'state file {store.path} holds words the sensor cannot '
                                   f'take ({error}); {where}; starting uncalibrated')
            self.get_logger().error(self._state_problem)
            return
        self._state = state
        self._compensation = compensation
        self.get_logger().info(f'calibration state loaded from {store.path} '
                               f'(compensation {"on" if compensation else "off"})')

    def _save_state(self):
        """Persist the calibration state; return a problem description or None."""
        try:
            self._state_store.save(self._state, self._compensation)
        except OSError as error:
            problem = f'state file not written ({error})'
            self._state_problem = problem
            self._state_unsaved = True
            return problem
        self._state_problem = None
        self._state_unsaved = False
        return None

    def _restore_nominal_words(self):
        triad = self._triad
        for axis in range(len(AXES)):
            triad.set_controller_gain(axis, self._nominal_gains[axis])
            triad.set_n_vref(axis, self._nominal_n_vref[axis])
        triad.temperature_compensation = False

    @property
    def is_calibrated(self):
        """Return True when references exist and the stored corrections are applied."""
        return self._state.has_reference and self._compensation

    def _publish_calibrated(self):
        self._calibrated_publisher.publish(Bool(data=self.is_calibrated))

    # Sensor thread ----------------------------------------------------------------------
    def _sensor_loop(self):
        """Advance the model at ``tick_rate_hz`` until the node closes (thread target)."""
        period = 1.0 / self._values['tick_rate_hz']
        deadline = time.monotonic()
        while not self._stop.is_set():
            with self._lock:
                try:
                    fast = self._sensor_step()
                except Exception as error:
                    # The sensor keeps running whatever one tick ran into; diagnostics tell.
                    fast = False
                    self._sensor_error = f'{type(error).__name__}: {error}'
                    self.get_logger().error(f'sensor thread: {self._sensor_error}',
                                            throttle_duration_sec=5.0)
            now = time.monotonic()
            if fast:
                # Let the executor thread take the lock between slices of a fast schedule.
                self._stop.wait(0.001)
                deadline = now
                continue
            deadline += period
            if deadline < now - period:
                deadline = now  # the thread was held up: no burst of catch-up ticks
            self._stop.wait(max(0.0, deadline - now))

    def _sensor_step(self):
        """Run one tick, or one slice of a fast schedule; return True for the latter."""
        run = self._schedule
        if run is not None and run.fast:
            self._run_fast_slice(run)
            return True
        self._advance_to_clock()
        return False

    def _advance_to_clock(self):
        """Run the model up to the node clock and publish every sample that is due."""
        now = self.get_clock().now().nanoseconds
        if now <= 0:
            # use_sim_time without /clock yet: there is no time to stamp samples with.
            return
        grid = self._grid
        if grid.start_ns is None:
            grid.anchor(now)
            return
        if grid.next_index and now < grid.stamp_ns(grid.next_index - 1):
            # The clock went back (a bag or simulation restarted): restart the stream.
            jump = (grid.stamp_ns(grid.next_index - 1) - now) / 1e9
            self._clock_note = f'clock jumped back by {jump:.3f} s; stream re-anchored'
            grid.anchor(now)
            return
        backlog = grid.due(now) - grid.next_index
        limit = int(MAX_CATCH_UP_S * self._values['sample_rate_hz'])
        if backlog > limit:
            self._skipped += backlog
            grid.next_index += backlog
            self._clock_note = f'node was {backlog} samples late; skipped them'
            return
        if backlog > 0:
            self._max_batch = max(self._max_batch, backlog)
            self._advance(backlog)

    def _advance(self, count):
        grid = self._grid
        while count > 0:
            run = self._schedule
            chunk = count if run is None else min(count, run.remaining)
            stamps = grid.stamp_ns(np.arange(grid.next_index, grid.next_index + chunk))
            force, stale = self._input_force(stamps)
            output = self._triad.run(chunk, force)
            self._publish_samples(grid.next_index, stamps, output, stale)
            grid.next_index += chunk
            count -= chunk
            if run is not None and run.feed(output):
                self._end_schedule()

    def _run_fast_slice(self, run):
        """Drive a fast schedule for up to ``FAST_SLICE_S`` of CPU time."""
        started = time.process_time()
        while time.process_time() - started < FAST_SLICE_S:
            n = min(FAST_CHUNK_SAMPLES, run.remaining)
            output = self._triad.run(n, self._held_force(n))
            self._saturated += output.saturated.sum(axis=0)
            if run.feed(output):
                # The stream keeps its grid: the samples due while the schedule computed
                # are not published (the sensor had no valid output), the next one
                # follows the node clock again.
                if self._grid.start_ns is not None:
                    due = self._grid.due(self.get_clock().now().nanoseconds)
                    self._withheld += max(0, due - self._grid.next_index)
                    self._grid.next_index = max(self._grid.next_index, due)
                self._end_schedule()
                return

    def _end_schedule(self):
        self._schedule = None
        self._pause_reason = None
        self._schedule_done.trigger()

    def schedule_done_callback(self):
        """Do nothing: the wake-up itself lets the executor resume the service coroutine."""

    def _publish_samples(self, first, stamps, output, stale):
        self._saturated += output.saturated.sum(axis=0)
        valid = output.valid.all(axis=1)
        if stale is not None:
            valid &= ~stale
        if self._schedule is not None:
            valid[:] = False
            reason = _SCHEDULE_PAUSE[self._schedule.kind]
        elif not valid.all():
            reason = 'ground-truth input stale' if stale is not None and stale.any() \
                else 'loops settling after re-closing'
        else:
            reason = None
        self._pause_reason = reason if not valid[-1] else None
        # The log time of everything this batch records: one clock read, not one per message.
        now_ns = self.get_clock().now().nanoseconds if self._recorder is not None else None
        if valid.any():
            messages = self._imu_encoder.encode(stamps[valid], output.accel[valid])
            topic = self._imu_publisher.topic_name
            for data in messages:
                self._imu_publisher.publish(data)
                if self._recorder is not None:
                    self._record(topic, IMU_TYPE, data, now_ns)
            self._published += len(messages)
        self._withheld += int(len(valid) - np.count_nonzero(valid))
        due = np.arange((-(first + 1)) % self._temperature_every, len(stamps),
                        self._temperature_every)
        if not len(due):
            return
        thermal = self._triad.thermal
        readings = output.temperature[due] if thermal is None \
            else thermal.reading_c(output.v_temp[due])
        self._last_temperature = float(readings[-1])
        message = self._temperature
        for stamp, reading in zip(stamps[due].tolist(), readings.tolist()):
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, NS_PER_S)
            message.temperature = reading
            self._publish(self._temperature_publisher, message, TEMPERATURE_TYPE, now_ns)

    def _publish(self, publisher, message, msgtype, now_ns=None):
        if self._recorder is None:
            publisher.publish(message)
            return
        data = serialize_message(message)
        publisher.publish(data)
        self._record(publisher.topic_name, msgtype, data,
                     self.get_clock().now().nanoseconds if now_ns is None else now_ns)

    def _record(self, topic, msgtype, data, now_ns):
        try:
            self._recorder.record(topic, msgtype, data, now_ns)
        except (OSError, ValueError) as error:
            self._recorder_problem = f'recording stopped: {error}'
            self.get_logger().error(self._recorder_problem)
            self._close_recorder()

    # Ground-truth input -----------------------------------------------------------------
    def input_imu_callback(self, message):
        """Take the specific force of a ground-truth ``sensor_msgs/Imu``."""
        self._accept_input(message.header.stamp, message.linear_acceleration)

    def input_accel_callback(self, message):
        """Take the specific force of a ground-truth ``geometry_msgs/AccelStamped``."""
        self._accept_input(message.header.stamp, message.accel.linear)

    def _accept_input(self, stamp, vector):
        value = (vector.x, vector.y, vector.z)
        time_ns = stamp.sec * NS_PER_S + stamp.nanosec
        if time_ns == 0:
            time_ns = self.get_clock().now().nanoseconds
        with self._lock:
            if not all(math.isfinite(v) for v in value):
                self._input_rejected += 1
                self._input_problem = f'non-finite ground-truth input rejected: {value}'
                return
            if self._inputs and time_ns < self._inputs[-1][0]:
                self._input_rejected += 1
                self._input_problem = 'ground-truth input out of order rejected'
                return
            self._inputs.append((time_ns, value))
            if len(self._inputs) > MAX_PENDING_INPUTS:
                # Inputs stamped ahead of the stream (another clock) must not pile up.
                self._held_input = self._inputs.pop(0)

    def _input_force(self, stamps):
        """Return (specific force per sample, stale mask) in topic mode, else (None, None)."""
        if self._values['input.mode'] != 'topic':
            return None, None
        count = len(stamps)
        fallback = self._held_input
        if fallback is None:
            fallback = (None, tuple(static_profile(self._values).specific_force))
        if not self._inputs:
            force = np.tile(fallback[1], (count, 1))
            times = np.full(count, -1 if fallback[0] is None else fallback[0], dtype=np.int64)
        else:
            times_in = np.array([t for t, _ in self._inputs], dtype=np.int64)
            values_in = np.array([v for _, v in self._inputs])
            index = np.searchsorted(times_in, stamps, side='right') - 1
            force = values_in[np.maximum(index, 0)]
            times = times_in[np.maximum(index, 0)]
            before = index < 0
            force[before] = fallback[1]
            times[before] = -1 if fallback[0] is None else fallback[0]
            last = int(index[-1])
            if last >= 0:
                # Keep the sample-and-hold value and every input not used yet.
                self._held_input = self._inputs[last]
                del self._inputs[:last + 1]
        timeout_ns = int(self._values['input.timeout_s'] * NS_PER_S)
        stale = (times < 0) | (stamps - times > timeout_ns)
        return force, stale

    def _held_force(self, count):
        if self._values['input.mode'] != 'topic':
            return None
        value = self._inputs[-1][1] if self._inputs else (
            self._held_input[1] if self._held_input
            else static_profile(self._values).specific_force)
        return np.tile(np.asarray(value, dtype=float), (count, 1))

    # Services ---------------------------------------------------------------------------
    async def capture_reference_callback(self, request, response):
        """Measure and persist the forward and feedback reference gains."""
        return await self._schedule_service(
            response, 'reference', lambda f, b: capture_reference(self._triad, self._state, f, b))

    async def estimate_forward_gain_callback(self, request, response):
        """Run the forward schedule and apply the correction in place."""
        return await self._schedule_service(
            response, 'forward', lambda f, b: forward_schedule(self._triad, self._state, f))

    async def estimate_feedback_gain_callback(self, request, response):
        """Run the feedback schedule and apply the correction in place."""
        return await self._schedule_service(
            response, 'feedback', lambda f, b: feedback_schedule(self._triad, self._state, b))

    async def self_calibrate_callback(self, request, response):
        """Run the forward, then the feedback schedule and apply both corrections."""
        return await self._schedule_service(
            response, 'self_calibrate',
            lambda f, b: self_calibrate(self._triad, self._state, f, b))

    async def calibrate_temperature_callback(self, request, response):
        """Run an accelerated chamber cycle, fit the zero bias and switch compensation on."""
        return await self._schedule_service(
            response, 'temperature',
            lambda f, b: temperature_schedule(self._triad, self._state,
                                              temperature_settings(self._values)),
            fast=True)

    async def _schedule_service(self, response, kind, make_schedule, fast=None):
        """Start a schedule, await its end, then persist, trace and answer."""
        if self._busy_kind is not None:
            response.success = False
            response.message = f'busy: {self._busy_kind} schedule running'
            return response
        # Busy from here until the answer: the state is saved and traced after the
        # sensor thread has let go of the schedule.
        self._busy_kind = kind
        try:
            return await self._run_schedule_service(response, kind, make_schedule, fast)
        finally:
            self._busy_kind = None

    async def _run_schedule_service(self, response, kind, make_schedule, fast):
        with self._lock:
            before = self._state.to_dict()
            try:
                run = ScheduleRun(kind, make_schedule(forward_settings(self._values),
                                                      feedback_settings(self._values)),
                                  not self._values['estimation.realtime'] if fast is None
                                  else fast)
            except Exception as error:
                # EstimationError and ValueError are the expected refusals; anything else
                # must still answer the caller instead of leaving the call hanging.
                return self._schedule_failed(response, kind, error, before)
            self._schedule = run
            self._pause_reason = _SCHEDULE_PAUSE[kind]
        try:
            result = await run.future
        except Exception as error:
            with self._lock:
                return self._schedule_failed(response, kind, error, before)
        results = result if isinstance(result, tuple) else (result,)
        with self._lock:
            if any(r.applied for r in results):
                self._compensation = True
            for r in results:
                self._last_results[r.kind] = r.summary()
            self._last_error = None
        summary = '; '.join(r.summary() for r in results)
        problems = []
        try:
            directory = Path(os.path.expanduser(self._values['trace_dir']))
            directory.mkdir(parents=True, exist_ok=True)
            self._last_trace = write_estimation_trace(
                trace_path(directory, kind, self.get_clock().now().nanoseconds), kind, results,
                source=self.get_fully_qualified_name())
        except OSError as error:
            problems.append(f'trace not written to {self._values["trace_dir"]} ({error})')
        problem = self._save_state()
        if problem:
            problems.append(problem)
        self._publish_calibrated()
        if problems:
            response.success = False
            response.message = (f'{"; ".join(problems)}; estimate and correction kept in the '
                                f'node and its diagnostics: {summary}')
            self._last_error = response.message
        else:
            response.success = True
            response.message = f'{summary}; trace {self._last_trace}'
        self.get_logger().info(response.message)
        return response

    def _schedule_failed(self, response, kind, error, before):
        """Answer a refused or failed schedule; keep and persist what it already applied."""
        self._schedule = None
        self._pause_reason = None
        response.success = False
        response.message = f'{kind} failed: {error}'
        if self._state.to_dict() != before:
            problem = self._save_state()
            response.message += '; corrections applied before the failure are kept' + \
                (f'; {problem}' if problem else '')
        self._last_error = response.message
        self.get_logger().warning(response.message)
        return response

    def set_compensation_callback(self, request, response):
        """Apply (true) the stored corrections or restore the nominal words (false)."""
        if self._busy_kind is not None:
            response.success = False
            response.message = f'busy: {self._busy_kind} schedule running'
            return response
        with self._lock:
            state = self._state
            if request.data and not (state.controller_gain or state.n_vref
                                     or state.temperature):
                response.success = False
                response.message = 'no stored corrections: call capture_reference, ' \
                                   'self_calibrate or calibrate_temperature first'
                return response
            try:
                if request.data:
                    state.apply_to(self._triad)
                else:
                    self._restore_nominal_words()
            except ValueError as error:
                response.success = False
                response.message = f'bad calibration state: {error}'
                return response
            self._compensation = bool(request.data)
            words = ', '.join(f'{axis} k(D(z)) {loop.controller.gain:.6g} N_VREF {loop.n_vref}'
                              for axis, loop in zip(AXES, self._triad.axes))
            thermal = 'on' if self._triad.temperature_compensation else 'off'
        problem = self._save_state()
        self._publish_calibrated()
        applied = 'stored corrections applied' if request.data else 'nominal words restored'
        response.success = problem is None
        response.message = f'{applied}: {words}; temperature compensation {thermal}' + \
            (f'; {problem}' if problem else '')
        return response

    # Recorder -------------------------------------------------------------------------
    def _restart_recorder(self):
        self._close_recorder()
        values = self._values
        if not values['recorder.enabled']:
            return
        max_bytes = values['recorder.max_bytes'] or None
        max_duration = values['recorder.max_duration_s']
        directory = Path(os.path.expanduser(values['recorder.directory']))
        try:
            directory.mkdir(parents=True, exist_ok=True)
            self._recorder = FlightRecorder(
                directory,
                prefix=self.get_name(), max_bytes=max_bytes,
                max_duration_ns=int(max_duration * NS_PER_S) if max_duration else None,
                qos={**self._recorder_qos, '/diagnostics': QosProfile(depth=10),
                     self._calibrated_publisher.topic_name: QOS_LATCHED})
            self._recorder_problem = None
        except (OSError, ValueError) as error:
            self._recorder_problem = f'recorder not started: {error}'
            self.get_logger().error(self._recorder_problem)

    def _close_recorder(self):
        recorder, self._recorder = self._recorder, None
        if recorder is not None:
            try:
                files = recorder.close()
            except (OSError, RecorderError) as error:
                self._recorder_problem = f'recording not closed cleanly: {error}'
                return
            if files:
                self.get_logger().info(f'recorded {", ".join(str(f) for f in files)}')

    # Diagnostics ----------------------------------------------------------------------
    def diagnostics_callback(self):
        """Publish the stream, calibration, temperature and input status (about 1 Hz)."""
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        with self._lock:
            array.status = [self._stream_status(), self._calibration_status(),
                            self._temperature_status(), self._input_status()]
            self._publish(self._diagnostics_publisher, array, DIAGNOSTICS_TYPE)

    def _status(self, topic, level, message, values):
        return DiagnosticStatus(
            level=level, name=f'{self.get_fully_qualified_name()}: {topic}',
            message=message, hardware_id=self._values['hardware_id'],
            values=[KeyValue(key=k, value=str(v)) for k, v in values])

    def _stream_status(self):
        triad = self._triad
        loops = []
        for axis, loop in enumerate(triad.axes):
            if loop.open_loop:
                loops.append('open')
            elif triad.sample_index < triad.settle_until[axis]:
                loops.append('settling')
            else:
                loops.append('closed')
        values = [('loop ' + a, s) for a, s in zip(AXES, loops)]
        values += [('I_ref ' + a, 'on' if loop.reference_current_on else 'off')
                   for a, loop in zip(AXES, triad.axes)]
        values += [('saturated samples ' + a, int(n)) for a, n in zip(AXES, self._saturated)]
        values += [('samples published', self._published),
                   ('samples withheld', self._withheld),
                   ('samples skipped (node late)', self._skipped),
                   ('largest batch per tick', self._max_batch),
                   ('sensor time [s]', f'{triad.time:.3f}')]
        if self._clock_note:
            values.append(('clock', self._clock_note))
        if self._recorder is not None:
            values.append(('recording', self._recorder.current_path or 'between files'))
        if self._recorder_problem:
            values.append(('recorder problem', self._recorder_problem))
        if self._sensor_error:
            values.append(('sensor thread error', self._sensor_error))
        level, message = DiagnosticStatus.OK, 'publishing'
        if self._pause_reason:
            level, message = DiagnosticStatus.WARN, f'paused: {self._pause_reason}'
        elif self._saturated.any():
            level, message = DiagnosticStatus.WARN, 'publishing; output saturated at times'
        if self._recorder_problem:
            level = DiagnosticStatus.WARN
            message += f'; {self._recorder_problem}'
        if self._sensor_error:
            level = DiagnosticStatus.ERROR
            message += f'; sensor thread error: {self._sensor_error}'
        return self._status('stream', level, message, values)

    def _calibration_status(self):
        state = self._state
        values = [('has reference', state.has_reference),
                  ('compensation', 'on' if self._compensation else 'off'),
                  ('state file', self._state_store.path or 'in memory only'),
                  ('schedule running', self._busy_kind or 'none')]
        values += [(f'k(D(z)) {a}', f'{loop.controller.gain:.9g}')
                   for a, loop in zip(AXES, self._triad.axes)]
        values += [(f'N_VREF {a}', loop.n_vref) for a, loop in zip(AXES, self._triad.axes)]
        for kind, estimate in state.last_estimates.items():
            values.append((f'last {kind} estimate [ppm]',
                           ', '.join(f'{a} {e:+.2f}' for a, e in zip(AXES, estimate))))
        values += [(f'last {kind}', summary) for kind, summary in self._last_results.items()]
        if self._last_trace:
            values.append(('last trace', self._last_trace))
        if self._last_error:
            values.append(('last error', self._last_error))
        if self._state_problem:
            values.append(('state file problem', self._state_problem))
            return self._status('calibration', DiagnosticStatus.ERROR, self._state_problem,
                                values)
        if not state.has_reference:
            return self._status('calibration', DiagnosticStatus.WARN,
                                'uncalibrated: no reference captured', values)
        if not self._compensation:
            return self._status('calibration', DiagnosticStatus.WARN,
                                'compensation bypassed: nominal words', values)
        message = 'calibrated'
        level = DiagnosticStatus.OK
        if self._last_error:
            level, message = DiagnosticStatus.WARN, f'calibrated; {self._last_error}'
        return self._status('calibration', level, message, values)

    def _temperature_status(self):
        triad = self._triad
        thermal = triad.thermal
        rom = 'stored' if self._state.temperature else 'none'
        compensating = 'on' if triad.temperature_compensation else 'off'
        values = [('thermal model', 'on' if thermal else 'off'),
                  ('temperature compensation', compensating), ('temperature ROM', rom)]
        if self._last_temperature is not None:
            values.append(('reading [degC]', f'{self._last_temperature:.3f}'))
        if thermal is None:
            values.append(('sensor temperature [degC]', f'{triad.temperature:.2f}'))
            return self._status('temperature', DiagnosticStatus.OK,
                                'no thermal model: constant temperature', values)
        values += [('ambient profile', thermal.config.ambient_profile),
                   ('body temperature [degC]', f'{thermal.sensor_c:.3f}')]
        if compensating == 'on':
            return self._status('temperature', DiagnosticStatus.OK,
                                'zero bias compensated (fixed-point CORDIC)', values)
        return self._status('temperature', DiagnosticStatus.OK,
                            'uncompensated: call calibrate_temperature', values)

    def _input_status(self):
        mode = self._values['input.mode']
        values = [('mode', mode), ('rejected inputs', self._input_rejected)]
        if mode == 'profile':
            values.append(('profile', self._values['input.profile']))
        if mode != 'topic':
            return self._status('input', DiagnosticStatus.OK, mode, values)
        now = self.get_clock().now().nanoseconds
        latest = self._inputs[-1] if self._inputs else self._held_input
        level, message = DiagnosticStatus.OK, 'ground-truth topic'
        if latest is None:
            level, message = DiagnosticStatus.WARN, \
                'no ground-truth input yet: imu/data_raw paused'
        else:
            age = (now - latest[0]) / 1e9
            values.append(('input age [s]', f'{age:.3f}'))
            if age > self._values['input.timeout_s']:
                level, message = DiagnosticStatus.WARN, \
                    f'ground-truth input stale ({age:.3f} s old): imu/data_raw paused'
        if self._input_problem:
            values.append(('last rejection', self._input_problem))
            if level == DiagnosticStatus.OK and self._input_rejected:
                level, message = DiagnosticStatus.WARN, \
                    f'ground-truth topic; {self._input_problem} (last value held)'
        return self._status('input', level, message, values)

    # Shutdown -------------------------------------------------------------------------
    def close(self):
        """Stop the sensor thread and a running schedule, save the state, close the recording."""
        self._stop.set()
        if self._sensor_thread.is_alive():
            self._sensor_thread.join(timeout=10.0)
        with self._lock:
            if self._schedule is not None:
                self._schedule.abort()
                self._schedule = None
            if self._state_unsaved:
                self._save_state()
            self._close_recorder()


def main(args=None):
    """Run the node until SIGINT or SIGTERM; return the exit status."""
    use_shipped_fastdds_profile()
    # Our own handlers only set a flag, so that a signal never interrupts a state-file
    # or recorder write half way: the spin loop below ends and the node closes cleanly.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = []
    previous = {number: signal.signal(number, lambda signum, frame: stop.append(signum))
                for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            node = QfaNode()
        except ValueError as error:
            print(f'qfa_node: invalid parameters: {error}', file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            while not stop and rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:
            pass
        finally:
            node.close()
            executor.shutdown()
            node.destroy_node()
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
