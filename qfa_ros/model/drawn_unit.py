r"""
A unit is a draw: one accelerometer triad within datasheet spreads.

Real triads of one type differ: turn-on bias, the shape of the thermal bias and
scale-factor curves, aging, misalignment, K2. :func:`draw_unit` draws them from a seed
(``numpy.random.default_rng([UNIT_STREAM, seed])``: independent of the noise streams
that the same seed drives) within :class:`UnitSpread`; :meth:`Unit.configure` writes
them into a :class:`~qfa_ros.model.triad_config.TriadConfig`. The same seed gives the same
unit; two seeds, two units.

Spreads (``DESIGN.md`` table, QA-2000-class datasheets, Ran et al. 2019) and, where no public
figure exists, this project's estimate (marked *estimate*):

=============================  =============================================  ============
quantity                       draw                                           source
=============================  =============================================  ============
turn-on bias at 25 degC         normal, sigma 1.3 mg, clipped to +-3.9 mg       datasheet < 4 mg
thermal bias slope              max \|db/dT| over -40..70 degC uniform in       datasheet
                                [0.2, 0.8] x 30 ug/degC                         < 30 ug/degC
thermal bias shape              two exponentials of V_temp plus linear,         estimate
                                quadratic and cubic terms (mixed weights)
scale-factor slope              max \|de/dT| uniform in [0.2, 0.8] x 180        datasheet
                                ppm/degC; quadratic and cubic terms              < 180 ppm/degC
scale factor at 25 degC         normal, sigma 300 ppm, clipped to +-1000 ppm    estimate
bias aging                      uniform in +-100 ug/year                        Ran 2019; < 160 ug
scale-factor aging              uniform in +-100 ppm/year (magnet, ``b``)       Ran 2019; < 310 ppm
K2                              magnitude uniform in [10, 30] ug/g^2,           datasheet
                                random sign
misalignment (off-diagonal)     normal, sigma 0.3 mrad, clipped to +-1 mrad     estimate
bias hysteresis                 uniform in [0, 3] ug (heating vs cooling)       estimate
temperature-probe lag           uniform in [0.5, 2] s (sensor chip bonded       estimate
                                to the accelerometer block)
I_ref temperature coefficient   normal, mean 30, sigma 10 ppm/degC, clipped     estimate
                                to [0, 60] (a precision reference and sense
                                resistor; the ``paper`` profile's 30 is the
                                type's mean)
forward-chain coefficients      normal around the ``paper`` profile's type       estimate
(DA1 reference, ``k_tz``,       figures 20, 7, 6 ppm/degC, sigma 7, 3, 3,
``k_amp``)                      clipped to +-3 sigma
=============================  =============================================  ============

The component coefficients act only where the error profile switches the source on
(:meth:`Unit.install_error_profile`: the profile says which sources act, the unit how
much); they come from their own generator stream (the child ``'unit.component_tcs'`` of
``SeedSequence([UNIT_STREAM, seed])``, :mod:`qfa_ros.model.random_streams`), so adding them moved
no other draw of a seed.
"""

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.polynomial.polynomial import polyval

from qfa_ros.model import random_streams
from qfa_ros.model.constants import MICRO_G, PPM, STANDARD_GRAVITY
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import AXES, QfaTriad

UNIT_STREAM = 0x756E6974
"""First word of the unit draw's seed sequence (keeps it apart from the noise streams)."""

FORWARD_TC_COMPONENTS = ('v_da1_ref', 'k_tz', 'k_amp')
"""Forward-chain components whose temperature coefficients a unit draws."""

_T_LOW, _T_HIGH, _T0 = -40.0, 70.0, 25.0
_HALF = 55.0
"""Half the -40..70 degC range: the polynomial shapes are drawn in ``x = (T - 25)/55``."""


@dataclass(frozen=True)
class UnitSpread:
    """
    Spreads of the unit draw (see the module table for the sources).

    Attributes are named with their unit; ``*_max`` bound a draw, ``*_sigma`` is a
    standard deviation, ``*_range`` a uniform interval.
    """

    turn_on_bias_sigma_ug: float = 1300.0
    turn_on_bias_max_ug: float = 3900.0
    bias_slope_max_ug_per_c: float = 30.0
    sf_slope_max_ppm_per_c: float = 180.0
    slope_fraction_range: tuple = (0.2, 0.8)
    sf_offset_sigma_ppm: float = 300.0
    sf_offset_max_ppm: float = 1000.0
    bias_aging_max_ug_per_year: float = 100.0
    sf_aging_max_ppm_per_year: float = 100.0
    k2_range_ug_per_g2: tuple = (10.0, 30.0)
    misalignment_sigma_mrad: float = 0.3
    misalignment_max_mrad: float = 1.0
    hysteresis_max_ug: float = 3.0
    probe_tau_range_s: tuple = (0.5, 2.0)
    i_ref_tc_mean_ppm_per_c: float = 30.0
    i_ref_tc_sigma_ppm_per_c: float = 10.0
    forward_tc_mean_ppm_per_c: tuple = (20.0, 7.0, 6.0)
    forward_tc_sigma_ppm_per_c: tuple = (7.0, 3.0, 3.0)
    tc_clip_sigmas: float = 3.0

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = np.asarray(getattr(self, field.name), dtype=float)
            if not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(f'{field.name} must be finite and >= 0')
        for name in ('slope_fraction_range', 'k2_range_ug_per_g2', 'probe_tau_range_s'):
            low, high = getattr(self, name)
            if low > high:
                raise ValueError(f'{name} must be (low, high) with low <= high')


@dataclass(frozen=True)
class Unit:
    """
    One drawn triad (SI units unless named otherwise; per axis x, y, z).

    Attributes
    ----------
    seed : int
        The seed it was drawn from.
    turn_on_bias : tuple
        Zero bias at 25 degC [m/s^2].
    bias_alpha, bias_beta, bias_poly : tuple
        Thermal bias curve, :class:`ThermalConfig` ``mixed`` model (it includes the
        turn-on bias: ``b(25 degC) = turn_on_bias``).
    sf_offset_ppm, sf_tc_ppm_per_c, sf_tc2_ppm_per_c2, sf_tc3_ppm_per_c3 : tuple
        Scale-factor error curve (:class:`ThermalConfig`).
    hysteresis_m_s2 : tuple
        Heating/cooling bias hysteresis amplitude [m/s^2].
    probe_tau_s : float
        Lag of the on-board temperature sensor behind the proof mass [s].
    bias_aging_per_year : tuple
        Bias aging [m/s^2 per year of aged sensor time].
    sf_aging_ppm_per_year : tuple
        Scale-factor aging, on the magnet flux ``b`` [ppm/year].
    k2 : tuple
        Second-order coefficient [1/(m/s^2)].
    misalignment : tuple
        3x3 cross-coupling (zero diagonal) [rad].
    i_ref_tc_ppm_per_c : tuple
        Temperature coefficient of each axis's I_ref source [ppm/degC].
    forward_tc_ppm_per_c : tuple
        Per :data:`FORWARD_TC_COMPONENTS` the coefficient of each axis [ppm/degC].
    """

    seed: int
    turn_on_bias: tuple
    bias_alpha: tuple
    bias_beta: tuple
    bias_poly: tuple
    sf_offset_ppm: tuple
    sf_tc_ppm_per_c: tuple
    sf_tc2_ppm_per_c2: tuple
    sf_tc3_ppm_per_c3: tuple
    hysteresis_m_s2: tuple
    probe_tau_s: float
    bias_aging_per_year: tuple
    sf_aging_ppm_per_year: tuple
    k2: tuple
    misalignment: tuple
    i_ref_tc_ppm_per_c: tuple = (0.0, 0.0, 0.0)
    forward_tc_ppm_per_c: tuple = ((0.0, 0.0, 0.0),) * len(FORWARD_TC_COMPONENTS)

    def thermal_config(self, base=None):
        """Return ``base`` (default :class:`ThermalConfig`) with this unit's curves."""
        base = ThermalConfig() if base is None else base
        return dataclasses.replace(
            base, bias_model='mixed', bias_alpha=self.bias_alpha, bias_beta=self.bias_beta,
            bias_poly=self.bias_poly, hysteresis_m_s2=self.hysteresis_m_s2,
            probe_tau_s=self.probe_tau_s, sf_offset_ppm=self.sf_offset_ppm,
            sf_tc_ppm_per_c=self.sf_tc_ppm_per_c, sf_tc2_ppm_per_c2=self.sf_tc2_ppm_per_c2,
            sf_tc3_ppm_per_c3=self.sf_tc3_ppm_per_c3)

    def configure(self, config, extra_misalignment=None):
        """
        Return ``config`` (a TriadConfig) as this unit.

        The thermal curves replace those of ``config.thermal`` (its ambient is kept; a
        config without a thermal model gets the turn-on bias as its constant bias);
        ``config.bias`` and ``config.k2`` are added to the unit's (a user's extra);
        ``extra_misalignment`` (3x3 [rad], e.g. the mounting) is added to the unit's.
        """
        misalignment = np.asarray(self.misalignment) + np.asarray(config.misalignment)
        if extra_misalignment is not None:
            misalignment = misalignment + np.asarray(extra_misalignment, dtype=float)
        bias = np.asarray(config.bias, dtype=float)
        thermal = None
        if config.thermal is not None:
            thermal = self.thermal_config(config.thermal)
        else:
            bias = bias + np.asarray(self.turn_on_bias)
        return dataclasses.replace(
            config, thermal=thermal, bias=tuple(bias.tolist()),
            k2=tuple((np.asarray(config.k2) + np.asarray(self.k2)).tolist()),
            misalignment=tuple(map(tuple, misalignment.tolist())))

    def install_aging(self, triad):
        """Write this unit's bias and scale-factor (magnet ``b``) aging into ``triad``."""
        triad.drift.set_bias_aging(self.bias_aging_per_year)
        for axis in range(len(AXES)):
            triad.drift.set_aging(axis, 'b', self.sf_aging_ppm_per_year[axis])

    def install_error_profile(self, triad, profile):
        """
        Write ``profile`` (an ErrorProfile) with this unit's coefficients into ``triad``.

        ``profile`` is a :class:`~qfa_ros.model.error_profiles.ErrorProfile`: it switches the
        sources on (``ideal`` leaves every one off); each forward-chain component it
        names and its I_ref source (when its coefficient is not zero) take this unit's
        coefficients instead of the type figure.
        """
        install_component_tcs(triad, profile, self.i_ref_tc_ppm_per_c,
                              self.forward_tc_ppm_per_c)

    def triad(self, config, rng=None, profile=None, extra_misalignment=None, start_ns=0):
        """Return a :class:`QfaTriad` that is this unit (:meth:`configure`, aging)."""
        triad = QfaTriad(self.configure(config, extra_misalignment), rng=rng, profile=profile,
                         start_ns=start_ns)
        self.install_aging(triad)
        return triad

    def zero_bias(self, temperature_c):
        """Return the thermal bias (..., 3) [m/s^2] at body temperatures (no hysteresis)."""
        return _mixed_bias(np.asarray(temperature_c, dtype=float)[..., None],
                           np.asarray(self.bias_alpha), np.asarray(self.bias_beta),
                           np.asarray(self.bias_poly))

    def scale_factor_error(self, temperature_c):
        """Return the scale-factor error (..., 3) [1] at body temperatures."""
        d = np.asarray(temperature_c, dtype=float)[..., None] - _T0
        tc1, tc2, tc3 = (np.asarray(c) for c in (self.sf_tc_ppm_per_c, self.sf_tc2_ppm_per_c2,
                                                  self.sf_tc3_ppm_per_c3))
        return PPM * (np.asarray(self.sf_offset_ppm) + d * (tc1 + d * (tc2 + d * tc3)))


def _voltage(temperature_c):
    # the default on-board sensor: 0.75 V at 25 degC, 10 mV/degC (ThermalConfig)
    return 0.75 + 0.010 * (temperature_c - _T0)


def _mixed_bias(t, alpha, beta, poly):
    v = _voltage(t)
    value = alpha[:, 0] * np.exp(beta[:, 0] * v) + alpha[:, 1] * np.exp(beta[:, 1] * v)
    return value + polyval(t - _T0, poly.T, tensor=False)


def _slope_scale(curve, grid, target):
    """Return the factor that makes ``max |d curve / dT|`` over ``grid`` equal ``target``."""
    slope = np.abs(np.gradient(curve, grid)).max()
    return target / slope if slope > 0 else 0.0


def draw_unit(seed, spread=None):
    """
    Draw one unit from ``seed`` within ``spread`` (default :class:`UnitSpread`).

    Parameters
    ----------
    seed : int
        Non-negative integer; the same seed gives the same unit.
    spread : UnitSpread, optional
        The spreads.

    Returns
    -------
    Unit
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f'seed must be a non-negative integer, got {seed!r}')
    spread = UnitSpread() if spread is None else spread
    rng = np.random.default_rng([UNIT_STREAM, int(seed)])
    grid = np.linspace(_T_LOW, _T_HIGH, 221)
    x = (grid - _T0) / _HALF
    v = _voltage(grid)
    alpha, beta, poly = np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 4))
    sf = np.zeros((3, 4))
    turn_on = np.clip(rng.normal(0.0, spread.turn_on_bias_sigma_ug, 3),
                      -spread.turn_on_bias_max_ug, spread.turn_on_bias_max_ug) * MICRO_G
    for axis in range(3):
        # Bias: two exponentials of V_temp with mixed weights plus a cubic in x.
        sign = rng.choice((-1.0, 1.0))
        beta[axis] = (sign * rng.uniform(1.0, 3.5), -sign * rng.uniform(0.3, 1.5))
        weights = rng.uniform(0.3, 1.0, 2) * rng.choice((-1.0, 1.0), 2)
        exps = np.exp(np.outer(v - 0.75, beta[axis]))
        spans = np.ptp(exps, axis=0)
        cubic = rng.uniform(-1.0, 1.0, 3) * (1.0, 0.35, 0.2)
        curve = exps @ (weights / spans) + cubic[0] * x + cubic[1] * x ** 2 + cubic[2] * x ** 3
        target = rng.uniform(*spread.slope_fraction_range) * spread.bias_slope_max_ug_per_c
        scale = _slope_scale(curve, grid, target * MICRO_G)
        alpha[axis] = weights / spans * scale * np.exp(-0.75 * beta[axis])
        poly[axis, 1:] = scale * cubic / _HALF ** np.arange(1, 4)
        at_t0 = _mixed_bias(np.array([[_T0]]), alpha[axis:axis + 1], beta[axis:axis + 1],
                            poly[axis:axis + 1])[0, 0]
        poly[axis, 0] = turn_on[axis] - at_t0
        # Scale factor: mostly linear, with quadratic and cubic terms.
        shape = rng.uniform(0.5, 1.0) * rng.choice((-1.0, 1.0)), \
            rng.uniform(-0.3, 0.3), rng.uniform(-0.15, 0.15)
        curve = shape[0] * x + shape[1] * x ** 2 + shape[2] * x ** 3
        target = rng.uniform(*spread.slope_fraction_range) * spread.sf_slope_max_ppm_per_c
        scale = _slope_scale(curve, grid, target)
        sf[axis, 1:] = scale * np.asarray(shape) / _HALF ** np.arange(1, 4)
    sf[:, 0] = np.clip(rng.normal(0.0, spread.sf_offset_sigma_ppm, 3),
                       -spread.sf_offset_max_ppm, spread.sf_offset_max_ppm)
    hysteresis = rng.uniform(0.0, spread.hysteresis_max_ug, 3) * MICRO_G
    probe_tau = float(rng.uniform(*spread.probe_tau_range_s))
    bias_aging = rng.uniform(-1.0, 1.0, 3) * spread.bias_aging_max_ug_per_year * MICRO_G
    sf_aging = rng.uniform(-1.0, 1.0, 3) * spread.sf_aging_max_ppm_per_year
    k2 = rng.uniform(*spread.k2_range_ug_per_g2, 3) * rng.choice((-1.0, 1.0), 3) \
        * MICRO_G / STANDARD_GRAVITY ** 2
    misalignment = np.clip(rng.normal(0.0, spread.misalignment_sigma_mrad, (3, 3)),
                           -spread.misalignment_max_mrad, spread.misalignment_max_mrad) * 1e-3
    np.fill_diagonal(misalignment, 0.0)
    i_ref_tc, forward_tc = draw_component_tcs(
        random_streams.seed_sequence(np.random.SeedSequence([UNIT_STREAM, int(seed)]),
                              'unit.component_tcs'),
        spread)

    def rows(array):
        return tuple(tuple(float(v) for v in row) for row in array)

    return Unit(seed=int(seed), turn_on_bias=tuple(turn_on.tolist()), bias_alpha=rows(alpha),
                bias_beta=rows(beta), bias_poly=rows(poly),
                sf_offset_ppm=tuple(sf[:, 0].tolist()), sf_tc_ppm_per_c=tuple(sf[:, 1].tolist()),
                sf_tc2_ppm_per_c2=tuple(sf[:, 2].tolist()),
                sf_tc3_ppm_per_c3=tuple(sf[:, 3].tolist()),
                hysteresis_m_s2=tuple(hysteresis.tolist()), probe_tau_s=probe_tau,
                bias_aging_per_year=tuple(bias_aging.tolist()),
                sf_aging_ppm_per_year=tuple(sf_aging.tolist()), k2=tuple(k2.tolist()),
                misalignment=rows(misalignment), i_ref_tc_ppm_per_c=tuple(i_ref_tc.tolist()),
                forward_tc_ppm_per_c=rows(forward_tc))


def install_component_tcs(triad, profile, i_ref_tc_ppm_per_c, forward_tc_ppm_per_c):
    """
    Write ``profile`` into ``triad`` with per-axis component coefficients [ppm/degC].

    ``profile`` (an :class:`~qfa_ros.model.error_profiles.ErrorProfile`) says which sources act:
    each forward-chain component it names (:data:`FORWARD_TC_COMPONENTS` rows of
    ``forward_tc_ppm_per_c``) and its I_ref source (when its coefficient is not zero)
    take the given coefficients instead of the type figure; ``ideal`` leaves all off.
    """
    profile.apply(triad)
    for axis in range(len(AXES)):
        for component, row in zip(FORWARD_TC_COMPONENTS, forward_tc_ppm_per_c):
            if component in profile.forward_tc_ppm:
                triad.drift.set_temperature_coefficient(axis, component, row[axis])
        if profile.i_ref_tc_ppm != 0.0:
            triad.drift.set_temperature_coefficient(axis, 'i_ref', i_ref_tc_ppm_per_c[axis])


def draw_component_tcs(seed_sequence, spread=None):
    """
    Draw the I_ref and forward-chain temperature coefficients of one unit [ppm/degC].

    Parameters
    ----------
    seed_sequence : numpy.random.SeedSequence
        The stream (the child ``'unit.component_tcs'`` of the unit's seed sequence:
        :func:`draw_unit`'s ``SeedSequence([UNIT_STREAM, seed])``, a fleet unit's own).
    spread : UnitSpread, optional
        The spreads.

    Returns
    -------
    i_ref : float64[3]
        Per axis.
    forward : float64[len(FORWARD_TC_COMPONENTS), 3]
        Per component and axis.
    """
    spread = UnitSpread() if spread is None else spread
    rng = np.random.default_rng(seed_sequence)

    def clipped(mean, sigma, size):
        mean, sigma = np.asarray(mean, float), np.asarray(sigma, float)
        limit = spread.tc_clip_sigmas * sigma
        return mean + np.clip(rng.normal(0.0, 1.0, size) * sigma, -limit, limit)

    i_ref = clipped(spread.i_ref_tc_mean_ppm_per_c, spread.i_ref_tc_sigma_ppm_per_c, 3)
    forward = clipped(np.asarray(spread.forward_tc_mean_ppm_per_c)[:, None],
                      np.asarray(spread.forward_tc_sigma_ppm_per_c)[:, None],
                      (len(FORWARD_TC_COMPONENTS), 3))
    return i_ref, forward
