"""
Schedules behind the services: run on the sensor thread, awaited by the service call.

A service callback is a coroutine: it starts a :class:`ScheduleRun` on the sample
stream, awaits its future (the executor serves everything else meanwhile), then writes
the trace, persists the state and answers. Nothing here blocks the executor.

Every schedule is bounded by the ranges of its parameters (``qfa_ros.ros.bounds``), so
it ends even when its caller has gone; ``~/cancel`` ends it at once and puts the sensor
back exactly as it was before the call.
"""

import copy
import errno

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.task import Future

from qfa_ros.calibration.schedule import EstimationError, next_request
from qfa_ros.model.constants import DEG_PER_HOUR
from qfa_ros.model.safe_files import system_reason
from qfa_ros.model.triad import AXES
from qfa_ros.model.triad_output import concatenate
from qfa_ros.ros.bounds import confined_directory
from qfa_ros.ros.progress import ScheduleReport
from qfa_ros.ros.recording import FreeSpaceGuard


class ScheduleCancelledError(Exception):
    """The running schedule was cancelled (``~/cancel``, deactivation); the sensor is restored."""


class SensorSnapshot:
    """
    What a schedule may change, taken before it starts: loop words and calibration state.

    Parameters
    ----------
    keeper
        :class:`~qfa_ros.ros.calibration_keeper.CalibrationKeeper`.
    """

    def __init__(self, keeper):
        triad = keeper.triad
        self._keeper = keeper
        self.state = copy.deepcopy(keeper.state)
        self.compensation = keeper.compensation
        self.gains = [loop.controller.gain for loop in triad.axes]
        self.n_vref = [loop.n_vref for loop in triad.axes]
        self.n_fpga = [loop.n_fpga for loop in triad.axes]
        self.temperature_compensation = triad.temperature_compensation
        self.temperature_compensator = triad.temperature_compensator

    def restore(self):
        """Write the words, switches and state back (after the schedule's own clean-up)."""
        keeper, triad = self._keeper, self._keeper.triad
        for axis in range(len(AXES)):
            triad.set_reference_current(axis, False)
            triad.set_n_fpga(axis, self.n_fpga[axis])
            triad.set_open_loop(axis, False)
            triad.set_controller_gain(axis, self.gains[axis])
            triad.set_n_vref(axis, self.n_vref[axis])
        triad.temperature_compensator = self.temperature_compensator
        triad.fixture = None  # the dividing head of a cancelled temperature calibration
        triad.temperature_compensation = self.temperature_compensation
        keeper.state = copy.deepcopy(self.state)
        keeper.compensation = self.compensation


class ScheduleRun:
    """
    A self-estimation or calibration schedule driven by the sensor thread.

    The schedule generator yields how many samples it needs (and its phases); the sensor
    thread feeds it the model output (as the samples become due, or as fast as the CPU
    allows when ``fast``) and sends the concatenated block back. ``future`` gets the
    result; ``progress`` counts every block fed and takes every phase announced.

    Parameters
    ----------
    kind : str
        Schedule name.
    generator : generator
        Schedule generator of :mod:`qfa_ros.calibration.estimation`,
        :mod:`qfa_ros.calibration.temperature` or :mod:`qfa_ros.calibration.gyro_bias`.
    fast : bool
        Run as fast as the CPU allows instead of at the node clock.
    progress : ScheduleProgress
        Where the schedule's phases and blocks are counted.
    started_ns : int
        The node clock at the call [ns] (``imu/data_raw`` withheld since).

    Raises
    ------
    EstimationError
        The schedule refuses to start (e.g. no reference).
    """

    def __init__(self, kind, generator, fast, progress, started_ns=0):
        self.kind = kind
        self.generator = generator
        self.fast = fast
        self.progress = progress
        self.started_ns = started_ns
        self.future = Future()
        self.parts = []
        self.remaining = next_request(generator, None, progress)

    def feed(self, output):
        """Hand over ``output`` (a block, counted once); return True once the schedule ends."""
        self.parts.append(output)
        count = len(output.stamps_ns)
        self.remaining -= count
        self.progress.advance(count)
        if self.remaining > 0:
            return False
        block, self.parts = concatenate(self.parts), []
        try:
            self.remaining = next_request(self.generator, block, self.progress)
        except StopIteration as stop:
            self.progress.finish()
            self.future.set_result(stop.value)
            return True
        except Exception as error:
            # Whatever stopped the schedule, the waiting service call reports it.
            self.future.set_exception(error)
            return True
        return False

    def abort(self, reason='node shutting down', error_type=EstimationError):
        """Stop the schedule: its ``finally`` blocks re-close the loops and the ambient."""
        self.generator.close()
        if not self.future.done():
            self.future.set_exception(error_type(reason))


class ScheduleService:
    """
    Run one schedule at a time for the Trigger services and answer them.

    Parameters
    ----------
    node
        The node (clock, logger, name, ``is_calibrated`` publication).
    lock
        The node lock.
    values
        The node's live parameter values.
    stream
        :class:`~qfa_ros.ros.stream.SampleStream` that drives the schedule.
    keeper
        :class:`~qfa_ros.ros.calibration_keeper.CalibrationKeeper`.
    """

    def __init__(self, node, lock, values, stream, keeper):
        self._node = node
        self._lock = lock  # the node lock: the model, the stream's schedule, the state
        self._values = values
        self._stream = stream
        self._keeper = keeper
        self._guard = FreeSpaceGuard(values['min_free_bytes'])
        # Read by the executor thread only (services, parameters, diagnostics).
        self.busy_kind = None
        # Why every call is refused now (a managed node not active), or None.
        self.refusal = None
        self._snapshot = None
        self.last_results = {}
        self.last_trace = None
        self.last_error = None
        # The running or last schedule's phase and progress (diagnostics, log).
        self.report = ScheduleReport(node, values['sample_rate_hz'])

    def busy_answer(self):
        """Return the reason a call must be refused now, or None."""
        if self.refusal is not None:
            return self.refusal
        if self.busy_kind is not None:
            return f'busy: {self.busy_kind} schedule running'
        return None

    async def run(self, response, spec):
        """
        Start the schedule of ``spec``, await its end, then persist, trace and answer.

        Parameters
        ----------
        response : std_srvs.srv.Trigger.Response
            The answer to fill.
        spec : ServiceSpec
            The service's row (:data:`~qfa_ros.ros.service_table.SERVICES`): its schedule,
            kind, pause and whether it always runs fast.

        Returns
        -------
        std_srvs.srv.Trigger.Response
            ``response``, answered.
        """
        busy = self.busy_answer()
        if busy:
            response.success = False
            response.message = busy
            return response
        # Busy from here until the answer: the state is saved and traced after the
        # sensor thread has let go of the schedule.
        self.busy_kind = spec.kind
        try:
            return await self._run(response, spec)
        finally:
            self.busy_kind = None

    async def _run(self, response, spec):
        keeper = self._keeper
        kind = spec.kind
        with self._lock:
            moving = keeper.triad.is_at_rest()
            if moving:
                response.success = False
                response.message = f'{kind} refused: {moving}'
                self.last_error = response.message
                return response
            before = keeper.state.to_dict()
            self._snapshot = SensorSnapshot(keeper)
            fast = spec.always_fast or not self._values['estimation.realtime']
            try:
                run = ScheduleRun(kind, spec.schedule(keeper.triad, keeper.state, self._values),
                                  fast, self.report.progress(kind, fast),
                                  self._node.get_clock().now().nanoseconds)
            except Exception as error:
                # EstimationError and ValueError are the expected refusals; anything else
                # must still answer the caller instead of leaving the call hanging.
                return self._failed(response, kind, error, before)
            self.report.started(run)
            self._stream.start_schedule(run, spec.pause)
        try:
            result = await run.future
        except ScheduleCancelledError as error:
            # cancel() has restored the sensor; nothing was applied or saved.
            response.success, response.message = False, str(error)
            self._node.get_logger().warning(response.message)
            return response
        except Exception as error:
            with self._lock:
                return self._failed(response, kind, error, before)
        results = result if isinstance(result, tuple) else (result,)
        with self._lock:
            if any(r.applied for r in results):
                keeper.compensation = True
            for r in results:
                self.last_results[r.kind] = r.summary()
            self.last_error = None
            self.report.ended('done')
        summary = '; '.join(r.summary() for r in results)
        problems = []
        node = self._node
        try:
            # Resolved again now: a symlink may have changed since the parameter was set.
            directory = confined_directory(self._values, 'trace_dir')
            directory.mkdir(parents=True, exist_ok=True)
            shortfall = self._guard.shortfall(directory, 'trace_dir')
            if shortfall:
                raise OSError(errno.ENOSPC, shortfall)
            # Imported here: the MCAP writer's packages load only when a trace is written.
            from qfa_ros.bag.estimation_trace import trace_path, write_estimation_trace
            self.last_trace = write_estimation_trace(
                trace_path(directory, kind, node.get_clock().now().nanoseconds), kind, results,
                source=node.get_fully_qualified_name())
        except (OSError, ValueError) as error:
            # The rule or the system's words: the caller may be a stranger, and the
            # path (resolved, as long as the value) is not its business.
            reason = system_reason(error) if isinstance(error, OSError) else error
            problems.append(f'trace not written to trace_dir ({reason})')
        problem = keeper.save()
        if problem:
            problems.append(problem)
        node.publish_calibrated()
        if problems:
            response.success = False
            response.message = (f'{"; ".join(problems)}; estimate and correction kept in the '
                                f'node and its diagnostics: {summary}')
            self.last_error = response.message
        else:
            response.success = True
            response.message = f'{summary}; trace {self.last_trace}'
        node.get_logger().info(response.message)
        return response

    def cancel(self, cause='through ~/cancel'):
        """
        Abort the running schedule and restore the sensor as it was before the call.

        The schedule's own ``finally`` blocks re-close the loops, switch ``I_ref`` off and
        restore the ambient; then the words, the temperature compensation and the
        calibration state of the snapshot are written back, the stream resumes on its grid
        and the pending call answers ``success: false``, ``... cancelled ...``. Call with
        the node lock held.

        Parameters
        ----------
        cause
            How it was cancelled, for the pending call's answer.

        Returns
        -------
        ``(success, message)`` for the ``~/cancel`` answer.
        """
        stream = self._stream
        run = stream.schedule
        if run is None:
            if self.busy_kind is not None:
                return False, (f'{self.busy_kind} schedule has finished its sensor time and '
                               'is being saved: too late to cancel')
            return False, 'no schedule running'
        run.abort(f'{run.kind} cancelled {cause}: loops, loop words and calibration state '
                  'restored as before the call; nothing saved', ScheduleCancelledError)
        self.report.ended(f'cancelled {cause}')
        self._snapshot.restore()
        if run.fast:
            stream.finish_fast_schedule()
        else:
            stream.schedule_ended()
        return True, f'{run.kind} schedule cancelled; sensor restored, stream resuming'

    def _failed(self, response, kind, error, before):
        """Answer a refused or failed schedule; keep and persist what it already applied."""
        self._stream.end_schedule()
        self.report.ended('failed')
        response.success = False
        response.message = f'{kind} failed: {error}'
        if self._keeper.state.to_dict() != before:
            problem = self._keeper.save()
            response.message += '; corrections applied before the failure are kept' + \
                (f'; {problem}' if problem else '')
        self.last_error = response.message
        self._node.get_logger().warning(response.message)
        return response

    def status(self):
        """Return ``(level, message, key values)`` for the ``calibration`` diagnostic."""
        keeper = self._keeper
        state = keeper.state
        triad_axes = keeper.triad.axes
        # The running or last schedule: its phase, progress and time left (or how it ended).
        sentence, progress = self.report.status(self._node.get_clock().now().nanoseconds)
        values = [('has reference', state.has_reference),
                  ('compensation', 'on' if keeper.compensation else 'off'),
                  ('state file', keeper.store.path or 'in memory only'),
                  ('schedule running', self.busy_kind or 'none'), *progress]
        values += [(f'k(D(z)) {a}', f'{loop.controller.gain:.9g}')
                   for a, loop in zip(AXES, triad_axes)]
        values += [(f'N_VREF {a}', loop.n_vref) for a, loop in zip(AXES, triad_axes)]
        if state.gyro_bias:
            values.append(('gyro bias correction [deg/h]', ', '.join(
                f'{a} {b / DEG_PER_HOUR:+.4f}' for a, b in zip(AXES, state.gyro_bias))))
        for kind, estimate in state.last_estimates.items():
            values.append((f'last {kind} estimate [ppm]',
                           ', '.join(f'{a} {e:+.2f}' for a, e in zip(AXES, estimate))))
        values += [(f'last {kind}', summary) for kind, summary in self.last_results.items()]
        if self.last_trace:
            values.append(('last trace', self.last_trace))
        if self.last_error:
            values.append(('last error', self.last_error))
        if keeper.problem:
            values.append(('state file problem', keeper.problem))
            level, message = DiagnosticStatus.ERROR, keeper.problem
        elif not state.has_reference:
            level, message = DiagnosticStatus.WARN, 'uncalibrated: no reference captured'
        elif not keeper.compensation:
            level, message = DiagnosticStatus.WARN, 'compensation bypassed: nominal words'
        elif self.last_error:
            level, message = DiagnosticStatus.WARN, f'calibrated; {self.last_error}'
        else:
            level, message = DiagnosticStatus.OK, 'calibrated'
        if sentence:
            # A running schedule is what the user looks for; a past one's end comes after.
            message = f'{sentence}; {message}' if self.report.running \
                else f'{message}; {sentence}'
        return level, message, values
