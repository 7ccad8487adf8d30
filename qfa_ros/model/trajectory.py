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

Built-in motion scripts: :func:`static`, :func:`six_position_tumble`,
:func:`rate_table_turn`, :func:`vehicle_drive`, :func:`coning`, :func:`sculling`.
Built-in scripts join their knots by quintic Hermite pieces through positions,
rates and accelerations (C2), so dwells stay exactly still.

Trajectory files are CSV (:func:`load_csv`): one header line, then
``time_s, latitude_deg, longitude_deg, height_m, roll_deg, pitch_deg, yaw_deg`` per
row, joined by a C2 cubic spline. A pose log is what Gazebo, a reference INS/GNSS or a
survey exports and is the quantity an INS is scored against; a command script (the
gnss-ins-sim motion definition) would be a second way to write what the built-in
scripts already are.

The sensors read the mean of f^b and w_ib^b over each sample period
(:meth:`Trajectory.sample_means`): exact integrals of verified per-piece Chebyshev fits of
the compiled twin of the kinematics, within 1e-10 m/s^2 and 1e-13 rad/s (or 1e-11 of the
magnitude), built by :mod:`qfa_ros.model.trajectory_means`.

One cohesive module: the pose representation, its exact kinematics, the scripts and the
file format that build it.
:mod:`scipy.interpolate` (a third of a second to import) is loaded only when a moving
trajectory is evaluated or a file read: a body at rest (``qfa-sim static``, the node's
default pose) never needs it.
"""

import csv
import io
import math
import os
import warnings

import numpy as np

from qfa_ros.model import earth
from qfa_ros.model.files import read_regular_file
from qfa_ros.model.trajectory_means import PiecewiseMeans
from qfa_ros.model.units import DEGREE

MAX_CSV_BYTES = 16 << 20
"""Largest trajectory file read [bytes]: 16 MiB, about 250 000 poses (7 h at 10 Hz)."""
CSV_COLUMNS = ('time_s', 'latitude_deg', 'longitude_deg', 'height_m', 'roll_deg',
               'pitch_deg', 'yaw_deg')


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
        k = self.kinematics(np.atleast_1d(t))
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


def quintic_poly(times, values, rates, accelerations):
    """
    Return the C2 piecewise quintic through knot values, rates and accelerations.

    A :class:`scipy.interpolate.PPoly`; :func:`quintic_coefficients` gives its ``(c, x)``.
    """
    from scipy.interpolate import PPoly
    return PPoly(*quintic_coefficients(times, values, rates, accelerations),
                 extrapolate=False)


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


def _location(latitude_deg, longitude_deg, height_m):
    earth.check_location(latitude_deg, longitude_deg, height_m)
    return math.radians(latitude_deg), math.radians(longitude_deg), float(height_m)


def _dwells(location, attitudes, dwell_s, move_s):
    """Knots resting ``dwell_s`` at each attitude, moving ``move_s`` between them."""
    times, poses = [], []
    t = 0.0
    for k, attitude in enumerate(attitudes):
        if k:
            t += move_s
        for _ in range(2):
            times.append(t)
            poses.append(tuple(location) + tuple(attitude))
            t += dwell_s
        t -= dwell_s
    poses = np.array(poses)
    zero = np.zeros_like(poses)
    return quintic_poly(times, poses, zero, zero)


def static(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0, roll=0.0, pitch=0.0,
           yaw=math.pi / 2):
    """Return a body at rest at a location, attitude in [rad] (yaw pi/2: x north)."""
    location = _location(latitude_deg, longitude_deg, height_m)
    pose = np.array([location + (roll, pitch, yaw)] * 2)
    zero = np.zeros_like(pose)
    return Trajectory(quintic_coefficients([0.0, 1.0], pose, zero, zero), 'static')


TUMBLE_ATTITUDES = ((0.0, 0.0), (math.pi, 0.0), (0.0, -math.pi / 2), (0.0, math.pi / 2),
                    (math.pi / 2, 0.0), (-math.pi / 2, 0.0))
"""(roll, pitch) of the six positions: z up, z down, x up, x down, y up, y down."""


def six_position_tumble(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0,
                        dwell_s=10.0, move_s=4.0, yaw=math.pi / 2):
    """Return the six-position tumble: each axis up then down, ``dwell_s`` at rest each."""
    location = _location(latitude_deg, longitude_deg, height_m)
    attitudes = [(r, p, yaw) for r, p in TUMBLE_ATTITUDES]
    return Trajectory(_dwells(location, attitudes, dwell_s, move_s), 'six-position tumble')


def rate_table_turn(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0, rate_deg_s=10.0,
                    turns=2, ramp_s=5.0, dwell_s=10.0, yaw=math.pi / 2):
    """
    Return a level rate-table run about z.

    Rest, a smooth ramp to ``rate_deg_s``, ``turns`` full turns at constant rate, a
    ramp down, rest.
    """
    location = _location(latitude_deg, longitude_deg, height_m)
    rate = math.radians(rate_deg_s)
    if rate == 0 or turns <= 0 or ramp_s <= 0 or dwell_s < 0:
        raise ValueError('rate_deg_s and turns must be non-zero; ramp_s > 0, dwell_s >= 0')
    # Smooth ramp (quintic Hermite of yaw): mean rate over the ramp is rate/2.
    hold = 2 * math.pi * turns / abs(rate)
    times = np.cumsum([0.0, dwell_s or 1e-3, ramp_s, hold, ramp_s, dwell_s or 1e-3])
    yaw_k = np.cumsum([yaw, 0.0, rate * ramp_s / 2, rate * hold, rate * ramp_s / 2, 0.0])
    rate_k = np.array([0.0, 0.0, rate, rate, 0.0, 0.0])
    values = np.array([location + (0.0, 0.0, y) for y in yaw_k])
    rates = np.zeros_like(values)
    rates[:, 5] = rate_k
    return Trajectory(quintic_poly(times, values, rates, np.zeros_like(values)),
                      'rate-table turn')


DRIVE_SCRIPT = (
    # (duration s, along-track acceleration m/s^2, yaw rate deg/s, climb-angle rate deg/s)
    (20.0, 0.0, 0.0, 0.0), (10.0, 1.5, 0.0, 0.0), (30.0, 0.0, 0.0, 0.0),
    (9.0, 0.0, 10.0, 0.0), (40.0, 0.0, 0.0, 0.0), (5.0, 0.0, 0.0, 0.6),
    (30.0, 0.0, 0.0, 0.0), (5.0, 0.0, 0.0, -0.6), (20.0, 0.5, 0.0, 0.0),
    (18.0, 0.0, -10.0, 0.0), (60.0, 0.0, 0.0, 0.0), (10.0, -1.0, 5.0, 0.0),
    (90.0, 0.0, 3.0, 0.0), (10.0, 1.0, 0.0, 0.0), (30.0, 0.0, -6.0, 0.0),
    (60.0, 0.0, 0.0, 0.0), (5.0, 0.0, 0.0, -0.8), (40.0, 0.0, 0.0, 0.0),
    (5.0, 0.0, 0.0, 0.8), (10.0, -1.5, 0.0, 0.0), (60.0, 0.0, 0.0, 0.0),
    (22.5, 0.0, 8.0, 0.0), (10.0, -1.0, 0.0, 0.0), (20.0, 0.0, 0.0, 0.0),
)
"""A 10-minute drive: accelerations, turns both ways, a hill, a stop at the end."""


def vehicle_drive(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0, yaw=math.pi / 2,
                  script=DRIVE_SCRIPT, ramp_s=1.0, knot_s=0.05):
    """
    Return a land-vehicle drive from a command script, gnss-ins-sim style.

    Each row ``(duration, acceleration, yaw rate, climb-angle rate)`` holds its
    commands; between rows they change smoothly over ``ramp_s`` (a C1 smoothstep),
    the body follows its velocity vector (no side slip, no roll), pitch = -climb
    angle (REP-103 pitch is nose down). The commands are integrated on a 1 kHz grid
    and joined by quintic Hermite pieces every ``knot_s``.
    """
    lat0, lon0, h0 = _location(latitude_deg, longitude_deg, height_m)
    script = np.asarray(script, dtype=float)
    if script.ndim != 2 or script.shape[1] != 4 or np.any(script[:, 0] <= 0):
        raise ValueError('script rows must be (duration > 0, accel, yaw rate, climb rate)')
    dt = 1e-3
    bounds = np.concatenate([[0.0], np.cumsum(script[:, 0])])
    t = np.arange(0.0, bounds[-1] + dt / 2, dt)
    commands = np.zeros((len(t), 3))
    previous = np.zeros(3)
    for (start, row) in zip(bounds[:-1], script):
        target = row[1:] * np.array([1.0, DEGREE, DEGREE])
        s = np.clip((t - start) / ramp_s, 0.0, 1.0)
        blend = s * s * (3 - 2 * s)
        active = t >= start
        commands[active] = previous + (target - previous) * blend[active, None]
        previous = target
    # Integrate (trapezoid) speed, heading and climb angle, then position.
    def integrate(rate, initial):
        return initial + np.concatenate([[0.0], np.cumsum((rate[1:] + rate[:-1]) * dt / 2)])
    speed = np.maximum(integrate(commands[:, 0], 0.0), 0.0)
    heading = integrate(commands[:, 1], yaw)
    climb = integrate(commands[:, 2], 0.0)
    ve = speed * np.cos(climb) * np.cos(heading)
    vn = speed * np.cos(climb) * np.sin(heading)
    vu = speed * np.sin(climb)
    h = integrate(vu, h0)
    r_n, _ = earth.radii_of_curvature(lat0)
    lat = integrate(vn / (r_n + h), lat0)
    if np.max(np.abs(lat)) > math.radians(earth.MOVING_LATITUDE_LIMIT_DEG):
        raise ValueError(f'latitude_deg {latitude_deg:g}: the drive comes within '
                         f'{90.0 - earth.MOVING_LATITUDE_LIMIT_DEG:g} deg of a pole, where '
                         'its longitude rate diverges')
    _, r_e = earth.radii_of_curvature(lat)
    lon = integrate(ve / ((r_e + h) * np.cos(lat)), lon0)
    channels = np.stack([lat, lon, h, np.zeros_like(t), -climb, heading], axis=-1)
    step = int(round(knot_s / dt))
    rates = np.gradient(channels, dt, axis=0)
    accelerations = np.gradient(rates, dt, axis=0)
    index = np.arange(0, len(t), step)
    if index[-1] != len(t) - 1:
        index = np.append(index, len(t) - 1)
    rates[[0, -1]] = 0.0
    accelerations[[0, -1]] = 0.0
    return Trajectory(quintic_poly(t[index], channels[index], rates[index],
                                   accelerations[index]), 'vehicle drive')


def _vibration(location, duration_s, frequency_hz, knots_per_cycle, motion):
    """Knots of a periodic ``motion(t) -> (values, rates, accelerations)`` (m, 6)."""
    if not frequency_hz > 0 or not duration_s > 0:
        raise ValueError('frequency_hz and duration_s must be positive')
    t = np.arange(0.0, duration_s, 1.0 / (frequency_hz * knots_per_cycle))
    t = np.append(t, duration_s)
    values, rates, accelerations = motion(t)
    values = values + np.array(location + (0.0, 0.0, 0.0))
    # The body rests at the end poses before and after: the rates step there.
    return Trajectory(quintic_poly(t, values, rates, accelerations))


def _sine(amplitude, w, s, c):
    """Return ``amplitude sin(w t)`` and its first two derivatives, given its sin and cos."""
    return amplitude * s, amplitude * w * c, -amplitude * w * w * s


def coning(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0, amplitude_deg=0.5,
           frequency_hz=10.0, duration_s=60.0, yaw=math.pi / 2, knots_per_cycle=32):
    """
    Return coning: roll = A sin(2 pi f t), pitch = A cos(2 pi f t) - A (90 deg apart).

    The body axis z traces a cone; a strapdown algorithm without a coning correction
    accumulates a z attitude drift of about ``pi f A^2`` [rad/s].
    """
    location = _location(latitude_deg, longitude_deg, height_m)
    amplitude, w = math.radians(amplitude_deg), 2 * math.pi * frequency_hz

    def motion(t):
        values, rates, accelerations = (np.zeros((len(t), 6)) for _ in range(3))
        s, c = np.sin(w * t), np.cos(w * t)
        values[:, 3], rates[:, 3], accelerations[:, 3] = _sine(amplitude, w, s, c)
        values[:, 4], rates[:, 4], accelerations[:, 4] = \
            amplitude * (c - 1), -amplitude * w * s, -amplitude * w * w * c
        values[:, 5] = yaw
        return values, rates, accelerations

    trajectory = _vibration(location, duration_s, frequency_hz, knots_per_cycle, motion)
    trajectory.name = 'coning'
    return trajectory


def sculling(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0, amplitude_deg=0.5,
             displacement_m=0.001, frequency_hz=10.0, duration_s=60.0, yaw=math.pi / 2,
             knots_per_cycle=32):
    """
    Return sculling: roll = A sin(2 pi f t) with an in-phase vertical vibration.

    The vibration of ``displacement_m`` amplitude along the ENU up axis, in phase with
    the roll, rectifies into a mean specific force along body y.
    """
    location = _location(latitude_deg, longitude_deg, height_m)
    amplitude, w = math.radians(amplitude_deg), 2 * math.pi * frequency_hz

    def motion(t):
        values, rates, accelerations = (np.zeros((len(t), 6)) for _ in range(3))
        s, c = np.sin(w * t), np.cos(w * t)
        values[:, 3], rates[:, 3], accelerations[:, 3] = _sine(amplitude, w, s, c)
        values[:, 2], rates[:, 2], accelerations[:, 2] = _sine(displacement_m, w, s, c)
        values[:, 5] = yaw
        return values, rates, accelerations

    trajectory = _vibration(location, duration_s, frequency_hz, knots_per_cycle, motion)
    trajectory.name = 'sculling'
    return trajectory


def load_csv(path, max_bytes=MAX_CSV_BYTES):
    """
    Return the :class:`Trajectory` of a CSV pose file (see the module docstring).

    The file is a stranger's: read by :func:`~qfa_ros.model.files.read_regular_file`
    (a regular file of at most ``max_bytes``), parsed in bounded memory, and no error
    quotes its content.

    Raises
    ------
    ValueError
        The file cannot be read or is not a pose file; the message names the path.
    """
    return parse_csv(read_regular_file(path, max_bytes), os.fspath(path))


def parse_csv(data, name='trajectory'):
    """Return the :class:`Trajectory` of the bytes of a CSV pose file called ``name``."""
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError:
        raise ValueError(f'{name}: not UTF-8 text') from None
    first, _, body = text.partition('\n')
    header = tuple(column.strip() for column in first.strip().split(','))
    if header != CSV_COLUMNS:
        raise ValueError(f'{name}: the first line must be the header '
                         f'{",".join(CSV_COLUMNS)}')
    try:
        # numpy's parser: memory proportional to the numbers, and its errors (which
        # quote the offending text) are replaced by one that does not.
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            data = np.loadtxt(io.StringIO(body), delimiter=',', ndmin=2, dtype=float)
    except ValueError:
        raise ValueError(f'{name}: every row after the header must be 7 comma-separated '
                         'numbers') from None
    if data.ndim != 2 or len(data) < 2 or data.shape[1] != 7:
        raise ValueError(f'{name}: needs at least two rows of 7 numbers')
    if not np.all(np.isfinite(data)) or np.any(np.diff(data[:, 0]) <= 0):
        raise ValueError(f'{name}: values must be finite and times strictly increasing')
    unusable = np.flatnonzero(~earth.location_usable(*data[:, 1:4].T))
    if unusable.size:
        raise ValueError(f'{name}: row {unusable[0] + 1}: latitude, longitude or height out '
                         'of range (see qfa_ros.model.earth.check_location)')
    channels = np.radians(data[:, 1:])
    channels[:, 2] = data[:, 3]
    channels[:, 3:] = np.unwrap(channels[:, 3:], axis=0)
    from scipy.interpolate import CubicSpline, PPoly
    spline = CubicSpline(data[:, 0], channels, axis=0, bc_type='clamped')
    return Trajectory(PPoly(spline.c, spline.x, extrapolate=False), f'file {name}')


def save_csv(path, trajectory, rate_hz=100.0):
    """Write ``trajectory`` sampled at ``rate_hz`` as a CSV pose file."""
    t = np.arange(trajectory.start, trajectory.end + 0.5 / rate_hz, 1.0 / rate_hz)
    k = trajectory.kinematics(t)
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(CSV_COLUMNS)
        for row in zip(t, np.degrees(k['latitude']), np.degrees(k['longitude']), k['height'],
                       *np.degrees(k['attitude']).T):
            writer.writerow([f'{v:.12g}' for v in row])


SCRIPTS = {
    'static': static,
    'tumble': six_position_tumble,
    'rate-table': rate_table_turn,
    'drive': vehicle_drive,
    'coning': coning,
    'sculling': sculling,
}
"""Built-in motion scripts by name (each takes latitude_deg, longitude_deg, height_m, yaw)."""
