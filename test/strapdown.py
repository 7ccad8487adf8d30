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
def _expm(x, y, z):
    """Return exp([v x]) of the rotation vector v = (x, y, z) (Rodrigues' formula).

    exp(K) = I + a K + b K^2 with K^2 = v v^T - |v|^2 I, a = sin|v| / |v| and
    b = (1 - cos|v|) / |v|^2 (a = 1, b = 1/2 below 1e-12 rad). Written out in scalars,
    as the whole mechanization: numba compiles each numpy expression on small arrays into
    a kernel of its own (the array version took ~20 s of CPU to compile).
    """
    angle2 = x * x + y * y + z * z
    angle = math.sqrt(angle2)
    if angle < 1e-12:
        a, b = 1.0, 0.5
    else:
        a, b = math.sin(angle) / angle, (1.0 - math.cos(angle)) / angle2
    m = np.empty((3, 3))
    m[0, 0], m[0, 1], m[0, 2] = 1.0 + b * (x * x - angle2), b * x * y - a * z, b * x * z + a * y
    m[1, 0], m[1, 1], m[1, 2] = b * x * y + a * z, 1.0 + b * (y * y - angle2), b * y * z - a * x
    m[2, 0], m[2, 1], m[2, 2] = b * x * z - a * y, b * y * z + a * x, 1.0 + b * (z * z - angle2)
    return m


@njit(cache=True)
def _product(a, b):
    """Return the 3 x 3 matrix product a b."""
    m = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            m[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return m


@njit(cache=True)
def _transport(lat, h, v_e, v_n):
    """Return (w_ie + w_en) in ENU [rad/s] and the Coriolis rate 2 w_ie + w_en."""
    r_n, r_e = _radii(lat)
    w_ie = (0.0, OMEGA * math.cos(lat), OMEGA * math.sin(lat))
    w_en = (-v_n / (r_n + h), v_e / (r_e + h), v_e * math.tan(lat) / (r_e + h))
    return ((w_ie[0] + w_en[0], w_ie[1] + w_en[1], w_ie[2] + w_en[2]),
            (2.0 * w_ie[0] + w_en[0], 2.0 * w_ie[1] + w_en[1], 2.0 * w_ie[2] + w_en[2]))


@njit(cache=True)
def _navigate(rate, force, period, lat, lon, h, velocity, dcm, hold_height):
    n = rate.shape[0]
    positions = np.empty((n, 3))
    velocities = np.empty((n, 3))
    dcms = np.empty((n, 3, 3))
    v_e, v_n, v_u = velocity[0], velocity[1], velocity[2]
    c = dcm.copy()
    p_x, p_y, p_z = 0.0, 0.0, 0.0  # the previous sample's angle increment
    h0 = h
    for k in range(n):
        x, y, z = rate[k, 0] * period, rate[k, 1] * period, rate[k, 2] * period
        f_x, f_y, f_z = force[k, 0] * period, force[k, 1] * period, force[k, 2] * period
        # Coning: dth + dth_prev x dth / 12; sculling: dv + dth x dv / 2.
        c_x = x + (p_y * z - p_z * y) / 12.0
        c_y = y + (p_z * x - p_x * z) / 12.0
        c_z = z + (p_x * y - p_y * x) / 12.0
        p_x, p_y, p_z = x, y, z
        r_x = f_x + 0.5 * (y * f_z - z * f_y)
        r_y = f_y + 0.5 * (z * f_x - x * f_z)
        r_z = f_z + 0.5 * (x * f_y - y * f_x)
        # C dv' in the navigation frame.
        d_e = c[0, 0] * r_x + c[0, 1] * r_y + c[0, 2] * r_z
        d_n = c[1, 0] * r_x + c[1, 1] * r_y + c[1, 2] * r_z
        d_u = c[2, 0] * r_x + c[2, 1] * r_y + c[2, 2] * r_z
        lat_m, h_m, m_e, m_n, m_u = lat, h, v_e, v_n, v_u
        for _ in range(2):
            w, cor = _transport(lat_m, h_m, m_e, m_n)
            z_e, z_n, z_u = w[0] * period, w[1] * period, w[2] * period
            g = gravity(lat_m, h_m)
            # v+ = v + (I - [z/2 x]) C dv' + (g - (2 w_ie + w_en) x v_mid) T
            e_new = v_e + d_e - 0.5 * (z_n * d_u - z_u * d_n) \
                - (cor[1] * m_u - cor[2] * m_n) * period
            n_new = v_n + d_n - 0.5 * (z_u * d_e - z_e * d_u) \
                - (cor[2] * m_e - cor[0] * m_u) * period
            u_new = v_u + d_u - 0.5 * (z_e * d_n - z_n * d_e) \
                + (-g - (cor[0] * m_n - cor[1] * m_e)) * period
            m_e, m_n, m_u = 0.5 * (v_e + e_new), 0.5 * (v_n + n_new), 0.5 * (v_u + u_new)
            r_n, r_e = _radii(lat_m)
            h_new = h + m_u * period
            h_m = 0.5 * (h + h_new)
            lat_new = lat + m_n / (r_n + h_m) * period
            lat_m = 0.5 * (lat + lat_new)
        r_n, r_e = _radii(lat_m)
        lon = lon + m_e / ((r_e + h_m) * math.cos(lat_m)) * period
        w, _ = _transport(lat_m, h_m, m_e, m_n)
        c = _product(_product(_expm(-w[0] * period, -w[1] * period, -w[2] * period), c),
                     _expm(c_x, c_y, c_z))
        lat, h, v_e, v_n, v_u = lat_new, h_new, e_new, n_new, u_new
        if hold_height:
            h = h0
            v_u = 0.0
        positions[k, 0] = lat
        positions[k, 1] = lon
        positions[k, 2] = h
        velocities[k, 0], velocities[k, 1], velocities[k, 2] = v_e, v_n, v_u
        for i in range(3):  # element by element: `dcms[k] = c` compiles for seconds
            for j in range(3):
                dcms[k, i, j] = c[i, j]
    return positions, dcms, velocities


def navigate(rate, force, period, lat, lon, h, velocity, dcm, hold_height=False):
    """
    Integrate ``rate`` [rad/s] and ``force`` [m/s^2] (n, 3) from the initial state.

    ``hold_height``: keep h and v_U at their initial values (a height aid; the free
    vertical channel diverges with a time constant of about 10 minutes).

    Returns (positions (n, 3): lat, lon, h after each sample; dcms (n, 3, 3);
    velocities (n, 3) ENU).
    """
    def floats(array):  # one compiled signature whatever the caller's arrays
        return np.ascontiguousarray(array, dtype=np.float64)

    return _navigate(floats(rate), floats(force), float(period), float(lat), float(lon),
                     float(h), floats(velocity), floats(dcm), bool(hold_height))


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
