"""
Unit constants of the project, each one defined here and nowhere else.

Each constant is the value of one unit in SI; multiply a number in that unit by it to get SI,
divide an SI value by it to get the unit (``bias_ug * MICRO_G`` is [m/s^2],
``rate / DEG_PER_HOUR`` is [deg/h]).

Attributes
----------
PPM : float
    One part per million (dimensionless): ``1e-6``.
STANDARD_GRAVITY : float
    Standard gravity g0 [m/s^2]: ``9.80665`` (CGPM 1901, exact).
MILLI_G : float
    One milli-g [m/s^2]: ``1e-3 * STANDARD_GRAVITY``.
MICRO_G : float
    One micro-g [m/s^2]: ``9.80665e-6`` (the double nearest the exact value; ``1e-6 *
    STANDARD_GRAVITY`` is one ulp below it).
DEGREE : float
    One degree of angle [rad]: ``pi / 180``.
ARCSEC : float
    One arc second [rad]: ``pi / 180 / 3600``.
DEG_PER_HOUR : float
    One degree per hour [rad/s]: ``pi / 180 / 3600``.
DEG_PER_ROOT_HOUR : float
    One degree per root hour, the unit of angle random walk [rad/s^0.5]:
    ``pi / 180 / sqrt(3600)``.
"""

import math

PPM = 1e-6
STANDARD_GRAVITY = 9.80665
MILLI_G = 1e-3 * STANDARD_GRAVITY
MICRO_G = 9.80665e-6
DEGREE = math.pi / 180.0
ARCSEC = math.pi / 180.0 / 3600.0
DEG_PER_HOUR = math.pi / 180.0 / 3600.0
DEG_PER_ROOT_HOUR = math.pi / 180.0 / 60.0

UNIT_NAMES = ('PPM', 'STANDARD_GRAVITY', 'MILLI_G', 'MICRO_G', 'DEGREE', 'ARCSEC',
              'DEG_PER_HOUR', 'DEG_PER_ROOT_HOUR')
"""The names this module defines (no other module of the project may assign them)."""
