"""An independent strapdown INS for the tests: ENU local-level mechanization (numba).

Written from Groves 2013 §5.4 / Titterton & Weston §3.5, separately from the emulator:
it only takes the sensor stream (rate and specific force means per sample) and an
initial pose. Per sample of period ``T``, with ``dth = w T``, ``dv = f T``::

    dth' = dth + dth_prev x dth / 12                     two-sample coning correction
    dv'  = dv + dth x dv / 2                             rotation compensation
    v+   = v + (I - [z/2 x]) C dv' + (g - (2 w_ie + w_en) x v_mid) T
    C+   = exp(-[z x]) C exp([dth' x]),  z = (w_ie + w_en)(mid) T
    lat+, lon+, h+ by the trapezoid rule on v

the midpoint quantities from one predictor pass. WGS-84 gravity and radii are coded
here again (not imported) so the test also checks the emulator's Earth.
"""

import math

from numba import njit
import numpy as np

A = 6378137.0
F = 1.0 / 298.257223563
E2 = F * (2.0 - F)
B = A * (1.0 - F)
OMEGA = 7.292115e-5
GAMMA_E = 9.7803253359
GAMMA_P = 9.8321849378
GM = 3.986004418e14


@njit(cache=True)
def gravity(lat, h):
    s2 = math.sin(lat) ** 2
    k = B * GAMMA_P / (A * GAMMA_E) - 1.0
    m = OMEGA * OMEGA * A * A * B / GM
    g0 = GAMMA_E * (1.0 + k * s2) / math.sqrt(1.0 - E2 * s2)
    return g0 * (1.0 - 2.0 / A * (1.0 + F + m - 2.0 * F * s2) * h + 3.0 * h * h / (A * A))


@njit(cache=True)
def _radii(lat):
    w2 = 1.0 - E2 * math.sin(lat) ** 2
    return A * (1.0 - E2) / w2 ** 1.5, A / math.sqrt(w2)


@njit(cache=True)
def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@njit(cache=True)
def _expm(v):
    angle = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    k = _skew(v)
    if angle < 1e-12:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + math.sin(angle) / angle * k \
        + (1.0 - math.cos(angle)) / (angle * angle) * k @ k


@njit(cache=True)
def _rates(lat, h, v):
    r_n, r_e = _radii(lat)
    w_ie = np.array([0.0, OMEGA * math.cos(lat), OMEGA * math.sin(lat)])
    w_en = np.array([-v[1] / (r_n + h), v[0] / (r_e + h), v[0] * math.tan(lat) / (r_e + h)])
    return w_ie, w_en


@njit(cache=True)
def navigate(rate, force, period, lat, lon, h, velocity, dcm, hold_height=False):
    """
    Integrate ``rate`` [rad/s] and ``force`` [m/s^2] (n, 3) from the initial state.

    ``hold_height``: keep h and v_U at their initial values (a height aid; the free
    vertical channel diverges with a time constant of about 10 minutes).

    Returns (positions (n, 3): lat, lon, h after each sample; dcms (n, 3, 3);
    velocities (n, 3) ENU).
    """
    n = rate.shape[0]
    positions = np.empty((n, 3))
    velocities = np.empty((n, 3))
    dcms = np.empty((n, 3, 3))
    v = velocity.copy()
    c = dcm.copy()
    previous = np.zeros(3)
    h0 = h
    for k in range(n):
        dth = rate[k] * period
        dv = force[k] * period
        dth_c = dth + np.cross(previous, dth) / 12.0
        previous = dth
        dv_r = dv + 0.5 * np.cross(dth, dv)
        lat_m, h_m, v_m = lat, h, v
        for _ in range(2):
            w_ie, w_en = _rates(lat_m, h_m, v_m)
            zeta = (w_ie + w_en) * period
            g = np.array([0.0, 0.0, -gravity(lat_m, h_m)])
            v_new = v + (np.eye(3) - 0.5 * _skew(zeta)) @ (c @ dv_r) \
                + (g - np.cross(2.0 * w_ie + w_en, v_m)) * period
            v_m = 0.5 * (v + v_new)
            r_n, r_e = _radii(lat_m)
            h_new = h + v_m[2] * period
            h_m = 0.5 * (h + h_new)
            lat_new = lat + v_m[1] / (r_n + h_m) * period
            lat_m = 0.5 * (lat + lat_new)
        r_n, r_e = _radii(lat_m)
        lon = lon + v_m[0] / ((r_e + h_m) * math.cos(lat_m)) * period
        w_ie, w_en = _rates(lat_m, h_m, v_m)
        c = _expm(-(w_ie + w_en) * period) @ c @ _expm(dth_c)
        lat, h, v = lat_new, h_new, v_new
        if hold_height:
            h = h0
            v[2] = 0.0
        positions[k, 0] = lat
        positions[k, 1] = lon
        positions[k, 2] = h
        velocities[k] = v
        dcms[k] = c
    return positions, dcms, velocities


def position_error(positions, latitude, longitude, height):
    """Return the (east, north, up) position error [m] against the truth arrays."""
    r_n, r_e = _radii(float(np.mean(latitude)))
    return np.stack([(positions[:, 1] - longitude) * (r_e + height) * np.cos(latitude),
                     (positions[:, 0] - latitude) * (r_n + height),
                     positions[:, 2] - height], axis=-1)


def attitude_error(dcms, truth):
    """Return the small-angle attitude error (n, 3) [rad]: C_true^T C_est = I + [e x]."""
    delta = np.einsum('nji,njk->nik', truth, dcms)
    return 0.5 * np.stack([delta[:, 2, 1] - delta[:, 1, 2], delta[:, 0, 2] - delta[:, 2, 0],
                           delta[:, 1, 0] - delta[:, 0, 1]], axis=-1)
