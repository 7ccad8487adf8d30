"""
Forward- and feedback-gain self-estimation and in-place compensation (Ran et al. 2019, §III-IV).

Every schedule here sees the sensor through a :class:`SensorPort` only (its words,
output, flags and on-board temperature reading); every coefficient it uses was measured
by a schedule and lives in the :class:`CalibrationState`. The I_ref temperature
coefficient the feedback schedule's temperature correction needs comes from
:mod:`qfa_ros.calibration.reference_tc`, which switches I_ref with the primitives here
(:func:`measure_segment`, :func:`switched_segments`).
"""

from dataclasses import asdict, dataclass
import math

import numpy as np

from qfa_ros.calibration.schedule import (
    EstimationError,
    EstimationResult,
    Phase,
    require_closed,
    SensorPort,
    stage,
)
from qfa_ros.model.checks import is_finite
from qfa_ros.model.constants import MICRO_G, PPM
from qfa_ros.model.triad import AXES, FLAG_ADC_CLIPPED

FORWARD_ORDERS = ('ascending', 'bidirectional', 'interleaved')
FEEDBACK_ORDERS = ('single', 'chopped')


@dataclass(frozen=True)
class ForwardSettings:
    """
    Forward-gain schedule (Ran et al. 2019, §III-A, eq. 17-22).

    Attributes
    ----------
    points : int
        Number of sweep steps n; the sweep writes ``N_FPGA + i dN0`` for i = 0..n.
    step : int
        dN0, the modulation-word increment [count].
    settle_s, average_s : float
        Discarded and averaged time per point [s].
    order : str
        ``ascending`` (the paper), ``bidirectional`` (up then down: a linear drift of
        the open-loop chain cancels from the slope) or ``interleaved`` (drift-decorrelating
        fixed permutation: even steps up, then odd steps down).
    """

    points: int = 10
    step: int = 1024
    settle_s: float = 0.02
    average_s: float = 0.5
    order: str = 'ascending'

    def __post_init__(self):
        check_int('points', self.points, 2, 1000)
        check_int('step', self.step, 1, 2 ** 14)
        check_seconds('settle_s', self.settle_s, allow_zero=True)
        check_seconds('average_s', self.average_s)
        if self.order not in FORWARD_ORDERS:
            raise ValueError(f'order must be one of {FORWARD_ORDERS}, got {self.order!r}')

    def sequence(self):
        """Return the sweep indices i in the order they are written."""
        up = list(range(self.points + 1))
        if self.order == 'bidirectional':
            return up + up[::-1]
        if self.order == 'interleaved':
            # Fixed bit-reversal-like interleave: neighbours in i are far apart in time.
            return sorted(up, key=lambda i: (i % 2, i if i % 2 == 0 else -i))
        return up


@dataclass(frozen=True)
class FeedbackSettings:
    """
    Feedback-gain schedule (Ran et al. 2019, §III-B, eq. 24-30).

    Attributes
    ----------
    cycles : int
        On/off pairs. ``single`` order: the paper's off, on (cycles = 1) repeated;
        ``chopped``: off-on-on-off quadruples (ABBA), so a linear output drift
        cancels in each quadruple.
    settle_s, average_s : float
        Discarded and averaged time per segment [s].
    order : str
        ``single`` or ``chopped``.
    motion_limit : float
        Largest standard deviation of 10 ms means within a segment beyond the
        expected noise before the input counts as moving [m/s^2]. With four or more
        segments it also bounds how far a segment mean may depart from the on/off
        model with a linear drift (beyond six standard deviations of the noise), which
        catches a move between segments.
    temperature_correction : bool
        Move the reference step to the present on-board temperature reading,
        ``step0 (1 + c (T - T0))``, with the coefficient ``c`` per axis in
        ``state.reference_tc_ppm`` (measured by :mod:`~qfa_ros.calibration.reference_tc`);
        refused without one. False = the paper's schedule.
    bias_instability : float
        Datasheet bias instability (Allan floor) [m/s^2]; adds to the standard error of
        the two-segment (paper) schedule, whose segments the white scatter alone does
        not describe. A specification the user sets, not the model's noise.
    """

    cycles: int = 1
    settle_s: float = 0.05
    average_s: float = 10.0
    order: str = 'single'
    motion_limit: float = 200.0 * MICRO_G
    temperature_correction: bool = False
    bias_instability: float = 3.0 * MICRO_G

    def __post_init__(self):
        check_int('cycles', self.cycles, 1, 10000)
        check_seconds('settle_s', self.settle_s, allow_zero=True)
        check_seconds('average_s', self.average_s)
        if self.order not in FEEDBACK_ORDERS:
            raise ValueError(f'order must be one of {FEEDBACK_ORDERS}, got {self.order!r}')
        if not is_finite(self.bias_instability, bool_ok=False) or self.bias_instability < 0:
            raise ValueError(f'bias_instability must be >= 0, got {self.bias_instability!r}')
        if not is_finite(self.motion_limit, bool_ok=False) or self.motion_limit <= 0:
            raise ValueError(f'motion_limit must be positive, got {self.motion_limit!r}')
        if not isinstance(self.temperature_correction, bool):
            raise ValueError('temperature_correction must be a bool, got '
                             f'{self.temperature_correction!r}')

    def sequence(self):
        """Return the switch states (True = I_ref on) of the segments in time order."""
        if self.order == 'chopped':
            return [False, True, True, False] * self.cycles
        return [False, True] * self.cycles


FORWARD_MATCHED = ()
"""Forward settings an estimate must share with its reference: none.

The open-loop chain has no transient that outlasts a sample; only the loop rate must match
(the forward gain of k(D(z)) is per loop step). Measured:
``bench/results/schedule_settings.md``."""
FEEDBACK_MATCHED = ('settle_s', 'average_s', 'order')
"""Feedback settings an estimate must share with its reference.

A segment mean includes what is left of the closed loop's transient after an I_ref
switch, so the step depends on the settle and averaging times and on the share of
segments that follow a switch (the order; and ``cycles`` in the ``single`` order, whose
first segment follows none). Measured: ``bench/results/schedule_settings.md``.
``motion_limit``, ``bias_instability`` and ``temperature_correction`` change refusals, the
standard error or the correction for the temperature, not what the step measures."""
REFERENCE_SETTING_TOLERANCE_PPM = 1.0
"""How far a setting may move a drift-free estimate before it must match [ppm]."""


def forward_sensor_time_s(settings, settle_time_s):
    """Return the sensor time of one forward schedule [s] (sweep plus the loops' settling)."""
    return len(settings.sequence()) * (settings.settle_s + settings.average_s) + settle_time_s


def feedback_sensor_time_s(settings, settle_time_s):
    """Return the sensor time of one feedback schedule [s] (segments plus the settling)."""
    return (len(settings.sequence()) * (settings.settle_s + settings.average_s)
            + settings.settle_s + settle_time_s)


def reference_settings(kind, settings, sensor):
    """
    Return what a ``kind`` estimate must share with its reference (stored at capture).

    The settings of :data:`FORWARD_MATCHED` or :data:`FEEDBACK_MATCHED` and the loop and
    sample rates (the loop's gain and transient are set in loop steps; the segments are
    whole samples, so at another sample rate the same seconds may cover other times). A
    reference and an estimate that share them see the same transient, which cancels in
    the ratio.
    """
    port = SensorPort.of(sensor)
    names = FORWARD_MATCHED if kind == 'forward' else FEEDBACK_MATCHED
    record = {name: getattr(settings, name) for name in names}
    if kind == 'feedback' and settings.order == 'single':
        record['cycles'] = settings.cycles
    record['sample_rate_hz'] = float(port.sample_rate_hz)
    record['loop_rate_hz'] = float(port.loop_rate_hz)
    return record


def _check_ready(kind, settings, port, state, check_settings=True):
    """Refuse a ``kind`` estimate without a reference or with settings other than its."""
    name = 'forward_slope' if kind == 'forward' else 'feedback_step'
    if any(getattr(r, name) is None for r in state.references):
        raise EstimationError(f'no {kind} reference captured: call capture_reference first')
    if not check_settings:
        return
    stored = state.reference_settings.get(kind)
    if not stored:
        raise EstimationError(
            f'the {kind} reference has no stored schedule settings (captured by an older '
            'version): an estimate with other settings would read a drift that is not there; '
            'capture the reference again')
    now = reference_settings(kind, settings, port)
    differ = [f'{name} {stored.get(name)!r} at the reference, {value!r} now'
              for name, value in now.items() if not _same(stored.get(name), value)]
    differ += [f'{name} {stored[name]!r} at the reference, unused now'
               for name in stored if name not in now]
    if differ:
        raise EstimationError(
            f'{kind} schedule settings differ from the reference\'s ({"; ".join(differ)}): '
            "the loop's transient would read as a drift of tens of ppm; set them back or "
            'capture the reference again')


def _same(a, b):
    if isinstance(a, str) or isinstance(b, str) or a is None or b is None:
        return a == b
    return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=1e-12)


def check_int(name, value, low, high):
    """Raise ValueError naming ``name`` unless ``value`` is a whole number in [low, high]."""
    if not is_finite(value, bool_ok=False) or int(value) != value \
            or not low <= value <= high:
        raise ValueError(f'{name} must be an integer in [{low}, {high}], got {value!r}')


def check_seconds(name, value, allow_zero=False):
    """Raise ValueError naming ``name`` unless ``value`` is a time [s] > 0 (>= 0 if allowed)."""
    if not is_finite(value, bool_ok=False, types=(int, float)) or value < 0 \
            or (value == 0 and not allow_zero):
        raise ValueError(f'{name} must be a {"non-negative" if allow_zero else "positive"} '
                         f'number of seconds, got {value!r}')


def fit_line(x, values):
    """
    Fit ``values`` (n, axes) by least squares on ``[x, 1]``; return slope, residuals, its error.

    The slope's standard error per axis is ``sqrt(sum r^2 / (n - 2) / sum (x - mean x)^2)``
    (``n - 2`` at least 1).
    """
    design = np.column_stack([x, np.ones(len(x))])
    coef, *_ = np.linalg.lstsq(design, values, rcond=None)
    residuals = values - design @ coef
    se = np.sqrt((residuals ** 2).sum(axis=0) / max(1, len(x) - 2) / ((x - x.mean()) ** 2).sum())
    return coef[0], residuals, se


def measure_segment(port, settle_s, average_s):
    """Yield the discard and averaging requests of one segment; return the averaged output."""
    if settle_s > 0:
        yield port.samples_for(settle_s)
    return port.view((yield port.samples_for(average_s)))


def forward_schedule(sensor, state, settings=ForwardSettings(), apply=True, capture=False,
                     check_settings=True):
    """
    Run the forward-gain schedule as a generator (see :func:`run_schedule`).

    Opens every loop (the pendulum latches on its stop), writes
    ``N_FPGA + i dN0`` in ``settings.sequence()`` order, averages ``N_out`` per point,
    fits the least-squares slope of eq. 19, compares it with the reference slope
    ``k_pre-eq0`` (``1 + dk_pre = slope / slope0``) and divides k(D(z)) by
    ``1 + dk_pre`` (eq. 22); then re-closes the loops. With ``capture`` the slope
    becomes the reference instead, stored with its settings
    (:func:`reference_settings`). ``sensor`` is a :class:`SensorPort` or a sensor
    model (wrapped in one). With ``check_settings`` (the default) an estimate whose
    settings or rates differ from the reference's is refused, before anything moves.
    """
    port = SensorPort.of(sensor)
    if not capture:
        _check_ready('forward', settings, port, state, check_settings)
    require_closed(port)
    start_ns = port.sensor_time_ns()
    axes = range(port.n_axes)
    base = [port.n_fpga(axis) for axis in axes]
    indices = settings.sequence()
    left_s = forward_sensor_time_s(settings, port.settle_time_s)
    means, stds, times = [], [], []
    try:
        for axis in axes:
            port.set_open_loop(axis, True)
        for number, i in enumerate(indices):
            yield Phase('loops open', f'point {number + 1} of {len(indices)}', left_s)
            left_s -= settings.settle_s + settings.average_s
            for axis in axes:
                port.set_n_fpga(axis, base[axis] + i * settings.step)
            out = yield from measure_segment(port, settings.settle_s, settings.average_s)
            if np.any(out.flags & FLAG_ADC_CLIPPED):
                raise EstimationError('ADC clipped during the forward sweep: reduce step')
            means.append(out.counts.mean(axis=0))
            stds.append(out.counts.std(axis=0))
            times.append(int(out.stamps_ns[-1]))
    finally:
        for axis in axes:
            port.set_n_fpga(axis, base[axis])
            port.set_open_loop(axis, False)
    # Wait for the loops to settle so that the schedule ends with valid output.
    yield Phase('loops re-closed', 'settling', port.settle_time_s)
    yield from measure_segment(port, 0.0, port.settle_time_s)
    delta_n = np.asarray(indices, dtype=float) * settings.step
    means = np.asarray(means)
    slope, residuals, slope_se = fit_line(delta_n, means)
    gains_before = np.array([port.controller_gain(axis) for axis in axes])
    points = {'time_ns': np.asarray(times, dtype=np.int64),
              'index': np.asarray(indices, dtype=float), 'delta_n': delta_n}
    for axis, name in enumerate(AXES):
        points[f'mean_{name}'] = means[:, axis]
        points[f'std_{name}'] = np.asarray(stds)[:, axis]
    if capture:
        reference = np.full(len(AXES), np.nan)
        ratio = np.ones(len(AXES))
    else:
        reference = np.array([r.forward_slope for r in state.references])
        ratio = slope / reference
    estimate = (ratio - 1.0) / PPM
    std_error = np.abs(slope_se / (reference if not capture else slope)) / PPM
    applied = False
    if capture:
        for axis, ref in enumerate(state.references):
            ref.forward_slope = float(slope[axis])
        state.reference_settings['forward'] = reference_settings('forward', settings, port)
    elif apply:
        for axis in axes:
            port.set_controller_gain(axis, gains_before[axis] / ratio[axis])
        applied = True
    gains_after = np.array([port.controller_gain(axis) for axis in axes])
    state.record_words(port)
    if not capture:
        state.last_estimates['forward'] = estimate.tolist()
    return EstimationResult('forward', asdict(settings), estimate, std_error, points, residuals,
                            slope, reference, gains_before, gains_after, applied, capture,
                            start_ns, port.sensor_time_ns())


def switched_segments(port, sequence, settings, check_motion=True):
    """
    Switch I_ref in ``sequence`` order; return segment means, stds, times, readings.

    Generator (sub-schedule). Also returns the per-segment Allan variance at the
    segment length estimated from the data (see :func:`_segment_allan_variance`) and
    the on-board temperature reading of each segment [degC].
    """
    axes = range(port.n_axes)
    means, stds, times, readings, allan = [], [], [], [], []
    block = max(1, int(round(0.01 * port.sample_rate_hz)))
    segment_s = settings.settle_s + settings.average_s
    left_s = len(sequence) * segment_s + settings.settle_s + port.settle_time_s
    try:
        for number, on in enumerate(sequence):
            yield Phase('I_ref steps', f'segment {number + 1} of {len(sequence)}, I_ref '
                        f'{"on" if on else "off"}', left_s - number * segment_s)
            for axis in axes:
                port.set_reference_current(axis, on)
            out = yield from measure_segment(port, settings.settle_s, settings.average_s)
            if np.any(out.saturated):
                # Any flag: DA2 or ADC clipped, or beyond the rated range.
                raise EstimationError('output saturated: the input must be in range')
            if check_motion:
                _check_motion(out.accel, block, settings.motion_limit)
            means.append(out.counts.mean(axis=0))
            stds.append(out.counts.std(axis=0))
            times.append(int(out.stamps_ns[-1]))
            readings.append(float(np.mean(port.temperature_c(out.v_temp))))
            allan.append(_segment_allan_variance(out.counts, port.sample_rate_hz))
    finally:
        for axis in axes:
            port.set_reference_current(axis, False)
    # Let the loops settle from the last switching so that the schedule ends valid.
    yield Phase('I_ref steps', 'I_ref off, settling', settings.settle_s + port.settle_time_s)
    yield from measure_segment(port, 0.0, settings.settle_s + port.settle_time_s)
    return (np.asarray(means), np.asarray(stds), np.asarray(times), np.asarray(readings),
            np.asarray(allan))


def _check_motion(accel, block, limit):
    """Refuse a segment whose 10 ms means scatter beyond the noise the data itself shows."""
    usable = len(accel) // block * block
    if usable < 2 * block:
        return
    block_means = accel[:usable].reshape(-1, block, 3).mean(axis=1)
    # The white noise of a block mean, from sample-to-sample differences (a slow move
    # barely changes them): std(diff) / sqrt(2) / sqrt(block).
    noise_std = np.std(np.diff(accel[:usable], axis=0), axis=0) / math.sqrt(2.0 * block)
    excess = block_means.std(axis=0) - noise_std
    if np.any(excess > limit):
        worst = float(np.max(excess) / MICRO_G)
        raise EstimationError(
            f'input is moving: 10 ms means scatter {worst:.0f} ug beyond the '
            f'noise (limit {limit / MICRO_G:.0f} ug); hold the sensor still')


def _segment_allan_variance(counts, rate_hz):
    """
    Return the Allan variance of the output at the segment length, from the segment [count^2].

    The segment is cut into halves: ``(m_2 - m_1)^2 / 2`` estimates the Allan variance at
    ``tau = T/2``, ``2 W / T + F`` (white density ``W`` from sample differences, ``F``
    the flicker floor); at ``tau = T`` it is ``W / T + F``, never below the white part.
    """
    n = len(counts) // 2 * 2
    if n < 8:
        return np.var(counts, axis=0) / max(1, len(counts))
    duration = n / rate_hz
    halves = counts[:n].reshape(2, -1, counts.shape[1]).mean(axis=1)
    avar_half = 0.5 * (halves[1] - halves[0]) ** 2
    white = np.var(np.diff(counts[:n], axis=0), axis=0) / 2.0 / rate_hz   # count^2 s
    return np.maximum(avar_half - white / duration, white / duration)


def feedback_schedule(sensor, state, settings=FeedbackSettings(), apply=True, capture=False,
                      check_settings=True):
    """
    Run the feedback-gain schedule as a generator (see :func:`run_schedule`).

    With the loops closed, switches the constant current source ``I_ref`` into the
    torquer (switch M1) in ``settings.sequence()`` order and averages ``N_out`` per
    segment. ``N_on - N_off = -I_ref / (k_VI k_DA (1 + dk_fb))`` (eq. 26-28), so
    ``1 + dk_fb = step0 / step``; the compensation writes
    ``N_VREF <- N_VREF / (1 + dk_fb)`` (eq. 29-30). With ``capture`` the step
    becomes the reference instead, stored with the on-board temperature reading.
    With ``settings.temperature_correction`` the reference step is first moved to the
    present reading with the I_ref temperature coefficient
    (:mod:`~qfa_ros.calibration.reference_tc`). The input must be static and in range.
    With ``check_settings`` (the default) an estimate whose :data:`FEEDBACK_MATCHED`
    settings or rates differ from the reference's is refused before anything moves (the
    captured settings are stored with the reference).
    """
    port = SensorPort.of(sensor)
    if not capture:
        _check_ready('feedback', settings, port, state, check_settings)
    correct = settings.temperature_correction and not capture
    if correct:
        if not state.reference_tc_ppm:
            raise EstimationError('temperature correction needs the I_ref temperature '
                                  'coefficient: run the temperature calibration (its I_ref '
                                  'steps at every plateau) or the reference_tc schedule first')
        if any(r is None for r in state.reference_readings_c()) \
                or not port.has_temperature_sensor:
            raise EstimationError('temperature correction needs the on-board temperature '
                                  'reading at the reference and now')
    require_closed(port)
    start_ns = port.sensor_time_ns()
    sequence = settings.sequence()
    means, stds, times, readings, allan = yield from switched_segments(port, sequence, settings)
    on = np.asarray(sequence)
    if len(on) >= 4:
        _check_between_segments(port, settings, on, times, means, allan)
    # Least squares of the segment means on [switch state, 1]: the step is the on/off
    # difference, and for the ABBA order the linear drift cancels by symmetry.
    step, residuals, step_se = fit_line(on.astype(float), means)
    if len(on) <= 2:
        # The sample scatter measures the white noise of each segment mean; the bias
        # instability, correlated over a segment, adds its Allan floor (the datasheet
        # figure of the settings), twice for the difference.
        per_segment = np.asarray(stds) / math.sqrt(port.samples_for(settings.average_s))
        floor = 2.0 * (settings.bias_instability / port.count_scale) ** 2
        step_se = np.sqrt((per_segment ** 2).sum(axis=0) + floor)
    reading = float(np.mean(readings))
    words_before = np.array([port.n_vref(axis) for axis in range(port.n_axes)], dtype=float)
    points = {'time_ns': np.asarray(times, dtype=np.int64),
              'segment': np.arange(len(on), dtype=float), 'reference_on': on.astype(float),
              'temperature_c': readings}
    for axis, name in enumerate(AXES):
        points[f'mean_{name}'] = means[:, axis]
        points[f'std_{name}'] = np.asarray(stds)[:, axis]
    if capture:
        reference = np.full(len(AXES), np.nan)
        ratio = np.ones(len(AXES))
    else:
        reference = np.array([r.feedback_step for r in state.references])
        if correct:
            shift = reading - np.asarray(state.reference_readings_c(), dtype=float)
            reference = reference * (1.0 + np.asarray(state.reference_tc_ppm) * PPM * shift)
        ratio = reference / step
    std_error = np.abs(step_se / step) / PPM
    estimate = (ratio - 1.0) / PPM
    applied = False
    if capture:
        for axis, ref in enumerate(state.references):
            ref.feedback_step = float(step[axis])
            state.set_reference_reading(axis, reading if math.isfinite(reading) else None)
        state.reference_settings['feedback'] = reference_settings('feedback', settings, port)
    elif apply:
        for axis in range(port.n_axes):
            port.set_n_vref(axis, int(round(words_before[axis] / ratio[axis])))
        applied = True
    words_after = np.array([port.n_vref(axis) for axis in range(port.n_axes)], dtype=float)
    state.record_words(port)
    if not capture:
        state.last_estimates['feedback'] = estimate.tolist()
    return EstimationResult('feedback', asdict(settings), estimate, std_error, points,
                            residuals, step, reference, words_before, words_after, applied,
                            capture, start_ns, port.sensor_time_ns())


def capture_reference(sensor, state, forward=ForwardSettings(), feedback=FeedbackSettings()):
    """Measure both references (Ran et al. 2019, §IV-A step 1); return the two results."""
    port = SensorPort.of(sensor)
    forward_result = yield from stage(
        forward_schedule(port, state, forward, capture=True), 'forward',
        feedback_sensor_time_s(feedback, port.settle_time_s))
    feedback_result = yield from stage(
        feedback_schedule(port, state, feedback, capture=True), 'feedback')
    state.captured_at_ns = port.sensor_time_ns()
    return forward_result, feedback_result


def self_calibrate(sensor, state, forward=ForwardSettings(), feedback=FeedbackSettings()):
    """
    Run the forward schedule, then the feedback schedule; return the two results.

    Both references and both schedules' settings are checked before anything moves.
    """
    port = SensorPort.of(sensor)
    _check_ready('forward', forward, port, state)
    _check_ready('feedback', feedback, port, state)
    forward_result = yield from stage(forward_schedule(port, state, forward), 'forward',
                                      feedback_sensor_time_s(feedback, port.settle_time_s))
    feedback_result = yield from stage(feedback_schedule(port, state, feedback), 'feedback')
    return forward_result, feedback_result


def _check_between_segments(port, settings, on, times_ns, means, allan):
    """
    Refuse a switching sequence whose segment means betray a move between segments.

    Within a segment the 10 ms-mean scatter catches motion; a move during a settle
    window (the sensor tilted between two segments) leaves each segment static but
    shifts the level. With four or more segments the means must follow
    ``step * on + offset + slope * t`` (a linear drift allowed); a residual beyond
    ``motion_limit`` plus six standard deviations of a segment mean (from the Allan
    variance the segments themselves show) is refused.
    """
    t = (times_ns - times_ns[0]) * 1e-9
    design = np.column_stack([on.astype(float), np.ones(len(on)), t])
    coef, *_ = np.linalg.lstsq(design, means, rcond=None)
    worst = np.max(np.abs(means - design @ coef), axis=0) * port.count_scale
    segment_std = math.sqrt(float(np.max(np.median(allan, axis=0)))) * port.count_scale
    limit = settings.motion_limit + 6.0 * segment_std
    if np.any(worst > limit):
        raise EstimationError(
            f'input is moving between segments: a segment mean departs '
            f'{float(np.max(worst)) / MICRO_G:.0f} ug from the on/off model (limit '
            f'{limit / MICRO_G:.0f} ug); hold the sensor still')
