"""
The sample stream: the sensor thread that advances the model and publishes its output.

Like a real driver's device thread, it plays the part of the sensor's own electronics:
every 1/``tick_rate_hz`` it advances the model to the node clock and publishes every
sample that has become due on an exact grid, and it drives the running schedule.
"""

import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from sensor_msgs.msg import Temperature

from qfa_ros.bag.imu_cdr import ImuEncoder
from qfa_ros.model.triad import AXES, NS_PER_S, SampleGrid

FAST_CHUNK_SAMPLES = 1000
FAST_SLICE_S = 0.02
"""CPU time a fast schedule may hold the model before the executor gets a turn [s]."""

MAX_CATCH_UP_S = 1.0
"""A tick later than this skips ahead instead of computing the backlog (e.g. a debugger stop)."""

IMU_TYPE = 'sensor_msgs/msg/Imu'
TEMPERATURE_TYPE = 'sensor_msgs/msg/Temperature'


class SampleStream:
    """
    Advance the model to the node clock and publish ``imu/data_raw`` and ``imu/temperature``.

    The sensor thread and the executor thread share the model, the grid, the running
    schedule, the ground-truth input and the recording; ``lock`` (the node's) makes each
    tick and each callback's use of them atomic.

    :param node: The node (clock and logger).
    :param lock: The node lock.
    :param triad: The model.
    :param values: The node's live parameter values.
    :param ground_truth: :class:`~qfa_ros.ros.ground_truth.GroundTruthInput`.
    :param recording: :class:`~qfa_ros.ros.recording.StreamRecording`.
    :param imu_publisher: Publisher of ``imu/data_raw``.
    :param temperature_publisher: Publisher of ``imu/temperature``.
    :param acceleration_covariance: Row-major 3x3 covariance [(m/s^2)^2].
    """

    def __init__(self, node, lock, triad, values, ground_truth, recording, imu_publisher,
                 temperature_publisher, acceleration_covariance):
        self._node = node
        self._lock = lock
        self._triad = triad
        self._values = values
        self._ground_truth = ground_truth
        self._recording = recording
        self._imu_publisher = imu_publisher
        self._temperature_publisher = temperature_publisher
        self._acceleration_covariance = acceleration_covariance
        self._rate_covariance = None
        self._temperature = Temperature()
        if triad.thermal is not None:
            self._temperature.variance = triad.thermal.reading_variance_c2
        self.set_frame_id(values['frame_id'])
        self.grid = SampleGrid(values['sample_rate_hz'])
        self._temperature_every = max(1, round(values['sample_rate_hz']
                                               / values['temperature_rate_hz']))
        self.schedule = None
        self.pause_reason = None
        self.published = 0
        self.withheld = 0
        self.skipped = 0
        self.max_batch = 0
        self.sensor_error = None
        self.clock_note = None
        self.saturated = np.zeros(len(AXES), dtype=np.int64)
        self.last_temperature = None
        self.on_schedule_end = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name='qfa_sensor', daemon=True)

    def start(self):
        """Start the sensor thread."""
        self._thread.start()

    def stop(self, timeout_s=10.0):
        """Stop the sensor thread and wait for it (at most ``timeout_s``)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=timeout_s)

    def set_frame_id(self, frame_id):
        """Stamp every following message with ``frame_id``."""
        self._imu_encoder = ImuEncoder(frame_id, self._acceleration_covariance,
                                       self._rate_covariance)
        self._temperature.header.frame_id = frame_id

    def set_rate_covariance(self, covariance):
        """Publish the gyros' angular velocity with this row-major 3x3 covariance [(rad/s)^2]."""
        self._rate_covariance = covariance
        self.set_frame_id(self._imu_encoder.frame_id)

    def start_schedule(self, run, reason):
        """Hand ``run`` to the sensor thread; the stream pauses for ``reason``."""
        self.schedule = run
        self.pause_reason = reason

    def end_schedule(self):
        """Forget the running schedule; the stream resumes."""
        self.schedule = None
        self.pause_reason = None

    # Sensor thread ----------------------------------------------------------------------
    def _loop(self):
        """Advance the model at ``tick_rate_hz`` until stopped (thread target)."""
        period = 1.0 / self._values['tick_rate_hz']
        deadline = time.monotonic()
        while not self._stop.is_set():
            with self._lock:
                try:
                    fast = self._step()
                except Exception as error:
                    # The sensor keeps running whatever one tick ran into; diagnostics tell.
                    fast = False
                    self.sensor_error = f'{type(error).__name__}: {error}'
                    self._node.get_logger().error(f'sensor thread: {self.sensor_error}',
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

    def _step(self):
        """Run one tick, or one slice of a fast schedule; return True for the latter."""
        run = self.schedule
        if run is not None and run.fast:
            self._run_fast_slice(run)
            return True
        self._advance_to_clock()
        return False

    def _now_ns(self):
        return self._node.get_clock().now().nanoseconds

    def _advance_to_clock(self):
        """Run the model up to the node clock and publish every sample that is due."""
        now = self._now_ns()
        if now <= 0:
            # use_sim_time without /clock yet: there is no time to stamp samples with.
            return
        grid = self.grid
        if grid.start_ns is None:
            grid.anchor(now)
            return
        if grid.next_index and now < grid.stamp_ns(grid.next_index - 1):
            # The clock went back (a bag or simulation restarted): restart the stream.
            jump = (grid.stamp_ns(grid.next_index - 1) - now) / 1e9
            self.clock_note = f'clock jumped back by {jump:.3f} s; stream re-anchored'
            grid.anchor(now)
            return
        backlog = grid.due(now) - grid.next_index
        limit = int(MAX_CATCH_UP_S * self._values['sample_rate_hz'])
        if backlog > limit:
            self.skipped += backlog
            grid.next_index += backlog
            self.clock_note = f'node was {backlog} samples late; skipped them'
            return
        if backlog > 0:
            self.max_batch = max(self.max_batch, backlog)
            self._advance(backlog)

    def _advance(self, count):
        grid = self.grid
        while count > 0:
            run = self.schedule
            chunk = count if run is None else min(count, run.remaining)
            stamps = grid.stamp_ns(np.arange(grid.next_index, grid.next_index + chunk))
            force, rate, stale = self._ground_truth.inputs(stamps)
            output = self._triad.run(chunk, force, angular_rate=rate)
            self._publish_samples(grid.next_index, stamps, output, stale)
            grid.next_index += chunk
            count -= chunk
            if run is not None and run.feed(output):
                self._schedule_ended()

    def _run_fast_slice(self, run):
        """Drive a fast schedule for up to ``FAST_SLICE_S`` of CPU time."""
        started = time.process_time()
        while time.process_time() - started < FAST_SLICE_S:
            n = min(FAST_CHUNK_SAMPLES, run.remaining)
            force, rate = self._ground_truth.held_inputs(n)
            output = self._triad.run(n, force, angular_rate=rate)
            self.saturated += output.saturated.sum(axis=0)
            if run.feed(output):
                # The stream keeps its grid: the samples due while the schedule computed
                # are not published (the sensor had no valid output), the next one
                # follows the node clock again.
                if self.grid.start_ns is not None:
                    due = self.grid.due(self._now_ns())
                    self.withheld += max(0, due - self.grid.next_index)
                    self.grid.next_index = max(self.grid.next_index, due)
                self._schedule_ended()
                return

    def _schedule_ended(self):
        self.end_schedule()
        if self.on_schedule_end is not None:
            self.on_schedule_end()

    def _publish_samples(self, first, stamps, output, stale):
        self.saturated += output.saturated.sum(axis=0)
        valid = output.valid.all(axis=1)
        if stale is not None:
            valid &= ~stale
        if self.schedule is not None:
            valid[:] = False
            reason = self.pause_reason
        elif not valid.all():
            reason = 'ground-truth input stale' if stale is not None and stale.any() \
                else 'loops settling after re-closing'
        else:
            reason = None
        self.pause_reason = reason if not valid[-1] else None
        recording = self._recording
        # The log time of everything this batch records: one clock read, not one per message.
        now_ns = self._now_ns() if recording.active else None
        if valid.any():
            rate = output.gyro[valid] if self._imu_encoder.has_rate else None
            messages = self._imu_encoder.encode(stamps[valid], output.accel[valid], rate)
            topic = self._imu_publisher.topic_name
            for data in messages:
                self._imu_publisher.publish(data)
                if recording.active:
                    recording.record(topic, IMU_TYPE, data, now_ns)
            self.published += len(messages)
        self.withheld += int(len(valid) - np.count_nonzero(valid))
        due = np.arange((-(first + 1)) % self._temperature_every, len(stamps),
                        self._temperature_every)
        if not len(due):
            return
        thermal = self._triad.thermal
        readings = output.temperature[due] if thermal is None \
            else thermal.reading_c(output.v_temp[due])
        self.last_temperature = float(readings[-1])
        message = self._temperature
        for stamp, reading in zip(stamps[due].tolist(), readings.tolist()):
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, NS_PER_S)
            message.temperature = reading
            recording.publish(self._temperature_publisher, message, TEMPERATURE_TYPE, now_ns)

    # Diagnostics ------------------------------------------------------------------------
    def status(self):
        """Return ``(level, message, key values)`` for the ``stream`` diagnostic."""
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
        values += [('saturated samples ' + a, int(n)) for a, n in zip(AXES, self.saturated)]
        values += [('samples published', self.published),
                   ('samples withheld', self.withheld),
                   ('samples skipped (node late)', self.skipped),
                   ('largest batch per tick', self.max_batch),
                   ('sensor time [s]', f'{triad.time:.3f}')]
        if self.clock_note:
            values.append(('clock', self.clock_note))
        recording = self._recording
        if recording.active:
            values.append(('recording', recording.current_path or 'between files'))
        if recording.problem:
            values.append(('recorder problem', recording.problem))
        if self.sensor_error:
            values.append(('sensor thread error', self.sensor_error))
        level, message = DiagnosticStatus.OK, 'publishing'
        if self.pause_reason:
            level, message = DiagnosticStatus.WARN, f'paused: {self.pause_reason}'
        elif self.saturated.any():
            level, message = DiagnosticStatus.WARN, 'publishing; output saturated at times'
        if recording.problem:
            level = DiagnosticStatus.WARN
            message += f'; {recording.problem}'
        if self.sensor_error:
            level = DiagnosticStatus.ERROR
            message += f'; sensor thread error: {self.sensor_error}'
        return level, message, values
