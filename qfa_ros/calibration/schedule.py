"""
What every schedule shares: its error and result, the sensor port, the sensor time, the driver.

A schedule is a generator that drives the loop words of a sensor, yields how many
samples it needs next, and receives them as one block; it returns its result. Between
two requests it may yield a :class:`Phase` instead: what it does from now on, in words,
and at most how much sensor time it still takes; the driver hands it to a
:class:`ScheduleProgress` and sends nothing back. :func:`run_schedule` drives one offline
as fast as the CPU allows; the node drives the same generators paced by the ROS clock.

Estimators see the sensor only through a :class:`SensorPort`: the words the FPGA can
write, the decimated output with its flags, and the on-board temperature sensor read
through its ADC. Nothing of the model's truth (true input, body temperature, drift,
noise configuration) passes through it; ``test_estimation_sees_no_truth`` audits that.
"""

from contextlib import contextmanager
from dataclasses import dataclass
import math
import sys
import time

import numpy as np

from qfa_ros.model import checks
from qfa_ros.model.triad import AXES
from qfa_ros.model.triad_output import concatenate


class EstimationError(ValueError):
    """A schedule cannot run or its data cannot give an estimate; nothing was applied."""


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
        axes = ', '.join(f'{a} {e:+.2f}±{s:.2f}' for a, e, s in
                         zip(AXES, self.estimate_ppm, self.std_error_ppm))
        if self.kind == 'reference_tc':
            action = 'stored' if self.applied else 'not stored'
            return (f'I_ref step temperature coefficient [ppm/degC] {axes}; {action}; '
                    f'{self.duration_s:.2f} s')
        if self.captured:
            what = 'k_pre-eq0 (dN_out/dN_FPGA)' if self.kind == 'forward' \
                else 'N_on - N_off [count]'
            values = ', '.join(f'{a} {m:.6g}' for a, m in zip(AXES, self.measured))
            return f'{self.kind} reference captured: {what} {values}; {self.duration_s:.2f} s'
        word = 'k(D(z))' if self.kind == 'forward' else 'N_VREF'
        if self.applied:
            change = ', '.join(f'{b:.6g}->{a:.6g}' for b, a in
                               zip(self.words_before, self.words_after))
            action = f'applied {word} {change}'
        else:
            action = 'no correction applied'
        return f'{self.kind} gain drift [ppm] {axes}; {action}; {self.duration_s:.2f} s'


@dataclass(frozen=True)
class SensorSamples:
    """
    What the sensor outputs over a block of samples (no truth).

    Attributes
    ----------
    stamps_ns : int64[n]
        Sample instants [ns].
    accel : float64[n, 3]
        Output through the nominal scale factor [m/s^2].
    counts : float64[n, 3]
        Mean output word per sample [count].
    flags : int8[n, 3]
        Saturation bits.
    valid : bool[n, 3]
        False while an axis is open or settling.
    v_temp : float64[n]
        On-board temperature-sensor ADC reading [V] (NaN without one).
    gyro : float64[n, 3] or None
        Published gyro rate [rad/s], after the gyro bias correction (NaN without gyros).
    """

    stamps_ns: np.ndarray
    accel: np.ndarray
    counts: np.ndarray
    flags: np.ndarray
    valid: np.ndarray
    v_temp: np.ndarray
    gyro: np.ndarray = None

    @property
    def saturated(self):
        """Return bool[n, 3]: any saturation bit set."""
        return self.flags != 0


class SensorPort:
    """
    The sensor as its own firmware knows it: output, flags, words, temperature reading.

    Wraps a :class:`qfa_ros.model.triad.QfaTriad` and exposes only what the real
    FPGA reads or writes: per axis k(D(z)), N_FPGA, N_VREF, the I_ref switch and the
    open/closed state; the published output and flags (:meth:`view`); the on-board
    temperature sensor through its ADC and nominal transfer function
    (:meth:`temperature_c`); and design constants (sample rate, nominal scale,
    settle time). The wrapped model is private.

    Parameters
    ----------
    triad : QfaTriad
        The sensor model.
    """

    __slots__ = ('_triad',)

    def __init__(self, triad):
        if isinstance(triad, SensorPort):
            raise ValueError('triad must be a sensor model, not a SensorPort')
        self._triad = triad

    @classmethod
    def of(cls, sensor):
        """Return ``sensor`` if it is a port, else a port over the sensor model."""
        return sensor if isinstance(sensor, SensorPort) else cls(sensor)

    # Design constants ----------------------------------------------------------------
    @property
    def n_axes(self):
        """Number of axes."""
        return len(AXES)

    @property
    def sample_rate_hz(self):
        """Published sample rate [Hz]."""
        return self._triad.config.sample_rate_hz

    @property
    def loop_rate_hz(self):
        """Digital loop rate [Hz] (the loop's transients are set in its steps)."""
        return self._triad.config.loop_rate_hz

    @property
    def settle_time_s(self):
        """Time the output stays flagged invalid after re-closing a loop [s]."""
        return self._triad.config.settle_time

    @property
    def count_scale(self):
        """Nominal scale factor of the output word [(m/s^2)/count]."""
        return self._triad.scale

    def samples_for(self, seconds):
        """Return how many samples (at least one) span ``seconds``."""
        return max(1, int(round(seconds * self.sample_rate_hz)))

    def sensor_time_ns(self):
        """Return the sensor time of the next sample [ns]."""
        return sensor_time_ns(self._triad)

    # Words ---------------------------------------------------------------------------
    def loops_closed(self):
        """Return True when every loop is closed."""
        return not any(loop.open_loop for loop in self._triad.axes)

    def set_open_loop(self, axis, open_loop):
        """Open (True) or re-close (False) the loop of ``axis``."""
        self._triad.set_open_loop(axis, open_loop)

    def n_fpga(self, axis):
        """Return the modulation word N_FPGA of ``axis``."""
        return self._triad.axes[axis].n_fpga

    def set_n_fpga(self, axis, word):
        """Write N_FPGA of ``axis``."""
        self._triad.set_n_fpga(axis, word)

    def n_vref(self, axis):
        """Return the DA0 reference word N_VREF of ``axis``."""
        return self._triad.axes[axis].n_vref

    def set_n_vref(self, axis, word):
        """Write N_VREF of ``axis``."""
        self._triad.set_n_vref(axis, word)

    def controller_gain(self, axis):
        """Return k(D(z)) of ``axis``."""
        return self._triad.axes[axis].controller.gain

    def set_controller_gain(self, axis, gain):
        """Write k(D(z)) of ``axis``."""
        self._triad.set_controller_gain(axis, gain)

    def set_reference_current(self, axis, on):
        """Close (True) or open (False) the I_ref switch M1 of ``axis``."""
        self._triad.set_reference_current(axis, on)

    @property
    def has_gyros(self):
        """Return True when the sensor has a gyro triad."""
        return self._triad.gyro is not None

    def gyro_bias_correction(self):
        """Return the gyro bias the firmware subtracts from the published rate [rad/s]."""
        return self._triad.gyro_bias_correction.copy()

    def set_gyro_bias_correction(self, bias):
        """Write the gyro bias correction [rad/s] (three finite values)."""
        bias = np.array(bias, dtype=float)
        if bias.shape != (3,) or not np.all(np.isfinite(bias)):
            raise ValueError(f'gyro bias correction must be 3 finite values, got {bias!r}')
        self._triad.gyro_bias_correction = bias

    # Output --------------------------------------------------------------------------
    @property
    def has_temperature_sensor(self):
        """Return True when the sensor has an on-board temperature sensor."""
        return self._triad.thermal is not None

    def temperature_c(self, v_temp):
        """Return the temperature [degC] the on-board sensor reports for ``v_temp`` [V].

        The nominal transfer function of the sensor chip (its datasheet), NaN without one.
        """
        if self._triad.thermal is None:
            return np.full(np.shape(v_temp), math.nan)
        return self._triad.thermal.reading_c(v_temp)

    def view(self, output):
        """Return the :class:`SensorSamples` of a model output block (drops the truth)."""
        if isinstance(output, SensorSamples):
            return output
        return SensorSamples(stamps_ns=output.stamps_ns, accel=output.accel,
                             counts=output.counts, flags=output.flags, valid=output.valid,
                             v_temp=output.v_temp, gyro=output.gyro)


def samples_for(triad, seconds):
    """Return how many samples (at least one) span ``seconds`` of sensor time."""
    return max(1, int(round(seconds * triad.config.sample_rate_hz)))


def sensor_time_ns(triad):
    """Return the instant the next sample starts [ns] (the triad's stamp origin + time)."""
    return int(triad.stamp_ns(triad.sample_index - 1))


def require_closed(sensor):
    """Raise :class:`EstimationError` if a loop is open (another schedule runs)."""
    if not SensorPort.of(sensor).loops_closed():
        raise EstimationError('a loop is open: another schedule is running')


@dataclass(frozen=True)
class Phase:
    """
    What a schedule does from now on, announced by yielding it between two requests.

    Attributes
    ----------
    name : str
        The phase in words a user understands (``loops open``, ``I_ref steps``,
        ``plateau 2 of 17 at -30 degC``); a driver logs each change of it.
    detail : str
        Where the schedule is within the phase (``point 5 of 11``, ``segment 3 of 6, I_ref
        on``); it changes without a log line.
    left_s : float
        Sensor time the schedule takes from here to its end, at most [s]: exact where the
        settings fix it, an upper bound where the schedule waits for a condition (the
        temperature calibration's extremes and soak).
    """

    name: str
    detail: str = ''
    left_s: float = 0.0

    def __str__(self):
        return f'{self.name}, {self.detail}' if self.detail else self.name


def stage(schedule, name, after_s=0.0):
    """
    Run ``schedule`` as one stage of a longer schedule (generator, same protocol).

    Its phases are named ``<name>: <phase>`` and their sensor time left lengthened by
    ``after_s``, the longest sensor time of what follows it [s]. Closing the stage closes
    ``schedule`` at once (its ``finally`` blocks re-close loops and switches).
    """
    try:
        request = next(schedule)
        while True:
            if isinstance(request, Phase):
                request = Phase(f'{name}: {request.name}', request.detail,
                                request.left_s + after_s)
            request = schedule.send((yield request))
    except StopIteration as stop:
        return stop.value
    finally:
        schedule.close()


def next_request(schedule, block, progress=None):
    """
    Send ``block`` (None to start) to ``schedule``; return how many samples it needs next.

    The phases it yields meanwhile go to ``progress`` (a :class:`ScheduleProgress`, or
    None). ``StopIteration`` carries the schedule's result, as from ``send``.
    """
    request = schedule.send(block)
    while isinstance(request, Phase):
        if progress is not None:
            progress.announce(request)
        request = schedule.send(None)
    return request


class ScheduleProgress:
    """
    How far a schedule is: its phase, the sensor time done and left, the fraction, the pace.

    A driver hands it every :class:`Phase` the schedule yields (:meth:`announce`) and
    counts every block of samples it runs (:meth:`advance`: once a block, never once a
    sample). The sensor time left is the phase's ``left_s`` less what ran since it was
    announced; the fraction done, ``done / (done + left)``, only goes up (held at its
    highest when a phase ran longer than it said) and reads 1 once :meth:`finish` is
    called with the schedule's result.

    Parameters
    ----------
    kind : str
        The schedule's name.
    sample_rate_hz : float
        Rate of the samples the driver counts [Hz].
    listener : callable, optional
        Called as ``listener(progress, changed)`` after every phase and block, ``changed``
        True when the phase's name changed (a log line, a bar's redraw).
    clock : callable
        Wall clock for the pace [s] (``time.monotonic``).
    pace_after_s : float
        Wall time after the first block before the pace is known [s]. A driver that
        computes in batches ahead of its clock (the node in real time) hands its blocks in
        bursts: over a shorter span the pace measures a burst, not the schedule.
    """

    def __init__(self, kind, sample_rate_hz, listener=None, clock=time.monotonic,
                 pace_after_s=0.0):
        if not sample_rate_hz > 0:
            raise ValueError(f'sample_rate_hz must be positive, got {sample_rate_hz!r}')
        if not pace_after_s >= 0:
            raise ValueError(f'pace_after_s must be 0 or more, got {pace_after_s!r}')
        self._pace_after_s = float(pace_after_s)
        self.kind = kind
        self._rate_hz = float(sample_rate_hz)
        self._listener = listener
        self._clock = clock
        self.phase = None
        self.samples = 0
        self._phase_samples = 0   # samples run when the phase was announced
        self._first_block = None  # (samples, clock) at the end of the first block
        self.fraction = 0.0
        self.finished = False

    def announce(self, phase):
        """Take ``phase`` as the schedule's present phase (it starts now)."""
        changed = self.phase is None or phase.name != self.phase.name
        self.phase, self._phase_samples = phase, self.samples
        self._update(changed)

    def advance(self, samples):
        """Count a block of ``samples`` the schedule ran."""
        self.samples += samples
        if self._first_block is None:
            self._first_block = (self.samples, self._clock())
        self._update(False)

    def finish(self):
        """Mark the schedule as returned: nothing is left, the fraction is 1."""
        self.finished = True
        self.fraction = 1.0
        if self._listener is not None:
            self._listener(self, False)

    def _update(self, changed):
        total = self.done_s + self.left_s
        if total > 0 and not self.finished:
            self.fraction = max(self.fraction, min(1.0, self.done_s / total))
        if self._listener is not None:
            self._listener(self, changed)

    @property
    def done_s(self):
        """Sensor time run since the start [s]."""
        return self.samples / self._rate_hz

    @property
    def left_s(self):
        """Sensor time left, at most [s] (0 once finished)."""
        if self.finished or self.phase is None:
            return 0.0
        return max(0.0, self.phase.left_s - (self.samples - self._phase_samples) / self._rate_hz)

    @property
    def pace(self):
        """
        Sensor seconds run per wall second since the first block, or None before then.

        None until ``pace_after_s`` of wall time has passed since the first block and a
        block has run since. From the first block on, not from the start: a driver that
        computes ahead of its clock (the node, ``stream.lead_s``) hands the first block early.
        """
        if self._first_block is None:
            return None
        samples, then = self._first_block
        elapsed = self._clock() - then
        ran = self.samples - samples
        known = ran and elapsed > 0 and elapsed >= self._pace_after_s
        return ran / self._rate_hz / elapsed if known else None

    @property
    def wall_left_s(self):
        """Wall time left at the pace so far [s], or None before the pace is known."""
        pace = self.pace
        return None if pace is None else self.left_s / pace

    def describe(self):
        """Return the phase in words (``loops open, point 5 of 11``), or ``starting``."""
        return 'starting' if self.phase is None else str(self.phase)


def run_schedule(triad, schedule, chunk_samples=1000, progress=None):
    """
    Drive a schedule generator offline, as fast as possible; return its result.

    The generator yields how many samples it needs (or a :class:`Phase`); the driver runs
    the triad for that many (in chunks of at most ``chunk_samples``) and sends back the
    output. A triad moving along a trajectory is refused with :class:`EstimationError`:
    self-estimation needs the sensor at rest.

    Parameters
    ----------
    triad : QfaTriad
        The sensor model the schedule drives.
    schedule : generator
        The schedule.
    chunk_samples : int
        Most samples the triad runs at once.
    progress : str or ScheduleProgress, optional
        A :class:`ScheduleProgress` to feed, or a name: show the schedule's phase and
        fraction in a tqdm bar on stderr (a terminal only) under that name.

    Returns
    -------
    object
        What the schedule returns.

    Raises
    ------
    EstimationError
        The schedule refuses or fails, or the triad moves.
    ValueError
        ``chunk_samples`` is no whole number of at least 1.
    """
    try:
        checks.count('chunk_samples', chunk_samples, least=1)
    except ValueError:
        schedule.close()
        raise
    moving = triad.is_at_rest() if hasattr(triad, 'is_at_rest') else None
    if moving:
        schedule.close()
        raise EstimationError(moving)
    if isinstance(progress, str):
        with _progress_bar(progress, triad.config.sample_rate_hz) as shown:
            return _drive(triad, schedule, chunk_samples, shown)
    return _drive(triad, schedule, chunk_samples, progress)


def _drive(triad, schedule, chunk_samples, progress):
    """Run ``schedule`` on ``triad`` to its end, its phases and blocks told to ``progress``."""
    try:
        request = next_request(schedule, None, progress)
        while True:
            parts = []
            remaining = request
            while remaining > 0:
                n = min(chunk_samples, remaining)
                parts.append(triad.run(n))
                remaining -= n
                if progress is not None:
                    progress.advance(n)
            request = next_request(schedule, concatenate(parts), progress)
    except StopIteration as stop:
        if progress is not None:
            progress.finish()
        return stop.value


@contextmanager
def _progress_bar(name, sample_rate_hz):
    """Yield a :class:`ScheduleProgress` drawn as a tqdm bar of percent (a terminal only)."""
    # Imported here: only a caller that asks for a bar needs tqdm.
    from tqdm import tqdm
    with tqdm(total=100, unit='%', desc=name, disable=None, file=sys.stderr,
              bar_format='{desc}: {percentage:3.0f}%|{bar}| {postfix}') as bar:
        def draw(progress, changed):
            bar.set_postfix_str(progress.describe(), refresh=False)
            bar.update(math.floor(100 * progress.fraction) - bar.n)
        yield ScheduleProgress(name, sample_rate_hz, draw)
