"""
Place a position in the ENU tangent plane of an origin on the WGS-84 Earth.

The truth odometry of the bags and of the node (``truth/odometry``) is in the ENU tangent
plane at the trajectory's first point, the origin ``truth/origin`` gives: ``p = C_e^n0
(r_e(p) - r_e(origin))`` (:func:`ecef_to_enu_matrix`, :func:`geodetic_to_ecef`).
:func:`enu_to_geodetic` inverts it: ``r_e = r_e(origin) + C_e^n0^T p``, then ECEF to
geodetic (:func:`ecef_to_geodetic`).
"""

import numpy as np

from qfa_ros.model import earth


def ecef_to_enu_matrix(latitude, longitude):
    """Return C_e^n, the rotation from ECEF to the local ENU frame, shape (..., 3, 3)."""
    sl, cl = np.sin(latitude), np.cos(latitude)
    so, co = np.sin(longitude), np.cos(longitude)
    zero = np.zeros_like(sl)
    return np.stack([np.stack([-so, co, zero], -1),
                     np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -2)


def geodetic_to_ecef(latitude, longitude, height):
    """Return ECEF positions [m], shape (..., 3)."""
    _, r_e = earth.radii_of_curvature(latitude)
    e2 = earth.ECCENTRICITY_SQUARED
    return np.stack([(r_e + height) * np.cos(latitude) * np.cos(longitude),
                     (r_e + height) * np.cos(latitude) * np.sin(longitude),
                     (r_e * (1 - e2) + height) * np.sin(latitude)], axis=-1)


def ecef_to_geodetic(position):
    """
    Return (latitude [rad], longitude [rad], height [m]) of ECEF positions (..., 3) [m].

    The fixed point ``tan(lat) = (z + e^2 N(lat) sin(lat)) / p`` from the spherical
    start, 8 passes (below 1e-12 rad for heights from -12 km to 100 km).
    """
    position = np.asarray(position, dtype=float)
    x, y, z = position[..., 0], position[..., 1], position[..., 2]
    e2 = earth.ECCENTRICITY_SQUARED
    a = earth.SEMI_MAJOR_AXIS
    p = np.hypot(x, y)
    longitude = np.arctan2(y, x)
    latitude = np.arctan2(z, p * (1.0 - e2))
    for _ in range(8):
        s = np.sin(latitude)
        r_e = a / np.sqrt(1.0 - e2 * s * s)
        latitude = np.arctan2(z + e2 * r_e * s, p)
    s, c = np.sin(latitude), np.cos(latitude)
    # h = p cos(lat) + z sin(lat) - a sqrt(1 - e2 sin^2(lat)): valid at the poles too.
    height = p * c + z * s - a * np.sqrt(1.0 - e2 * s * s)
    return latitude, longitude, height


def enu_to_geodetic(position, latitude, longitude, height):
    """
    Return (latitude [rad], longitude [rad], height [m]) of tangent-plane positions.

    Parameters
    ----------
    position : array_like, shape (..., 3)
        East, north, up [m] in the ENU tangent plane at the origin.
    latitude, longitude : float
        Geodetic origin [rad].
    height : float
        Height of the origin above the ellipsoid [m].
    """
    c_e_n0 = ecef_to_enu_matrix(latitude, longitude)
    ecef = geodetic_to_ecef(latitude, longitude, height) \
        + np.asarray(position, dtype=float) @ c_e_n0
    return ecef_to_geodetic(ecef)
