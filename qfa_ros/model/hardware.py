"""Nominal hardware of one QFA axis and the loop gains it implies (Ran et al. 2019, eq. 1-13)."""

from dataclasses import asdict, dataclass, fields, replace
import numbers

from qfa_ros.model import checks
from qfa_ros.model.constants import STANDARD_GRAVITY

FORWARD_COMPONENTS = ('k1', 'c_ref', 'v_da1_ref', 'k_tz', 'k_amp', 'v_ad_ref')
"""Forward-channel drift terms of Ran et al. 2019, eq. 6-8 (relative, dimensionless)."""

FEEDBACK_COMPONENTS = ('v_da2_ref', 'k_vi', 'l_coil', 'b')
"""Feedback-channel drift terms of Ran et al. 2019, eq. 9-13 (relative, dimensionless)."""

REFERENCE_COMPONENTS = ('i_ref',)
"""Drift of the constant current source I_ref (Ran et al. 2019, Fig. 7)."""

DRIFT_COMPONENTS = FORWARD_COMPONENTS + FEEDBACK_COMPONENTS + REFERENCE_COMPONENTS


@dataclass(frozen=True)
class AxisHardware:
    r"""
    Nominal hardware of one digital closed-loop QFA axis (SI units).

    The defaults are derived from the public figures of DESIGN.md section 2; the
    derivation of each is in ``docs/model.md``. Signal path (Ran et al. 2019, Fig. 2)::

        M_in = K0 a                          K0 = m L            [kg m]
        J th'' + C th' + D th = M_in - M_fb  pendulum            [N m]
        dC   = k1 th                         k1 = 2 C0 l / d     [F/rad]
        dV   = k_CV dC                       k_CV = V_IN k_amp k_b / (4 C0)   [V/F]
        V_IN = N_FPGA V_DA1_ref / 2^(N_DA1-1) k_tz               [V]
        e    = round(k_AD k_demo dV)         k_AD = 2^(N_AD-1) / V_AD_ref     [count/V]
        N_PI = D(z) e = k(D(z)) D0(z) e      integer PID          [count]
        I    = N_PI k_DA2 k_VI               k_DA2 = V_DA2_ref / 2^(N_DA2-1), k_VI = 1/R
        M_fb = k_t I                         k_t = B L_coil L     [N m/A]

    with ``V_DA2_ref = N_VREF K_DA0`` (eq. 30). In steady state
    ``N_PI k_DA2 k_VI k_t = K0 a`` (eq. 13), so the scale factor depends only on the
    feedback gain. The open-loop bridge (eq. 16) outputs
    ``dV = V_IN k_amp r_ol`` independent of the pendulum position and of ``k1``.

    Attributes
    ----------
    pendulum_mass, pendulum_arm : float
        m [kg] and the arm L [m] of the quartz pendulum; K0 = m L, J = m L^2.
    damping : float
        Squeeze-film damping C [N m s/rad].
    damping_ratio : float
        zeta = C / (2 sqrt(J D)); sets the flexure stiffness D [N m/rad].
    stop_angle : float
        Mechanical stop of the pendulum [rad].
    pickoff_c0, pickoff_gap, pickoff_arm : float
        Capacitance at rest C0 [F], plate gap d [m], capacitor arm l [m].
    n_fpga, n_da1_bits, v_da1_ref, k_tz, k_amp, k_demo : float
        Modulation amplitude word, DA1 bits and reference [V], follow-up amplifier
        gain, instrumentation amplifier gain, demodulation gain.
    open_loop_bridge_ratio : float
        Bridge ratio ``1 - C_ref1/(C_ref1 + C_ref2)`` seen with the pendulum on its
        stop (eq. 16), dimensionless.
    n_ad_bits, v_ad_ref : float
        ADC bits and reference [V].
    n_da2_bits, v_da2_ref, n_da0_bits, v_da0_ref : float
        Feedback DA bits and reference [V]; the reference DA0 that provides it.
    sense_resistor : float
        V/I sampling resistor R [ohm].
    magnet_flux_density : float
        Effective B [T]; the coil length follows from the scale factor.
    scale_factor : float
        Torquer current per input [A/(m/s^2)] (1.2 mA/g).
    i_ref : float
        Constant current source [A] (Ran et al. 2019, Fig. 7).
    adsorption_g : float
        Electrostatic adsorption moment that latches the open-loop pendulum on its
        stop, as an equivalent input [g].
    input_range_g : float
        Rated input range [g]; beyond it the output is flagged saturated.
    """

    pendulum_mass: float = 0.7e-3
    pendulum_arm: float = 9.0e-3
    damping: float = 1.69e-4
    damping_ratio: float = 12.0
    stop_angle: float = 2.0e-3
    pickoff_c0: float = 12e-12
    pickoff_gap: float = 25e-6
    pickoff_arm: float = 7.0e-3
    n_fpga: int = 16384
    n_da1_bits: int = 16
    v_da1_ref: float = 2.5
    k_tz: float = 2.0
    k_amp: float = 4.0
    k_demo: float = 1.0
    open_loop_bridge_ratio: float = 0.28
    n_ad_bits: int = 24
    v_ad_ref: float = 5.0
    n_da2_bits: int = 24
    v_da2_ref: float = 5.0
    n_da0_bits: int = 24
    v_da0_ref: float = 6.0
    sense_resistor: float = 58.0
    magnet_flux_density: float = 0.4
    scale_factor: float = 1.2e-3 / STANDARD_GRAVITY
    i_ref: float = 0.737237e-3
    adsorption_g: float = 5.0
    input_range_g: float = 50.0

    def __post_init__(self):
        for field in fields(self):
            value = getattr(self, field.name)
            checks.finite(field.name, value, types=numbers.Real, bool_ok=False)
            if value <= 0:
                raise ValueError(f'{field.name} must be positive, got {value!r}')
        for name, low, high in (('n_da1_bits', 4, 32), ('n_ad_bits', 4, 24),
                                ('n_da2_bits', 8, 28), ('n_da0_bits', 8, 28)):
            value = getattr(self, name)
            if int(value) != value or not low <= value <= high:
                raise ValueError(f'{name} must be an integer in [{low}, {high}], got {value!r}')
        if self.n_fpga >= 2 ** (self.n_da1_bits - 1):
            raise ValueError('n_fpga must be below the DA1 full scale 2^(n_da1_bits-1)')
        if self.damping_ratio <= 1.0:
            raise ValueError('damping_ratio must exceed 1 (the QFA pendulum is overdamped)')
        if self.v_da2_ref >= self.v_da0_ref:
            raise ValueError('v_da2_ref must be below v_da0_ref (DA0 provides it)')
        if self.pickoff_arm * self.stop_angle >= self.pickoff_gap:
            raise ValueError('stop_angle must keep the plates apart: pickoff_arm * stop_angle '
                             '< pickoff_gap')

    def replace(self, **changes):
        """Return a copy with ``changes`` applied (validated)."""
        return replace(self, **changes)

    def to_dict(self):
        """Return the fields as a plain dict."""
        return asdict(self)

    # Derived mechanical constants ---------------------------------------------------------
    @property
    def pendulosity(self):
        """K0 = m L [kg m]."""
        return self.pendulum_mass * self.pendulum_arm

    @property
    def inertia(self):
        """J = m L^2 [kg m^2]."""
        return self.pendulum_mass * self.pendulum_arm ** 2

    @property
    def stiffness(self):
        """D from the damping ratio: D = (C / (2 zeta))^2 / J [N m/rad]."""
        return (self.damping / (2.0 * self.damping_ratio)) ** 2 / self.inertia

    @property
    def k_pickoff(self):
        """k1 = 2 C0 l / d [F/rad] (Ran et al. 2019, section II-B-2)."""
        return 2.0 * self.pickoff_c0 * self.pickoff_arm / self.pickoff_gap

    @property
    def torquer_gain(self):
        """k_t = B L_coil L = K0 / SF [N m/A] (eq. 11-12)."""
        return self.pendulosity / self.scale_factor

    @property
    def coil_length(self):
        """Effective coil length L_coil = k_t / (B L) [m]."""
        return self.torquer_gain / (self.magnet_flux_density * self.pendulum_arm)

    @property
    def da0_gain(self):
        """K_DA0 = V_DA0_ref / 2^N_DA0 [V/count] (eq. 30)."""
        return self.v_da0_ref / 2 ** self.n_da0_bits

    @property
    def n_vref(self):
        """Nominal DA0 word N_VREF giving v_da2_ref (eq. 30) [count]."""
        return int(round(self.v_da2_ref / self.da0_gain))

    @property
    def da2_full_scale(self):
        """Largest DA2 command magnitude 2^(N_DA2-1) - 1 [count]."""
        return 2 ** (self.n_da2_bits - 1) - 1

    @property
    def adc_full_scale(self):
        """Largest ADC code magnitude 2^(N_AD-1) - 1 [count]."""
        return 2 ** (self.n_ad_bits - 1) - 1


@dataclass(frozen=True)
class LoopGains:
    """
    Effective (drifted) loop gains of one axis, recomputed when drift changes.

    Attributes
    ----------
    k_sense : float
        Closed-loop pick-off chain k1 k_CV k_AD k_demo [count/rad].
    open_loop_counts_per_fpga : float
        Open-loop ADC output per unit N_FPGA, eq. 16 times k_AD k_demo [count].
    k_da2_vi : float
        k_DA2 k_VI [A/count] (with V_DA2_ref = N_VREF K_DA0).
    k_t : float
        Torquer gain [N m/A].
    i_ref : float
        Constant current source [A].
    """

    k_sense: float
    open_loop_counts_per_fpga: float
    k_da2_vi: float
    k_t: float
    i_ref: float

    @property
    def feedback_gain(self):
        """k_fb = k_DA2 k_VI k_t [N m/count] (eq. 13)."""
        return self.k_da2_vi * self.k_t


def loop_gains(hw, drift, n_fpga, n_vref, open_loop_cref_sensitivity=1.0):
    """
    Return the effective :class:`LoopGains` of ``hw`` under relative ``drift``.

    Every block carries its own ``(1 + delta)`` exactly as Ran et al. 2019 write it:
    ``k1 (1 + dk1)``, ``k_CV (1 + dC_ref)(1 + dV_DA1)(1 + dk_tz)(1 + dk_amp)``,
    ``k_AD / (1 + dV_AD)``, ``V_DA2_ref (1 + dV_DA2)``, ``k_VI (1 + dk_VI)``,
    ``L_coil (1 + dL)``, ``B (1 + dB)``.

    Parameters
    ----------
    hw : AxisHardware
        Nominal hardware.
    drift : Mapping[str, float]
        Relative drift per component of :data:`DRIFT_COMPONENTS` (missing = 0).
    n_fpga : float
        Modulation amplitude word written to DA1.
    n_vref : float
        Reference word written to DA0.
    open_loop_cref_sensitivity : float
        How much of the reference-capacitor drift the open-loop bridge (eq. 16) sees
        relative to the closed-loop bridge (eq. 5); 1 is the paper's assumption.
    """
    def factor(name):
        return 1.0 + float(drift.get(name, 0.0))

    v_in = n_fpga * hw.v_da1_ref * factor('v_da1_ref') / 2 ** (hw.n_da1_bits - 1) \
        * hw.k_tz * factor('k_tz')
    k_ad = 2 ** (hw.n_ad_bits - 1) / (hw.v_ad_ref * factor('v_ad_ref'))
    amp = hw.k_amp * factor('k_amp')
    k_cv = v_in * amp * factor('c_ref') / (4.0 * hw.pickoff_c0)
    k_sense = hw.k_pickoff * factor('k1') * k_cv * k_ad * hw.k_demo
    c_ref_open = 1.0 + open_loop_cref_sensitivity * float(drift.get('c_ref', 0.0))
    open_loop_counts = v_in / n_fpga * amp * hw.open_loop_bridge_ratio * c_ref_open * k_ad \
        * hw.k_demo
    v_da2_ref = n_vref * hw.da0_gain * factor('v_da2_ref')
    k_da2_vi = v_da2_ref / 2 ** (hw.n_da2_bits - 1) / hw.sense_resistor * factor('k_vi')
    k_t = hw.torquer_gain * factor('l_coil') * factor('b')
    return LoopGains(k_sense=k_sense, open_loop_counts_per_fpga=open_loop_counts,
                     k_da2_vi=k_da2_vi, k_t=k_t, i_ref=hw.i_ref * factor('i_ref'))


def nominal_gains(hw):
    """Return the undrifted :class:`LoopGains` of ``hw``."""
    return loop_gains(hw, {}, hw.n_fpga, hw.n_vref)


def counts_to_accel(hw):
    """Return the nominal output scale k_fb / K0 [(m/s^2)/count]."""
    return nominal_gains(hw).feedback_gain / hw.pendulosity
