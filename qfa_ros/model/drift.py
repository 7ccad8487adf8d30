"""Parameter drift of the loop gains: steps and linear aging (sensor time)."""

import numpy as np

from qfa_ros.model import checks
from qfa_ros.model.constants import PPM
from qfa_ros.model.hardware import DRIFT_COMPONENTS

SECONDS_PER_YEAR = 365.25 * 86400.0
NUMBER_TYPES = (int, float, np.floating)
"""What a drift setter takes as a number (a bool too, not a string or a numpy integer)."""


class DriftModel:
    r"""
    Relative drift ``delta`` of every loop component of every axis.

    ``delta_c(t, T) = step_c + aged_c + rate_c * accel * (t - t_a) + tc_c * (T - T_ref)``
    where ``t`` is sensor time [s], ``rate_c`` the aging rate [1/s] (set in ppm/year),
    ``accel`` the time-acceleration factor (1 = real time; 3.15e7 makes a year pass in
    a second), ``tc_c`` the temperature coefficient [1/degC] and ``T`` the sensor
    temperature [degC] against the reference temperature ``T_ref`` (25 degC, the
    datasheet's). Aging is continuous: changing a rate or the acceleration at time
    ``t_a`` (read from ``clock``) first accumulates the aging so far into ``aged_c``,
    so the new rate acts from then on and the drift never jumps. Without a clock,
    aging counts from sensor time 0.

    Parameters
    ----------
    n_axes : int
        Number of axes.
    """

    def __init__(self, n_axes=3):
        self.n_axes = n_axes
        self.components = DRIFT_COMPONENTS
        self.step = np.zeros((n_axes, len(DRIFT_COMPONENTS)))
        self.rate = np.zeros((n_axes, len(DRIFT_COMPONENTS)))
        self.temperature_coefficient = np.zeros((n_axes, len(DRIFT_COMPONENTS)))
        self.reference_temperature = 25.0
        self.time_acceleration = 1.0
        self.version = 0
        # Callable returning the present sensor time [s]; QfaTriad sets it.
        self.clock = None
        self.aged = np.zeros((n_axes, len(DRIFT_COMPONENTS)))
        self.aged_at = 0.0
        # Aging of the zero bias (a unit's, qfa_ros.model.drawn_unit) [m/s^2 per aged second]
        # and the aged time accumulated up to aged_at [s].
        self.bias_rate = np.zeros(n_axes)
        self.aged_time = 0.0

    def _index(self, axis, component):
        if component not in self.components:
            raise ValueError(f'unknown drift component {component!r}; '
                             f'expected one of {", ".join(self.components)}')
        return checks.index('axis', axis, self.n_axes), self.components.index(component)

    def set_step(self, axis, component, delta):
        """Set the step drift of ``component`` on ``axis`` (relative, e.g. 200e-6)."""
        checks.finite('delta', delta, NUMBER_TYPES)
        self.step[self._index(axis, component)] = delta
        self.version += 1

    def set_aging(self, axis, component, ppm_per_year):
        """Set the linear aging rate of ``component`` on ``axis`` [ppm/year]."""
        checks.finite('ppm_per_year', ppm_per_year, NUMBER_TYPES)
        index = self._index(axis, component)
        self._fold_aging()
        self.rate[index] = ppm_per_year * PPM / SECONDS_PER_YEAR
        self.version += 1

    def set_temperature_coefficient(self, axis, component, ppm_per_degc):
        """Set the temperature coefficient of ``component`` on ``axis`` [ppm/degC]."""
        checks.finite('ppm_per_degc', ppm_per_degc, NUMBER_TYPES)
        self.temperature_coefficient[self._index(axis, component)] = ppm_per_degc * PPM
        self.version += 1

    def set_time_acceleration(self, factor):
        """Set the aging time-acceleration factor (>= 0)."""
        checks.finite('time_acceleration', factor, NUMBER_TYPES)
        if factor < 0:
            raise ValueError(f'time_acceleration must be >= 0, got {factor!r}')
        self._fold_aging()
        self.time_acceleration = float(factor)
        self.version += 1

    def _fold_aging(self):
        # Accumulate the aging up to now so that a new rate or acceleration starts here.
        now = 0.0 if self.clock is None else float(self.clock())
        self.aged = self.aged + self.rate * self.time_acceleration * (now - self.aged_at)
        self.aged_time += self.time_acceleration * (now - self.aged_at)
        self.aged_at = now

    def set_bias_aging(self, per_year):
        """Set the zero-bias aging per axis [m/s^2 per year of aged sensor time]."""
        values = checks.finite_vector('per_year', per_year, self.n_axes)
        self._fold_aging()
        self.bias_rate = values / SECONDS_PER_YEAR

    def bias_at(self, t):
        """Return the aged zero-bias change per axis [m/s^2] at sensor time ``t`` [s]."""
        return self.bias_rate * (self.aged_time + self.time_acceleration * (t - self.aged_at))

    @property
    def aging(self):
        """Return True if any aging rate is non-zero."""
        return bool(np.any(self.rate != 0) and self.time_acceleration > 0)

    def at(self, axis, t, temperature=None):
        """Return ``{component: delta}`` of ``axis`` at time ``t`` [s] and ``temperature``."""
        values = self.step[axis] + self.aged[axis] \
            + self.rate[axis] * self.time_acceleration * (t - self.aged_at)
        if temperature is not None:
            values = values + self.temperature_coefficient[axis] \
                * (temperature - self.reference_temperature)
        return dict(zip(self.components, values.tolist()))
