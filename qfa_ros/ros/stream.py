"""
The sample stream: the sensor thread that computes the model ahead and the paced output.

Like a real sensor's electronics, whose filter has a group delay, the sensor thread runs
the model ahead of the clock in batches: every ``stream.batch_s`` it computes the samples
stamped up to ``stream.lead_s`` ahead, encodes them and hands them to the
:class:`~qfa_ros.ros.pacing.Pacer`, which publishes each one at its own instant. With the
ground-truth topic input a sample cannot be computed before its input exists: the thread
computes when an input arrives and the pacer publishes at once.
"""

import bisect
import copy
from itertools import repeat
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Temperature

from qfa_ros.bag.imu_cdr import ImuEncoder
from qfa_ros.bag.qos import QosProfile
from qfa_ros.model.triad import AXES, NS_PER_S, SampleGrid
from qfa_ros.ros.pacing import (
    LATE_NS,
    lower_thread_priority,
    Pacer,
    RecordingQueue,
    STALE_NS,
)
from qfa_ros.ros.progress import withheld_note

FAST_CHUNK_SAMPLES = 1000
FAST_SLICE_S = 0.02
"""CPU time a fast schedule may hold the model before the executor gets a turn [s]."""

MAX_CATCH_UP_S = 1.0
"""A backlog longer than this is skipped instead of computed (e.g. the process was stopped)."""

SKIP_WARN_S = 10.0
"""The stream diagnostic stays WARN this long (wall time) after samples were skipped [s]."""

WARM_UP_SAMPLES = 50
"""Samples run on a copy of the model before the grid is anchored (JIT, first calls)."""

FIRST_MARGIN_S = 0.01
"""Least time between anchoring the grid and the first sample's instant [s]."""

FIRST_MARGIN_FACTOR = 4.0
"""The first batch is given this many times its cost, as measured on the warm copy."""

IMU_TYPE = 'sensor_msgs/msg/Imu'
TEMPERATURE_TYPE = 'sensor_msgs/msg/Temperature'

_HISTORY = {0: 'system_default', 1: 'keep_last', 2: 'keep_all'}
_RELIABILITY = {0: 'system_default', 1: 'reliable', 2: 'best_effort'}
_DURABILITY = {0: 'system_default', 1: 'transient_local', 2: 'volatile'}
# An unset (system default) liveliness is automatic: what rmw reports for the publisher.
_LIVELINESS = {0: 'automatic', 1: 'automatic', 3: 'manual_by_topic'}


def publishable(items, publish_from_ns, now_ns):
    """
    Return the queued ``(stamp_ns, ...)`` items that may still be published, in order.

    Active (``publish_from_ns`` an instant [ns]), those stamped from it on. Paused
    (``publish_from_ns`` None), those not yet due at ``now_ns()`` [ns]: a batch computed
    ahead of the clock when the pause came, whose samples a quick resumption publishes (the
    pacer drops each one that comes due while paused). Discarding them too left a hole of
    a batch in the next active period (a CI run: 104 samples, 14 after its activation).
    """
    floor = now_ns() if publish_from_ns is None else publish_from_ns
    if not items or items[0][0] >= floor:
        return items
    return [item for item in items if item[0] >= floor]


def offered_qos(profile):
    """Return the rosbag2 offered QoS of an ``rclpy.qos.QoSProfile`` (a publisher's)."""
    def duration(value):
        nanoseconds = value.nanoseconds
        return None if nanoseconds <= 0 else nanoseconds
    return QosProfile(
        history=_HISTORY.get(int(profile.history), 'unknown'), depth=int(profile.depth),
        reliability=_RELIABILITY.get(int(profile.reliability), 'unknown'),
        durability=_DURABILITY.get(int(profile.durability), 'unknown'),
        deadline_ns=duration(profile.deadline), lifespan_ns=duration(profile.lifespan),
        liveliness=_LIVELINESS.get(int(profile.liveliness), 'unknown'),
        liveliness_lease_duration_ns=duration(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


def ros_qos(profile):
    """Return a new ``rclpy.qos.QoSProfile`` of a :class:`~qfa_ros.bag.qos.QosProfile`."""
    return QoSProfile(history=HistoryPolicy[profile.history.upper()], depth=profile.depth,
                      reliability=ReliabilityPolicy[profile.reliability.upper()],
                      durability=DurabilityPolicy[profile.durability.upper()])


class SampleStream:
    """
    Compute the model ahead of the clock; publish each ``imu/data_raw`` sample at its instant.

    ``imu/temperature`` readings are paced the same way, after the sample they belong to.

    Three threads: the sensor thread (model, grid, schedules, encoding; it holds ``lock``,
    the node's, for each batch, as the executor does for each callback that touches the
    model, the grid, the running schedule or the ground-truth input); the pacer thread
    (publishes; never takes ``lock``); the recording thread (writes the flight recording
    under the recording's own lock, never ``lock``: a write the disk holds up must not
    hold up the sensor thread).

    Parameters
    ----------
    node
        The node (clock and logger).
    lock
        The node lock.
    triad
        The model.
    values
        The node's live parameter values.
    ground_truth
        :class:`~qfa_ros.ros.input_queue.GroundTruthInput`.
    recording
        :class:`~qfa_ros.ros.recording.StreamRecording`.
    imu_publisher
        Publisher of ``imu/data_raw``.
    temperature_publisher
        Publisher of ``imu/temperature``.
    acceleration_covariance
        Row-major 3x3 covariance [(m/s^2)^2].
    process_tuning
        None, or the process's interpreter settings: an object whose ``warmed()`` the sensor thread
        calls after its warm-up (before the grid is anchored) and ``streaming()`` after its first
        batch (before the first sample is due). Process-wide, so only the process entry point
        passes one (:class:`qfa_ros.cli.node.ProcessTuning`); a node run inside another program
        leaves its interpreter as it is.
    """

    def __init__(self, node, lock, triad, values, ground_truth, recording, imu_publisher,
                 temperature_publisher, acceleration_covariance, process_tuning=None):
        self._node = node
        self._lock = lock  # the node lock: each batch and each schedule slice holds it
        self._triad = triad
        self._values = values
        self._ground_truth = ground_truth
        self._recording = recording
        self._imu_publisher = imu_publisher
        self._temperature_publisher = temperature_publisher
        self._acceleration_covariance = acceleration_covariance
        self._process_tuning = process_tuning
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
        # Samples stamped before this are not published [ns]; None: nothing is published
        # (a managed node's inactive state, :meth:`pause`). Written by the executor, read
        # by the sensor thread; resume and a batch's hand-over under _publishing_lock.
        self.publish_from_ns = 0
        # Protects publish_from_ns against a batch's hand-over to the pacer: a resumption
        # (executor thread) takes its instant and resumes the pacer either wholly before a
        # batch is filtered and queued (sensor thread) or wholly after; else a batch
        # computed up to an instant after the resumption could be discarded as inactive.
        self._publishing_lock = threading.Lock()
        self.unpublished = 0
        self.computed = 0
        self.withheld = 0
        self.skipped = 0
        self._last_skip = None
        # The pacer's dropped messages already logged, and when (sensor thread only).
        self._drops_logged = (0, None)
        self.skip_note = None
        self.sensor_error = None
        self.clock_note = None
        self.saturated = np.zeros(len(AXES), dtype=np.int64)
        self.last_temperature = None
        self.on_schedule_end = None
        # Called (pacer thread) once the first batch is published: the node logs its
        # start-up lines then, off the first sample's path.
        self.on_publishing = None
        # How long the first sample's instant follows the anchoring of the grid [ns]; the
        # warm-up measures what the first batch costs and shortens it (at most lead_s).
        self._first_margin_ns = int(values['stream.lead_s'] * NS_PER_S)
        self._stop = threading.Event()
        # Set by the pacer when it runs dry and by a ground-truth input: compute now.
        self._wake = threading.Event()
        self.recording_queue = RecordingQueue(recording)
        self.pacer = Pacer(node, self.recording_queue.append, self._wake.set,
                           self._started_publishing)
        self._thread = threading.Thread(target=self._loop, name='qfa_sensor', daemon=True)

    def start(self):
        """Start the sensor, pacer and recording threads."""
        self.recording_queue.start()
        self.pacer.start()
        self._thread.start()

    def pause(self):
        """
        Publish nothing from now on; the sensor runs on (a managed node's ``deactivate``).

        Returns once no publication is under way: nothing is published after it. The
        samples computed while paused are counted (:attr:`unpublished`), not published or
        recorded, and none ahead of the clock. Takes no lock the sensor thread holds: what
        a batch it is computing holds ahead of the clock goes to the pacer, which drops
        each one that comes due while paused (:func:`publishable`).
        """
        self.pacer.pause()
        self.publish_from_ns = None

    def resume(self):
        """
        Publish again from the present on, on the same sample grid (``activate``).

        The first sample published is the first one stamped at or after now; each one after
        it follows on the grid: those computed before the pause and not yet due are
        published from the pacer's queue, the sensor thread computes on from there.
        """
        with self._publishing_lock:
            # The present as the pacer resumes, not before: a sample due between the two
            # was dropped as paused (a Jazzy suite run: the first sample of a period missing).
            self.publish_from_ns = self.pacer.resume(lambda: max(0, self._now_ns()))
        self._wake.set()

    def _started_publishing(self):
        if self.on_publishing is not None:
            self.on_publishing()

    def stop(self, timeout_s=10.0):
        """Stop the threads (at most ``timeout_s`` each); record what was published."""
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout=timeout_s)
        self.pacer.stop(timeout_s)
        self.recording_queue.stop(timeout_s)

    def flush_recording(self):
        """Record what was published so far (any thread)."""
        self.recording_queue.flush()

    def input_arrived(self):
        """Wake the sensor thread: a ground-truth input makes samples computable."""
        self._wake.set()

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

    @property
    def published(self):
        """Return how many messages the pacer published (imu/data_raw and imu/temperature)."""
        return self.pacer.published

    # Sensor thread ----------------------------------------------------------------------
    def _loop(self):
        """Compute a batch every ``stream.batch_s`` until stopped (thread target)."""
        # The warm-up and the first batch run at the process's priority and with Python's
        # default switch interval: the first sample waits for them, and the pacer has
        # nothing to publish yet. From then on this thread yields to the pacer (and the
        # process, if it asked for it, switches the GIL sooner: process_tuning).
        yielding = False
        try:
            self._warm_up()
        except Exception as error:
            self.sensor_error = f'warm-up: {type(error).__name__}: {error}'
            self._node.get_logger().error(f'sensor thread: {self.sensor_error}')
        while not self._stop.is_set():
            with self._lock:
                try:
                    fast = self._step()
                except Exception as error:
                    # The sensor keeps running whatever one batch ran into; diagnostics tell.
                    fast = False
                    self.sensor_error = f'{type(error).__name__}: {error}'
                    self._node.get_logger().error(f'sensor thread: {self.sensor_error}',
                                                  throttle_duration_sec=5.0)
            if not yielding:
                # Before the first sample's instant (the margin of the first batch).
                if self._process_tuning is not None:
                    self._process_tuning.streaming()
                lower_thread_priority()
                yielding = True
            if fast:
                # Let the executor thread take the lock between slices of a fast schedule.
                self._stop.wait(0.001)
                continue
            self._wake.wait(self._values['stream.batch_s'])
            self._wake.clear()

    def _warm_up(self):
        """Pay for JIT loading and first calls before the grid is anchored (on copies)."""
        with self._lock:
            model = copy.deepcopy(self._triad)
            encoder = self._imu_encoder
        output = model.run(WARM_UP_SAMPLES)
        encoder.encode(output.stamps_ns, output.accel)
        serialize_message(self._temperature)
        if model.thermal is not None:
            model.thermal.reading_c(output.v_temp)
        # What a warm batch costs, per sample: the first batch (lead_s of samples) is
        # computed at once, and its first sample is due as soon as it can be ready.
        started = time.perf_counter()
        output = model.run(WARM_UP_SAMPLES)
        encoder.encode(output.stamps_ns, output.accel, output.gyro if encoder.has_rate else None)
        per_sample_s = (time.perf_counter() - started) / WARM_UP_SAMPLES
        lead_s = self._values['stream.lead_s']
        first_batch_s = per_sample_s * lead_s * self._values['sample_rate_hz']
        self._first_margin_ns = int(min(lead_s, FIRST_MARGIN_S
                                        + FIRST_MARGIN_FACTOR * first_batch_s) * NS_PER_S)
        # Before the grid is anchored: a process running only this node freezes its
        # start-up objects here (ProcessTuning.warmed), a collection that holds the GIL.
        if self._process_tuning is not None:
            self._process_tuning.warmed()

    def _step(self):
        """Compute one batch, or one slice of a fast schedule; return True for the latter."""
        run = self.schedule
        if run is not None and run.fast:
            self._run_fast_slice(run)
            return True
        self._advance_to_clock()
        return False

    def _now_ns(self):
        return self._node.get_clock().now().nanoseconds

    def _compute_until(self, now):
        """Return the instant up to which samples can be computed now [ns]."""
        ground_truth = self._ground_truth
        if not ground_truth.active:
            return now + int(self._values['stream.lead_s'] * NS_PER_S)
        # A sample takes the latest input stamped at or before it: it is final once an
        # input stamped at or after it has arrived, or once it is a batch old (held input).
        latest = ground_truth.pending[-1][0] if ground_truth.pending else (
            ground_truth.held[0] if ground_truth.held else None)
        waited = now - int(self._values['stream.batch_s'] * NS_PER_S)
        return waited if latest is None else max(waited, min(latest, now))

    def _advance_to_clock(self):
        """Compute every sample that can be computed now and queue it for its instant."""
        # Read before the clock: the pacer publishes a stamp only once the clock has reached
        # it, so only a clock that went back can read earlier than this.
        last = self.pacer.last_stamp_ns
        now = self._now_ns()
        if now <= 0:
            # use_sim_time without /clock yet: there is no time to stamp samples with.
            return
        grid = self.grid
        if grid.start_ns is None:
            # The first sample ends as soon as the first batch (computed now, up to lead_s
            # ahead) can be ready: the warm-up paid for the first calls and measured the
            # cost of a batch. Every later batch keeps the lead_s margin.
            grid.anchor(now + self._first_margin_ns)
        if last is not None and now < last:
            # The clock went back (a bag or simulation restarted): restart the stream.
            self.clock_note = f'clock jumped back by {(last - now) / 1e9:.3f} s; ' \
                'stream re-anchored'
            self.pacer.clear()
            grid.anchor(now)
        backlog = grid.due(now) - grid.next_index
        limit = int(MAX_CATCH_UP_S * self._values['sample_rate_hz'])
        if backlog > limit:
            self._skip(backlog)
        self._log_drops()
        until = self._compute_until(now)
        if self.publish_from_ns is None:
            # Not publishing: the sensor runs on, nothing is computed ahead.
            until = min(until, now)
        count = grid.due(until) - grid.next_index
        if count > 0:
            self._advance(count)

    def _skip(self, count):
        """Skip ``count`` samples the node can no longer compute in time; say so loudly."""
        self.grid.next_index += count
        self.skipped += count
        self._last_skip = time.monotonic()
        seconds = count / self._values['sample_rate_hz']
        self.skip_note = (f'{count} samples ({seconds:.3f} s) skipped: the node was held up '
                          'or its clock jumped ahead')
        self._node.get_logger().warning(
            f'{self.skip_note}; the stream resumes on its grid (more than '
            f'{MAX_CATCH_UP_S:g} s behind the clock is never computed)')

    def _log_drops(self):
        """Log the messages the pacer dropped, at most every ``SKIP_WARN_S``."""
        dropped = self.pacer.dropped
        logged, when = self._drops_logged
        if dropped == logged or (when is not None
                                 and time.monotonic() - when < SKIP_WARN_S):
            return
        self._drops_logged = (dropped, time.monotonic())
        self._node.get_logger().warning(
            f'{dropped - logged} messages dropped unpublished more than '
            f'{STALE_NS / 1e9:g} s after their instant: the publishing thread was held up; '
            f'the stream resumes at the present ({dropped} since start)')

    def _advance(self, count):
        grid = self.grid
        while count > 0:
            run = self.schedule
            chunk = count if run is None else min(count, run.remaining)
            stamps = grid.stamp_ns(np.arange(grid.next_index, grid.next_index + chunk))
            force, rate, stale = self._ground_truth.inputs(stamps)
            output = self._triad.run(chunk, force, angular_rate=rate)
            self._queue_samples(grid.next_index, stamps, output, stale)
            grid.next_index += chunk
            self.computed += chunk
            count -= chunk
            if run is not None and run.feed(output):
                self.schedule_ended()

    def _run_fast_slice(self, run):
        """Drive a fast schedule for up to ``FAST_SLICE_S`` of CPU time."""
        started = time.process_time()
        while time.process_time() - started < FAST_SLICE_S:
            n = min(FAST_CHUNK_SAMPLES, run.remaining)
            force, rate = self._ground_truth.held_inputs(n)
            output = self._triad.run(n, force, angular_rate=rate)
            self.saturated += output.saturated.sum(axis=0)
            if run.feed(output):
                self.finish_fast_schedule()
                return

    def finish_fast_schedule(self):
        """
        End a fast schedule (finished or cancelled) and resume the stream at the present.

        The stream keeps its grid: the samples due while the schedule computed are not
        published (the sensor had no valid output), the next one follows the clock again.
        """
        if self.grid.start_ns is not None:
            due = self.grid.due(self._now_ns())
            self.withheld += max(0, due - self.grid.next_index)
            self.grid.next_index = max(self.grid.next_index, due)
        self.schedule_ended()

    def schedule_ended(self):
        """Forget the running schedule and wake whoever awaits its end; the stream resumes."""
        run = self.schedule
        self.end_schedule()
        if self.on_schedule_end is not None:
            # The hook is told which schedule ended (the calibration event's kind).
            self.on_schedule_end(None if run is None else run.kind)

    def _queue_samples(self, first, stamps, output, stale):
        """Encode the valid samples and the temperature readings; queue them for the pacer."""
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
        items = []
        if valid.any():
            valid_stamps = stamps[valid]
            rate = output.gyro[valid] if self._imu_encoder.has_rate else None
            messages = self._imu_encoder.encode(valid_stamps, output.accel[valid], rate)
            items = list(zip(valid_stamps.tolist(), repeat(self._imu_publisher), repeat(IMU_TYPE),
                             messages))
        self.withheld += int(len(valid) - np.count_nonzero(valid))
        due = np.arange((-(first + 1)) % self._temperature_every, len(stamps),
                        self._temperature_every)
        if len(due):
            thermal = self._triad.thermal
            readings = output.temperature[due] if thermal is None \
                else thermal.reading_c(output.v_temp[due])
            self.last_temperature = float(readings[-1])
            message = self._temperature
            imu_stamps = [item[0] for item in items]
            # Inserted from the last: the earlier insertion points stay valid.
            for stamp, reading in reversed(list(zip(stamps[due].tolist(),
                                                    readings.tolist()))):
                message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp,
                                                                                 NS_PER_S)
                message.temperature = reading
                # The temperature reading follows the sample it belongs to.
                items.insert(bisect.bisect_right(imu_stamps, stamp),
                             (stamp, self._temperature_publisher, TEMPERATURE_TYPE,
                              serialize_message(message)))
        with self._publishing_lock:
            kept = publishable(items, self.publish_from_ns, self._now_ns)
            self.unpublished += len(items) - len(kept)
            self.pacer.put(kept)

    # Diagnostics ------------------------------------------------------------------------
    def status(self):
        """Return ``(level, message, key values)`` for the ``stream`` diagnostic."""
        triad = self._triad
        values = [('loop ' + a, 'open' if loop.open_loop else 'settling'
                   if triad.sample_index < triad.settle_until[axis] else 'closed')
                  for axis, (a, loop) in enumerate(zip(AXES, triad.axes))]
        values += [('I_ref ' + a, 'on' if loop.reference_current_on else 'off')
                   for a, loop in zip(AXES, triad.axes)]
        values += [('saturated samples ' + a, int(n)) for a, n in zip(AXES, self.saturated)]
        pacer = self.pacer
        values += [('samples computed', self.computed),
                   ('messages published', pacer.published),
                   ('messages waiting for their instant', pacer.pending),
                   ('samples withheld', self.withheld),
                   ('samples skipped', self.skipped),
                   ('messages not published (node inactive)',
                    self.unpublished + pacer.unpublished),
                   (f'messages published > {LATE_NS / 1e6:g} ms late', pacer.late),
                   (f'messages dropped > {STALE_NS / 1e9:g} s late', pacer.dropped),
                   ('largest publication delay [ms]', f'{pacer.max_delay_ns / 1e6:.3f}'),
                   ('sensor time [s]', f'{triad.time:.3f}')]
        if self.clock_note:
            values.append(('clock', self.clock_note))
        if self.skip_note:
            values.append(('last skip', self.skip_note))
        recording = self._recording
        if recording.active:
            values.append(('recording', recording.current_path or 'between files'))
        if recording.problem:
            values.append(('recorder problem', recording.problem))
        values += recording.retention_values()
        if self.sensor_error:
            values.append(('sensor thread error', self.sensor_error))
        level, message = DiagnosticStatus.OK, 'publishing'
        dropped_at = self._drops_logged[1]
        # A pause is the state the stream is in (a schedule asked for it): said first;
        # skips and drops since are counted in the values.
        if self.pause_reason:
            level, message = DiagnosticStatus.WARN, f'paused: {self.pause_reason}'
            if self.schedule is not None:
                # Why, since when and how long still (the schedule's own progress).
                note = withheld_note(self.schedule, self._now_ns())
                values.append(('imu/data_raw', note))
                message += f'; imu/data_raw {note}'
        elif self._last_skip is not None and time.monotonic() - self._last_skip < SKIP_WARN_S:
            level, message = DiagnosticStatus.WARN, \
                f'{self.skip_note}; {self.skipped} samples skipped since start'
        elif dropped_at is not None and time.monotonic() - dropped_at < SKIP_WARN_S:
            level, message = DiagnosticStatus.WARN, \
                f'{pacer.dropped} messages dropped more than {STALE_NS / 1e9:g} s late ' \
                'since start: the publishing thread was held up'
        elif self.saturated.any():
            level, message = DiagnosticStatus.WARN, 'publishing; output saturated at times'
        if recording.problem:
            # WARN for a write error; ERROR when it stopped for lack of free space.
            level = max(level, recording.problem_level)
            message += f'; {recording.problem}'
        if self.sensor_error:
            level = DiagnosticStatus.ERROR
            message += f'; sensor thread error: {self.sensor_error}'
        return level, message, values
