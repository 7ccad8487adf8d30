r"""Trajectories on the WGS-84 Earth: specific force and angular rate in the body frame.

A :class:`Trajectory` is a piecewise polynomial of time (one
:class:`scipy.interpolate.PPoly` with six channels): geodetic latitude and longitude
[rad], height [m], and the REP-103 Euler angles roll, pitch, yaw [rad] of the body
(x forward, y left, z up) in the local ENU frame, ``C_b^n = R_z(yaw) R_y(pitch)
R_x(roll)``. Everything the sensors see follows from it by exact differentiation
(Groves 2013, eq. 5.54, the local-navigation-frame equations)::

    v^n   = ((R_E + h) cos(phi) lambda', (R_N + h) phi', h')             ENU velocity
    f^b   = C_n^b (dv^n/dt + (2 w_ie^n + w_en^n) x v^n - g^n)           specific force
    w_ib^b = C_n^b (w_ie^n + w_en^n) + w_nb^b                             angular rate
    w_nb^b = (roll' - yaw' sin p,  pitch' cos r + yaw' sin r cos p,
              -pitch' sin r + yaw' cos r cos p)

with ``g^n`` the WGS-84 normal gravity (plumb bob: gravitation plus centrifugal), so
the specific force and angular rate are consistent with the pose to rounding. Before
the first knot and after the last one the body rests at the end pose.

The built-in motion scripts and the trajectory files that build one are in
:mod:`qfa_ros.model.motion_scripts`.

The sensors read the mean of f^b and w_ib^b over each sample period
(:meth:`Trajectory.sample_means`): exact integrals of verified per-piece Chebyshev fits of
the compiled twin of the kinematics, within 1e-10 m/s^2 and 1e-13 rad/s (or 1e-11 of the
magnitude), built by :mod:`qfa_ros.model.trajectory_means`.

:mod:`scipy.interpolate` (a third of a second to import) is loaded only when a moving
trajectory is evaluated or a file read: a body at rest (``qfa-sim static``, the node's
default pose) never needs it.
"""

import numpy as np

from qfa_ros.model import earth
from qfa_ros.model.geodetic import ecef_to_enu_matrix, geodetic_to_ecef
from qfa_ros.model.trajectory_means import PiecewiseMeans


def euler_to_dcm(roll, pitch, yaw):
    """Return C_b^n = R_z(yaw) R_y(pitch) R_x(roll), shape (..., 3, 3)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1)], -2)


def dcm_to_quaternion(dcm):
    """
    Return the unit quaternion (x, y, z, w), ``w >= 0``, of rotation matrices (..., 3, 3).

    Shepperd's method: the component of largest magnitude comes from the diagonal, the
    other three from sums and differences of the off-diagonal pairs divided by it, so
    every rotation, a half turn included, keeps full precision and its signs (reading
    each sign off a difference that vanishes at a half turn gives another rotation).
    """
    m = np.asarray(dcm, dtype=float)
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # 4 x^2, 4 y^2, 4 z^2, 4 w^2
    squares = np.stack([1.0 + 2.0 * m[..., 0, 0] - trace, 1.0 + 2.0 * m[..., 1, 1] - trace,
                        1.0 + 2.0 * m[..., 2, 2] - trace, 1.0 + trace], axis=-1)
    xy, xz, yz = m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0], \
        m[..., 1, 2] + m[..., 2, 1]
    xw, yw, zw = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], \
        m[..., 1, 0] - m[..., 0, 1]
    # Row k: 4 q_k (x, y, z, w), for k = x, y, z, w.
    rows = np.stack([np.stack([squares[..., 0], xy, xz, xw], axis=-1),
                     np.stack([xy, squares[..., 1], yz, yw], axis=-1),
                     np.stack([xz, yz, squares[..., 2], zw], axis=-1),
                     np.stack([xw, yw, zw, squares[..., 3]], axis=-1)], axis=-2)
    largest = np.argmax(squares, axis=-1)[..., None, None]
    q = np.take_along_axis(rows, largest, axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:] < 0.0, -q, q)


def quaternion_to_dcm(quaternion):
    """Return the rotation matrix of unit quaternions (x, y, z, w), shape (..., 3, 3)."""
    x, y, z, w = np.moveaxis(np.asarray(quaternion, dtype=float), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)],
        -2)


class Trajectory:
    """
    Pose of the body as a piecewise polynomial of time, and what the sensors see.

    Parameters
    ----------
    poly : scipy.interpolate.PPoly or tuple
        Six channels (lat [rad], lon [rad], h [m], roll, pitch, yaw [rad]) over time [s]:
        a ``PPoly`` or its ``(c, x)`` (coefficients (k, m, 6), breakpoints (m + 1,)),
        from which the ``PPoly`` is made when first needed.
    name : str
        What it is (printed by ``qfa-sim``).
    """

    def __init__(self, poly, name='trajectory'):
        if isinstance(poly, tuple):
            c, x = (np.asarray(v, dtype=float) for v in poly)
            self._poly = None
        else:
            c, x = poly.c, poly.x
            self._poly = poly
        if c.ndim != 3 or c.shape[2] != 6 or x.shape != (c.shape[1] + 1,):
            raise ValueError('poly must have six channels')
        self._c, self._x = c, x
        self.name = name
        self.start = float(x[0])
        self.end = float(x[-1])
        self._derivatives = None
        # Without terms of order >= 1 every piece is its constant: the values at the start
        # and the end are the first and last pieces' constants.
        self._still = bool(np.all(c[:-1] == 0.0)) and np.allclose(c[-1, 0], c[-1, -1])
        self._constant = self._still and bool(np.all(c[-1] == c[-1, 0]))
        self._rest_cache = None
        # The kinematics and local pose of a constant motion, the same at every instant.
        self._constant_cache = {}
        self._means = None

    @property
    def poly(self):
        """Return the :class:`scipy.interpolate.PPoly` of the six channels."""
        if self._poly is None:
            from scipy.interpolate import PPoly
            self._poly = PPoly(self._c, self._x, extrapolate=False)
        return self._poly

    def shifted(self, start_s):
        """Return the same motion starting at time ``start_s`` [s] instead of its own."""
        if start_s == self.start:
            return self
        return Trajectory((self._c, self._x - self.start + start_s), self.name)

    @property
    def duration(self):
        """Return the scripted duration [s] (the body rests afterwards)."""
        return self.end - self.start

    @property
    def is_static(self):
        """Return True when the body never moves."""
        return self._still

    def _channels(self, t):
        t = np.asarray(t, dtype=float)
        if self._constant:
            # The constant of every piece, what PPoly's Horner scheme returns exactly
            # when every higher coefficient is zero; no rates, no accelerations.
            zero = np.zeros((len(t), 6))
            return np.broadcast_to(self._c[-1, 0], zero.shape).copy(), zero, zero.copy()
        if self._derivatives is None:
            self._derivatives = (self.poly.derivative(1), self.poly.derivative(2))
        d1, d2 = self._derivatives
        clamped = np.clip(t, self.start, self.end)
        inside = ((t >= self.start) & (t <= self.end))[:, None]
        return (self.poly(clamped), np.where(inside, d1(clamped), 0.0),
                np.where(inside, d2(clamped), 0.0))

    def kinematics(self, t):
        """
        Return a dict of the motion at times ``t`` [s] (arrays over ``t``).

        Keys: ``latitude``, ``longitude``, ``height``, ``attitude`` (roll, pitch,
        yaw), ``dcm`` (C_b^n), ``velocity`` (ENU [m/s]), ``specific_force`` (body
        [m/s^2]), ``angular_rate`` (w_ib^b [rad/s]), ``body_rate`` (w_nb^b [rad/s]).
        """
        if self._constant:
            # The same at every instant: computed once (the truth publisher asks ten times
            # a second), repeated over ``t``.
            return self._repeat_constant('kinematics', self._kinematics, len(t))
        return self._kinematics(t)

    def _repeat_constant(self, name, compute, n):
        if name not in self._constant_cache:
            self._constant_cache[name] = compute(np.array([self.start]))
        value = self._constant_cache[name]
        if isinstance(value, dict):
            return {key: np.repeat(a, n, axis=0) for key, a in value.items()}
        return tuple(np.repeat(a, n, axis=0) for a in value)  # copies: callers may write

    def _kinematics(self, t):
        p, dp, ddp = self._channels(t)
        lat, lon, h = p[:, 0], p[:, 1], p[:, 2]
        dlat, dlon, dh = dp[:, 0], dp[:, 1], dp[:, 2]
        r_n, r_e = earth.radii_of_curvature(lat)
        dr_n, dr_e = earth.radii_derivatives(lat)
        cl, sl = np.cos(lat), np.sin(lat)
        velocity = np.stack([(r_e + h) * cl * dlon, (r_n + h) * dlat, dh], axis=-1)
        acceleration = np.stack([
            (dr_e * dlat + dh) * cl * dlon - (r_e + h) * sl * dlat * dlon
            + (r_e + h) * cl * ddp[:, 1],
            (dr_n * dlat + dh) * dlat + (r_n + h) * ddp[:, 0],
            ddp[:, 2]], axis=-1)
        w_ie = earth.earth_rate_enu(lat)
        w_en = earth.transport_rate_enu(lat, h, velocity)
        force_n = acceleration + np.cross(2.0 * w_ie + w_en, velocity) \
            - earth.gravity_enu(lat, h)
        roll, pitch, yaw = p[:, 3], p[:, 4], p[:, 5]
        droll, dpitch, dyaw = dp[:, 3], dp[:, 4], dp[:, 5]
        dcm = euler_to_dcm(roll, pitch, yaw)
        cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
        body_rate = np.stack([droll - dyaw * sp, dpitch * cr + dyaw * sr * cp,
                              -dpitch * sr + dyaw * cr * cp], axis=-1)
        specific_force = np.einsum('nji,nj->ni', dcm, force_n)
        angular_rate = np.einsum('nji,nj->ni', dcm, w_ie + w_en) + body_rate
        return {'latitude': lat, 'longitude': lon, 'height': h, 'attitude': p[:, 3:],
                'dcm': dcm, 'velocity': velocity, 'specific_force': specific_force,
                'angular_rate': angular_rate, 'body_rate': body_rate}

    def evaluate(self, t):
        """Return the specific force f^b [m/s^2] at times ``t`` [s], shape (n, 3)."""
        return self.kinematics(np.atleast_1d(t))['specific_force']

    def angular_rate(self, t):
        """Return w_ib^b [rad/s] at times ``t`` [s], shape (n, 3)."""
        return self.kinematics(np.atleast_1d(t))['angular_rate']

    def sample_means(self, start, period, n):
        """
        Return (mean f^b, mean w_ib^b) over ``n`` samples of ``period`` from ``start``.

        Each (n, 3) [m/s^2], [rad/s]: the exact means over each sample (what a strapdown
        algorithm reads as velocity and angle increments divided by the period), within
        1e-10 m/s^2 and 1e-13 rad/s or 1e-11 of the magnitude
        (:mod:`qfa_ros.model.trajectory_means`), however the samples are cut into calls.
        """
        if self._still:
            force, rate = self.rest_values()
            return np.tile(force, (n, 1)), np.tile(rate, (n, 1))
        if self._means is None:
            self._means = PiecewiseMeans(self._c, self._x)
        return self._means.sample_means(start, period, n)

    def rest_values(self):
        """
        Return (f^b, w_ib^b) of a body at rest (:attr:`is_static`), each shape (3,).

        The values at the start, computed once: what every sample of a trajectory at rest
        sees, so a caller can hold them over a whole chunk.
        """
        if not self._still:
            raise ValueError(f'{self.name} is not at rest')
        if self._rest_cache is None:
            k = self.kinematics(np.array([self.start]))
            self._rest_cache = (k['specific_force'][0], k['angular_rate'][0])
        return self._rest_cache

    def local_pose(self, t):
        """
        Return (position, quaternion, velocity, body rate) for an odometry message.

        Position [m] in the ENU tangent plane at the trajectory's first point;
        orientation (x, y, z, w) of the body in that plane; velocity [m/s] in body
        axes; body rate w_nb^b [rad/s] in body axes.
        """
        t = np.atleast_1d(t)
        if self._constant:
            return self._repeat_constant('local_pose', self._local_pose, len(t))
        return self._local_pose(t)

    def _local_pose(self, t):
        k = self.kinematics(t)
        origin = self._channels(np.array([self.start]))[0][0]
        c_e_n0 = ecef_to_enu_matrix(origin[0], origin[1])
        delta = geodetic_to_ecef(k['latitude'], k['longitude'], k['height']) \
            - geodetic_to_ecef(origin[0], origin[1], origin[2])
        position = delta @ c_e_n0.T
        # C_b^n0 = C_e^n0 C_n^e C_b^n.
        c_n_e = np.swapaxes(ecef_to_enu_matrix(k['latitude'], k['longitude']), -1, -2)
        dcm0 = c_e_n0 @ c_n_e @ k['dcm']
        velocity_body = np.einsum('nji,nj->ni', k['dcm'], k['velocity'])
        return position, dcm_to_quaternion(dcm0), velocity_body, k['body_rate']


def quintic_coefficients(times, values, rates, accelerations):
    """
    Return ``(c, x)`` of the C2 piecewise quintic through knot values, rates, accelerations.

    ``times`` (m,) strictly increasing [s]; the others (m, channels). Per piece of
    length ``h``, with the residuals ``D0 = y1 - y0 - y0' h - y0'' h^2/2``,
    ``D1 = y1' - y0' - y0'' h``, ``D2 = y1'' - y0''``, the cubic to quintic
    coefficients are ``(20 D0 - 8 D1 h + D2 h^2) / (2 h^3)``,
    ``(-30 D0 + 14 D1 h - 2 D2 h^2) / (2 h^4)``, ``(12 D0 - 6 D1 h + D2 h^2) / (2 h^5)``.
    """
    x = np.asarray(times, dtype=float)
    if x.ndim != 1 or len(x) < 2 or np.any(np.diff(x) <= 0):
        raise ValueError('times must be at least two strictly increasing values')
    y, d, a = (np.asarray(v, dtype=float) for v in (values, rates, accelerations))
    h = np.diff(x)[:, None]
    d0 = y[1:] - y[:-1] - d[:-1] * h - a[:-1] * h * h / 2
    d1 = d[1:] - d[:-1] - a[:-1] * h
    d2 = a[1:] - a[:-1]
    c = np.empty((6,) + d0.shape)
    c[5], c[4], c[3] = y[:-1], d[:-1], a[:-1] / 2
    c[2] = (20 * d0 - 8 * d1 * h + d2 * h * h) / (2 * h ** 3)
    c[1] = (-30 * d0 + 14 * d1 * h - 2 * d2 * h * h) / (2 * h ** 4)
    c[0] = (12 * d0 - 6 * d1 * h + d2 * h * h) / (2 * h ** 5)
    return c, x
