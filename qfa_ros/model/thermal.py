r"""
Thermal behaviour of the emulated sensor: ambient, body lag, temperature sensor, bias.

Everything is advanced chunk by chunk with explicit state; a run split into chunks of
any lengths (same ``dt``) equals one long run sample for sample, bit for bit.
"""

import dataclasses
from dataclasses import dataclass
import math
from typing import NamedTuple

import numba
import numpy as np

from qfa_ros.model import checks, random_streams
from qfa_ros.model.constants import MILLI_G, PPM

AMBIENT_PROFILES = ('constant', 'ramp', 'cycle', 'room')
CYCLE_SHAPES = ('trapezoid', 'sine')
BIAS_MODELS = ('double_exp', 'polynomial', 'mixed', 'none')
N_AXES = 3

DEFAULT_BIAS_ALPHA = ((0.08 * MILLI_G, 0.90 * MILLI_G),
                      (-0.12 * MILLI_G, -0.25 * MILLI_G),
                      (0.05 * MILLI_G, 0.60 * MILLI_G))
"""Default double-exponential alphas per axis [m/s^2] (see :class:`ThermalConfig`)."""

DEFAULT_BIAS_BETA = ((2.0, -0.6), (1.5, -1.2), (2.4, -0.3))
"""Default double-exponential betas per axis [1/V]."""


def _per_axis(name, value, columns=None):
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f'{name} must be a numeric array, got {value!r}') from error
    expected = (N_AXES,) if columns is None else (N_AXES, columns)
    if columns == -1:
        ok = array.ndim == 2 and array.shape[0] == N_AXES and array.shape[1] >= 1
    else:
        ok = array.shape == expected
    if not ok:
        raise ValueError(f'{name} must have shape {expected if columns != -1 else "(3, k)"}, '
                         f'got {array.shape}')
    if not np.all(np.isfinite(array)):
        raise ValueError(f'{name} must be finite')
    return array


@dataclass(frozen=True)
class ThermalConfig:
    r"""
    Thermal model of the triad (SI units: s, degC, V, m/s^2).

    Ambient ``T_a(t)``:

    * ``constant``: ``T_a = ambient_c``;
    * ``ramp``: ``T_a = clip(ambient_c + ramp_rate_c_per_s * t, *ramp_limits_c)``;
    * ``cycle``: between ``cycle_low_c`` and ``cycle_high_c`` with period
      ``cycle_period_s``, starting at the midpoint and heating; ``trapezoid`` is a
      triangle wave clipped so that ``cycle_dwell_fraction`` of the period is spent on
      the two plateaus, ``sine`` a sine;
    * ``room``: ``T_a = ambient_c + room_amplitude_c * tanh(x)`` with ``x`` an
      Ornstein-Uhlenbeck process of unit variance and correlation time
      ``room_correlation_s`` (bounded wander, strictly inside ``+-room_amplitude_c``).

    Sensor body (proof mass) ``T_s``: ``tau_s dT_s/dt = T_a - T_s``, discretized exactly
    for an ambient that is linear between samples (first-order hold):
    ``T_s[k+1] = a T_s[k] + (1 - c) T_a[k+1] + (c - a) T_a[k]``, ``a = e^(-dt/tau_s)``,
    ``c = tau_s (1 - a) / dt`` (exact for constant, ramp and trapezoid ambients).
    The temperature-sensor chip ``T_p`` lags the body with ``probe_tau_s`` (0: none),
    discretized the same way.

    Temperature sensor (TMP36-like: 10 mV/degC, 0.75 V at 25 degC):
    ``V_temp = tsensor_v0 + tsensor_k_v_per_c (T_p - tsensor_t0_c) + n_v``, ``n_v``
    white with rms ``tsensor_noise_v``, then an ``adc_bits`` unipolar ADC on
    ``[0, adc_vref_v)``: ``code = clip(round(V/LSB), 0, 2^bits - 1)``,
    ``LSB = adc_vref_v / 2^adc_bits`` (16 bit, 2.5 V: 38 uV = 0.004 degC).

    Zero bias per axis ``i`` [m/s^2], a function of the body temperature through the
    noiseless sensor voltage ``V_s = tsensor_v0 + k_v (T_s - T0)``:

    * ``double_exp`` (default, Liu, Li and Shen, eq. 1):
      ``b_i = bias_alpha[i,0] e^(bias_beta[i,0] V_s) + bias_alpha[i,1] e^(bias_beta[i,1] V_s)``;
      the defaults give 0.43 / 0.43 / 0.66 mg peak to peak over -40..+70 degC, curved,
      with temperature coefficients of at most 15 / 10 / 20 ug/degC (QA-2000 class:
      < 30 ug/degC);
    * ``polynomial``: ``b_i = sum_k bias_poly[i,k] (T_s - T0)^k`` [m/s^2/degC^k];
    * ``mixed``: the sum of the two (a drawn unit, :mod:`qfa_ros.model.drawn_unit`: a curve that
      is not the fitted model's own shape);
    * ``none``: 0;

    plus hysteresis ``hysteresis_m_s2[i] * h``, with ``h`` in ``[-1, 1]`` moving towards
    +1 while heating and -1 while cooling, rate-independently:
    ``h += (sign(dT_s) - h) (1 - e^(-|dT_s| / hysteresis_c))``.

    Scale-factor relative error per axis (dimensionless), ``d = T_s - T0``:
    ``e_i = 1e-6 (sf_offset_ppm[i] + sf_tc_ppm_per_c[i] d + sf_tc2_ppm_per_c2[i] d^2
    + sf_tc3_ppm_per_c3[i] d^3)`` (datasheet: < 180 ppm/degC uncompensated).
    """

    ambient_profile: str = 'cycle'
    ambient_c: float = 25.0
    ramp_rate_c_per_s: float = 0.01
    ramp_limits_c: tuple = (-40.0, 70.0)
    cycle_low_c: float = -40.0
    cycle_high_c: float = 70.0
    cycle_period_s: float = 7200.0
    cycle_shape: str = 'trapezoid'
    cycle_dwell_fraction: float = 0.3
    room_amplitude_c: float = 1.5
    room_correlation_s: float = 600.0
    sensor_tau_s: float = 300.0
    initial_sensor_c: float = None
    probe_tau_s: float = 0.0
    tsensor_v0: float = 0.75
    tsensor_t0_c: float = 25.0
    tsensor_k_v_per_c: float = 0.010
    tsensor_noise_v: float = 0.2e-3
    adc_bits: int = 16
    adc_vref_v: float = 2.5
    bias_model: str = 'double_exp'
    bias_alpha: tuple = DEFAULT_BIAS_ALPHA
    bias_beta: tuple = DEFAULT_BIAS_BETA
    bias_poly: tuple = ((0.0,), (0.0,), (0.0,))
    hysteresis_m_s2: tuple = (0.0, 0.0, 0.0)
    hysteresis_c: float = 5.0
    sf_tc_ppm_per_c: tuple = (80.0, 100.0, 60.0)
    sf_tc2_ppm_per_c2: tuple = (0.0, 0.0, 0.0)
    sf_tc3_ppm_per_c3: tuple = (0.0, 0.0, 0.0)
    sf_offset_ppm: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for name, choices in (('ambient_profile', AMBIENT_PROFILES),
                              ('cycle_shape', CYCLE_SHAPES), ('bias_model', BIAS_MODELS)):
            if getattr(self, name) not in choices:
                raise ValueError(f'{name} must be one of {choices}, '
                                 f'got {getattr(self, name)!r}')
        for name in ('ambient_c', 'ramp_rate_c_per_s', 'cycle_low_c', 'cycle_high_c',
                     'tsensor_v0', 'tsensor_t0_c'):
            checks.finite(name, getattr(self, name))
        for name in ('cycle_period_s', 'room_correlation_s', 'sensor_tau_s',
                     'tsensor_k_v_per_c', 'adc_vref_v', 'hysteresis_c'):
            checks.positive(name, getattr(self, name))
        for name in ('room_amplitude_c', 'probe_tau_s', 'tsensor_noise_v'):
            checks.positive(name, getattr(self, name), allow_zero=True)
        if self.cycle_low_c >= self.cycle_high_c:
            raise ValueError('cycle_low_c must be < cycle_high_c')
        dwell = checks.finite('cycle_dwell_fraction', self.cycle_dwell_fraction)
        if not 0 <= dwell < 1:
            raise ValueError(f'cycle_dwell_fraction must be in [0, 1), got {dwell!r}')
        limits = np.asarray(self.ramp_limits_c, dtype=float)
        if limits.shape != (2,) or not np.all(np.isfinite(limits)) or limits[0] > limits[1]:
            raise ValueError(f'ramp_limits_c must be (low, high), got {self.ramp_limits_c!r}')
        if self.initial_sensor_c is not None:
            checks.finite('initial_sensor_c', self.initial_sensor_c)
        if (isinstance(self.adc_bits, bool) or not isinstance(self.adc_bits, int)
                or not 8 <= self.adc_bits <= 24):
            raise ValueError(f'adc_bits must be an integer in [8, 24], got {self.adc_bits!r}')
        _per_axis('bias_alpha', self.bias_alpha, 2)
        _per_axis('bias_beta', self.bias_beta, 2)
        _per_axis('bias_poly', self.bias_poly, -1)
        for name in ('hysteresis_m_s2', 'sf_tc_ppm_per_c', 'sf_tc2_ppm_per_c2',
                     'sf_tc3_ppm_per_c3', 'sf_offset_ppm'):
            _per_axis(name, getattr(self, name))

    @property
    def adc_lsb_v(self):
        """Return the temperature ADC LSB [V]."""
        return self.adc_vref_v / (1 << self.adc_bits)


class ThermalChunk(NamedTuple):
    """Arrays of one :meth:`ThermalModel.run` call, ``n`` samples (SI units)."""

    time: np.ndarray
    """Sample times [s]."""
    ambient_c: np.ndarray
    """Ambient temperature [degC]."""
    sensor_c: np.ndarray
    """Sensor body (proof mass) temperature [degC]."""
    v_temp_true: np.ndarray
    """Noiseless temperature-sensor voltage at the sensor chip [V]."""
    v_temp: np.ndarray
    """Measured temperature-sensor voltage, noisy and ADC-quantized [V]."""
    adc_code: np.ndarray
    """Temperature ADC code (int64)."""
    bias: np.ndarray
    """Zero bias per axis, shape (n, 3) [m/s^2]."""
    scale_factor_error: np.ndarray
    """Scale-factor relative error per axis, shape (n, 3) [1]."""


@numba.njit(cache=True, nogil=True)
def _advance(ambient_det, room_noise, use_room, room_center, room_amplitude, room_phi,
             room_gain, room_x, ambient_now, sensor_now, probe_now, hysteresis_now,
             a_s, c_s, a_p, c_p, hysteresis_width):
    """Advance ambient/body/probe/hysteresis recursions over one chunk."""
    n = room_noise.shape[0]
    ambient = np.empty(n)
    sensor = np.empty(n)
    probe = np.empty(n)
    hysteresis = np.empty(n)
    for k in range(n):
        ambient[k] = ambient_now
        sensor[k] = sensor_now
        probe[k] = probe_now
        hysteresis[k] = hysteresis_now
        if use_room:
            room_x = room_phi * room_x + room_gain * room_noise[k]
            ambient_next = room_center + room_amplitude * math.tanh(room_x)
        else:
            ambient_next = ambient_det[k + 1]
        # same recursion as the docstring, arranged to be exact for a constant input
        sensor_next = (ambient_next + a_s * (sensor_now - ambient_now)
                       - c_s * (ambient_next - ambient_now))
        probe_next = (sensor_next + a_p * (probe_now - sensor_now)
                      - c_p * (sensor_next - sensor_now))
        change = sensor_next - sensor_now
        if change != 0.0:
            target = 1.0 if change > 0.0 else -1.0
            hysteresis_now += (target - hysteresis_now) * (
                1.0 - math.exp(-abs(change) / hysteresis_width))
        ambient_now, sensor_now, probe_now = ambient_next, sensor_next, probe_next
    return ambient, sensor, probe, hysteresis, room_x, ambient_now, sensor_now, probe_now, \
        hysteresis_now


def _lag_coefficients(tau, dt):
    if tau == 0:
        return 0.0, 0.0
    a = math.exp(-dt / tau)
    return a, -math.expm1(-dt / tau) * tau / dt


class ThermalModel:
    r"""
    Chunk-wise thermal model of the triad: ambient, body, temperature sensor, bias.

    See :class:`ThermalConfig` for every equation and unit.  Random numbers (room
    wander, temperature-sensor noise) come from a private stream, the injected
    generator's child ``'thermal.environment'`` (:mod:`qfa_ros.model.random_streams`), two
    normals per sample drawn row-wise, so a run split into chunks equals one long run
    and the parent generator's other users do not shift it; :meth:`reset` replays it
    from the start.

    Parameters
    ----------
    config : ThermalConfig
        Model parameters.
    rng : numpy.random.Generator
        Source of all randomness.
    """

    def __init__(self, config=None, rng=None):
        if config is None:
            config = ThermalConfig()
        if not isinstance(config, ThermalConfig):
            raise ValueError(f'config must be a ThermalConfig, got {type(config).__name__}')
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f'rng must be a numpy.random.Generator, got {type(rng).__name__}')
        self.config = config
        self._rng = random_streams.generator(rng, 'thermal.environment')
        self._rng_start = self._rng.bit_generator.state
        self._alpha = np.asarray(config.bias_alpha, dtype=float)
        self._beta = np.asarray(config.bias_beta, dtype=float)
        self._poly = np.asarray(config.bias_poly, dtype=float)
        self._hysteresis_amplitude = np.asarray(config.hysteresis_m_s2, dtype=float)
        self._sf_tc = np.asarray(config.sf_tc_ppm_per_c, dtype=float) * PPM
        self._sf_tc2 = np.asarray(config.sf_tc2_ppm_per_c2, dtype=float) * PPM
        self._sf_tc3 = np.asarray(config.sf_tc3_ppm_per_c3, dtype=float) * PPM
        self._sf_offset = np.asarray(config.sf_offset_ppm, dtype=float) * PPM
        self.reset()

    def reset(self):
        """Return to time 0, the initial temperatures and the start of the noise stream."""
        self._rng.bit_generator.state = self._rng_start
        self.sample_index = 0
        self._segment_index = 0
        self._segment_time = 0.0
        self._dt = None
        self._profile_origin = 0.0
        self._room_x = 0.0
        self._ambient_now = float(self.ambient_at(np.zeros(1))[0])
        initial = self.config.initial_sensor_c
        self._sensor_now = self._ambient_now if initial is None else float(initial)
        self._probe_now = self._sensor_now
        self._hysteresis_now = 0.0

    @property
    def time(self):
        """Return the time of the next sample [s]."""
        if self._dt is None:
            return self._segment_time
        return self._segment_time + (self.sample_index - self._segment_index) * self._dt

    @property
    def sensor_c(self):
        """Return the body temperature at the next sample [degC]."""
        return self._sensor_now

    @property
    def probe_c(self):
        """Return the temperature-sensor chip's temperature at the next sample [degC]."""
        return self._probe_now

    @property
    def hysteresis(self):
        """Return the bias hysteresis state at the next sample (-1 cooling .. 1 heating)."""
        return self._hysteresis_now

    def ambient_at(self, t):
        """Return the deterministic ambient profile at times ``t`` [s] (room: its centre)."""
        cfg = self.config
        t = np.asarray(t, dtype=float) - self._profile_origin
        if cfg.ambient_profile == 'ramp':
            low, high = cfg.ramp_limits_c
            return np.clip(cfg.ambient_c + cfg.ramp_rate_c_per_s * t, low, high)
        if cfg.ambient_profile == 'cycle':
            middle = 0.5 * (cfg.cycle_high_c + cfg.cycle_low_c)
            half = 0.5 * (cfg.cycle_high_c - cfg.cycle_low_c)
            phase = np.mod(t / cfg.cycle_period_s, 1.0)
            if cfg.cycle_shape == 'sine':
                return middle + half * np.sin(2.0 * np.pi * phase)
            triangle = np.where(phase < 0.25, 4.0 * phase,
                                np.where(phase < 0.75, 2.0 - 4.0 * phase, 4.0 * phase - 4.0))
            return middle + half * np.clip(triangle / (1.0 - cfg.cycle_dwell_fraction),
                                           -1.0, 1.0)
        return np.full(t.shape, cfg.ambient_c)

    def set_ambient(self, **changes):
        """Change the ambient profile (a chamber program) from the present time on.

        ``changes`` are :class:`ThermalConfig` ambient fields (``ambient_profile``,
        ``ambient_c``, ``cycle_low_c``, ``cycle_high_c``, ``cycle_period_s``, ...); the
        new profile's time origin is now, so a cycle starts at its midpoint, heating.
        The body and probe temperatures continue from their present values.
        """
        allowed = {'ambient_profile', 'ambient_c', 'ramp_rate_c_per_s', 'ramp_limits_c',
                   'cycle_low_c', 'cycle_high_c', 'cycle_period_s', 'cycle_shape',
                   'cycle_dwell_fraction', 'room_amplitude_c', 'room_correlation_s'}
        unknown = set(changes) - allowed
        if unknown:
            raise ValueError(f'not ambient fields: {sorted(unknown)}')
        self.config = dataclasses.replace(self.config, **changes)
        self._profile_origin = self.time
        self._ambient_now = float(self.ambient_at(np.array([self.time]))[0])

    def voltage_at(self, temperature_c):
        """Return the noiseless temperature-sensor voltage at ``temperature_c`` [V]."""
        cfg = self.config
        return cfg.tsensor_v0 + cfg.tsensor_k_v_per_c * (
            np.asarray(temperature_c, dtype=float) - cfg.tsensor_t0_c)

    def reading_c(self, v_temp):
        """Return the temperature [degC] the on-board sensor reports for ``v_temp`` [V]."""
        cfg = self.config
        return cfg.tsensor_t0_c + (np.asarray(v_temp, dtype=float) - cfg.tsensor_v0) \
            / cfg.tsensor_k_v_per_c

    @property
    def reading_variance_c2(self):
        """Return the variance of :meth:`reading_c` [degC^2]: sensor noise and ADC LSB."""
        cfg = self.config
        return (cfg.tsensor_noise_v ** 2 + cfg.adc_lsb_v ** 2 / 12.0) / cfg.tsensor_k_v_per_c ** 2

    def zero_bias(self, sensor_c, hysteresis=0.0):
        """Return the zero bias (..., 3) [m/s^2] at body temperature(s) ``sensor_c``."""
        cfg = self.config
        temperature = np.asarray(sensor_c, dtype=float)[..., None]
        bias = np.zeros(np.broadcast_shapes(temperature.shape, (N_AXES,)))
        if cfg.bias_model in ('double_exp', 'mixed'):
            v = self.voltage_at(temperature)
            bias = bias + (self._alpha[:, 0] * np.exp(self._beta[:, 0] * v)
                           + self._alpha[:, 1] * np.exp(self._beta[:, 1] * v))
        if cfg.bias_model in ('polynomial', 'mixed'):
            offset = temperature - cfg.tsensor_t0_c
            poly = np.zeros(np.broadcast_shapes(offset.shape, (N_AXES,)))
            for power in range(self._poly.shape[1] - 1, -1, -1):
                poly = poly * offset + self._poly[:, power]
            bias = bias + poly
        return bias + self._hysteresis_amplitude * np.asarray(hysteresis, dtype=float)[..., None]

    def scale_factor_error(self, sensor_c):
        """Return the scale-factor relative error (..., 3) at body temperature(s) [1]."""
        offset = np.asarray(sensor_c, dtype=float)[..., None] - self.config.tsensor_t0_c
        return self._sf_offset + offset * (self._sf_tc + offset * (self._sf_tc2
                                                                   + offset * self._sf_tc3))

    def run(self, n, dt):
        """Advance ``n`` samples of period ``dt`` [s] and return a :class:`ThermalChunk`."""
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f'n must be an integer >= 0, got {n!r}')
        dt = checks.positive('dt', dt)
        n = int(n)
        cfg = self.config
        if dt != self._dt:
            # a new dt starts a new time segment so that times stay t0 + k*dt exactly
            self._segment_time = self.time
            self._segment_index = self.sample_index
            self._dt = dt
        index = np.arange(self.sample_index, self.sample_index + n + 1, dtype=np.int64)
        times = self._segment_time + (index - self._segment_index) * dt
        noise = self._rng.standard_normal((n, 2))
        use_room = cfg.ambient_profile == 'room'
        ambient_det = np.zeros(1) if use_room else self.ambient_at(times)
        room_phi = math.exp(-dt / cfg.room_correlation_s)
        room_gain = math.sqrt(-math.expm1(-2.0 * dt / cfg.room_correlation_s))
        a_s, c_s = _lag_coefficients(cfg.sensor_tau_s, dt)
        a_p, c_p = _lag_coefficients(cfg.probe_tau_s, dt)
        (ambient, sensor, probe, hysteresis, self._room_x, self._ambient_now,
         self._sensor_now, self._probe_now, self._hysteresis_now) = _advance(
            ambient_det, np.ascontiguousarray(noise[:, 0]), use_room, cfg.ambient_c,
            cfg.room_amplitude_c, room_phi, room_gain, self._room_x, self._ambient_now,
            self._sensor_now, self._probe_now, self._hysteresis_now, a_s, c_s, a_p, c_p,
            cfg.hysteresis_c)
        self.sample_index += n
        v_true = self.voltage_at(probe)
        code = np.clip(np.rint((v_true + cfg.tsensor_noise_v * noise[:, 1]) / cfg.adc_lsb_v),
                       0, (1 << cfg.adc_bits) - 1).astype(np.int64)
        if n and sensor[0] == sensor[-1] and np.all(sensor == sensor[0]) \
                and np.all(hysteresis == hysteresis[0]):
            # A body at a constant temperature (the usual static case): the temperature
            # terms are evaluated once, not per sample, and held (read-only views).
            bias = np.broadcast_to(self.zero_bias(sensor[:1], hysteresis[:1]), (n, N_AXES))
            scale_factor_error = np.broadcast_to(self.scale_factor_error(sensor[:1]),
                                                 (n, N_AXES))
        else:
            bias = self.zero_bias(sensor, hysteresis)
            scale_factor_error = self.scale_factor_error(sensor)
        return ThermalChunk(time=times[:n], ambient_c=ambient, sensor_c=sensor,
                            v_temp_true=v_true, v_temp=code * cfg.adc_lsb_v, adc_code=code,
                            bias=bias, scale_factor_error=scale_factor_error)
