"""
The calibration set-up around the sensor: a climatic chamber and a two-position fixture.

This is test equipment, not the sensor: it changes the sensor model's environment
(ambient temperature, orientation in gravity) and knows the input it imposes, as a
laboratory does. Estimators read the sensor through
:class:`qfa_ros.calibration.schedule.SensorPort` only; they receive a bench to command
it, never to read the model.
"""

import math

import numpy as np

from qfa_ros.model.checks import is_finite
from qfa_ros.model.constants import STANDARD_GRAVITY
from qfa_ros.model.input_profiles import StaticProfile

DIAGONAL = np.ones(3) / math.sqrt(3.0)
"""Fixture axis: every sensor axis at 54.7 deg from vertical, g / sqrt(3) each."""


def idle(triad, seconds, step_s=10.0):
    """
    Let ``seconds`` of environment time pass without simulating the loops.

    The thermal model (room wander, body lag, temperature sensor) advances in steps of
    ``step_s`` (its recursions are exact for any step); the loops keep their state and
    follow the new temperature from the next run. Used for soaks and for the hours
    between experiments, which would otherwise cost 10 kHz loop steps.
    """
    if not is_finite(seconds) or seconds < 0:
        raise ValueError(f'seconds must be >= 0, got {seconds!r}')
    if triad.thermal is None or seconds == 0:
        return
    steps = int(seconds // step_s)
    if steps:
        triad.thermal.run(steps, step_s)
    rest = seconds - steps * step_s
    if rest > 0:
        triad.thermal.run(1, rest)


class ChamberBench:
    """
    Chamber plateaus and a fixture with two positions ``+-DIAGONAL`` in gravity.

    Parameters
    ----------
    triad : QfaTriad
        The sensor model in the set-up (with a thermal model).
    gravity : float
        Local gravity the laboratory knows [m/s^2].
    """

    def __init__(self, triad, gravity=STANDARD_GRAVITY):
        if triad.thermal is None:
            raise ValueError('triad must have a thermal model for a chamber')
        if not is_finite(gravity) or gravity <= 0:
            raise ValueError(f'gravity must be positive, got {gravity!r}')
        self._triad = triad
        self.gravity = float(gravity)
        self._profile = triad.profile
        config = triad.thermal.config
        self._ambient = {name: getattr(config, name) for name in (
            'ambient_profile', 'ambient_c', 'room_amplitude_c', 'room_correlation_s')}

    def set_chamber_c(self, temperature_c):
        """Hold the chamber at ``temperature_c`` [degC]."""
        self._triad.thermal.set_ambient(ambient_profile='constant', ambient_c=temperature_c)

    def soak(self, seconds):
        """Wait ``seconds`` for the sensor body to reach the chamber temperature."""
        idle(self._triad, seconds)

    def known_input(self, sign):
        """Return the specific force of fixture position ``sign`` (+1 or -1) [m/s^2]."""
        return sign * self.gravity * DIAGONAL

    def set_position(self, sign):
        """Turn the fixture to position ``sign``."""
        if sign not in (1, -1):
            raise ValueError(f'sign must be +1 or -1, got {sign!r}')
        self._triad.profile = StaticProfile(tuple(self.known_input(sign)))

    def restore(self):
        """Put the sensor back in its room and orientation."""
        self._triad.thermal.set_ambient(**self._ambient)
        self._triad.profile = self._profile
