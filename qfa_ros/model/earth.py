"""WGS-84 Earth: normal gravity, radii of curvature, Earth and transport rates (ENU, SI).

The navigation frame is local-level East-North-Up (REP-103); latitudes are geodetic
[rad], heights above the ellipsoid [m]. Every function takes numpy arrays (broadcast).

References: NIMA TR8350.2 (WGS-84, 3rd ed.), eq. 4-1 (Somigliana) and 4-3 (height
term); P. D. Groves, *Principles of GNSS, Inertial, and Multisensor Integrated
Navigation Systems*, 2nd ed., eq. 2.105-2.106 (radii) and 5.44 (transport rate).
"""

import numpy as np

from qfa_ros.model import checks

SEMI_MAJOR_AXIS = 6378137.0
"""WGS-84 a [m]."""
FLATTENING = 1.0 / 298.257223563
"""WGS-84 f."""
EARTH_RATE = 7.292115e-5
"""WGS-84 omega_ie [rad/s]."""
GM = 3.986004418e14
"""WGS-84 gravitational constant GM [m^3/s^2]."""
ECCENTRICITY_SQUARED = FLATTENING * (2.0 - FLATTENING)
GAMMA_EQUATOR = 9.7803253359
"""Normal gravity at the equator [m/s^2] (TR8350.2 table 3.4)."""
SOMIGLIANA_K = 0.00193185265241
"""Somigliana constant k = b gamma_p / (a gamma_e) - 1 (TR8350.2 table 3.4)."""
GRAVITY_RATIO_M = 0.00344978650684
"""m = omega^2 a^2 b / GM of the height term."""


def normal_gravity(latitude, height=0.0):
    r"""
    Return WGS-84 normal gravity magnitude [m/s^2] at ``latitude`` [rad], ``height`` [m].

    Somigliana on the ellipsoid, then the second-order height term::

        gamma_0 = gamma_e (1 + k sin^2 phi) / sqrt(1 - e^2 sin^2 phi)
        gamma_h = gamma_0 (1 - 2/a (1 + f + m - 2 f sin^2 phi) h + 3 h^2 / a^2)

    Normal gravity includes the centrifugal acceleration of the Earth's rotation.
    """
    s2 = np.sin(latitude) ** 2
    gamma0 = GAMMA_EQUATOR * (1.0 + SOMIGLIANA_K * s2) / np.sqrt(1.0 - ECCENTRICITY_SQUARED * s2)
    h = np.asarray(height, dtype=float)
    return gamma0 * (1.0 - 2.0 / SEMI_MAJOR_AXIS
                     * (1.0 + FLATTENING + GRAVITY_RATIO_M - 2.0 * FLATTENING * s2) * h
                     + 3.0 * h * h / SEMI_MAJOR_AXIS ** 2)


def gravity_enu(latitude, height=0.0):
    """Return the gravity vector g^n = (0, 0, -gamma) [m/s^2], shape (..., 3)."""
    gamma = np.asarray(normal_gravity(latitude, height))
    zero = np.zeros_like(gamma)
    return np.stack([zero, zero, -gamma], axis=-1)


def radii_of_curvature(latitude):
    """
    Return (R_N meridian, R_E prime vertical) radii of curvature [m].

    ``R_N = a (1 - e^2) / (1 - e^2 sin^2 phi)^(3/2)``, ``R_E = a / sqrt(1 - e^2 sin^2 phi)``.
    """
    w2 = 1.0 - ECCENTRICITY_SQUARED * np.sin(latitude) ** 2
    return (SEMI_MAJOR_AXIS * (1.0 - ECCENTRICITY_SQUARED) / w2 ** 1.5,
            SEMI_MAJOR_AXIS / np.sqrt(w2))


def radii_derivatives(latitude):
    """Return (dR_N/dphi, dR_E/dphi) [m/rad]."""
    s, c = np.sin(latitude), np.cos(latitude)
    w2 = 1.0 - ECCENTRICITY_SQUARED * s * s
    return (3.0 * SEMI_MAJOR_AXIS * (1.0 - ECCENTRICITY_SQUARED) * ECCENTRICITY_SQUARED * s * c
            / w2 ** 2.5,
            SEMI_MAJOR_AXIS * ECCENTRICITY_SQUARED * s * c / w2 ** 1.5)


def earth_rate_enu(latitude):
    """Return omega_ie^n = Omega (0, cos phi, sin phi) [rad/s], shape (..., 3)."""
    phi = np.asarray(latitude, dtype=float)
    return EARTH_RATE * np.stack([np.zeros_like(phi), np.cos(phi), np.sin(phi)], axis=-1)


def transport_rate_enu(latitude, height, velocity):
    """
    Return the transport rate omega_en^n [rad/s] of the ENU frame, shape (..., 3).

    ``(-v_N / (R_N + h), v_E / (R_E + h), v_E tan(phi) / (R_E + h))`` with
    ``velocity`` = (v_E, v_N, v_U) [m/s].
    """
    r_n, r_e = radii_of_curvature(latitude)
    v = np.asarray(velocity, dtype=float)
    east = v[..., 0] / (r_e + height)
    return np.stack([-v[..., 1] / (r_n + height), east, east * np.tan(latitude)], axis=-1)


LOCATION_LIMITS = (('latitude_deg', -90.0, 90.0), ('longitude_deg', -180.0, 360.0),
                   ('height_m', -12000.0, 100000.0))
"""Usable range of each geodetic coordinate (the normal-gravity formula's heights).

The poles are included: normal gravity, the Earth rate (all vertical there), the radii and
a body at rest are regular at +-90 deg. What divides by ``cos(latitude)`` is motion in
longitude: :data:`MOVING_LATITUDE_LIMIT_DEG`.
"""
MOVING_LATITUDE_LIMIT_DEG = 89.9
r"""Largest \|latitude| [deg] of a path integrated from its east velocity (a drive).

The longitude rate ``v_E / ((R_E + h) cos(latitude))`` diverges at a pole, and a path
through one leaves its meridian: within 0.1 deg (11 km) of a pole a drive is refused.
"""


def check_location(latitude_deg, longitude_deg, height_m):
    """Raise ``ValueError`` naming the parameter unless the location is usable."""
    for (name, low, high), value in zip(LOCATION_LIMITS,
                                        (latitude_deg, longitude_deg, height_m)):
        if not checks.is_finite(value) or not low <= value <= high:
            raise ValueError(f'{name} must be in [{low:g}, {high:g}], got {value!r}')


def location_usable(latitude_deg, longitude_deg, height_m):
    """Return, elementwise, whether the locations pass :func:`check_location`."""
    usable = True
    for (_, low, high), value in zip(LOCATION_LIMITS,
                                     (latitude_deg, longitude_deg, height_m)):
        value = np.asarray(value, dtype=float)
        usable = usable & np.isfinite(value) & (low <= value) & (value <= high)
    return usable
