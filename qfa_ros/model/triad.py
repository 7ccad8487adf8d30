"""Digital closed-loop QFA triad: three simulated loops, decimated output (pure model).

With the gyro triad and the motion input beside the loops it is the whole sensor
assembly: one cohesive thing, because every run advances all of it together. Its
configuration is :class:`~qfa_ros.model.triad_config.TriadConfig`, its output
:class:`~qfa_ros.model.triad_output.TriadOutput`.
"""

from fractions import Fraction
import math
from types import SimpleNamespace

import numpy as np

from qfa_ros.model import checks, kernel, random_streams
from qfa_ros.model.axis import AxisLoop, start_axes
from qfa_ros.model.drift import DriftModel
from qfa_ros.model.gyro import GyroTriad
from qfa_ros.model.hardware import counts_to_accel
from qfa_ros.model.input_profiles import StaticProfile
from qfa_ros.model.noise import NoiseSource
from qfa_ros.model.parallel import available_cores
from qfa_ros.model.thermal import ThermalModel
from qfa_ros.model.triad_config import TriadConfig
from qfa_ros.model.triad_output import concatenate, TriadOutput

AXES = ('x', 'y', 'z')
NS_PER_S = 1_000_000_000
FLAG_DA2_CLIPPED, FLAG_ADC_CLIPPED, FLAG_OVER_RANGE = 1, 2, 4
MAX_CONTROLLER_GAIN = 4.0


class SampleGrid:
    """
    Instants of a stream of samples, exact in integer nanoseconds.

    Sample ``j`` is stamped ``start_ns + (j + 1) / rate_hz``: the end of its averaging
    block. A rate that is not an integer number of nanoseconds uses an exact fraction.

    Parameters
    ----------
    rate_hz : float
        Sample rate [Hz].
    start_ns : int or None
        Instant the stream starts [ns]; None until :meth:`anchor` is called.
    """

    def __init__(self, rate_hz, start_ns=None):
        rate = Fraction(rate_hz).limit_denominator(1_000_000)
        self._numerator = rate.numerator
        self._scale = NS_PER_S * rate.denominator
        self.start_ns = start_ns
        self.next_index = 0

    def anchor(self, start_ns):
        """Start the stream at ``start_ns``: sample 0 ends one period later."""
        self.start_ns = int(start_ns)
        self.next_index = 0

    def stamp_ns(self, index):
        """Return the instant of sample(s) ``index`` [ns] (int, or int64 array)."""
        return self.start_ns + (index + 1) * self._scale // self._numerator

    def due(self, now_ns):
        """Return how many samples have their instant at or before ``now_ns``."""
        return max(0, (int(now_ns) - self.start_ns) * self._numerator // self._scale)


class QfaTriad:
    r"""
    Three digital closed-loop QFA axes advancing in discrete time.

    Each axis runs the loop of :class:`qfa_ros.model.hardware.AxisHardware` at
    ``dt = 1/loop_rate_hz`` in the compiled kernel; the published output is the
    mean of ``decimation = loop_rate_hz / sample_rate_hz`` loop outputs (anti-alias
    averaging), converted with the nominal scale factor ``k_fb,nom / K0``. The loop
    input of axis ``i`` is ``(bias_i + a_i + k2_i a_i^2)(1 + e_i(T)) + b_i(T) + w_i``
    with ``a = (I + M) f``, ``w`` the acceleration noise and, with a thermal model,
    ``b_i(T)`` the zero bias and ``e_i(T)`` the scale-factor error at the body
    temperature. With temperature compensation on, the published output subtracts the
    fixed-point double-exponential zero-bias model evaluated at the measured V_temp.

    Parameters
    ----------
    config : TriadConfig
        Configuration.
    rng : numpy.random.Generator or int or None
        Source of every random number (an int is a seed).
    profile : object with ``evaluate(t) -> (n, 3)``, optional
        Input specific force [m/s^2] as a function of sensor time [s]; default level.
        A :class:`StaticProfile` is applied as one value per chunk; a
        :class:`qfa_ros.model.trajectory.Trajectory` (it has ``sample_means``) as its mean
        over each sample, with the angular rate the gyros see; other profiles are
        evaluated at every loop step and rotate with no rate.
    start_ns : int, optional
        Origin of the sample stamps [ns] (default 0), e.g. an epoch for a recording;
        the physics runs on :attr:`time` from 0.

    Attributes
    ----------
    workers : int
        Threads :meth:`run` may use for the three axes when a chunk has at least
        ``qfa_ros.model.axis.PARALLEL_MIN_STEPS`` loop steps (default: the cores
        available, at most 3; 1 runs them in turn). Each axis draws from its own
        stream, so the output does not depend on it.
    """

    def __init__(self, config=None, rng=None, profile=None, start_ns=0):
        self.config = TriadConfig() if config is None else config
        self.rng = np.random.default_rng(rng)  # a Generator is returned as it is
        self.profile = StaticProfile.level() if profile is None else profile
        self.decimation = self.config.decimation
        self.dt = 1.0 / self.config.loop_rate_hz
        self.sample_period = 1.0 / self.config.sample_rate_hz
        if isinstance(start_ns, (bool, float)) or int(start_ns) != start_ns:
            raise ValueError(f'start_ns must be an integer number of ns, got {start_ns!r}')
        self._grid = SampleGrid(self.config.sample_rate_hz, start_ns=int(start_ns))
        self.noise = NoiseSource(self.config.noise, len(AXES), self.config.loop_rate_hz,
                                 self.config.sample_rate_hz, self.rng)
        self.axes = [AxisLoop(self.config, self.noise, i) for i in range(len(AXES))]
        self.workers = min(len(AXES), available_cores())
        self.drift = DriftModel(len(AXES))
        self.drift.clock = lambda: self.time
        self.thermal = None
        if self.config.thermal is not None:
            self.thermal = ThermalModel(self.config.thermal,
                                        random_streams.generator(self.rng, 'triad.thermal'))
        self.gyro = None
        if self.config.gyro is not None:
            # A named child: the accelerometers' streams are the same with or without gyros.
            self.gyro = GyroTriad(self.config.gyro, self.config.sample_rate_hz,
                                  random_streams.generator(self.rng, 'triad.gyro'))
        # Gyro bias correction [rad/s] the firmware subtracts from the published rate
        # (a gyro bias schedule estimates it); zero until one ran.
        self.gyro_bias_correction = np.zeros(3)
        # Temperature compensation: apply(accel, v_temp) -> accel (a ThermalCompensation).
        self.temperature_compensator = None
        self.temperature_compensation = False
        # Calibration fixture (dividing head): a profile replacing every input while set.
        self.fixture = None
        self.scale = counts_to_accel(self.config.hardware)
        self.sample_index = 0
        self.settle_until = np.zeros(len(AXES), dtype=np.int64)
        self._misalignment = np.eye(3) + np.asarray(self.config.misalignment, dtype=float)
        self._bias = np.asarray(self.config.bias, dtype=float)
        self._k2 = np.asarray(self.config.k2, dtype=float)
        self._applied_version = None
        self.temperature = self.drift.reference_temperature
        if self.thermal is not None:
            self.temperature = self.thermal.sensor_c
        self._refresh(force=True)
        self._start_equilibrium()

    # Time ------------------------------------------------------------------------------
    @property
    def time(self):
        """Sensor time of the next sample's start [s]."""
        return self.sample_index * self.sample_period

    def stamp_ns(self, sample_index):
        """Return the data-ready instant (end of the averaging block) of samples [ns]."""
        return self._grid.stamp_ns(np.asarray(sample_index, dtype=np.int64))

    # Loop words --------------------------------------------------------------------------
    def _refresh(self, force=False):
        key = (self.drift.version, self.temperature,
               self.sample_index if self.drift.aging else None)
        if force or key != self._applied_version:
            for i, axis in enumerate(self.axes):
                axis.update(self.drift.at(i, self.time, self.temperature))
            self._applied_version = key

    def invalidate(self):
        """Recompute the kernel parameters after a loop word or switch changed."""
        self._refresh(force=True)

    def set_open_loop(self, axis, open_loop):
        """Open (True) or re-close (False) the loop of ``axis``."""
        axis = checks.index('axis', axis, len(AXES))
        loop = self.axes[axis]
        if open_loop and not loop.open_loop:
            loop.open()
        elif not open_loop and loop.open_loop:
            loop.close()
            settle = int(math.ceil(self.config.settle_time / self.sample_period))
            self.settle_until[axis] = self.sample_index + settle
        self.invalidate()

    def set_noise(self, config, rng):
        """
        Replace the acceleration noise by ``config`` drawn from ``rng`` from now on.

        Parameters
        ----------
        config : NoiseConfig
            The new noise (e.g. white and bias instability off for a noiseless twin).
        rng : numpy.random.Generator or int
            Source of the new random_streams.
        """
        self.noise = NoiseSource(config, len(AXES), self.config.loop_rate_hz,
                                 self.config.sample_rate_hz, np.random.default_rng(rng))
        for axis, loop in enumerate(self.axes):
            loop.attach_noise(self.noise, axis)

    def set_temperature(self, temperature):
        """Set the sensor temperature [degC] that drives the temperature coefficients."""
        self.temperature = checks.finite('temperature', temperature)

    def set_reference_current(self, axis, on):
        """Close (True) or open (False) the switch M1 of the constant current source."""
        self.axes[checks.index('axis', axis, len(AXES))].reference_current_on = bool(on)
        self.invalidate()

    def set_n_fpga(self, axis, word):
        """Write the modulation amplitude word N_FPGA of ``axis``."""
        self._set_word(axis, 'n_fpga', word, self.config.hardware.n_da1_bits - 1)

    def set_n_vref(self, axis, word):
        """Write the DA0 reference word N_VREF of ``axis`` (eq. 30)."""
        self._set_word(axis, 'n_vref', word, self.config.hardware.n_da0_bits)

    def _set_word(self, axis, name, word, bits):
        # Write the loop word ``name`` of ``axis``, an integer in (0, 2^bits).
        try:
            valid = int(word) == word and 0 < word < 2 ** bits
        except (TypeError, ValueError, OverflowError):
            valid = False
        if not valid:
            raise ValueError(f'{name} must be an integer in (0, 2^{bits}), got {word!r}')
        setattr(self.axes[checks.index('axis', axis, len(AXES))], name, int(word))
        self.invalidate()

    def set_controller_gain(self, axis, gain):
        """Write k(D(z)) of ``axis`` (quantized to the Q32 gain word).

        The bound keeps every int64 product of the kernel below 2^62 at full-scale ADC.
        """
        if not (checks.is_finite(gain) and 0 < gain < MAX_CONTROLLER_GAIN):
            raise ValueError(f'controller gain must be in (0, {MAX_CONTROLLER_GAIN}), '
                             f'got {gain!r}')
        loop = self.axes[checks.index('axis', axis, len(AXES))]
        loop.controller = loop.controller.with_gain(gain)
        self.invalidate()

    # Simulation --------------------------------------------------------------------------
    def _start_equilibrium(self):
        # Start each loop at rest under the initial input so runs need no warm-up.
        f0 = self.profile.evaluate(np.zeros(1))[0]
        sensed = self._sensed(f0[None, :], self.time)[:, 0]
        if self.thermal is not None:  # the loop input includes the thermal terms (run)
            sensed = sensed * (1.0 + self.thermal.scale_factor_error(self.temperature)) \
                + self.thermal.zero_bias(self.temperature)
        for i, loop in enumerate(self.axes):
            command = int(round(loop.hw.pendulosity * sensed[i] / loop.gains.feedback_gain))
            command = max(-loop.hw.da2_full_scale, min(loop.hw.da2_full_scale, command))
            loop.state_i[kernel.T_APPLIED] = command
            loop.state_i[kernel.T_LAST] = command
            loop.state_i[kernel.T_INTEGRATOR] = command << 28

    def _sensed(self, specific_force, time):
        # Rows per axis (3, n) of the force each axis senses; compiled, as numpy's
        # matmul and temporaries cost more than the trajectory means themselves.
        force = np.ascontiguousarray(specific_force, dtype=float)
        sensed = np.empty((len(AXES), len(force)))
        kernel.sense(force, self._misalignment, self._bias + self.drift.bias_at(time),
                     self._k2, sensed)
        return sensed

    # Motion (trajectory, gyros) -------------------------------------------------------
    def is_at_rest(self):
        """Return None when the input is a body at rest, else why it is not."""
        if hasattr(self.profile, 'is_static') and not self.profile.is_static:
            return f'the sensor is moving ({self.profile.name}): self-estimation needs it ' \
                'at rest'
        return None

    def run(self, n_samples, specific_force=None, angular_rate=None):
        """
        Advance ``n_samples`` output samples and return a :class:`TriadOutput`.

        Parameters
        ----------
        n_samples : int
            Number of published samples (``n_samples * decimation`` loop steps).
        specific_force : array_like, optional
            True specific force in the sensor frame [m/s^2], shape (n_samples, 3) (held
            over each sample) or (n_samples * decimation, 3) (per loop step). Default:
            the profile evaluated at every loop step (a trajectory: its mean over each
            sample, held).
        angular_rate : array_like, optional
            True angular rate w_ib^b [rad/s] per sample, shape (n_samples, 3), with
            ``specific_force``; default: the trajectory's, or zero.
        """
        n_samples = checks.count('n_samples', n_samples)
        chunk = self._prepare(self.sample_index, n_samples, specific_force, angular_rate)
        self._launch(chunk).join()
        return self._finish(chunk)

    def run_chunks(self, n_samples, chunk_samples):
        """
        Advance ``n_samples`` in chunks of ``chunk_samples``; yield each chunk's output.

        The outputs are those of :meth:`run` called chunk after chunk (same numbers), but
        the work around the loops overlaps them: while the threads run a chunk's loops
        and gyros, the calling thread prepares the next chunk's input and thermal terms,
        then assembles the chunk's output, and the caller's own work on a yielded chunk
        overlaps the next chunk's loops. The triad's state must not be changed while
        iterating; closing the generator early lets the chunk in flight finish first
        (the triad has then advanced past the last chunk yielded).

        Parameters
        ----------
        n_samples : int
            Samples to run in all.
        chunk_samples : int
            Samples per chunk (the last one may be shorter), at least 1.
        """
        n_samples = checks.count('n_samples', n_samples)
        chunk_samples = checks.count('chunk_samples', chunk_samples, least=1)
        sizes = [min(chunk_samples, n_samples - done)
                 for done in range(0, n_samples, chunk_samples)]
        if not sizes:
            return
        chunk = self._prepare(self.sample_index, sizes[0])
        running = self._launch(chunk)
        start = self.sample_index + sizes[0]
        try:
            for size in sizes[1:] + [None]:
                upcoming = None if size is None else self._prepare(start, size)
                running.join()
                running = None
                output = self._finish(chunk)
                if upcoming is not None:
                    start += size
                    chunk = upcoming
                    running = self._launch(chunk)
                yield output
        finally:
            if running is not None:
                running.join()
                self._finish(chunk)

    def _prepare(self, start_index, n_samples, specific_force=None, angular_rate=None):
        # Everything a chunk's loops need that does not depend on them: the input and
        # the thermal terms (the thermal model advances, the loops do not).
        force, truth, rate = self._input(start_index * self.sample_period, n_samples,
                                         specific_force, angular_rate)
        # The chunk's arrays until _finish; rows per axis: one value for the chunk, one
        # per sample or one per loop step.
        chunk = SimpleNamespace(n_samples=n_samples, truth=truth, rate=rate)
        chunk.sensed = self._sensed(force, start_index * self.sample_period)
        if self.thermal is not None:
            terms = self.thermal.run(n_samples, self.sample_period)
            chunk.temperature = terms.sensor_c
            chunk.v_temp = terms.v_temp
            chunk.scale = 1.0 + _held_or_per_sample(terms.scale_factor_error)
            chunk.offset = _held_or_per_sample(terms.bias)
        else:
            chunk.temperature = np.full(n_samples, self.temperature)
            chunk.v_temp = np.full(n_samples, np.nan)
            chunk.scale = np.ones((len(AXES), 1))
            chunk.offset = np.zeros((len(AXES), 1))
        return chunk

    def _launch(self, chunk):
        # Start the chunk's loops (and gyros) on the threads; the triad is at its start.
        if self.thermal is not None:
            # Gains follow the chunk's mean temperature: it moves far slower than a chunk.
            self.temperature = float(chunk.temperature.mean())
        self._refresh()
        n_samples = chunk.n_samples
        chunk.counts = np.empty((len(AXES), n_samples))
        chunk.flags = np.empty((len(AXES), n_samples), dtype=np.int8)
        if self.gyro is None:
            chunk.gyro, beside = np.full((n_samples, 3), np.nan), ()
        else:
            # The gyros share nothing with the loops: they run beside them on the threads.
            call, chunk.gyro, _ = self.gyro.job(chunk.rate, chunk.truth, chunk.temperature)
            beside = (call,)
        return start_axes(self.axes, chunk.sensed, chunk.scale, chunk.offset,
                          self.decimation, chunk.counts, chunk.flags, self.workers, beside)

    def _finish(self, chunk):
        # The chunk's output once its loops ran; the triad moves to its end.
        n_samples = chunk.n_samples
        gyro = chunk.gyro
        if self.gyro is not None:
            gyro -= self.gyro_bias_correction
        index = self.sample_index + np.arange(n_samples)
        valid = (index[:, None] >= self.settle_until) \
            & ~np.array([loop.open_loop for loop in self.axes])
        self.sample_index += n_samples
        counts = chunk.counts.T
        accel = counts * self.scale
        if self.temperature_compensation and self.temperature_compensator is not None:
            accel = self.temperature_compensator.apply(accel, chunk.v_temp)
        return TriadOutput(stamps_ns=self.stamp_ns(index), accel=accel,
                           counts=counts.copy(), flags=chunk.flags.T.copy(), valid=valid,
                           truth=chunk.truth, temperature=chunk.temperature,
                           v_temp=chunk.v_temp, gyro=gyro, rate_truth=chunk.rate)

    def _input(self, start, n_samples, specific_force, angular_rate=None):
        # Return the specific force at the rate it changes ((1, 3), (n_samples, 3) or
        # (n_steps, 3)), its mean per sample (truth) and the angular rate per sample, for
        # the samples from sensor time ``start`` [s].
        n_steps = n_samples * self.decimation
        rate = None
        if self.fixture is not None:
            # The dividing head replaces every other input while it is set.
            force = self.fixture.evaluate(start + np.arange(n_steps) * self.dt)
            angular_rate = None
        elif specific_force is None:
            if isinstance(self.profile, StaticProfile):
                force = np.asarray(self.profile.specific_force, dtype=float)[None, :]
                return force, np.repeat(force, n_samples, axis=0), \
                    self._rate(n_samples, angular_rate)
            if getattr(self.profile, 'is_static', False):
                # A trajectory at rest: one value for the chunk, as a StaticProfile.
                force, rest_rate = self.profile.rest_values()
                force = force[None, :]
                if angular_rate is None:
                    angular_rate = np.repeat(rest_rate[None, :], n_samples, axis=0)
                return force, np.repeat(force, n_samples, axis=0), \
                    self._rate(n_samples, angular_rate)
            if hasattr(self.profile, 'sample_means'):
                # A trajectory: its mean specific force and angular rate over each sample.
                force, rate = self.profile.sample_means(start, self.sample_period, n_samples)
            else:
                force = self.profile.evaluate(start + np.arange(n_steps) * self.dt)
        else:
            force = np.asarray(specific_force, dtype=float)
            if force.shape not in ((n_samples, 3), (n_steps, 3)):
                raise ValueError(f'specific_force must have shape ({n_samples}, 3) or '
                                 f'({n_steps}, 3), got {force.shape}')
            if not np.all(np.isfinite(force)):
                raise ValueError('specific_force must be finite')
        rate = self._rate(n_samples, rate if angular_rate is None else angular_rate)
        if len(force) == n_samples:
            return force, force.copy(), rate
        blocks = force.reshape(n_samples, self.decimation, 3)
        if np.array_equal(blocks, np.broadcast_to(blocks[:, :1], blocks.shape)):
            return blocks[:, 0], blocks[:, 0].copy(), rate  # held over each sample
        return force, blocks.mean(axis=1), rate

    @staticmethod
    def _rate(n_samples, angular_rate):
        # The angular rate per sample [rad/s], zero when none is given.
        if angular_rate is None:
            return np.zeros((n_samples, 3))
        rate = np.asarray(angular_rate, dtype=float)
        if rate.shape != (n_samples, 3) or not np.all(np.isfinite(rate)):
            raise ValueError(f'angular_rate must be finite, shape ({n_samples}, 3)')
        return rate

    def run_for(self, duration_s, chunk_samples=1000):
        """Run ``duration_s`` seconds in chunks and return the concatenated output."""
        # A chunk of none would never finish the run.
        checks.count('chunk_samples', chunk_samples, least=1)
        if isinstance(duration_s, (bool, np.bool_)):
            raise ValueError(f'duration_s must be a number of seconds, got {duration_s!r}')
        duration_s = checks.positive('duration_s', duration_s, allow_zero=True)
        total = round(duration_s * self.config.sample_rate_hz)
        parts = []
        while total > 0:
            n = min(chunk_samples, total)
            parts.append(self.run(n))
            total -= n
        return concatenate(parts)


def _held_or_per_sample(values):
    """Return per-axis rows of (n, 3) ``values``: (3, 1) when all rows are equal, else (3, n)."""
    if len(values) and np.all(values == values[0]):
        return np.ascontiguousarray(values[:1].T)
    return np.ascontiguousarray(values.T)
