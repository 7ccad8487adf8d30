"""The configuration of a :class:`~qfa_ros.model.triad.QfaTriad` (pure model, SI units)."""

from dataclasses import dataclass, field
import numbers

import numpy as np

from qfa_ros.model import checks
from qfa_ros.model.constants import MICRO_G, STANDARD_GRAVITY
from qfa_ros.model.gyro import GyroConfig
from qfa_ros.model.hardware import AxisHardware
from qfa_ros.model.noise import NoiseConfig


@dataclass(frozen=True)
class TriadConfig:
    """
    Configuration of the triad (SI units unless named otherwise).

    Attributes
    ----------
    hardware : AxisHardware
        Nominal hardware, the same design for the three axes.
    loop_rate_hz : float
        Digital loop rate (ADC, controller, DAC) [Hz].
    sample_rate_hz : float
        Published sample rate [Hz]; ``loop_rate_hz`` must be an integer multiple.
    noise : NoiseConfig
        Noise of each axis.
    misalignment : tuple
        3x3 small-angle misalignment / cross-coupling matrix ``M``: each loop senses
        ``((I + M) f)_i``.
    bias : tuple
        IEEE 1293 bias term per axis [m/s^2].
    k2 : tuple
        IEEE 1293 second-order coefficient per axis [1/(m/s^2)]: the loop senses
        ``bias + a + k2 a^2``.
    crossover_hz, integrator_ratio, lead_pole_ratio : float
        Controller design targets (see :func:`qfa_ros.model.design.design_controller`).
    open_loop_cref_sensitivity : float
        Share of the reference-capacitor drift seen by the open-loop bridge.
    settle_time : float
        Time after re-closing a loop during which its output is flagged invalid [s].
    thermal : ThermalConfig or None
        Thermal model (ambient, body lag, temperature sensor, zero bias and
        scale-factor error versus temperature, Liu, Li and Shen); None keeps the sensor at the
        drift model's reference temperature with no thermal errors.
    gyro : GyroConfig or None
        Error model of the gyro triad beside the accelerometers
        (:mod:`qfa_ros.model.gyro`); None: no gyros (``TriadOutput.gyro`` is NaN).
    """

    hardware: AxisHardware = field(default_factory=AxisHardware)
    loop_rate_hz: float = 10000.0
    sample_rate_hz: float = 1000.0
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    misalignment: tuple = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    bias: tuple = (0.0, 0.0, 0.0)
    k2: tuple = (0.0, 0.0, 0.0)
    crossover_hz: float = 300.0
    integrator_ratio: float = 0.1
    lead_pole_ratio: float = 6.0
    open_loop_cref_sensitivity: float = 1.0
    settle_time: float = 0.05
    thermal: object = None
    gyro: object = field(default_factory=GyroConfig)

    def __post_init__(self):
        for name in ('loop_rate_hz', 'sample_rate_hz', 'settle_time', 'crossover_hz'):
            value = getattr(self, name)
            # settle_time may be 0 (no settling), as a number: False is not a time.
            zero_allowed = name == 'settle_time'
            if not checks.is_finite(value, bool_ok=False, types=numbers.Real) or value < 0 \
                    or (value == 0 and not zero_allowed):
                rule = 'finite and >= 0' if zero_allowed else 'a positive finite number'
                raise ValueError(f'{name} must be {rule}, got {value!r}')
        ratio = self.loop_rate_hz / self.sample_rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError('loop_rate_hz must be an integer multiple of sample_rate_hz, got '
                             f'{self.loop_rate_hz!r} / {self.sample_rate_hz!r}')
        if not checks.is_finite(self.open_loop_cref_sensitivity):
            raise ValueError('open_loop_cref_sensitivity must be finite, got '
                             f'{self.open_loop_cref_sensitivity!r}')
        matrix = np.asarray(self.misalignment, dtype=float)
        if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
            raise ValueError('misalignment must be a finite 3x3 matrix')
        for name in ('bias', 'k2'):
            vector = np.asarray(getattr(self, name), dtype=float)
            if vector.shape != (3,) or not np.all(np.isfinite(vector)):
                raise ValueError(f'{name} must be 3 finite numbers')

    @property
    def decimation(self):
        """Loop steps per published sample."""
        return int(round(self.loop_rate_hz / self.sample_rate_hz))

    @classmethod
    def from_datasheet(cls, bias_ug=(0.0, 0.0, 0.0), k2_ug_per_g2=(0.0, 0.0, 0.0), **kwargs):
        """Build a config with bias in micro-g and K2 in micro-g/g^2 (datasheet units)."""
        bias = tuple(b * MICRO_G for b in bias_ug)
        k2 = tuple(k * MICRO_G / STANDARD_GRAVITY ** 2 for k in k2_ug_per_g2)
        return cls(bias=bias, k2=k2, **kwargs)
