"""Forward- and feedback-gain self-estimation and in-place compensation (seed 1 §III-IV)."""

from dataclasses import asdict, dataclass
import math

import numpy as np

from qfa_ros.calibration.schedule import (
    EstimationError,
    require_closed,
    samples_for,
    sensor_time_ns,
)
from qfa_ros.model.noise import flicker_component_variance, gauss_markov_allan_variance, MICRO_G
from qfa_ros.model.triad import AXES, FLAG_ADC_CLIPPED

PPM = 1e-6
FORWARD_ORDERS = ('ascending', 'bidirectional', 'interleaved')
FEEDBACK_ORDERS = ('single', 'chopped')


@dataclass(frozen=True)
class ForwardSettings:
    """
    Forward-gain schedule (seed 1 §III-A, eq. 17-22).

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
        _check_int('points', self.points, 2, 1000)
        _check_int('step', self.step, 1, 2 ** 14)
        _check_time('settle_s', self.settle_s, allow_zero=True)
        _check_time('average_s', self.average_s)
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
    Feedback-gain schedule (seed 1 §III-B, eq. 24-30).

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
    reference_tc_ppm : float
        Temperature coefficient of I_ref [ppm/degC] known from the temperature
        calibration. Non-zero enables the co-regression on the temperature channel:
        the reference step is moved to the present temperature,
        ``step0 (1 + tc (T - T0))``, before the comparison. 0 = the paper's schedule.
    """

    cycles: int = 1
    settle_s: float = 0.05
    average_s: float = 10.0
    order: str = 'single'
    motion_limit: float = 200.0 * MICRO_G
    reference_tc_ppm: float = 0.0

    def __post_init__(self):
        _check_int('cycles', self.cycles, 1, 10000)
        _check_time('settle_s', self.settle_s, allow_zero=True)
        _check_time('average_s', self.average_s)
        if self.order not in FEEDBACK_ORDERS:
            raise ValueError(f'order must be one of {FEEDBACK_ORDERS}, got {self.order!r}')
        if not math.isfinite(self.motion_limit) or self.motion_limit <= 0:
            raise ValueError(f'motion_limit must be positive, got {self.motion_limit!r}')
        if not math.isfinite(self.reference_tc_ppm):
            raise ValueError(f'reference_tc_ppm must be finite, got {self.reference_tc_ppm!r}')

    def sequence(self):
        """Return the switch states (True = I_ref on) of the segments in time order."""
        if self.order == 'chopped':
            return [False, True, True, False] * self.cycles
        return [False, True] * self.cycles


@dataclass
class EstimationResult:
    """
    Everything one schedule measured, estimated and applied.

    Attributes
    ----------
    kind : str
        ``forward``, ``feedback`` or ``reference``.
    settings : dict
        The schedule settings.
    estimate_ppm, std_error_ppm : float64[3]
        Estimated relative drift of the channel per axis and its standard error [ppm].
    points : dict of numpy arrays
        Raw points, each with its end time ``time_ns`` [ns]: forward ``index, delta_n,
        mean_x, std_x, ...``; feedback ``segment, reference_on, mean_x, std_x, ...``
        [count].
    residuals : float64[n, 3]
        Fit residuals (forward: regression; feedback: segment means minus the
        on/off model) [count].
    measured : float64[3]
        Forward slope dN_out/dN_FPGA or feedback step N_on - N_off [count].
    reference : float64[3]
        The reference it was compared with (NaN while capturing).
    words_before, words_after : float64[3]
        k(D(z)) (forward) or N_VREF (feedback) before and after compensation.
    applied : bool
        Whether the correction was written.
    captured : bool
        Whether this run captured the reference instead of estimating.
    start_ns, end_ns : int
        Sensor time span of the schedule [ns].
    """

    kind: str
    settings: dict
    estimate_ppm: np.ndarray
    std_error_ppm: np.ndarray
    points: dict
    residuals: np.ndarray
    measured: np.ndarray
    reference: np.ndarray
    words_before: np.ndarray
    words_after: np.ndarray
    applied: bool
    captured: bool
    start_ns: int
    end_ns: int

    @property
    def duration_s(self):
        """Sensor time the schedule took [s]."""
        return (self.end_ns - self.start_ns) * 1e-9

    def to_mapping(self):
        """Return the scalar and per-axis fields as a mapping (trace result)."""
        per_axis = {}
        for name in ('estimate_ppm', 'std_error_ppm', 'measured', 'reference', 'words_before',
                     'words_after'):
            values = np.asarray(getattr(self, name), dtype=float)
            per_axis[name] = {axis: float(v) for axis, v in zip(AXES, values)}
        return {**per_axis, 'applied': bool(self.applied), 'captured': bool(self.captured),
                'duration_s': self.duration_s, 'start_ns': int(self.start_ns),
                'end_ns': int(self.end_ns), 'summary': self.summary()}

    def summary(self):
        """Return a one-line human summary."""
        if self.captured:
            what = 'k_pre-eq0 (dN_out/dN_FPGA)' if self.kind == 'forward' \
                else 'N_on - N_off [count]'
            values = ', '.join(f'{a} {m:.6g}' for a, m in zip(AXES, self.measured))
            return f'{self.kind} reference captured: {what} {values}; {self.duration_s:.2f} s'
        axes = ', '.join(f'{a} {e:+.2f}±{s:.2f}' for a, e, s in
                         zip(AXES, self.estimate_ppm, self.std_error_ppm))
        word = 'k(D(z))' if self.kind == 'forward' else 'N_VREF'
        if self.applied:
            change = ', '.join(f'{b:.6g}->{a:.6g}' for b, a in
                               zip(self.words_before, self.words_after))
            action = f'applied {word} {change}'
        else:
            action = 'no correction applied'
        return f'{self.kind} gain drift [ppm] {axes}; {action}; {self.duration_s:.2f} s'


def _check_int(name, value, low, high):
    if isinstance(value, bool) or int(value) != value or not low <= value <= high:
        raise ValueError(f'{name} must be an integer in [{low}, {high}], got {value!r}')


def _check_time(name, value, allow_zero=False):
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0 \
            or (value == 0 and not allow_zero):
        raise ValueError(f'{name} must be a {"non-negative" if allow_zero else "positive"} '
                         f'number of seconds, got {value!r}')


def _segment(triad, settle_s, average_s):
    """Yield the discard and averaging requests of one segment; return the averaged output."""
    if settle_s > 0:
        yield samples_for(triad, settle_s)
    return (yield samples_for(triad, average_s))


def forward_schedule(triad, state, settings=ForwardSettings(), apply=True, capture=False):
    """
    Run the forward-gain schedule as a generator (see :func:`run_schedule`).

    Opens every loop (the pendulum latches on its stop), writes
    ``N_FPGA + i dN0`` in ``settings.sequence()`` order, averages ``N_out`` per point,
    fits the least-squares slope of eq. 19, compares it with the reference slope
    ``k_pre-eq0`` (``1 + dk_pre = slope / slope0``) and divides k(D(z)) by
    ``1 + dk_pre`` (eq. 22); then re-closes the loops. With ``capture`` the slope
    becomes the reference instead.
    """
    if not capture and any(r.forward_slope is None for r in state.references):
        raise EstimationError('no forward reference captured: call capture_reference first')
    require_closed(triad)
    start_ns = sensor_time_ns(triad)
    base = [loop.n_fpga for loop in triad.axes]
    indices = settings.sequence()
    means, stds, times = [], [], []
    try:
        for axis in range(len(AXES)):
            triad.set_open_loop(axis, True)
        for i in indices:
            for axis in range(len(AXES)):
                triad.set_n_fpga(axis, base[axis] + i * settings.step)
            out = yield from _segment(triad, settings.settle_s, settings.average_s)
            if np.any(out.flags & FLAG_ADC_CLIPPED):
                raise EstimationError('ADC clipped during the forward sweep: reduce step')
            means.append(out.counts.mean(axis=0))
            stds.append(out.counts.std(axis=0))
            times.append(int(out.stamps_ns[-1]))
    finally:
        for axis in range(len(AXES)):
            triad.set_n_fpga(axis, base[axis])
            triad.set_open_loop(axis, False)
    # Wait for the loops to settle so that the schedule ends with valid output.
    yield from _segment(triad, 0.0, triad.config.settle_time)
    delta_n = np.asarray(indices, dtype=float) * settings.step
    means = np.asarray(means)
    design = np.column_stack([delta_n, np.ones_like(delta_n)])
    coef, *_ = np.linalg.lstsq(design, means, rcond=None)
    slope = coef[0]
    residuals = means - design @ coef
    dof = max(1, len(delta_n) - 2)
    slope_se = np.sqrt((residuals ** 2).sum(axis=0) / dof
                       / ((delta_n - delta_n.mean()) ** 2).sum())
    gains_before = np.array([loop.controller.gain for loop in triad.axes])
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
    elif apply:
        for axis in range(len(AXES)):
            triad.set_controller_gain(axis, gains_before[axis] / ratio[axis])
        applied = True
    gains_after = np.array([loop.controller.gain for loop in triad.axes])
    state.record_words(triad)
    state.updated_at_ns = sensor_time_ns(triad)
    if not capture:
        state.last_estimates['forward'] = estimate.tolist()
    return EstimationResult('forward', asdict(settings), estimate, std_error, points, residuals,
                            slope, reference, gains_before, gains_after, applied, capture,
                            start_ns, sensor_time_ns(triad))


def feedback_schedule(triad, state, settings=FeedbackSettings(), apply=True, capture=False):
    """
    Run the feedback-gain schedule as a generator (see :func:`run_schedule`).

    With the loops closed, switches the constant current source ``I_ref`` into the
    torquer (switch M1) in ``settings.sequence()`` order and averages ``N_out`` per
    segment. ``N_on - N_off = -I_ref / (k_VI k_DA (1 + dk_fb))`` (eq. 26-28), so
    ``1 + dk_fb = step0 / step``; the compensation writes
    ``N_VREF <- N_VREF / (1 + dk_fb)`` (eq. 29-30). With ``capture`` the step
    becomes the reference instead. The input must be static and in range.
    """
    if not capture and any(r.feedback_step is None for r in state.references):
        raise EstimationError('no feedback reference captured: call capture_reference first')
    require_closed(triad)
    start_ns = sensor_time_ns(triad)
    sequence = settings.sequence()
    means, stds, times = [], [], []
    block = max(1, int(round(0.01 * triad.config.sample_rate_hz)))
    noise_std = _block_noise_std(triad, block)
    try:
        for on in sequence:
            for axis in range(len(AXES)):
                triad.set_reference_current(axis, on)
            out = yield from _segment(triad, settings.settle_s, settings.average_s)
            if np.any(out.saturated):
                # Any flag: DA2 or ADC clipped, or beyond the rated range.
                raise EstimationError('output saturated: the input must be in range')
            usable = len(out.accel) // block * block
            if usable >= 2 * block:
                block_means = out.accel[:usable].reshape(-1, block, 3).mean(axis=1)
                excess = block_means.std(axis=0) - noise_std
                if np.any(excess > settings.motion_limit):
                    worst = float(np.max(excess) / MICRO_G)
                    raise EstimationError(
                        f'input is moving: 10 ms means scatter {worst:.0f} ug beyond the '
                        f'noise (limit {settings.motion_limit / MICRO_G:.0f} ug); '
                        'hold the sensor still')
            means.append(out.counts.mean(axis=0))
            stds.append(out.counts.std(axis=0))
            times.append(int(out.stamps_ns[-1]))
    finally:
        for axis in range(len(AXES)):
            triad.set_reference_current(axis, False)
    # Let the loops settle from the last switching so that the schedule ends valid.
    yield from _segment(triad, 0.0, settings.settle_s + triad.config.settle_time)
    means = np.asarray(means)
    on = np.asarray(sequence)
    if len(on) >= 4:
        _check_between_segments(triad, settings, on, np.asarray(times), means)
    # Least squares of the segment means on [switch state, 1]: the step is the on/off
    # difference, and for the ABBA order the linear drift cancels by symmetry.
    design = np.column_stack([on.astype(float), np.ones(len(on))])
    coef, *_ = np.linalg.lstsq(design, means, rcond=None)
    step = coef[0]
    residuals = means - design @ coef
    if len(on) > 2:
        dof = len(on) - 2
        step_se = np.sqrt((residuals ** 2).sum(axis=0) / dof
                          / ((on - on.mean()) ** 2).sum())
    else:
        # The sample scatter measures the white noise of each segment mean; the bias
        # instability, correlated over a segment, adds the Allan variance of the
        # configured Gauss-Markov sum at tau = average_s, twice for the difference.
        per_segment = np.asarray(stds) / math.sqrt(samples_for(triad, settings.average_s))
        flicker = 2.0 * _flicker_allan_variance(triad, settings.average_s) / triad.scale ** 2
        step_se = np.sqrt((per_segment ** 2).sum(axis=0) + flicker)
    words_before = np.array([loop.n_vref for loop in triad.axes], dtype=float)
    points = {'time_ns': np.asarray(times, dtype=np.int64),
              'segment': np.arange(len(on), dtype=float), 'reference_on': on.astype(float)}
    for axis, name in enumerate(AXES):
        points[f'mean_{name}'] = means[:, axis]
        points[f'std_{name}'] = np.asarray(stds)[:, axis]
    if capture:
        reference = np.full(len(AXES), np.nan)
        ratio = np.ones(len(AXES))
        std_error = np.abs(step_se / step) / PPM
    else:
        reference = np.array([r.feedback_step for r in state.references])
        if settings.reference_tc_ppm:
            # Co-regression on the temperature channel: I_ref has moved with temperature.
            shift = np.array([triad.temperature - (r.temperature if r.temperature is not None
                                                   else triad.temperature)
                              for r in state.references])
            reference = reference * (1.0 + settings.reference_tc_ppm * PPM * shift)
        ratio = reference / step
        std_error = np.abs(step_se / step) / PPM
    estimate = (ratio - 1.0) / PPM
    applied = False
    if capture:
        for axis, ref in enumerate(state.references):
            ref.feedback_step = float(step[axis])
            ref.temperature = float(triad.temperature)
    elif apply:
        for axis in range(len(AXES)):
            triad.set_n_vref(axis, int(round(words_before[axis] / ratio[axis])))
        applied = True
    words_after = np.array([loop.n_vref for loop in triad.axes], dtype=float)
    state.record_words(triad)
    state.updated_at_ns = sensor_time_ns(triad)
    if not capture:
        state.last_estimates['feedback'] = estimate.tolist()
    return EstimationResult('feedback', asdict(settings), estimate, std_error, points,
                            residuals, step, reference, words_before, words_after, applied,
                            capture, start_ns, sensor_time_ns(triad))


def capture_reference(triad, state, forward=ForwardSettings(), feedback=FeedbackSettings()):
    """Measure both references (seed 1 §IV-A step 1); return the two results."""
    forward_result = yield from forward_schedule(triad, state, forward, capture=True)
    feedback_result = yield from feedback_schedule(triad, state, feedback, capture=True)
    state.captured_at_ns = sensor_time_ns(triad)
    return forward_result, feedback_result


def self_calibrate(triad, state, forward=ForwardSettings(), feedback=FeedbackSettings()):
    """Run the forward schedule, then the feedback schedule; return the two results."""
    forward_result = yield from forward_schedule(triad, state, forward)
    feedback_result = yield from feedback_schedule(triad, state, feedback)
    return forward_result, feedback_result


def _flicker_allan_variance(triad, tau):
    """Return the Allan variance of the configured bias instability at ``tau`` [(m/s^2)^2]."""
    noise = triad.config.noise
    variance = flicker_component_variance(noise)
    if variance == 0:
        return 0.0
    return float(sum(gauss_markov_allan_variance(tau, variance, t)
                     for t in noise.correlation_times))


def _check_between_segments(triad, settings, on, times_ns, means):
    """
    Refuse a switching sequence whose segment means betray a move between segments.

    Within a segment the 10 ms-mean scatter catches motion; a move during a settle
    window (the sensor tilted between two segments) leaves each segment static but
    shifts the level. With four or more segments the means must follow
    ``step * on + offset + slope * t`` (a linear drift allowed); a residual beyond
    ``motion_limit`` plus six standard deviations of a segment mean is refused.
    """
    t = (times_ns - times_ns[0]) * 1e-9
    design = np.column_stack([on.astype(float), np.ones(len(on)), t])
    coef, *_ = np.linalg.lstsq(design, means, rcond=None)
    worst = np.max(np.abs(means - design @ coef), axis=0) * triad.scale
    noise = triad.config.noise
    segment_std = math.sqrt(noise.noise_density ** 2 / settings.average_s
                            + _flicker_allan_variance(triad, settings.average_s))
    limit = settings.motion_limit + 6.0 * segment_std
    if np.any(worst > limit):
        raise EstimationError(
            f'input is moving between segments: a segment mean departs '
            f'{float(np.max(worst)) / MICRO_G:.0f} ug from the on/off model (limit '
            f'{limit / MICRO_G:.0f} ug); hold the sensor still')


def _block_noise_std(triad, block):
    """Return the expected std of ``block``-sample means from the white noise [m/s^2]."""
    density = triad.config.noise.noise_density
    return density * math.sqrt(triad.config.sample_rate_hz / block)
