"""
What every schedule shares: its error and result, the sensor port, the sensor time, the driver.

A schedule is a generator that drives the loop words of a sensor, yields how many
samples it needs next, and receives them as one block; it returns its result.
:func:`run_schedule` drives one offline as fast as the CPU allows; the node drives the
same generators paced by the ROS clock.

Estimators see the sensor only through a :class:`SensorPort`: the words the FPGA can
write, the decimated output with its flags, and the on-board temperature sensor read
through its ADC. Nothing of the model's truth (true input, body temperature, drift,
noise configuration) passes through it; ``test_estimation_sees_no_truth`` audits that.
"""

from dataclasses import dataclass
import math

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


def run_schedule(triad, schedule, chunk_samples=1000, progress=None):
    """
    Drive a schedule generator offline, as fast as possible; return its result.

    The generator yields how many samples it needs; the driver runs the triad for that
    many (in chunks of at most ``chunk_samples``) and sends back the output. A triad
    moving along a trajectory is refused with :class:`EstimationError`: self-estimation
    needs the sensor at rest. ``progress``, if given, is called with the sensor seconds
    of every chunk run.
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
    try:
        request = next(schedule)
        while True:
            parts = []
            remaining = request
            while remaining > 0:
                n = min(chunk_samples, remaining)
                parts.append(triad.run(n))
                remaining -= n
                if progress is not None:
                    progress(n / triad.config.sample_rate_hz)
            request = schedule.send(concatenate(parts))
    except StopIteration as stop:
        return stop.value
