"""
How far a running schedule is, where a ROS user looks: ``/diagnostics`` and the log.

A schedule announces its phases itself (:class:`~qfa_ros.calibration.schedule.Phase`:
what it does, in words, and at most how much sensor time is left); the sensor thread
counts each block it feeds the schedule into its
:class:`~qfa_ros.calibration.schedule.ScheduleProgress`. :class:`ScheduleReport` logs
every phase change at INFO (one line a phase, never one a block) and turns the running
schedule, or the last one until the next starts, into the key values of the
``calibration`` diagnostic; :func:`withheld_note` is the ``stream`` diagnostic's line
about ``imu/data_raw``.
"""

from qfa_ros.calibration.schedule import ScheduleProgress
from qfa_ros.model.triad import NS_PER_S

RUNNING = 'running'
"""The ``schedule outcome`` of a schedule still running on the sensor."""
ANSWERING = 'answering'
"""The ``schedule outcome`` once its sensor time is over, while the call writes its trace
and state and answers."""
REALTIME_PACE_AFTER_S = 0.5
"""Wall time a real-time schedule runs before its pace and wall time left are told [s]: the
sensor thread feeds it in batches (``stream.batch_s``) up to ``stream.lead_s`` ahead, and
on a busy machine catches a stall up at once, so a shorter span measures a burst. From the
first block on, a 1 s schedule's first report read 0.0 s left (a CI run beside two soaks)."""


def _seconds(value, digits=1):
    return 'unknown' if value is None else f'{value:.{digits}f}'


def withheld_note(run, now_ns):
    """
    Return what ``imu/data_raw`` misses while ``run`` runs, one line.

    Parameters
    ----------
    run : ScheduleRun
        The running schedule (its ``progress`` and ``started_ns``, the node clock at its
        start [ns]).
    now_ns : int
        The node clock now [ns].

    Returns
    -------
    str
        ``withheld since 1764412345.120 s ROS time (12.3 s), about 14.1 s more (45 %
        done)``: since when, for how long so far, and for how long still at the
        schedule's pace.
    """
    progress = run.progress
    so_far = max(0, now_ns - run.started_ns) / NS_PER_S
    return (f'withheld since {run.started_ns / NS_PER_S:.3f} s ROS time ({so_far:.1f} s), '
            f'about {_seconds(progress.wall_left_s)} s more ({100 * progress.fraction:.0f} % '
            'done)')


class ScheduleReport:
    """
    The running or last schedule, as the log and the ``calibration`` diagnostic tell it.

    Written by the executor (start, end) and the sensor thread (the progress it feeds),
    read by the diagnostics: all of it under the node lock.

    Parameters
    ----------
    node : rclpy.node.Node
        The node (its logger and clock).
    sample_rate_hz : float
        Rate of the samples the sensor thread feeds [Hz].
    """

    def __init__(self, node, sample_rate_hz):
        self._node = node
        self._rate_hz = sample_rate_hz
        # The running or last schedule's run, and how it ended (RUNNING until it has).
        self.run = None
        self.outcome = None

    def progress(self, kind, fast):
        """Return a new progress for a ``kind`` schedule that logs its phase changes.

        In real time (``fast`` False) the pace waits for :data:`REALTIME_PACE_AFTER_S`.
        """
        return ScheduleProgress(kind, self._rate_hz, self._log_phase,
                                pace_after_s=0.0 if fast else REALTIME_PACE_AFTER_S)

    def started(self, run):
        """Show ``run`` (a :class:`~qfa_ros.ros.schedule_service.ScheduleRun`) from now on."""
        self.run, self.outcome = run, RUNNING

    @property
    def running(self):
        """Whether the schedule still runs on the sensor (``imu/data_raw`` withheld)."""
        return self.outcome == RUNNING and not self.run.future.done()

    def ended(self, outcome):
        """
        Say how the running schedule ended, once; nothing if none runs.

        Parameters
        ----------
        outcome : str
            ``done``, ``cancelled <how>`` or ``failed``.
        """
        if self.outcome == RUNNING:
            self.outcome = outcome

    def _log_phase(self, progress, changed):
        """Log a phase change at INFO (the sensor thread, per phase, not per block)."""
        if changed:
            self._node.get_logger().info(
                f'{progress.kind}: {progress.phase.name} ({100 * progress.fraction:.0f} % '
                f'done, at most {progress.left_s:.1f} s of sensor time left)')

    def status(self, now_ns):
        """
        Return the schedule's sentence and key values for the ``calibration`` diagnostic.

        Parameters
        ----------
        now_ns : int
            The node clock now [ns].

        Returns
        -------
        sentence : str or None
            What runs, how far and how long it still takes; or how the last schedule ended
            when it was cancelled or failed; None otherwise.
        values : list of (str, str)
            ``schedule outcome`` (``running``, ``answering``, ``done``, ``cancelled
            <how>``, ``failed``), ``schedule phase``, ``schedule progress [%]``,
            ``sensor time done [s]``; while it runs also ``sensor time left at most
            [s]``, ``pace [sensor s per wall s]``, ``wall time left [s]`` and
            ``imu/data_raw``. Empty before the first schedule.
        """
        run = self.run
        if run is None:
            return None, []
        progress = run.progress
        phase = f'{progress.kind}: {progress.describe()}'
        # Rounded once: the sentence's whole percent is the key value's, rounded again.
        percent = round(100 * progress.fraction, 1)
        outcome = ANSWERING if self.outcome == RUNNING and not self.running else self.outcome
        values = [('schedule outcome', outcome), ('schedule phase', phase),
                  ('schedule progress [%]', f'{percent:.1f}'),
                  ('sensor time done [s]', f'{progress.done_s:.2f}')]
        if outcome != RUNNING:
            sentence = None if outcome in ('done', ANSWERING) else \
                f'last schedule {outcome} at {percent:.0f} % ({phase})'
            return sentence, values
        pace, wall_left_s = progress.pace, progress.wall_left_s
        values += [('sensor time left at most [s]', f'{progress.left_s:.2f}'),
                   ('pace [sensor s per wall s]', _seconds(pace, 3)),
                   ('wall time left [s]', _seconds(wall_left_s)),
                   ('imu/data_raw', withheld_note(run, now_ns))]
        return (f'{phase}, {percent:.0f} % done, about {_seconds(wall_left_s)} s left; '
                'imu/data_raw withheld'), values
