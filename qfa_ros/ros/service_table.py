"""
The node's services, as data: one row per service, everything else derived from it.

:data:`SERVICES` is the one table. Derived from it: the services the node offers
(:class:`~qfa_ros.ros.services.CalibrationServices` creates one per row), what the stream
says while a schedule runs (:meth:`~qfa_ros.ros.schedule_service.ScheduleService.run`), the
loop-step budget of every schedule (:func:`budget_problem`, checked with the parameters by
:func:`~qfa_ros.ros.parameter_checks.check_all`), the kind of a correction on
``~/calibration_events`` (:meth:`~qfa_ros.ros.truth.TruthPublisher.mark`), the services
tables of ``docs/node.md`` and the README (:mod:`qfa_ros.ros.interface_docs`) and the
tests' lists of services.
"""

from dataclasses import dataclass
from typing import Callable

from std_srvs.srv import SetBool, Trigger

from qfa_ros.calibration.estimation import (
    capture_reference,
    feedback_schedule,
    feedback_sensor_time_s,
    forward_schedule,
    forward_sensor_time_s,
    self_calibrate,
)
from qfa_ros.calibration.gyro_bias import gyro_bias_schedule, GyroBiasSettings
from qfa_ros.calibration.temperature import temperature_calibration
from qfa_ros.ros.bounds import (
    CHAMBER_WORST_S,
    FEEDBACK_WORST_S,
    FORWARD_WORST_S,
    MAX_SCHEDULE_LOOP_STEPS,
    SCHEDULE_WORST_S,
    SETTLE_TIME_S,
)
from qfa_ros.ros.model_settings import (
    feedback_settings,
    forward_settings,
    gyro_bias_settings,
    temperature_settings,
)
from qfa_ros.ros.parameter_table import SPECS


@dataclass(frozen=True)
class ServiceSpec:
    """
    One service of the node: a schedule it runs, or a handler that answers at once.

    Parameters
    ----------
    name : str
        Service name, relative to the node (``~/capture_reference``).
    srv_type : type
        Service type (``std_srvs.srv.Trigger``).
    doc : str
        What it does, in one line (the README and ``docs/node.md``).
    kind : str or None
        What the running schedule is called: in the busy answer (``busy: <kind> schedule
        running``), the refusals, the trace file (``qfa_<kind>_<ns>.mcap``), the ``schedule
        running`` diagnostic and the ``kind`` of the correction on ``~/calibration_events``.
        None: the service applies no correction.
    details : str
        What ``docs/node.md`` adds to ``doc`` ('' for nothing).
    schedule : callable or None
        ``schedule(triad, state, values)`` returns the schedule generator, given the model,
        the calibration state and the node's live parameter values. None: ``handler``.
    handler : str or None
        The method of :class:`~qfa_ros.ros.services.CalibrationServices` that answers a
        service running no schedule, called as ``handler(spec, request, response)``.
    pause : str
        The stream's diagnostic while the schedule runs (``paused: <pause>``).
    always_fast : bool
        The schedule runs as fast as the CPU allows whatever ``estimation.realtime`` says.
    sensor_time_s : callable or None
        ``sensor_time_s(values)``: the longest sensor time one call takes with the
        parameter values ``values`` [s] (the loops' settling included).
    worst_s : float
        The longest sensor time a call may take [s]: what the parameter ranges allow, or
        less; a setting that would take longer is refused (:func:`budget_problem`).
    parameters : str
        The parameters that set the sensor time, as a refusal names them.
    worst_note : str
        What a refusal beyond ``worst_s`` adds in parentheses ('' for nothing).
    stream : str
        What the call does to the stream, for a service running no schedule (a
        schedule's is derived: :func:`stream_effect`).

    Raises
    ------
    ValueError
        Neither or both of ``schedule`` and ``handler``; a schedule without its kind,
        pause, sensor time or worst case; a handler without its ``stream`` line.
    """

    name: str
    srv_type: type
    doc: str
    kind: str = None
    details: str = ''
    schedule: Callable = None
    handler: str = None
    pause: str = ''
    always_fast: bool = False
    sensor_time_s: Callable = None
    worst_s: float = None
    parameters: str = ''
    worst_note: str = ''
    stream: str = ''

    def __post_init__(self):
        if (self.schedule is None) == (self.handler is None):
            raise ValueError(f'{self.name}: give either schedule or handler')
        if self.schedule is not None and not (
                self.kind and self.pause and self.sensor_time_s and self.worst_s
                and self.parameters):
            raise ValueError(f'{self.name}: a schedule needs its kind, pause, sensor_time_s, '
                             'worst_s and parameters')
        if self.handler is not None and not self.stream:
            raise ValueError(f'{self.name}: a handler needs its stream line')

    @property
    def type_name(self):
        """Return the service type as ROS names it (``std_srvs/srv/Trigger``)."""
        return f'{self.srv_type.__module__.split(".")[0]}/srv/{self.srv_type.__name__}'

    @property
    def call(self):
        """Return the name without ``~/`` (``capture_reference``), as refusals name a call."""
        return self.name.removeprefix('~/')


def gyro_bias_time_s(duration_s):
    """Return the sensor time of one gyro bias calibration of ``duration_s`` [s]."""
    return GyroBiasSettings(duration_s=duration_s).sensor_time_s()


def _forward_s(values):
    return forward_sensor_time_s(forward_settings(values), SETTLE_TIME_S)


def _feedback_s(values):
    return feedback_sensor_time_s(feedback_settings(values), SETTLE_TIME_S)


def _estimation_s(values):
    return _forward_s(values) + _feedback_s(values)


ESTIMATION = 'estimation.forward.* / estimation.feedback.*'
"""The parameters of the estimation schedules, as a refusal names them."""

SERVICES = (
    ServiceSpec(
        '~/capture_reference', Trigger,
        'forward and feedback references (Ran et al. 2019, §IV-A step 1), persisted',
        kind='reference',
        schedule=lambda triad, state, values: capture_reference(
            triad, state, forward_settings(values), feedback_settings(values)),
        pause='reference capture running (open loop, then I_ref steps)',
        sensor_time_s=_estimation_s, worst_s=SCHEDULE_WORST_S, parameters=ESTIMATION),
    ServiceSpec(
        '~/estimate_forward_gain', Trigger,
        'forward schedule; `k(D(z)) ← k(D(z))/(1 + δk_pre)` in place', kind='forward',
        schedule=lambda triad, state, values: forward_schedule(
            triad, state, forward_settings(values)),
        pause='forward-gain schedule running: loops open, no valid output',
        sensor_time_s=_forward_s, worst_s=FORWARD_WORST_S, parameters='estimation.forward.*'),
    ServiceSpec(
        '~/estimate_feedback_gain', Trigger,
        'feedback schedule; `N_VREF ← N_VREF/(1 + δk_fb)` in place', kind='feedback',
        schedule=lambda triad, state, values: feedback_schedule(
            triad, state, feedback_settings(values)),
        pause='feedback-gain schedule running: I_ref steps of about 0.6 g on the output',
        sensor_time_s=_feedback_s, worst_s=FEEDBACK_WORST_S,
        parameters='estimation.feedback.*'),
    ServiceSpec(
        '~/self_calibrate', Trigger,
        'both estimates, forward first, each correction applied in place',
        kind='self_calibrate',
        details='if the feedback half fails, the forward correction it already applied is '
                'kept and persisted, and the answer says so',
        schedule=lambda triad, state, values: self_calibrate(
            triad, state, forward_settings(values), feedback_settings(values)),
        pause='self-calibration running (open loop, then I_ref steps)',
        sensor_time_s=_estimation_s, worst_s=SCHEDULE_WORST_S, parameters=ESTIMATION),
    ServiceSpec(
        '~/calibrate_temperature', Trigger,
        'accelerated chamber program with the sensor tumbling through six positions on a '
        'dividing head: zero bias and scale factor against temperature per axis (Liu, Li '
        'and Shen), misalignment and K2; ROM stored, compensation on',
        kind='temperature',
        details='`temperature_calibration.*`: plateaus −40…+70 °C every 10 °C, 3600 s of '
                'sensor time by default, the turning points held until the reading is stable; '
                'the dividing head replaces any input. The fit is against the on-board reading '
                "moved to the proof mass's temperature (the reading's lag behind the mass, "
                "estimated from the data: `V + τ dV/dt`), Liu, Li and Shen's double "
                'exponential (alternating iteration, linear baseline) on the fixed-point '
                'CORDIC path; the ROM goes into the calibration state. The I_ref step at '
                'every plateau and its temperature coefficient are stored too '
                '(*Temperature*). Then the chamber returns to the ambient: with a constant '
                'ambient the call ends when the reading is back within 0.05 °C of where it '
                'started (the answer gives the soak time), in the wandering room (default) '
                "after the last plateau, the room's centre",
        schedule=lambda triad, state, values: temperature_calibration(
            triad, state, temperature_settings(values)),
        pause='temperature calibration running: accelerated chamber cycle (and I_ref steps '
              'at its plateaus)',
        always_fast=True,
        sensor_time_s=lambda values: temperature_settings(values).max_sensor_time_s(),
        worst_s=CHAMBER_WORST_S,
        parameters='temperature_calibration.period_s, temperature_calibration.low_c, '
                   'temperature_calibration.high_c, temperature_calibration.cycles, '
                   'temperature_calibration.reference_steps',
        worst_note='its plateaus between low_c and high_c, the soaks at the turning '
                   'points and back'),
    ServiceSpec(
        '~/calibrate_gyros', Trigger,
        "gyro bias at rest (phidgets_spatial's `imu/calibrate`): the mean rate minus the "
        'Earth rate in the body axes, subtracted from `angular_velocity` at once and kept in '
        'the state file',
        kind='gyro_bias',
        details='averages the gyros and accelerometers for `gyro_bias.duration_s`, levels '
                'the body from the accelerometer mean (roll, pitch), takes the heading from '
                '`input.yaw` and the latitude from `latitude_deg` '
                '(`qfa_ros/calibration/gyro_bias.py`; a heading error of 1° leaves 0.19 °/h '
                'at 45°); the correction is kept in the state file as `gyro_bias` [rad/s] '
                '(`set_compensation false` switches it off with the other corrections). '
                'Refused when the input moves (a trajectory, or a 1 s mean departing from '
                'the run mean by more than `gyro_bias.motion_limit_deg_per_hr` / '
                '`gyro_bias.motion_limit_ug`) or without gyros',
        schedule=lambda triad, state, values: gyro_bias_schedule(
            triad, state, gyro_bias_settings(values)),
        pause='gyro bias calibration running: averaging the gyros at rest',
        sensor_time_s=lambda values: gyro_bias_time_s(values['gyro_bias.duration_s']),
        worst_s=gyro_bias_time_s(SPECS['gyro_bias.duration_s'].high),
        parameters='gyro_bias.duration_s'),
    ServiceSpec(
        '~/set_compensation', SetBool,
        'true: write the stored corrections (k(D(z)), N_VREF, temperature ROM, gyro bias) '
        'into the running sensor; false: restore the nominal words, temperature compensation '
        'and gyro correction off',
        kind='set_compensation', handler='set_compensation',
        stream='no pause: the next sample has the corrections (one calibration event)'),
    ServiceSpec(
        '~/cancel', Trigger,
        'abort the running schedule: loops, words and calibration state restored as before '
        'the call, nothing saved; `success: false`, `no schedule running` when there is none',
        handler='cancel', stream='ends the pause: the stream resumes at the present'),
)
"""Every service of the node, in the order the docs list them."""

TIMING = ('A schedule takes its sensor time at the node clock, or as fast as the CPU allows '
          'with `estimation.realtime: false`; the `imu/data_raw` samples due meanwhile are '
          'never published.')
"""How a schedule's sensor time passes, as the docs say it under the services table."""

SERVICE = {spec.name: spec for spec in SERVICES}
"""The rows of :data:`SERVICES` by service name."""

SCHEDULE_SERVICES = tuple(spec for spec in SERVICES if spec.schedule is not None)
"""The rows that run a schedule."""


def budget_problem(values, services=SCHEDULE_SERVICES):
    """
    Return why one schedule call would take too long or too many loop steps, or None.

    Each schedule in turn: its sensor time with ``values`` must stay within its
    ``worst_s``, and that time times ``loop_rate_hz`` within
    :data:`~qfa_ros.ros.bounds.MAX_SCHEDULE_LOOP_STEPS`.

    Parameters
    ----------
    values : dict
        Every parameter's value by name.
    services : sequence of ServiceSpec
        The rows to check: every schedule of :data:`SERVICES`.

    Returns
    -------
    str or None
        The refusal, naming the parameters that set the sensor time, or None.
    """
    loop_rate_hz = values['loop_rate_hz']
    for spec in services:
        sensor_s = spec.sensor_time_s(values)
        if sensor_s > spec.worst_s:
            note = f' ({spec.worst_note})' if spec.worst_note else ''
            return (f'{spec.parameters}: one {spec.call} would take {sensor_s:.0f} s of '
                    f'sensor time{note}; at most {spec.worst_s:.0f} s are allowed')
        steps = sensor_s * loop_rate_hz
        if steps > MAX_SCHEDULE_LOOP_STEPS:
            return (f'{spec.parameters}: one {spec.call} would take {sensor_s:.0f} s of '
                    f'sensor time, {steps:.3g} loop steps at loop_rate_hz {loop_rate_hz:g}; '
                    f'at most {MAX_SCHEDULE_LOOP_STEPS:.3g} are allowed')
    return None


def stream_effect(spec, values):
    """
    Return what a call of ``spec`` does to the stream, in one line.

    Parameters
    ----------
    spec : ServiceSpec
        The service.
    values : dict
        Parameter values (the defaults, for the docs): the sensor time they give.

    Returns
    -------
    str
        The pause and how long it lasts, or the handler's ``stream`` line. A schedule
        takes its sensor time at the node clock unless it always runs fast or
        ``estimation.realtime`` is false (:data:`TIMING`).
    """
    if spec.schedule is None:
        return spec.stream
    default_s, worst_s = spec.sensor_time_s(values), spec.worst_s
    if spec.always_fast:
        return (f'always as fast as the CPU allows: up to {default_s:.0f} s of sensor time at '
                f'the defaults (at most {worst_s:.0f} s), neither `imu/data_raw` nor '
                '`imu/temperature` meanwhile; then the stream resumes at the present')
    return (f'pauses `imu/data_raw` for {default_s:.0f} s of sensor time at the defaults (at '
            f'most {worst_s:.0f} s); `imu/temperature` goes on')
