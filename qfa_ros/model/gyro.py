"""Navigation-grade gyroscope triad (IEEE Std 952 FOG error model), drawn per unit.

The output equation follows IEEE Std 952-1997 (interferometric fiber optic gyro), its
model ``S0 dN/dt = (I + E + D)(1 + eps_k 1e-6)^-1`` written for a rate output: per
axis ``i`` and published sample ``k`` (period ``T``)::

    w_s   = (I + M) w_ib                                   misalignment M
    y_i   = w_s,i (1 + s_i + s_T,i dT + a_i sgn(w_s,i))    scale factor, its temperature
                                                           coefficient, asymmetry
          + b_i + b_T,i dT + (G f)_i                       turn-on bias, bias temperature
                                                           coefficient, g-sensitivity
          + n_ARW + n_BI + n_RRW                           angle random walk, bias
                                                           instability, rate random walk
    y_i  -> angle quantization (residual carried), clipped at the rate range

with ``dT`` the body temperature minus ``reference_c`` (the accelerometers' thermal
model drives both triads) and ``f`` the specific force [m/s^2]. Noise per sample:
``n_ARW ~ N(0, N^2 / T)``; ``n_BI`` a sum of first-order Gauss-Markov processes scaled
to the Allan floor ``B`` (as :mod:`qfa_ros.model.noise` does for the accelerometers);
``n_RRW`` a random walk with steps ``N(0, K^2 T)``. The two slow processes advance
once per block of ``m`` samples (``m T`` at most a tenth of the shortest correlation
time, and 0.1 s) and hold over it: their Allan deviation is unchanged from ``m T`` on,
where the ARW dwarfs them anyway (0.38 deg/h against 0.003 deg/h at 0.1 s with the
defaults), and they cost ``1/m`` of the random numbers; a rate random walk without
bias instability (an emulated Kalibr ``imu.yaml``) steps every sample (``m = 1``).
``s, a, b, M, G, b_T, s_T`` are drawn once per unit from zero-mean normal laws with the
configured 1-sigma spreads.
"""

from dataclasses import dataclass, replace
import math

from numba import njit
import numpy as np

from qfa_ros.model import checks, random_streams
from qfa_ros.model.constants import ARCSEC, DEG_PER_HOUR, DEG_PER_ROOT_HOUR, PPM, STANDARD_GRAVITY
from qfa_ros.model.noise import flicker_component_variance

ERROR_TERMS = ('arw', 'bias_instability', 'rate_random_walk', 'turn_on_bias', 'scale_factor',
               'scale_factor_asymmetry', 'misalignment', 'g_sensitivity', 'bias_tc',
               'scale_factor_tc', 'quantization')
"""The :class:`GyroConfig` error terms: each finite and >= 0, all 0 in :meth:`GyroConfig.ideal`."""


@dataclass(frozen=True)
class GyroConfig:
    """
    Error model of the gyro triad (SI units; 1-sigma spreads of the per-unit draws).

    Defaults: the navigation-grade (1 nmi/h class) gyro of ``docs/model.md``: the
    Honeywell HG9900 brochure (N61-1638-000-000) gives gyro bias 0.0035 deg/h, ARW
    0.002 deg/sqrt(h) and scale factor 5 ppm (1 sigma); the other terms are typical of
    the class, not from that sheet.

    Attributes
    ----------
    arw : float
        Angle random walk N [rad/sqrt(s)]: Allan deviation N / sqrt(tau).
    bias_instability : float
        Allan floor B [rad/s] of the Gauss-Markov sum with ``correlation_times`` [s].
    rate_random_walk : float
        K [rad/s/sqrt(s)]: Allan deviation K sqrt(tau / 3).
    turn_on_bias : float
        Spread of the turn-on bias b [rad/s].
    scale_factor : float
        Spread of the scale-factor error s [dimensionless].
    scale_factor_asymmetry : float
        Spread of the asymmetry a [dimensionless].
    misalignment : float
        Spread of each element of M [rad].
    g_sensitivity : float
        Spread of each element of G [(rad/s)/(m/s^2)].
    bias_tc, scale_factor_tc : float
        Spreads of the temperature coefficients b_T [rad/s/K] and s_T [1/K].
    reference_c : float
        Temperature at which the temperature terms vanish [degC].
    quantization : float
        Angle quantum of the output [rad] (0: none).
    range : float
        Rate range [rad/s]; beyond it the output is clipped and flagged.
    bias : tuple
        Known bias per axis [rad/s] added to the drawn turn-on bias (a unit whose bias
        was measured, as ``TriadConfig.bias`` for the accelerometers); default none.
    """

    arw: float = 0.002 * DEG_PER_ROOT_HOUR
    bias_instability: float = 0.003 * DEG_PER_HOUR
    correlation_times: tuple = (1.0, 10.0, 100.0, 1000.0, 10000.0)
    rate_random_walk: float = 0.003 * DEG_PER_HOUR / 60.0
    turn_on_bias: float = 0.0035 * DEG_PER_HOUR
    scale_factor: float = 5.0 * PPM
    scale_factor_asymmetry: float = 1.0 * PPM
    misalignment: float = 5.0 * ARCSEC
    g_sensitivity: float = 0.001 * DEG_PER_HOUR / STANDARD_GRAVITY
    bias_tc: float = 0.0003 * DEG_PER_HOUR
    scale_factor_tc: float = 0.5 * PPM
    reference_c: float = 25.0
    quantization: float = 1e-9
    range: float = math.radians(490.0)
    bias: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for name in ERROR_TERMS:
            checks.non_negative(f'gyro {name}', getattr(self, name), (int, float))
        if not checks.is_finite(self.reference_c):
            raise ValueError(f'gyro reference_c must be finite, got {self.reference_c!r}')
        if not checks.is_finite(self.range) or self.range <= 0:
            raise ValueError(f'gyro range must be positive, got {self.range!r}')
        checks.positive_times('gyro correlation_times', self.correlation_times)
        checks.finite_vector('gyro bias', self.bias)

    @classmethod
    def ideal(cls):
        """Return a gyro with every error switched off (range kept)."""
        return cls(**dict.fromkeys(ERROR_TERMS, 0.0))

    def with_errors(self, **changes):
        """Return a copy with ``changes`` applied (validated)."""
        return replace(self, **changes)


@dataclass(frozen=True)
class GyroUnit:
    """The per-unit draw of a :class:`GyroConfig` (vectors per axis, matrices 3x3)."""

    bias: np.ndarray
    scale_factor: np.ndarray
    asymmetry: np.ndarray
    misalignment: np.ndarray
    g_sensitivity: np.ndarray
    bias_tc: np.ndarray
    scale_factor_tc: np.ndarray

    @classmethod
    def draw(cls, config, rng):
        """Draw one unit from ``config``'s spreads with ``rng``."""
        def normal(sigma, shape):
            return rng.standard_normal(shape) * sigma
        return cls(bias=np.asarray(config.bias, dtype=float) + normal(config.turn_on_bias, 3),
                   scale_factor=normal(config.scale_factor, 3),
                   asymmetry=normal(config.scale_factor_asymmetry, 3),
                   misalignment=normal(config.misalignment, (3, 3)) * (1 - np.eye(3)),
                   g_sensitivity=normal(config.g_sensitivity, (3, 3)),
                   bias_tc=normal(config.bias_tc, 3),
                   scale_factor_tc=normal(config.scale_factor_tc, 3))


class GyroTriad:
    """
    Three gyro axes advancing at the published sample rate ``dt = 1 / sample_rate_hz``.

    Parameters
    ----------
    config : GyroConfig
        Error model.
    sample_rate_hz : float
        Output rate [Hz].
    rng : numpy.random.Generator or int
        Source of the unit draw and of the noise (one child stream per source and
        axis, so the output does not depend on the chunk lengths).
    """

    def __init__(self, config, sample_rate_hz, rng):
        if not checks.is_finite(sample_rate_hz) or sample_rate_hz <= 0:
            raise ValueError(f'sample_rate_hz must be positive, got {sample_rate_hz!r}')
        if not isinstance(rng, np.random.Generator):
            rng = np.random.default_rng(rng)
        self.config = config
        self.dt = 1.0 / sample_rate_hz
        unit_stream = random_streams.generator(rng, 'gyro.unit')
        flicker = random_streams.generator(rng, 'gyro.flicker')
        walk = random_streams.generator(rng, 'gyro.walk')
        # The white noise is three draws a sample, the gyros' largest cost beside the
        # loops: numpy's SFC64 draws a normal in ~2/3 of PCG64's time, from the same seed.
        white = np.random.Generator(
            np.random.SFC64(random_streams.seed_sequence(rng, 'gyro.white')))
        self.unit = GyroUnit.draw(config, unit_stream)
        self._white, self._flicker, self._walk = white, flicker, walk
        self._white_std = config.arw / math.sqrt(self.dt)
        block_s = min(0.1 * min(config.correlation_times), 0.1)
        self._block = max(1, int(block_s / self.dt))
        if config.bias_instability == 0 and config.rate_random_walk > 0:
            # A rate random walk alone (an emulated imu.yaml) steps every sample, as
            # Kalibr's discrete model does.
            self._block = 1
        period = self._block * self.dt
        self._phi = np.exp(-period / np.asarray(config.correlation_times, dtype=float))
        variance = flicker_component_variance(config)
        self._innovation_std = np.sqrt(variance * (1.0 - self._phi ** 2))
        self._flicker_state = flicker.standard_normal((3, len(self._phi))) * math.sqrt(variance)
        self._walk_state = np.zeros(3)
        self._walk_std = config.rate_random_walk * math.sqrt(period)
        self._slow = self._flicker_state.sum(axis=1) if config.bias_instability > 0 \
            else np.zeros(3)
        self._slow_left = self._block  # samples the current slow value still holds
        self._angle_residual = np.zeros(3)
        self._sensing = np.eye(3) + self.unit.misalignment

    @property
    def in_run_bias(self):
        """Return the slow bias processes' value held now (3,) [rad/s]: flicker + walk."""
        return self._slow.copy()

    def variance(self):
        """Return the variance of one published sample per axis [(rad/s)^2] (REP-145)."""
        c = self.config
        return c.arw ** 2 / self.dt + c.bias_instability ** 2 \
            + (c.quantization / self.dt) ** 2 / 6.0

    def run(self, rate, specific_force, temperature):
        """
        Return (output rate [rad/s], saturated bool) per sample, each (n, 3).

        Parameters
        ----------
        rate : array_like, (n, 3)
            True angular rate of the body w.r.t. inertial space, body axes, averaged
            over each sample [rad/s].
        specific_force : array_like, (n, 3)
            Specific force per sample [m/s^2] (g-sensitivity).
        temperature : array_like, (n,)
            Body temperature per sample [degC].
        """
        job, output, saturated = self.job(rate, specific_force, temperature)
        job(0, len(output))
        return output, saturated

    def job(self, rate, specific_force, temperature):
        """
        Return (call, output, saturated): ``call(a, b)`` writes :meth:`run`'s samples a..b-1.

        The arguments are those of :meth:`run`, checked now. The calls must cover
        ``0..n`` in order (one call, or consecutive slices); each runs the compiled loop,
        which releases the GIL, so the triad runs them on the threads beside the
        accelerometer axes.
        """
        rate = np.ascontiguousarray(rate, dtype=float)
        force = np.ascontiguousarray(specific_force, dtype=float)
        n = len(rate)
        if rate.shape != (n, 3) or force.shape != (n, 3):
            raise ValueError('rate and specific_force must have shape (n, 3)')
        d_t = np.ascontiguousarray(np.broadcast_to(
            np.asarray(temperature, dtype=float) - self.config.reference_c, (n,)))
        output = np.empty((n, 3))
        saturated = np.empty((n, 3), dtype=np.bool_)
        u = self.unit
        c = self.config

        flicker_on = c.bias_instability > 0
        n_components = len(self._phi)

        def call(a, b):
            # Every stream's normals for a..b-1, drawn here in the kernel's order (the
            # slow processes' per block starting in it, the white noise's per sample and
            # axis): numba 0.58-0.60 keeps ~585 bytes at every call that unboxes a
            # Generator (numba issue 9103), and numpy draws the same numbers.
            starts = len(range(self._slow_left, b - a, self._block))
            shocks = self._flicker.standard_normal((starts if flicker_on else 0, 3,
                                                    n_components))
            steps = self._walk.standard_normal((starts if self._walk_std > 0 else 0, 3))
            white = self._white.standard_normal((b - a if self._white_std > 0 else 0, 3))
            slow_left = np.array([self._slow_left], dtype=np.int64)
            _gyro_chunk(white, self._white_std, self._block, shocks, self._phi,
                        self._innovation_std, self._flicker_state, steps, self._walk_std,
                        self._walk_state, self._slow, slow_left, rate[a:b], force[a:b],
                        d_t[a:b], self._sensing, u.scale_factor, u.scale_factor_tc,
                        u.asymmetry, u.bias, u.bias_tc, u.g_sensitivity, c.quantization,
                        self.dt, c.range, self._angle_residual, output[a:b], saturated[a:b])
            self._slow_left = int(slow_left[0])

        return call, output, saturated


@njit(cache=True, nogil=True)
def _gyro_chunk(white, white_std, block, shocks, phi, innovation_std, flicker_state, steps,
                walk_std, walk_state, slow, slow_left, rate, force, d_t, sensing, sf, sf_tc,
                asymmetry, bias, bias_tc, g_sens, quantum, dt, limit, residual, out,
                saturated):
    """
    Run the noise and the output equation of the module docstring over ``n`` samples.

    The slow processes (Gauss-Markov sum ``phi_j b_j + q_j v``, then the rate random
    walk, its steps summed from the chunk's first block and added to the walk's value at
    the chunk's start) advance once per ``block`` samples and hold; ``slow`` (3,) is
    the value held and ``slow_left[0]`` the samples it still holds. Their standard
    normals come per block that starts in the chunk: ``shocks`` (blocks, 3, components)
    for the Gauss-Markov sum (none: no bias instability) and ``steps`` (blocks, 3) for
    the walk (none: no walk). The white noise is ``white_std`` times ``white`` (n, 3),
    standard normals per sample and axis (none when ``white_std`` is 0). Each stream is
    read in a fixed order, so the output depends on the seed, not on the chunk lengths.
    Then the angle is quantized (``residual`` carries the remainder) and clipped.
    """
    n = rate.shape[0]
    n_components = phi.shape[0]
    # The output equation without noise first: no draws, no branch, so LLVM can
    # vectorize it (a sgn(w) w = a |w|); the noise and the quantization follow.
    for k in range(n):
        w0, w1, w2 = rate[k, 0], rate[k, 1], rate[k, 2]
        f0, f1, f2 = force[k, 0], force[k, 1], force[k, 2]
        change = d_t[k]
        for i in range(3):
            sensed = sensing[i, 0] * w0 + sensing[i, 1] * w1 + sensing[i, 2] * w2
            out[k, i] = sensed * (1.0 + sf[i] + sf_tc[i] * change) \
                + asymmetry[i] * abs(sensed) + bias[i] + bias_tc[i] * change \
                + g_sens[i, 0] * f0 + g_sens[i, 1] * f1 + g_sens[i, 2] * f2
    walk_start = walk_state.copy()
    walked = np.zeros(3)
    started = 0  # blocks started in this chunk
    left = slow_left[0]
    for k in range(n):
        if left == 0:
            for i in range(3):
                value = 0.0
                if shocks.shape[0]:
                    for j in range(n_components):
                        state = phi[j] * flicker_state[i, j] \
                            + shocks[started, i, j] * innovation_std[j]
                        flicker_state[i, j] = state
                        value += state
                slow[i] = value
            if steps.shape[0]:
                for i in range(3):
                    step = steps[started, i] * walk_std
                    walked[i] += step
                    slow[i] += walk_start[i] + walked[i]
            started += 1
            left = block
        left -= 1
        if white_std > 0:
            for i in range(3):
                out[k, i] += slow[i] + white[k, i] * white_std
        else:
            for i in range(3):
                out[k, i] += slow[i]
    # Then each axis on its own: whole angle quanta per sample, the remainder carried to
    # the next (the count of a sample is the change of floor(angle / quantum), the angle
    # summed from the residual: the running sum is the only chain from sample to sample,
    # where carrying the remainder itself would chain a floor and four operations);
    # then the range.
    per_quantum = 1.0 / quantum if quantum > 0 else 0.0
    quantum_rate = quantum / dt
    for i in range(3):
        angle = residual[i]
        previous = math.floor(angle * per_quantum)
        first = previous
        for k in range(n):
            value = out[k, i]
            if quantum > 0:
                angle += value * dt
                counts = math.floor(angle * per_quantum)
                value = (counts - previous) * quantum_rate
                previous = counts
            saturated[k, i] = abs(value) > limit
            out[k, i] = min(max(value, -limit), limit)
        if quantum > 0:
            residual[i] = angle - (previous - first) * quantum
    if steps.shape[0]:
        for i in range(3):
            walk_state[i] = walk_start[i] + walked[i]
    slow_left[0] = left
