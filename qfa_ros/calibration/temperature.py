"""
Multi-position temperature calibration: chamber plateaus, a tumbling dividing head, fits.

As a lab calibrates a navigation accelerometer: the triad sits on a dividing head in a
chamber; the chamber steps through plateaus from the ambient down to ``low_c``, up to
``high_c`` and back to the ambient; all the while the head tumbles through the six
positions +x, +y, +z, -z, -y, -x (a palindrome: every axis's +-g pair and zero-input
blocks are centred on the tumble's middle, so a linear temperature trend cancels).
Per axis the zero bias and the scale factor against the on-board temperature reading
are fitted by Liu, Li and Shen's double exponential (with a linear baseline) and evaluated on the
fixed-point CORDIC path; the constant misalignment and K2 the tumble measures are kept
too. With ``reference_steps`` (:func:`temperature_calibration`) the I_ref step is measured
at the end of every plateau and its temperature coefficient fitted against the on-board
reading: the coefficient the feedback schedule's temperature correction needs. At the
end the chamber returns to the ambient it had and, for a constant ambient, the schedule
soaks until the on-board reading is back where it started, so the sensor leaves as a lab
would.
Only what the sensor can know is used: outputs, the temperature reading and the known
fixture positions.

The chamber program, its tumble records and their fit share the block format and the
settings; the reading's lag behind the proof mass, estimated from the same records, is
:mod:`qfa_ros.calibration.probe_lag`.
"""

from contextlib import contextmanager
import dataclasses
from dataclasses import asdict, dataclass

import numpy as np

from qfa_ros.calibration.estimation import check_int
from qfa_ros.calibration.probe_lag import estimate_probe_lag, global_fit, reading_rate
from qfa_ros.calibration.reference_tc import fit_plateau_steps, plateau_step, plateau_step_time_s
from qfa_ros.calibration.schedule import (
    EstimationError,
    Phase,
    require_closed,
    samples_for,
    sensor_time_ns,
    stage,
)
from qfa_ros.calibration.thermal_compensation import calibrate_zero_bias, ThermalCompensation
from qfa_ros.model.checks import is_finite
from qfa_ros.model.constants import MICRO_G, PPM, STANDARD_GRAVITY
from qfa_ros.model.input_profiles import StaticProfile
from qfa_ros.model.triad import AXES, FLAG_ADC_CLIPPED, FLAG_DA2_CLIPPED
from qfa_ros.model.triad_config import TriadConfig

AMBIENT_FIELDS = ('ambient_profile', 'ambient_c', 'cycle_low_c', 'cycle_high_c',
                  'cycle_period_s', 'cycle_shape', 'cycle_dwell_fraction')

MAX_STEPS = 1e6
"""Most plateau steps from ``low_c`` to ``high_c`` (``(high_c - low_c) / step_c``): a
program of more takes at least two million tumbles."""

POSITIONS = ((0, 1), (1, 1), (2, 1), (2, -1), (1, -1), (0, -1))
"""Tumble order as (axis up, sign): +x, +y, +z, -z, -y, -x."""



def position_force(axis, sign):
    """Return the specific force [m/s^2] of the fixture position ``axis`` up, ``sign``."""
    force = [0.0, 0.0, 0.0]
    force[axis] = sign * STANDARD_GRAVITY
    return np.array(force)


@dataclass(frozen=True)
class TemperatureSettings:
    """
    Temperature-calibration schedule.

    Attributes
    ----------
    low_c, high_c : float
        Chamber limits [degC].
    period_s : float
        Sensor time of one chamber program (all plateaus) [s]; each plateau holds
        ``period_s / plateaus``. Accelerated against a real chamber: the fits use the
        on-board reading of every tumble, not settled plateaus.
    cycles : int
        Number of chamber programs.
    block_s : float
        Dwell of the dividing head in each of the six positions [s].
    settle_s : float
        Discarded start of every position (the loop's transient after a rotation; the
        default loop settles to 1 ug in 0.05 s) [s].
    step_c : float
        Spacing of the chamber plateaus [degC]; at least ``(high_c - low_c) /``
        :data:`MAX_STEPS`.
    bins : int
        V_temp bins of the fits.
    m_bits : int
        Fixed-point fraction bits of the zero-bias compensator (Liu, Li and Shen: 16).
    sf_m_bits : int
        Fraction bits of the scale-factor compensator (24: its CORDIC error, 7.6e-8,
        is far below the 20 ppm the correction must reach; at 16 it is 2.4e-5 of each
        term).
    stable_c_per_tumble : float
        The turning points (the first plateau at ``low_c`` and at ``high_c``) hold until
        the on-board reading moves less than this from one tumble to the next (at most ten
        holds) [degC]: the fits then cover the whole range instead of extrapolating to it.
    return_tolerance_c : float
        The soak at the end lasts until the on-board reading (tumble mean) is within
        this of where it was at the start [degC].
    max_soak_s : float
        Longest soak [s]; beyond it the calibration fails with the time it still needs.
    apply : bool
        Store the coefficients and switch temperature compensation on.
    reference_steps : bool
        Measure the I_ref step at the end of every plateau and fit its temperature
        coefficient (:func:`temperature_calibration`; about 4.3 s of sensor time per
        plateau). Off by default here (offline studies); the node's
        ``temperature_calibration.reference_steps`` is on by default.
    """

    low_c: float = -40.0
    high_c: float = 70.0
    period_s: float = 3600.0
    cycles: int = 1
    block_s: float = 1.0
    settle_s: float = 0.25
    step_c: float = 10.0
    bins: int = 60
    m_bits: int = 16
    sf_m_bits: int = 24
    stable_c_per_tumble: float = 0.02
    return_tolerance_c: float = 0.05
    max_soak_s: float = 6000.0
    apply: bool = True
    reference_steps: bool = False

    def __post_init__(self):
        for name in ('low_c', 'high_c', 'period_s', 'block_s', 'step_c', 'settle_s',
                     'stable_c_per_tumble', 'return_tolerance_c', 'max_soak_s'):
            value = getattr(self, name)
            if not is_finite(value, bool_ok=False, types=(int, float)):
                raise ValueError(f'{name} must be a finite number, got {value!r}')
        if not -60.0 <= self.low_c < self.high_c <= 125.0:
            raise ValueError('low_c and high_c must satisfy -60 <= low_c < high_c <= 125 degC')
        if self.period_s < 60.0:
            raise ValueError(f'period_s must be at least 60 s, got {self.period_s!r}')
        if not 0 < self.block_s <= self.period_s / 100:
            raise ValueError('block_s must be positive and at most period_s / 100')
        if not 0 < self.step_c <= self.high_c - self.low_c:
            raise ValueError('step_c must be positive and at most high_c - low_c')
        if (self.high_c - self.low_c) / self.step_c > MAX_STEPS:
            raise ValueError(f'step_c must be at least (high_c - low_c) / {MAX_STEPS:g} '
                             f'(the plateaus are a list), got {self.step_c!r}')
        if self.return_tolerance_c <= 0 or self.max_soak_s < 0 \
                or not self.stable_c_per_tumble > 0:
            raise ValueError('return_tolerance_c and stable_c_per_tumble must be > 0 and '
                             'max_soak_s >= 0')
        for name in ('apply', 'reference_steps'):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f'{name} must be a bool, got {getattr(self, name)!r}')
        for name, low, high in (('cycles', 1, 100), ('bins', 10, 10000), ('m_bits', 8, 30),
                                ('sf_m_bits', 8, 30)):
            check_int(name, getattr(self, name), low, high)

    def max_sensor_time_s(self):
        """
        Return the longest sensor time one calibration may take [s], whatever the ambient.

        The longest of :meth:`program_time_s` over the ambients: per cycle it is
        ``period_s (1 + 18 / n) + n T`` for ``n`` plateaus of ``T`` [s] of tumbles and
        I_ref steps each (the two turning points soak up to ten holds of ``period_s / n``),
        convex in ``n``, so the longest is at the fewest plateaus (an ambient at ``high_c``
        or above) or at the most (at ``low_c`` or below).
        """
        return max(self.program_time_s(self.low_c), self.program_time_s(self.high_c))

    def program_time_s(self, ambient_c):
        """
        Return the longest sensor time of the program that starts at ``ambient_c`` [s].

        A tumble at the start and one at the end, every plateau at its longest
        (:meth:`plateau_limits_s`) in every cycle, and the soak back at its longest
        (``max_soak_s``).
        """
        tumble = len(POSITIONS) * self.block_s
        plateaus = self.plateau_limits_s(self.plateaus(ambient_c))
        return tumble + self.cycles * sum(plateaus) + self.max_soak_s + tumble

    def plateau_limits_s(self, plateaus):
        """
        Return the longest sensor time of each of ``plateaus`` [s].

        Each holds ``period_s / len(plateaus)``, the :meth:`turning_points` up to ten
        times that (:meth:`plateau_time_s`).
        """
        hold = self.period_s / len(plateaus)
        return [self.plateau_time_s(hold, extreme) for extreme in self.turning_points(plateaus)]

    def plateau_time_s(self, hold_s, extreme):
        """
        Return the longest sensor time of a plateau held ``hold_s`` [s].

        Its whole tumbles (``hold_s``, or ten times it at an ``extreme``, plus the tumble
        that passes it) and, with ``reference_steps``, its I_ref step measurement.
        """
        seconds = (10 * hold_s if extreme else hold_s) + len(POSITIONS) * self.block_s
        if self.reference_steps:
            seconds += plateau_step_time_s(TriadConfig.settle_time)
        return seconds

    def turning_points(self, plateaus):
        """
        Return which of ``plateaus`` soak until the reading is stable: the turning points.

        The first plateau (``low_c``) and the first at ``high_c``; a later plateau at the
        same temperature (the way back ending at an ambient of ``low_c`` or ``high_c``)
        holds like any other, so no program has more than two.
        """
        top = plateaus.index(self.high_c)
        return [index in (0, top) for index in range(len(plateaus))]

    def plateaus(self, ambient_c):
        """Return the chamber plateaus [degC]: low, up to high, down to ``ambient_c``."""
        up = np.arange(self.low_c, self.high_c + 1e-9, self.step_c)
        if up[-1] < self.high_c:
            up = np.append(up, self.high_c)
        end = min(max(ambient_c, self.low_c), self.high_c)
        down = np.arange(self.high_c - self.step_c, end, -self.step_c)
        return [float(t) for t in np.concatenate([up, down, [ambient_c]])]


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
    compensation : ThermalCompensation
        Bias and scale-factor calibrations per axis, misalignment, K2.
    points : dict of numpy arrays
        Per tumble: ``time_ns``, ``v_temp`` [V], ``bias_<axis>`` [m/s^2],
        ``scale_<axis>`` (relative scale-factor error) [1] at the reading
        ``v_temp_scale_<axis>`` [V] (the axis's +-g pair's).
    blocks : dict of numpy arrays
        Raw position blocks: ``time_ns``, ``v_temp`` [V], ``temperature`` (on-board
        reading) [degC], ``force`` (n, 3) fixture input and ``output`` (n, 3) [m/s^2].
    applied : bool
        Whether compensation was stored and switched on.
    soak_s : float
        Sensor time of the final soak back to the starting temperature [s].
    plateau_extra : list
        What the ``at_plateau`` hook returned at every plateau.
    probe_lag_s : float
        Lag of the on-board reading behind the proof mass the fit estimated and removed
        [s] (:func:`estimate_probe_lag`).
    start_ns, end_ns : int
        Sensor time span [ns].
    """

    kind: str
    settings: dict
    compensation: ThermalCompensation
    points: dict
    blocks: dict
    applied: bool
    soak_s: float
    start_ns: int
    end_ns: int
    plateau_extra: list = dataclasses.field(default_factory=list)
    probe_lag_s: float = 0.0

    @property
    def residuals(self):
        """Per tumble and axis: bias minus its fixed-point compensation [m/s^2]."""
        return np.column_stack([self.points[f'compensated_{a}'] for a in AXES])

    @property
    def calibrations(self):
        """Return the zero-bias calibrations per axis."""
        return self.compensation.bias

    @property
    def duration_s(self):
        """Sensor time the schedule took [s]."""
        return (self.end_ns - self.start_ns) * 1e-9

    def summary(self):
        """Return a one-line human summary."""
        c = self.compensation
        axes = ', '.join(
            f'{a} {b.p2p_before / MICRO_G:.0f}->{b.p2p_after / MICRO_G:.1f} ug / '
            f'{s.p2p_before / PPM:.0f}->{s.p2p_after / PPM:.1f} ppm'
            for a, b, s in zip(AXES, c.bias, c.scale))
        action = 'compensation on' if self.applied else 'not applied'
        return (f'temperature calibration (six positions): zero-drift p2p and scale-factor '
                f'p2p {axes}; {action}; {self.duration_s:.0f} s incl. {self.soak_s:.0f} s '
                'soak back to the starting temperature')

    def to_mapping(self):
        """Return the fits, comparison figures and ROM words as a mapping (trace result)."""
        mapping = {'applied': self.applied, 'duration_s': self.duration_s,
                   'soak_s': self.soak_s, 'start_ns': self.start_ns, 'end_ns': self.end_ns,
                   'probe_lag_s': self.probe_lag_s, 'summary': self.summary()}
        c = self.compensation
        # bias keys as the single-position calibration had them (fit.<axis>, ...); the
        # scale-factor correction's with a _scale suffix, in ppm
        for suffix, calibrations, unit, scale in (('', c.bias, 'ug', MICRO_G),
                                                  ('_scale', c.scale, 'ppm', PPM)):
            for axis, cal in zip(AXES, calibrations):
                mapping[f'fit{suffix}.{axis}'] = {name: getattr(cal.fit, name) for name in (
                    'alpha1', 'alpha2', 'beta1', 'beta2', 'offset', 'slope', 'rmse', 'r_squared',
                    'iterations', 'converged')}
                for name, poly in (('poly3', cal.poly3), ('poly4', cal.poly4)):
                    mapping[f'{name}{suffix}.{axis}'] = {'rmse': poly.rmse,
                                                         'r_squared': poly.r_squared}
                mapping[f'p2p_before_{unit}{suffix}.{axis}'] = cal.p2p_before / scale
                mapping[f'p2p_after_{unit}{suffix}.{axis}'] = cal.p2p_after / scale
                mapping[f'cancellation_bits{suffix}.{axis}'] = cal.cancellation_bits
                mapping[f'rom{suffix}.{axis}'] = {**cal.compensator().rom(),
                                                  'v_range': list(cal.v_range)}
        mapping['misalignment'] = c.misalignment.tolist()
        mapping['k2'] = c.k2.tolist()
        return mapping


@contextmanager
def chamber_program(triad, **ambient):
    """
    Set ``ambient`` (thermal-model fields) for a chamber program; yield the settings it had.

    However the program ends, the dividing head is removed, those :data:`AMBIENT_FIELDS`
    settings are restored and temperature compensation is switched back to what it was.
    """
    previous = {name: getattr(triad.thermal.config, name) for name in AMBIENT_FIELDS}
    compensating = triad.temperature_compensation
    if ambient:
        triad.thermal.set_ambient(**ambient)
    try:
        yield previous
    finally:
        triad.fixture = None
        triad.thermal.set_ambient(**previous)
        triad.temperature_compensation = compensating


def fixture_profile(axis, sign):
    """Return the dividing head at ``axis`` up, ``sign`` as a static input profile."""
    return StaticProfile(tuple(float(v) for v in position_force(axis, sign)))


def tumble(triad, settings, blocks, phase=Phase('tumble')):
    """
    Run a six-position tumble, a record per position (generator); return its reading [degC].

    ``phase`` names the tumble (its ``left_s``: the sensor time left at its start, at most);
    each position is announced as ``<detail>, attitude k of 6 (<axis> up)``.
    """
    keep_from = min(samples_for(triad, settings.settle_s),
                    samples_for(triad, settings.block_s) // 2)
    for number, (axis, sign) in enumerate(POSITIONS):
        attitude = (f'attitude {number + 1} of {len(POSITIONS)} '
                    f'({"+" if sign > 0 else "-"}{AXES[axis]} up)')
        yield Phase(phase.name, f'{phase.detail}, {attitude}' if phase.detail else attitude,
                    phase.left_s - number * settings.block_s)
        triad.fixture = fixture_profile(axis, sign)
        out = yield samples_for(triad, settings.block_s)
        if np.any(out.flags & (FLAG_DA2_CLIPPED | FLAG_ADC_CLIPPED)):
            raise EstimationError('output saturated during the tumble')
        # the first settle_s follow the rotation: the loop's transient is not data
        blocks.append((int(out.stamps_ns[-1]), out.v_temp[keep_from:].mean(),
                       position_force(axis, sign), out.accel[keep_from:].mean(axis=0)))
    return float(triad.thermal.reading_c(np.mean([b[1] for b in blocks[-len(POSITIONS):]])))


def hold_plateau(triad, settings, blocks, tumbles, phase, hold_s, extreme):
    """
    Tumble at a chamber plateau until its hold has passed (generator, same protocol).

    ``phase`` names the plateau, its ``left_s`` the sensor time left at its start. An
    ``extreme`` plateau holds on until the on-board reading moves less than
    ``stable_c_per_tumble`` from one tumble to the next (at most ten holds): the fits then
    cover the whole range instead of extrapolating to it.
    """
    tumble_s = len(POSITIONS) * settings.block_s
    count, last = 0, None
    while True:
        tumbles.append(len(blocks))
        reading = yield from tumble(triad, settings, blocks, Phase(
            phase.name, f'tumble {count + 1}', phase.left_s - count * tumble_s))
        count += 1
        stable = last is not None and abs(reading - last) <= settings.stable_c_per_tumble
        last = reading
        if count * tumble_s >= hold_s and (not extreme or stable
                                           or count * tumble_s >= 10 * hold_s):
            return


def soak_back(triad, settings, blocks, start_reading):
    """
    Tumble until the reading is back within ``return_tolerance_c`` of ``start_reading``.

    Generator, same protocol; returns the soak's sensor time [s].

    Raises
    ------
    EstimationError
        Still away after ``max_soak_s``.
    """
    tumble_s = len(POSITIONS) * settings.block_s
    soak_s = 0.0
    while True:
        reading = yield from tumble(triad, settings, blocks, Phase(
            'soak back to the starting temperature', f'tumble {round(soak_s / tumble_s) + 1}',
            settings.max_soak_s + tumble_s - soak_s))
        if abs(reading - start_reading) <= settings.return_tolerance_c:
            return soak_s
        soak_s += tumble_s
        if soak_s > settings.max_soak_s:
            raise EstimationError(
                f'the sensor is still {reading - start_reading:+.2f} degC from its '
                f'starting temperature after a {soak_s:.0f} s soak: raise '
                'temperature_calibration max_soak_s or let it settle first')


def temperature_schedule(triad, state, settings=TemperatureSettings(), at_plateau=None):
    """
    Run the chamber program with a tumbling head, fit bias and scale factor (generator).

    Same protocol as :func:`qfa_ros.calibration.schedule.run_schedule`.

    Parameters
    ----------
    triad : QfaTriad
        The sensor (with a thermal model).
    state : CalibrationState
        Gets the ROM (``state.temperature``) with ``settings.apply``.
    settings : TemperatureSettings
        The schedule.
    at_plateau : callable, optional
        Extra measurements at the end of every plateau (the hook for, e.g., I_ref steps
        at chamber plateaus): ``at_plateau(triad, index, chamber_c)`` returns a generator
        of the same protocol, run with ``yield from`` while the head rests at +z; its
        return values are collected in ``result.plateau_extra``.
    """
    if triad.thermal is None:
        raise EstimationError('the sensor has no thermal model (TriadConfig.thermal is None)')
    require_closed(triad)
    start_ns = sensor_time_ns(triad)
    blocks, tumbles, extra = [], [], []
    soak_s = 0.0
    ambient = float(triad.thermal.ambient_at(np.array([triad.thermal.time]))[0])
    plateaus = settings.plateaus(ambient)
    hold = settings.period_s / len(plateaus)
    tumble_s = len(POSITIONS) * settings.block_s
    # The longest sensor time of each plateau: the phases say what is left, at most.
    turning = settings.turning_points(plateaus)
    limits = settings.plateau_limits_s(plateaus)
    with chamber_program(triad) as previous:
        soak = previous['ambient_profile'] == 'constant'
        left_s = (tumble_s + settings.cycles * sum(limits)
                  + (settings.max_soak_s + tumble_s if soak else 0.0))
        triad.temperature_compensation = False
        start_reading = yield from tumble(triad, settings, blocks, Phase(
            'tumble at the starting temperature', '', left_s))
        left_s -= tumble_s
        for cycle in range(settings.cycles):
            for index, chamber_c in enumerate(plateaus):
                triad.thermal.set_ambient(ambient_profile='constant', ambient_c=chamber_c)
                name = (f'cycle {cycle + 1} of {settings.cycles}, ' if settings.cycles > 1
                        else '') + f'plateau {index + 1} of {len(plateaus)} at {chamber_c:g} degC'
                yield from hold_plateau(triad, settings, blocks, tumbles, Phase(name, '', left_s),
                                        hold, turning[index])
                left_s -= limits[index]
                if at_plateau is not None:
                    # --- per-plateau hook: extra measurements at this chamber plateau ---
                    triad.fixture = fixture_profile(2, 1)
                    extra.append((yield from stage(at_plateau(triad, index, chamber_c), name,
                                                   left_s)))
        # Back to the ambient it had; soak until the on-board reading has returned.
        triad.thermal.set_ambient(**previous)
        if soak:
            soak_s = yield from soak_back(triad, settings, blocks, start_reading)
    yield Phase('fitting', 'bias, scale factor, misalignment, K2', 0.0)
    compensation, points, lag = fit_multiposition(blocks, tumbles, settings)
    end_ns = sensor_time_ns(triad)
    if settings.apply:
        state.temperature = compensation.to_dict()
        triad.temperature_compensator = compensation
        triad.temperature_compensation = True
        state.updated_at_ns = end_ns
    times_ns, v_temp, force, output = (np.array(column) for column in zip(*blocks))
    raw = {'time_ns': times_ns, 'v_temp': v_temp, 'temperature': triad.thermal.reading_c(v_temp),
           'force': force, 'output': output, 'zero': output - force}
    return TemperatureResult('temperature', asdict(settings), compensation, points, raw,
                             settings.apply, soak_s, start_ns, end_ns, extra, lag)


def temperature_calibration(triad, state, settings=TemperatureSettings()):
    """
    Run :func:`temperature_schedule`, with the I_ref steps at every plateau (generator).

    Same protocol as :func:`qfa_ros.calibration.schedule.run_schedule`. With
    ``settings.reference_steps`` the hook is
    :func:`qfa_ros.calibration.reference_tc.plateau_step` (it sees the sensor through a
    :class:`~qfa_ros.calibration.schedule.SensorPort` only) and, after the chamber
    program, :func:`~qfa_ros.calibration.reference_tc.fit_plateau_steps` fits the
    coefficient and, with ``settings.apply``, stores it in ``state.reference_tc_ppm``.
    Returns ``(TemperatureResult,)`` or ``(TemperatureResult, EstimationResult)`` (kind
    ``reference_tc``).
    """
    if not settings.reference_steps:
        result = yield from temperature_schedule(triad, state, settings)
        return (result,)
    result = yield from temperature_schedule(triad, state, settings, plateau_step)
    steps = fit_plateau_steps(result.plateau_extra, state, settings.apply,
                              result.start_ns, result.end_ns)
    return result, steps


def fit_multiposition(blocks, tumbles, settings):
    """
    Fit bias, scale factor, misalignment and K2 per axis from the tumble blocks.

    The on-board reading lags the proof mass (the probe's lag: a second or two); while the
    chamber moves it reads a temperature the mass had a moment before, which biases the
    fits by the curves' slopes times the lag times the rate (40 ppm of scale factor on a
    steep axis when the body follows the chamber within seconds). So first the lag is
    estimated from the blocks (:func:`estimate_probe_lag`) and every block's reading moved
    to the mass's, ``V + tau dV/dt`` (nothing changes on a settled plateau, where the
    compensation is used). Then, per axis, one linear least squares over every block:
    ``y_i = B(V) + (1 + S(V)) f_i + M_ij f_j + M_il f_l + K2_i f_i^2`` with ``B`` and
    ``S`` Chebyshev series in the scaled V (degrees 6 and 4): the constant ``M`` and
    ``K2``. Then per tumble, with those removed, ``y_i - f_i = b + b' dV + s f_i +
    s' dV_pair f_i`` (``dV = V - V_mean``, ``dV_pair = V - V_pair``, ``V_pair`` the mean
    reading of the axis's +-g pair: the temperature moves during a tumble): the bias at
    the tumble's mean reading, the scale-factor error at the pair's, where the pair's
    difference fixes it whatever ``s'`` (at the tumble's mean it would be carried there by
    ``s'``, which two blocks read at almost one temperature leave undetermined: thousands
    of ppm at a plateau's end). Last, Liu, Li and Shen's double exponential (linear
    baseline) through the tumbles' bias and through the scale-factor correction
    ``1/(1 + s) - 1``, and their fixed-point compensators.
    """
    if len(tumbles) < 10:
        raise EstimationError(f'only {len(tumbles)} tumbles: lengthen period_s')
    times_ns, v, force, output = (np.array(column) for column in zip(*blocks))
    rate = reading_rate(times_ns * 1e-9, v)
    lag = estimate_probe_lag(v, rate, force, output)
    v = v + lag * rate
    misalignment, k2, _ = global_fit(v, force, output)
    corrected = output - force @ misalignment.T - k2 * force ** 2
    n = len(POSITIONS)
    v_mean = np.array([v[first:first + n].mean() for first in tumbles])
    v_pair, bias, scale = (np.empty((len(tumbles), 3)) for _ in range(3))
    for k, first in enumerate(tumbles):
        rows = slice(first, first + n)
        vv = v[rows]
        for i in range(3):
            f = force[rows, i]
            dv = vv - vv.mean()
            # The scale factor at the +-g pair's own mean reading: the pair's difference
            # gives it whatever s' is. Taken at the tumble's mean instead, it is carried
            # there by s', which two blocks read at almost one temperature do not fix.
            pair = vv[f != 0].mean()
            design = np.column_stack([np.ones(n), dv, f, (vv - pair) * f])
            c = np.linalg.lstsq(design, corrected[rows, i] - f, rcond=None)[0]
            bias[k, i], scale[k, i], v_pair[k, i] = c[0], c[2], pair
    try:
        bias_cal = [calibrate_zero_bias(v_mean, bias[:, i], m_bits=settings.m_bits,
                                        n_bins=settings.bins, baseline=True) for i in range(3)]
        scale_cal = [calibrate_zero_bias(v_pair[:, i], 1.0 / (1.0 + scale[:, i]) - 1.0,
                                         m_bits=settings.sf_m_bits, n_bins=settings.bins,
                                         baseline=True) for i in range(3)]
    except ValueError as error:
        raise EstimationError(f'temperature fit failed: {error}') from error
    points = {'time_ns': times_ns[np.asarray(tumbles) + n - 1], 'v_temp': v_mean}
    for i, name in enumerate(AXES):
        points[f'bias_{name}'] = bias[:, i]
    for i, name in enumerate(AXES):
        points[f'compensated_{name}'] = bias[:, i] - bias_cal[i].compensator().evaluate_fixed(
            v_mean, clip=True)
    for i, name in enumerate(AXES):
        points[f'scale_{name}'] = scale[:, i]
        points[f'v_temp_scale_{name}'] = v_pair[:, i]
    return ThermalCompensation(bias_cal, scale_cal, misalignment, k2), points, lag
