"""
The trajectories a run can follow: built-in motion scripts by name, and pose files.

Built-in motion scripts (:data:`SCRIPTS`): :func:`static`, :func:`six_position_tumble`,
:func:`rate_table_turn`, :func:`vehicle_drive`, :func:`coning`, :func:`sculling`.
Built-in scripts join their knots by quintic Hermite pieces through positions,
rates and accelerations (C2), so dwells stay exactly still.

Trajectory files are CSV (:func:`load_csv`): one header line, then
``time_s, latitude_deg, longitude_deg, height_m, roll_deg, pitch_deg, yaw_deg`` per
row, joined by a C2 cubic spline. A pose log is what Gazebo, a reference INS/GNSS or a
survey exports and is the quantity an INS is scored against; a command script (the
gnss-ins-sim motion definition) would be a second way to write what the built-in
scripts already are.

Each returns a :class:`qfa_ros.model.trajectory.Trajectory`.
"""

import csv
import io
import math
import os
import warnings

import numpy as np

from qfa_ros.model import checks, earth
from qfa_ros.model.constants import DEGREE
from qfa_ros.model.safe_files import read_regular_file
from qfa_ros.model.trajectory import quintic_coefficients, Trajectory

MAX_CSV_BYTES = 16 << 20
"""Largest trajectory file read [bytes]: 16 MiB, about 250 000 poses (7 h at 10 Hz)."""
CSV_COLUMNS = ('time_s', 'latitude_deg', 'longitude_deg', 'height_m', 'roll_deg',
               'pitch_deg', 'yaw_deg')


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
    return quintic_coefficients(times, poses, zero, zero)


def static(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0, roll=0.0, pitch=0.0,
           yaw=math.pi / 2):
    """Return a body at rest at a location, attitude in [rad] (yaw pi/2: x north)."""
    location = _location(latitude_deg, longitude_deg, height_m)
    for name, angle in (('roll', roll), ('pitch', pitch), ('yaw', yaw)):
        checks.finite(name, angle)
    return Trajectory(_dwells(location, [(roll, pitch, yaw)], 1.0, 0.0), 'static')


TUMBLE_ATTITUDES = ((0.0, 0.0), (math.pi, 0.0), (0.0, -math.pi / 2), (0.0, math.pi / 2),
                    (math.pi / 2, 0.0), (-math.pi / 2, 0.0))
"""(roll, pitch) of the six positions: z up, z down, x up, x down, y up, y down."""


def six_position_tumble(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0,
                        dwell_s=10.0, move_s=4.0, yaw=math.pi / 2):
    """Return the six-position tumble: each axis up then down, ``dwell_s`` at rest each."""
    location = _location(latitude_deg, longitude_deg, height_m)
    checks.positive('dwell_s', dwell_s)
    checks.positive('move_s', move_s)
    checks.finite('yaw', yaw)
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
    for name, value in (('rate_deg_s', rate_deg_s), ('turns', turns), ('ramp_s', ramp_s),
                        ('dwell_s', dwell_s), ('yaw', yaw)):
        checks.finite(name, value)
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
    return Trajectory(quintic_coefficients(times, values, rates, np.zeros_like(values)),
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
    checks.finite('yaw', yaw)
    checks.positive('ramp_s', ramp_s)
    checks.positive('knot_s', knot_s)
    script = np.asarray(script, dtype=float)
    if script.ndim != 2 or script.shape[1] != 4 or np.any(script[:, 0] <= 0) \
            or not np.all(np.isfinite(script)):
        raise ValueError('script rows must be finite (duration > 0, accel, yaw rate, climb '
                         'rate)')
    dt = 1e-3
    if knot_s < dt:
        raise ValueError(f'knot_s must be at least the {dt:g} s grid, got {knot_s!r}')
    bounds = np.concatenate([[0.0], np.cumsum(script[:, 0])])
    t = np.arange(0.0, bounds[-1] + dt / 2, dt)
    commands = np.zeros((len(t), 3))
    previous = np.zeros(3)
    # Each row's commands hold from its start until the next row's start (which takes over).
    firsts = np.searchsorted(t, bounds[:-1])
    for first, last, start, row in zip(firsts, list(firsts[1:]) + [len(t)], bounds, script):
        target = row[1:] * np.array([1.0, DEGREE, DEGREE])
        s = np.clip((t[first:last] - start) / ramp_s, 0.0, 1.0)
        blend = s * s * (3 - 2 * s)
        commands[first:last] = previous + (target - previous) * blend[:, None]
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
    return Trajectory(quintic_coefficients(t[index], channels[index], rates[index],
                                   accelerations[index]), 'vehicle drive')


def _vibration(name, location, duration_s, frequency_hz, knots_per_cycle, yaw, amplitude_deg,
               second):
    """
    Return a roll ``A sin(w t)`` and a second motion in step with it, knots per cycle.

    ``second(s, c, w)`` returns the second channel's index and its values, rates and
    accelerations, given ``s = sin(w t)`` and ``c = cos(w t)``.
    """
    checks.positive('frequency_hz', frequency_hz)
    checks.positive('duration_s', duration_s)
    checks.finite('yaw', yaw)
    checks.finite('amplitude_deg', amplitude_deg)
    try:
        valid = not isinstance(knots_per_cycle, bool) and knots_per_cycle >= 1 \
            and int(knots_per_cycle) == knots_per_cycle
    except (TypeError, ValueError, OverflowError):
        valid = False
    if not valid:
        raise ValueError(f'knots_per_cycle must be an integer >= 1, got {knots_per_cycle!r}')
    t = np.arange(0.0, duration_s, 1.0 / (frequency_hz * knots_per_cycle))
    t = np.append(t, duration_s)
    w = 2 * math.pi * frequency_hz
    values, rates, accelerations = (np.zeros((len(t), 6)) for _ in range(3))
    s, c = np.sin(w * t), np.cos(w * t)
    values[:, 3], rates[:, 3], accelerations[:, 3] = _sine(math.radians(amplitude_deg), w, s, c)
    channel, *motion = second(s, c, w)
    values[:, channel], rates[:, channel], accelerations[:, channel] = motion
    values[:, 5] = yaw
    values = values + np.array(location + (0.0, 0.0, 0.0))
    # The body rests at the end poses before and after: the rates step there.
    return Trajectory(quintic_coefficients(t, values, rates, accelerations), name)


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
    a = math.radians(amplitude_deg)
    return _vibration('coning', location, duration_s, frequency_hz, knots_per_cycle, yaw,
                      amplitude_deg, lambda s, c, w: (4, a * (c - 1), -a * w * s, -a * w * w * c))


def sculling(latitude_deg=45.0, longitude_deg=0.0, height_m=0.0, amplitude_deg=0.5,
             displacement_m=0.001, frequency_hz=10.0, duration_s=60.0, yaw=math.pi / 2,
             knots_per_cycle=32):
    """
    Return sculling: roll = A sin(2 pi f t) with an in-phase vertical vibration.

    The vibration of ``displacement_m`` amplitude along the ENU up axis, in phase with
    the roll, rectifies into a mean specific force along body y.
    """
    location = _location(latitude_deg, longitude_deg, height_m)
    checks.finite('displacement_m', displacement_m)
    return _vibration('sculling', location, duration_s, frequency_hz, knots_per_cycle, yaw,
                      amplitude_deg, lambda s, c, w: (2, *_sine(displacement_m, w, s, c)))


def load_csv(path, max_bytes=MAX_CSV_BYTES):
    """
    Return the :class:`Trajectory` of a CSV pose file (see the module docstring).

    The file is a stranger's: read by :func:`~qfa_ros.model.safe_files.read_regular_file`
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
    checks.positive('rate_hz', rate_hz)
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
