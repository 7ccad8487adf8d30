"""Controller design and the linearized loop of one QFA axis (discrete time, exact ZOH)."""

from dataclasses import dataclass, replace
import math

import numpy as np

from qfa_ros.model import checks
from qfa_ros.model.hardware import nominal_gains
from qfa_ros.model.noise import acceleration_variance

GAIN_FRAC_BITS = 32
"""Fraction bits of the controller gain word k(D(z))."""

COEF_FRAC_BITS = 20
"""Fraction bits of the lead and integrator coefficients."""

@dataclass(frozen=True)
class ControllerDesign:
    r"""
    Integer PID of one axis: a lead-compensated PI behind the scalar gain k(D(z)).

    Per loop step ``n`` (integer arithmetic, ``>>`` rounds to nearest)::

        x[n] = k_D e[n]                                  k_D = gain_word / 2^32
        y[n] = a1 y[n-1] + b0 x[n] + b1 x[n-1]           lead, coefficients / 2^20
        I[n] = I[n-1] + ki y[n]                          integrator, ki / 2^20
        N_PI[n] = clamp(y[n] + I[n])                     DA2 command

    so ``D(z) = k_D (b0 + b1 z^-1)/(1 - a1 z^-1) (1 + ki / (1 - z^-1))``. The lead
    zero cancels the pendulum's fast pole ``C/J``; the design places the loop
    crossover at ``crossover_hz``, the PI zero a decade below and the lead pole at
    ``lead_pole_ratio`` times the crossover. The command is applied one loop step
    later (``compute_delay`` = 1: ADC conversion and FPGA computation).

    Attributes
    ----------
    gain_word : int
        k(D(z)) in Q32 [count/count].
    lead_a1, lead_b0, lead_b1 : int
        Lead coefficients in Q20.
    integrator_gain : int
        ki in Q20 (= omega_i Ts).
    crossover_hz, integrator_ratio, lead_pole_ratio : float
        Design targets the words were computed from.
    """

    gain_word: int
    lead_a1: int
    lead_b0: int
    lead_b1: int
    integrator_gain: int
    crossover_hz: float
    integrator_ratio: float
    lead_pole_ratio: float

    @property
    def gain(self):
        """k(D(z)) as a number [count/count]."""
        return self.gain_word / 2 ** GAIN_FRAC_BITS

    def with_gain(self, gain):
        """Return the same controller with k(D(z)) = ``gain`` (quantized to Q32)."""
        if not checks.is_finite(gain) or gain <= 0:
            raise ValueError(f'controller gain must be positive and finite, got {gain!r}')
        return replace(self, gain_word=int(round(gain * 2 ** GAIN_FRAC_BITS)))

    def transfer(self, z):
        """Evaluate D(z) at complex points ``z`` (quantized coefficients)."""
        q = 2.0 ** COEF_FRAC_BITS
        zi = 1.0 / z
        lead = (self.lead_b0 / q + self.lead_b1 / q * zi) / (1.0 - self.lead_a1 / q * zi)
        return self.gain * lead * (1.0 + self.integrator_gain / q / (1.0 - zi))


def pendulum_matrices(hw, loop_period):
    """
    Return the exact ZOH discretization (Ad, Bd) of the pendulum.

    Continuous model ``J th'' + C th' + D th = M`` with state ``[th, th']`` and the
    moment ``M`` [N m] held over each loop period ``Ts`` [s]: ``Ad = e^(A Ts)``,
    ``Bd = int_0^Ts e^(A s) ds B`` (block matrix exponential).
    """
    if not loop_period > 0:
        raise ValueError(f'loop_period must be positive, got {loop_period!r}')
    a = np.array([[0.0, 1.0],
                  [-hw.stiffness / hw.inertia, -hw.damping / hw.inertia]])
    b = np.array([[0.0], [1.0 / hw.inertia]])
    block = np.zeros((3, 3))
    block[:2, :2] = a
    block[:2, 2:] = b
    phi = matrix_exponential(block * loop_period)
    return phi[:2, :2].copy(), phi[:2, 2].copy()


def matrix_exponential(matrix):
    """
    Return ``e^matrix`` of a small square matrix (Taylor series, scaling and squaring).

    The matrix is scaled by ``2^-s`` to a 1-norm of at most 1/2, its series summed to 20
    terms (remainder below 1e-24 of the result) and squared ``s`` times: equal to
    ``scipy.linalg.expm`` to rounding (``test_matrix_exponential_equals_scipy``). Not that
    one because its LAPACK solve wakes scipy's OpenBLAS helper thread, which then spins
    for ~0.1 s on the other core after every triad construction; numpy's 3x3 products
    run on the calling thread.
    """
    matrix = np.asarray(matrix, dtype=float)
    norm = np.linalg.norm(matrix, 1)
    squarings = max(0, math.ceil(math.log2(2.0 * norm))) if norm > 0 else 0
    scaled = matrix / 2.0 ** squarings
    result = np.eye(len(matrix))
    term = np.eye(len(matrix))
    for k in range(1, 21):
        term = term @ scaled / k
        result = result + term
    for _ in range(squarings):
        result = result @ result
    return result


def design_controller(hw, loop_rate_hz, crossover_hz=300.0, integrator_ratio=0.1,
                      lead_pole_ratio=6.0):
    """
    Design the integer controller of :class:`ControllerDesign` for ``hw``.

    The lead is the Tustin image of ``(1 + s/w_z)/(1 + s/w_p)`` with ``w_z = C/J``
    and ``w_p = lead_pole_ratio w_c``; k(D(z)) is then set so that the discrete
    loop gain is exactly 1 at ``crossover_hz``.
    """
    loop_rate_hz = checks.positive('loop_rate_hz', loop_rate_hz)
    ts = 1.0 / loop_rate_hz
    nyquist = loop_rate_hz / 2.0
    if not checks.is_finite(crossover_hz) or not 0 < crossover_hz < nyquist / 4:
        raise ValueError(f'crossover_hz must be in (0, {nyquist / 4:g}), got {crossover_hz!r}')
    if not checks.is_finite(integrator_ratio) or not 0 < integrator_ratio < 1:
        raise ValueError(f'integrator_ratio must be in (0, 1), got {integrator_ratio!r}')
    # An infinite lead pole is clamped below Nyquist: kept valid.
    if not (checks.is_finite(lead_pole_ratio) or lead_pole_ratio == math.inf) \
            or not 1 < lead_pole_ratio:
        raise ValueError(f'lead_pole_ratio must exceed 1, got {lead_pole_ratio!r}')
    w_c = 2 * math.pi * crossover_hz
    w_z = hw.damping / hw.inertia
    w_p = min(lead_pole_ratio * w_c, 0.9 * math.pi * loop_rate_hz)
    c_z, c_p = 2.0 / (w_z * ts), 2.0 / (w_p * ts)
    b0, b1, a1 = (1 + c_z) / (1 + c_p), (1 - c_z) / (1 + c_p), -(1 - c_p) / (1 + c_p)
    q = 2 ** COEF_FRAC_BITS
    unit = ControllerDesign(2 ** GAIN_FRAC_BITS, round(a1 * q), round(b0 * q), round(b1 * q),
                            round(integrator_ratio * w_c * ts * q), crossover_hz,
                            integrator_ratio, lead_pole_ratio)
    model = LinearLoop(hw, unit, loop_rate_hz)
    gain = 1.0 / abs(model.loop_gain(np.array([crossover_hz]))[0])
    return unit.with_gain(gain)


class LinearLoop:
    r"""
    Linearized discrete loop of one axis: plant, controller, delay, decimation.

    ``P(z)``: moment [N m] to ADC counts through the ZOH pendulum and ``k_sense``;
    the loop gain is ``L(z) = k_fb P(z) D(z) z^-1`` (``k_fb`` [N m/count]); the
    closed-loop response from input acceleration [m/s^2] to the command is
    ``H(z) = K0 P(z) D(z) / (1 + L(z))`` [count/(m/s^2)], and the published output
    [m/s^2] is ``H(z) s_nom A(z)`` with ``s_nom = k_fb,nom / K0`` and ``A(z)`` the
    averaging decimator of ``decimation`` loop steps.
    """

    def __init__(self, hw, controller, loop_rate_hz, gains=None):
        self.hw = hw
        self.controller = controller
        self.loop_period = 1.0 / loop_rate_hz
        self.gains = nominal_gains(hw) if gains is None else gains
        self.ad, self.bd = pendulum_matrices(hw, self.loop_period)

    def _plant(self, z):
        # C (zI - Ad)^-1 Bd for the angle output, written out for a 2x2 system.
        a = self.ad
        det = (z - a[0, 0]) * (z - a[1, 1]) - a[0, 1] * a[1, 0]
        angle = ((z - a[1, 1]) * self.bd[0] + a[0, 1] * self.bd[1]) / det
        return angle * self.gains.k_sense

    def _z(self, freq_hz):
        return np.exp(2j * np.pi * np.asarray(freq_hz, dtype=float) * self.loop_period)

    def _loop(self, z):
        # L(z) = k_fb P(z) D(z) z^-1 at points z of the unit circle.
        return self.gains.feedback_gain * self._plant(z) * self.controller.transfer(z) / z

    def loop_gain(self, freq_hz):
        """Return L(e^{jwTs}) at ``freq_hz`` (dimensionless)."""
        return self._loop(self._z(freq_hz))

    def closed_loop(self, freq_hz, decimation=1):
        """Return the output/input response [(m/s^2)/(m/s^2)] at ``freq_hz``."""
        z = self._z(freq_hz)
        response = self.hw.pendulosity * self._plant(z) * self.controller.transfer(z) \
            / (1.0 + self._loop(z))
        scale = nominal_gains(self.hw).feedback_gain / self.hw.pendulosity
        averaging = sum(z ** -k for k in range(decimation)) / decimation
        return response * scale * averaging

    def adc_response(self, freq_hz, decimation=1):
        """Return the published output per ADC code, ``s_nom D A / (1 + L)`` [(m/s^2)/count]."""
        z = self._z(freq_hz)
        averaging = sum(z ** -k for k in range(decimation)) / decimation
        scale = nominal_gains(self.hw).feedback_gain / self.hw.pendulosity
        return scale * self.controller.transfer(z) * averaging / (1.0 + self._loop(z))

    def noise_shares(self, decimation=1, points=2 ** 16):
        r"""
        Return how white noise at the loop input and at the ADC reaches a published sample.

        A published sample is one loop step of the loop-rate output filtered by ``H(z)
        A(z)`` (input acceleration) or ``s_nom D(z) A(z) / (1 + L(z))`` (ADC code), so the
        variance a white sequence of variance ``sigma^2`` per loop step leaves in it is
        ``sigma^2 <|G|^2>``, the mean of ``|G|^2`` around the unit circle (Parseval;
        ``points`` bins offset by half a bin, which skips the integrator's pole at DC).

        Returns
        -------
        white_share : float
            ``decimation <|H A|^2>``: the per-sample variance of white acceleration noise
            of density N over ``N^2 f_s`` (the output's noise-equivalent bandwidth over
            ``f_s / 2``) [1].
        adc_gain : float
            ``sqrt(<|s_nom D A / (1 + L)|^2>)``: the standard deviation of a published
            sample per count of white ADC noise [(m/s^2)/count].
        """
        if decimation < 1 or points < 16:
            raise ValueError('decimation must be >= 1 and points >= 16')
        rate = 1.0 / self.loop_period
        freq = (np.arange(points) + 0.5) * rate / points
        adc = self.adc_response(freq, decimation)
        white = decimation * np.mean(np.abs(self.closed_loop(freq, decimation)) ** 2)
        return float(white), float(np.sqrt(np.mean(np.abs(adc) ** 2)))

    def margins(self):
        """Return (crossover Hz, phase margin deg, gain margin dB, -3 dB bandwidth Hz)."""
        nyquist = 0.5 / self.loop_period
        freq = np.logspace(-1, math.log10(nyquist * 0.999), 40000)
        loop = self.loop_gain(freq)
        mag = np.abs(loop)
        cross = np.nonzero(np.diff(np.sign(mag - 1.0)))[0]
        crossover = freq[cross[-1]]
        phase = np.unwrap(np.angle(loop))
        phase_margin = 180.0 + math.degrees(phase[cross[-1]])
        # Only phase crossings above the gain crossover bound the gain (the type-1 loop
        # approaches -180 deg at low frequency with a gain far above 1).
        turns = np.nonzero(np.diff(np.sign(phase + np.pi)))[0]
        turns = turns[turns > cross[-1]]
        gain_margin = -20 * math.log10(mag[turns[0]]) if len(turns) else math.inf
        closed = np.abs(self.closed_loop(freq))
        below = np.nonzero(closed < 1 / math.sqrt(2))[0]
        bandwidth = freq[below[0]] if len(below) else nyquist
        return crossover, phase_margin, gain_margin, bandwidth


def designed_loop(config):
    """Return the :class:`LinearLoop` of a TriadConfig's hardware and controller targets."""
    controller = design_controller(config.hardware, config.loop_rate_hz, config.crossover_hz,
                                   config.integrator_ratio, config.lead_pole_ratio)
    return LinearLoop(config.hardware, controller, config.loop_rate_hz)


def published_acceleration_variance(config):
    """
    Return the ``linear_acceleration_covariance`` diagonal of ``config`` [(m/s^2)^2].

    The per-sample variance of the noise that is white at the published rate, through the
    designed loop and the averaging decimator (:meth:`LinearLoop.noise_shares`,
    :func:`qfa_ros.model.noise.acceleration_variance`).

    Parameters
    ----------
    config : qfa_ros.model.triad_config.TriadConfig
        Hardware, loop and sample rate, controller targets and noise.
    """
    white_share, adc_gain = designed_loop(config).noise_shares(config.decimation)
    return acceleration_variance(config.noise, config.sample_rate_hz, white_share, adc_gain)
