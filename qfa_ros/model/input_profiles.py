"""Input specific-force profiles in the sensor frame (pure functions of time)."""

from dataclasses import dataclass
import math

import numpy as np

from qfa_ros.model import checks
from qfa_ros.model.constants import STANDARD_GRAVITY


def gravity_in_sensor_frame(roll, pitch, gravity=STANDARD_GRAVITY):
    """
    Return the specific force [m/s^2] of a sensor at rest with the given attitude.

    A level sensor (roll = pitch = 0, z up) reads +g on z (REP-145: the IMU at rest
    measures the reaction to gravity). Angles in radians, aerospace sequence.
    """
    return gravity * np.array([-math.sin(pitch),
                               math.sin(roll) * math.cos(pitch),
                               math.cos(roll) * math.cos(pitch)])


@dataclass(frozen=True)
class StaticProfile:
    """Constant specific force ``f`` [m/s^2] (e.g. a static orientation in gravity)."""

    specific_force: tuple = (0.0, 0.0, STANDARD_GRAVITY)

    def __post_init__(self):
        checks.finite_vector('specific_force', self.specific_force)

    @classmethod
    def level(cls):
        """Return the level sensor, +g on z."""
        return cls()

    @classmethod
    def orientation(cls, roll, pitch):
        """Return a static sensor at ``roll``, ``pitch`` [rad] in gravity."""
        return cls(tuple(gravity_in_sensor_frame(roll, pitch)))

    def evaluate(self, t):
        """Return f(t) as an (n, 3) array for times ``t`` [s]."""
        return np.broadcast_to(np.asarray(self.specific_force, dtype=float),
                               (len(t), 3)).copy()


@dataclass(frozen=True)
class StepProfile:
    """Piecewise-constant specific force: ``levels[k]`` from ``times[k]`` on [s, m/s^2]."""

    times: tuple
    levels: tuple

    def __post_init__(self):
        try:
            sized = len(self.times) == len(self.levels) and len(self.times) > 0
        except TypeError:
            # None or a number: no sequence.
            sized = False
        if not sized:
            raise ValueError('times and levels must be non-empty and of equal length')
        if not all(checks.is_finite(t) for t in self.times):
            raise ValueError(f'times must be finite numbers [s], got {self.times!r}')
        if any(b <= a for a, b in zip(self.times, self.times[1:])):
            raise ValueError('times must increase strictly')
        for level in self.levels:
            checks.finite_vector('levels', level)

    def evaluate(self, t):
        """Return f(t) as an (n, 3) array for times ``t`` [s]."""
        index = np.searchsorted(np.asarray(self.times), np.asarray(t), side='right') - 1
        levels = np.asarray(self.levels, dtype=float)
        return levels[np.clip(index, 0, len(levels) - 1)]


@dataclass(frozen=True)
class SineProfile:
    """Static ``offset`` plus sine vibration ``amplitude sin(2 pi f t)`` per axis [m/s^2]."""

    frequency_hz: float
    amplitude: tuple = (0.0, 0.0, STANDARD_GRAVITY)
    offset: tuple = (0.0, 0.0, 0.0)
    phase: float = 0.0

    def __post_init__(self):
        if not checks.is_finite(self.frequency_hz) or self.frequency_hz <= 0:
            raise ValueError(f'frequency_hz must be positive, got {self.frequency_hz!r}')
        if not checks.is_finite(self.phase):
            raise ValueError(f'phase must be finite [rad], got {self.phase!r}')
        checks.finite_vector('amplitude', self.amplitude)
        checks.finite_vector('offset', self.offset)

    def evaluate(self, t):
        """Return f(t) as an (n, 3) array for times ``t`` [s]."""
        wave = np.sin(2 * math.pi * self.frequency_hz * np.asarray(t) + self.phase)
        return np.asarray(self.offset) + wave[:, None] * np.asarray(self.amplitude)


def tumble_profile(dwell_s=10.0):
    """Return the six-position tumble (+-x, +-y, +-z up), ``dwell_s`` seconds each."""
    checks.positive('dwell_s', dwell_s)
    g = STANDARD_GRAVITY
    levels = ((0, 0, g), (0, 0, -g), (g, 0, 0), (-g, 0, 0), (0, g, 0), (0, -g, 0))
    times = tuple(k * dwell_s for k in range(len(levels)))
    return StepProfile(times=times, levels=tuple(tuple(map(float, v)) for v in levels))
