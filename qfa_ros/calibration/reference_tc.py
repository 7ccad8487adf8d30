"""
The I_ref step's temperature coefficient (what the feedback schedule's correction needs).

Two ways to measure it, both returning an :class:`EstimationResult` of kind
``reference_tc``: :func:`plateau_step` at every chamber plateau of the temperature
calibration and :func:`fit_plateau_steps` over them, or, offline,
:func:`reference_tc_schedule` (I_ref steps against gravity at several chamber plateaus).
Both switch I_ref with the primitives of :mod:`qfa_ros.calibration.estimation`.
"""

from dataclasses import asdict, dataclass

import numpy as np

from qfa_ros.calibration.estimation import (
    check_seconds,
    feedback_sensor_time_s,
    FeedbackSettings,
    fit_line,
    measure_segment,
    switched_segments,
)
from qfa_ros.calibration.schedule import (
    EstimationError,
    EstimationResult,
    Phase,
    require_closed,
    SensorPort,
    stage,
)
from qfa_ros.model.constants import PPM
from qfa_ros.model.triad import AXES


@dataclass(frozen=True)
class ReferenceTcSettings:
    """
    I_ref temperature-coefficient schedule (chamber plateaus, two-position fixture).

    Attributes
    ----------
    plateaus_c : tuple of float
        Chamber plateaus [degC], at least two.
    soak_s : float
        Soak at each plateau before measuring [s] (several body time constants).
    position_s : float
        Averaged time per fixture position [s].
    switching : FeedbackSettings
        I_ref switching at each position.
    """

    plateaus_c: tuple = (15.0, 25.0, 35.0)
    soak_s: float = 2400.0
    position_s: float = 2.0
    switching: FeedbackSettings = FeedbackSettings(cycles=4, settle_s=0.02, average_s=0.28,
                                                   order='chopped')

    def __post_init__(self):
        temps = np.asarray(self.plateaus_c, dtype=float)
        if temps.ndim != 1 or len(temps) < 2 or not np.all(np.isfinite(temps)) \
                or np.ptp(temps) < 1.0:
            raise ValueError('plateaus_c must be at least two finite temperatures spanning '
                             f'1 degC or more, got {self.plateaus_c!r}')
        check_seconds('soak_s', self.soak_s, allow_zero=True)
        check_seconds('position_s', self.position_s)
        if not isinstance(self.switching, FeedbackSettings):
            raise ValueError('switching must be FeedbackSettings')


POSITION_SETTLE_S = 0.1
"""Discarded start of each fixture position of :func:`reference_tc_schedule` [s]."""


def fit_reference_tc(readings_c, ratios):
    """
    Fit the relative temperature coefficient of the I_ref step against gravity.

    Parameters
    ----------
    readings_c : float64[m]
        On-board temperature reading per plateau [degC].
    ratios : float64[m, 3]
        I_ref step divided by the output change of a known input per plateau and axis
        (the step in units of true specific force).

    Returns
    -------
    tc_ppm, std_error_ppm : float64[3]
        ``d ln(ratio) / dT`` [ppm/degC] and its standard error (NaN with two plateaus).

    Raises
    ------
    EstimationError
        A reading is not finite (no on-board sensor) or they span less than 1 degC.
    """
    t = np.asarray(readings_c, dtype=float)
    if not np.all(np.isfinite(t)):
        raise EstimationError('the sensor has no on-board temperature reading')
    if np.ptp(t) < 1.0:
        raise EstimationError('the plateaus differ by less than 1 degC on the on-board sensor')
    y = np.log(np.abs(np.asarray(ratios, dtype=float)))
    design = np.column_stack([t - t.mean(), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    dof = len(t) - 2
    if dof > 0:
        residuals = y - design @ coef
        se = np.sqrt((residuals ** 2).sum(axis=0) / dof / ((t - t.mean()) ** 2).sum())
    else:
        se = np.full(y.shape[1], np.nan)
    return coef[0] / PPM, se / PPM


def reference_tc_schedule(sensor, bench, state, settings=ReferenceTcSettings(), apply=True):
    r"""
    Estimate the temperature coefficient of the I_ref step against gravity (generator).

    At each chamber plateau (``bench.set_chamber_c``, ``bench.soak``) and in the two
    fixture positions ``+u`` and ``-u`` (``bench.set_position(+1 / -1)``, known
    specific force ``bench.known_input(sign)``, every axis carrying a share of g):
    the static output ``N_+`` and ``N_-`` and the I_ref step ``S`` (chopped).
    ``ratio = S (f_+ - f_-) / (N_+ - N_-)`` is the step expressed in true specific
    force, ``-k_t I_ref (1 + e(T)) / K0``-like: it moves with the I_ref, torquer and
    lumped scale-factor temperature coefficients but not with ``k_VI k_DA`` (which
    cancels) nor the zero bias (the two positions cancel it). Its relative slope
    against the on-board temperature reading, ``c = a_Iref + a_kt - e``, is the
    coefficient the feedback schedule needs: with ``step0 (1 + c dT)`` as reference
    it restores the output scale at the reference temperature to first order.
    With ``apply`` the coefficient goes into ``state.reference_tc_ppm``. The bench is
    the calibration set-up (chamber and fixture), not the sensor; the estimator reads
    the sensor through a :class:`SensorPort` only. Returns an :class:`EstimationResult`
    of kind ``reference_tc`` (``estimate_ppm`` in ppm/degC).
    """
    port = SensorPort.of(sensor)
    require_closed(port)
    start_ns = port.sensor_time_ns()
    readings, ratios, times = [], [], []
    # Sensor time of one fixture position: its settling and level, then the I_ref steps
    # (the soaks are environment time: bench.soak runs no samples).
    steps_s = plateau_step_time_s(port.settle_time_s, settings.switching)
    position_s = POSITION_SETTLE_S + settings.position_s + steps_s
    left_s = 2 * position_s * len(settings.plateaus_c)
    try:
        for number, plateau in enumerate(settings.plateaus_c):
            bench.set_chamber_c(plateau)
            bench.soak(settings.soak_s)
            name = f'plateau {number + 1} of {len(settings.plateaus_c)} at {plateau:g} degC'
            levels, steps, temps = {}, [], []
            for sign in (1, -1):
                yield Phase(name, f'fixture {"+" if sign > 0 else "-"}', left_s)
                left_s -= position_s
                bench.set_position(sign)
                out = yield from measure_segment(port, POSITION_SETTLE_S, settings.position_s)
                if np.any(out.saturated):
                    raise EstimationError('output saturated in the fixture position')
                levels[sign] = out.counts.mean(axis=0)
                temps.append(float(np.mean(port.temperature_c(out.v_temp))))
                means, _, seg_times, seg_temps, _ = yield from stage(switched_segments(
                    port, settings.switching.sequence(), settings.switching, check_motion=False),
                    name, left_s)
                on = np.asarray(settings.switching.sequence(), dtype=float)
                steps.append(fit_line(on, means)[0])
                temps.extend(seg_temps.tolist())
                times.append(int(seg_times[-1]))
            known = np.asarray(bench.known_input(1), float) - np.asarray(bench.known_input(-1),
                                                                          float)
            if np.any(np.abs(known) < 1.0):
                raise EstimationError('every axis needs a known input of at least 1 m/s^2 '
                                      'between the two fixture positions')
            ratios.append(np.mean(steps, axis=0) * known / (levels[1] - levels[-1]))
            readings.append(float(np.mean(temps)))
    finally:
        bench.restore()
    readings, ratios = np.asarray(readings), np.asarray(ratios)
    tc, se = fit_reference_tc(readings, ratios)
    if apply:
        state.reference_tc_ppm = [float(v) for v in tc]
        state.updated_at_ns = port.sensor_time_ns()
    points = {'time_ns': np.asarray(times[1::2], dtype=np.int64), 'temperature_c': readings}
    for axis, name in enumerate(AXES):
        points[f'ratio_{name}'] = ratios[:, axis]
    empty = np.full(len(AXES), np.nan)
    return EstimationResult('reference_tc', asdict(settings), tc, se, points,
                            ratios / ratios.mean(axis=0) - 1.0, tc, empty, empty, empty,
                            apply, False, start_ns, port.sensor_time_ns())


PLATEAU_SWITCHING = FeedbackSettings(cycles=2, settle_s=0.25, average_s=0.25, order='chopped')
"""I_ref switching of :func:`plateau_step`: two off-on-on-off quadruples, 4 s of segments (each
0.25 s discarded after a switch, as after a tumble rotation: the loop's transient)."""


def plateau_step_time_s(settle_time_s, settings=PLATEAU_SWITCHING):
    """Return the sensor time of one :func:`plateau_step` [s] (segments, settling)."""
    return feedback_sensor_time_s(settings, settle_time_s)


def plateau_step(sensor, index=None, chamber_c=None, settings=PLATEAU_SWITCHING):
    """
    Measure the I_ref step and the on-board temperature reading at a plateau (generator).

    The ``at_plateau`` hook of
    :func:`qfa_ros.calibration.temperature.temperature_schedule` (``index`` and
    ``chamber_c`` are the hook's arguments, unused: the chamber setting is not what the
    sensor is at). With the loops closed and the input static, switches I_ref in the
    chopped order of ``settings`` and fits ``N_on - N_off`` per axis from the segment
    means [count] (a linear drift of the output, e.g. the body still warming, cancels
    in each off-on-on-off quadruple). Returns ``{'time_ns', 'reading_c', 'step',
    'std_error'}``: the end of the last segment [ns], the mean on-board reading over the
    segments [degC], the step and its standard error per axis [count].
    """
    port = SensorPort.of(sensor)
    require_closed(port)
    sequence = settings.sequence()
    means, _, times, readings, _ = yield from switched_segments(port, sequence, settings,
                                                        check_motion=False)
    step, _, se = fit_line(np.asarray(sequence, dtype=float), means)
    return {'time_ns': int(times[-1]), 'reading_c': float(np.mean(readings)),
            'step': step, 'std_error': se}


def fit_plateau_steps(steps, state, apply=True, start_ns=0, end_ns=0):
    """
    Fit the I_ref step's temperature coefficient from :func:`plateau_step` results.

    ``d ln|N_on - N_off| / dT`` against the on-board reading, per axis, by
    :func:`fit_reference_tc` [ppm/degC]. The step in counts is ``-I_ref / (k_VI k_DA)``:
    it moves with the I_ref source and the V/I and DA2 chain, not with k_t nor the
    scale-factor curve. That is the coefficient the feedback schedule's temperature
    correction needs once the temperature compensation (the ROM of the same
    calibration) keeps the output scale flat over temperature: with it, a feedback
    estimate away from the reference temperature sees only the chain's own drift.
    With ``apply`` it goes into ``state.reference_tc_ppm``. Returns an
    :class:`EstimationResult` of kind ``reference_tc`` (``estimate_ppm`` in ppm/degC,
    ``points``: per plateau the reading and the step per axis; ``residuals``: relative
    departure of each step from the fitted line).

    Raises
    ------
    EstimationError
        Fewer than three plateaus, or their readings span less than 1 degC.
    """
    if len(steps) < 3:
        raise EstimationError(f'I_ref steps at {len(steps)} plateaus: at least three are '
                              'needed for a coefficient with a standard error')
    readings = np.array([s['reading_c'] for s in steps], dtype=float)
    values = np.array([s['step'] for s in steps], dtype=float)
    tc, se = fit_reference_tc(readings, values)
    slope = tc * PPM
    line = np.log(np.abs(values)).mean(axis=0) + np.outer(readings - readings.mean(), slope)
    residuals = np.log(np.abs(values)) - line
    if apply:
        state.reference_tc_ppm = [float(v) for v in tc]
        state.updated_at_ns = int(end_ns)
    points = {'time_ns': np.array([s['time_ns'] for s in steps], dtype=np.int64),
              'temperature_c': readings}
    for axis, name in enumerate(AXES):
        points[f'step_{name}'] = values[:, axis]
        points[f'step_std_error_{name}'] = np.array([s['std_error'][axis] for s in steps])
    empty = np.full(len(AXES), np.nan)
    settings = {'source': 'temperature calibration plateaus',
                **{f'switching.{k}': v for k, v in asdict(PLATEAU_SWITCHING).items()}}
    return EstimationResult('reference_tc', settings, tc, se, points, residuals, tc, empty,
                            empty, empty, apply, False, int(start_ns), int(end_ns))
