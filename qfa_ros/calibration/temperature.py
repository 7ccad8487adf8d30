"""Temperature calibration of the zero bias: chamber cycle, fit, fixed-point ROM (seed 2)."""

from dataclasses import asdict, dataclass
import math

import numpy as np

from qfa_ros.calibration.schedule import (
    EstimationError,
    require_closed,
    samples_for,
    sensor_time_ns,
)
from qfa_ros.calibration.tempfit import calibrate_zero_bias
from qfa_ros.model.noise import MICRO_G
from qfa_ros.model.triad import AXES, FLAG_ADC_CLIPPED, FLAG_DA2_CLIPPED

AMBIENT_FIELDS = ('ambient_profile', 'ambient_c', 'cycle_low_c', 'cycle_high_c',
                  'cycle_period_s', 'cycle_shape', 'cycle_dwell_fraction')


@dataclass(frozen=True)
class TemperatureSettings:
    """
    Temperature-calibration schedule.

    Attributes
    ----------
    low_c, high_c : float
        Chamber cycle limits [degC].
    period_s : float
        Cycle period [s] (trapezoid, 30 % dwell on each plateau); it may be far
        shorter than a real chamber's because the bias follows the body temperature,
        which the on-board sensor reads without lag.
    cycles : int
        Number of cycles.
    block_s : float
        Averaging block of the recorded points [s].
    bins : int
        V_temp bins of the fit (seed 2 fits the binned curve).
    m_bits : int
        Fixed-point fraction bits of the CORDIC compensator (seed 2: 16).
    apply : bool
        Store the coefficients and switch temperature compensation on.
    """

    low_c: float = -40.0
    high_c: float = 70.0
    period_s: float = 3600.0
    cycles: int = 1
    block_s: float = 1.0
    bins: int = 100
    m_bits: int = 16
    apply: bool = True

    def __post_init__(self):
        for name in ('low_c', 'high_c', 'period_s', 'block_s'):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f'{name} must be a finite number, got {value!r}')
        if not -60.0 <= self.low_c < self.high_c <= 125.0:
            raise ValueError('low_c and high_c must satisfy -60 <= low_c < high_c <= 125 degC')
        if self.period_s < 60.0:
            raise ValueError(f'period_s must be at least 60 s, got {self.period_s!r}')
        if not 0 < self.block_s <= self.period_s / 50:
            raise ValueError('block_s must be positive and at most period_s / 50')
        for name, low, high in (('cycles', 1, 100), ('bins', 10, 10000), ('m_bits', 8, 30)):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or not low <= value <= high:
                raise ValueError(f'{name} must be an integer in [{low}, {high}], got {value!r}')


@dataclass
class TemperatureResult:
    """
    What a temperature calibration measured and stored.

    Attributes
    ----------
    kind : str
        ``temperature``.
    settings : dict
        The schedule settings.
    calibrations : list of TemperatureCalibration
        One per axis (fit, poly3/poly4 comparison, p2p before/after, ROM).
    points : dict of numpy arrays
        Binned curve: ``time_ns`` (end of the schedule), ``v_temp`` [V],
        ``bias_<axis>`` and ``compensated_<axis>`` [m/s^2].
    residuals : float64[n, 3]
        Binned zero output after the fixed-point compensation [m/s^2].
    blocks : dict of numpy arrays
        The recorded cycle, one row per ``block_s``: ``time_ns``, ``v_temp`` [V],
        ``temperature`` [degC], ``zero`` (n, 3) [m/s^2].
    applied : bool
        Whether compensation was stored and switched on.
    start_ns, end_ns : int
        Sensor time span [ns].
    """

    kind: str
    settings: dict
    calibrations: list
    points: dict
    residuals: np.ndarray
    blocks: dict
    applied: bool
    start_ns: int
    end_ns: int

    @property
    def duration_s(self):
        """Sensor time the schedule took [s]."""
        return (self.end_ns - self.start_ns) * 1e-9

    def summary(self):
        """Return a one-line human summary."""
        axes = ', '.join(f'{a} {c.p2p_before / MICRO_G:.0f}->{c.p2p_after / MICRO_G:.1f} ug'
                         for a, c in zip(AXES, self.calibrations))
        action = 'compensation on' if self.applied else 'not applied'
        return (f'temperature calibration: zero-drift p2p {axes}; {action}; '
                f'{self.duration_s:.0f} s')

    def to_mapping(self):
        """Return the fit, comparison figures and ROM words as a mapping (trace result).

        ``rom.<axis>`` holds the integer words and formats the compensator was built
        from (what ``state.temperature`` stores), so the trace alone reproduces the
        fixed-point compensation bit for bit.
        """
        mapping = {'applied': self.applied, 'duration_s': self.duration_s,
                   'start_ns': self.start_ns, 'end_ns': self.end_ns, 'summary': self.summary()}
        for axis, c in zip(AXES, self.calibrations):
            mapping[f'fit.{axis}'] = {
                'alpha1': c.fit.alpha1, 'alpha2': c.fit.alpha2, 'beta1': c.fit.beta1,
                'beta2': c.fit.beta2, 'rmse': c.fit.rmse, 'r_squared': c.fit.r_squared,
                'iterations': c.fit.iterations, 'converged': c.fit.converged}
            mapping[f'poly3.{axis}'] = {'rmse': c.poly3.rmse, 'r_squared': c.poly3.r_squared}
            mapping[f'poly4.{axis}'] = {'rmse': c.poly4.rmse, 'r_squared': c.poly4.r_squared}
            mapping[f'p2p_before_ug.{axis}'] = c.p2p_before / MICRO_G
            mapping[f'p2p_after_ug.{axis}'] = c.p2p_after / MICRO_G
            mapping[f'cancellation_bits.{axis}'] = c.cancellation_bits
            mapping[f'rom.{axis}'] = {**c.compensator().rom(), 'v_range': list(c.v_range)}
        return mapping


def temperature_schedule(triad, state, settings=TemperatureSettings()):
    """
    Run a chamber temperature cycle, fit the zero bias, store the ROM (generator).

    Same protocol as :func:`qfa_ros.calibration.estimation.run_schedule`. The sensor must stay
    static at a known orientation (the chamber fixture): the zero output is the
    output minus that known specific force, averaged over ``block_s`` blocks with
    the measured V_temp. Per axis, :func:`qfa_ros.calibration.tempfit.calibrate_zero_bias` bins
    the curve by V_temp and fits the double exponential by alternating iteration,
    with the 3rd/4th-order polynomials for comparison, and builds the fixed-point
    CORDIC compensator. With ``settings.apply`` the coefficients go into
    ``state.temperature`` and compensation is switched on. The ambient profile is
    restored afterwards. A sensor at +1 g on an axis calibrates that axis's
    scale-factor temperature error at 1 g together with its zero bias.
    """
    if triad.thermal is None:
        raise EstimationError('the sensor has no thermal model (TriadConfig.thermal is None)')
    require_closed(triad)
    start_ns = sensor_time_ns(triad)
    previous = {name: getattr(triad.thermal.config, name) for name in AMBIENT_FIELDS}
    was_compensating = triad.temperature_compensation
    triad.temperature_compensation = False
    v_temp, zero, times, temperature, truth0 = [], [], [], [], None
    blocks = int(round(settings.cycles * settings.period_s / settings.block_s))
    try:
        triad.thermal.set_ambient(ambient_profile='cycle', cycle_low_c=settings.low_c,
                                  cycle_high_c=settings.high_c,
                                  cycle_period_s=settings.period_s, cycle_shape='trapezoid',
                                  cycle_dwell_fraction=0.3)
        for _ in range(blocks):
            out = yield samples_for(triad, settings.block_s)
            if np.any(out.flags & (FLAG_DA2_CLIPPED | FLAG_ADC_CLIPPED)):
                raise EstimationError('output saturated: the input must be in range')
            if truth0 is None:
                truth0 = out.truth[0]
            if np.max(np.abs(out.truth - truth0)) > 1e-9:
                raise EstimationError('the input moved: temperature calibration needs the '
                                      'sensor static at a known orientation')
            v_temp.append(out.v_temp.mean())
            zero.append((out.accel - out.truth).mean(axis=0))
            times.append(int(out.stamps_ns[-1]))
            temperature.append(out.temperature.mean())
    finally:
        triad.thermal.set_ambient(**previous)
        triad.temperature_compensation = was_compensating
    v_temp = np.asarray(v_temp)
    zero = np.asarray(zero)
    try:
        calibrations = [calibrate_zero_bias(v_temp, zero[:, axis], m_bits=settings.m_bits,
                                            n_bins=settings.bins) for axis in range(len(AXES))]
    except ValueError as error:
        raise EstimationError(f'temperature fit failed: {error}') from error
    end_ns = sensor_time_ns(triad)
    bins = np.linspace(v_temp.min(), v_temp.max(), settings.bins + 1)
    which = np.clip(np.digitize(v_temp, bins) - 1, 0, settings.bins - 1)
    used = np.unique(which)
    centres = np.array([v_temp[which == b].mean() for b in used])
    means = np.array([zero[which == b].mean(axis=0) for b in used])
    compensated = np.column_stack([means[:, axis] - c.compensator().evaluate_fixed(centres)
                                   for axis, c in enumerate(calibrations)])
    points = {'time_ns': np.full(len(used), end_ns, dtype=np.int64), 'v_temp': centres}
    for axis, name in enumerate(AXES):
        points[f'bias_{name}'] = means[:, axis]
    for axis, name in enumerate(AXES):
        points[f'compensated_{name}'] = compensated[:, axis]
    if settings.apply:
        state.temperature = {axis: c.to_dict() for axis, c in zip(AXES, calibrations)}
        triad.temperature_compensators = [c.compensator() for c in calibrations]
        triad.temperature_compensation = True
        state.updated_at_ns = end_ns
    blocks = {'time_ns': np.asarray(times, dtype=np.int64), 'v_temp': v_temp,
              'temperature': np.asarray(temperature), 'zero': zero}
    return TemperatureResult('temperature', asdict(settings), calibrations, points, compensated,
                             blocks, settings.apply, start_ns, end_ns)
