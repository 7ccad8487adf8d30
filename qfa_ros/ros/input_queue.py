"""Ground-truth input: specific force and angular rate from a topic, held onto the grid."""

import math

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np

from qfa_ros.model import earth
from qfa_ros.model.checks import is_finite
from qfa_ros.model.trajectory import quaternion_to_dcm
from qfa_ros.model.triad import NS_PER_S
from qfa_ros.ros.model_settings import static_profile

MAX_PENDING_INPUTS = 10000
MAX_SPECIFIC_FORCE = 1.0e4
"""Largest ground-truth specific force taken [m/s^2] (1000 g; the sensor saturates at 50 g)."""
MAX_ANGULAR_RATE = 1.0e3
"""Largest ground-truth angular rate taken [rad/s]."""


class GroundTruthInput:
    """
    Specific force and angular rate from a topic (``input.mode: topic``).

    ``input/imu`` (sensor_msgs/Imu: linear_acceleration, and angular_velocity unless
    its covariance[0] is -1), ``input/accel`` (geometry_msgs/AccelStamped: specific
    force only) or ``input/odometry`` (nav_msgs/Odometry, e.g. Gazebo's ground truth:
    see :meth:`accept_odometry`). Rates are w.r.t. inertial space in body axes; where a
    topic gives none, the static body's (the Earth rate at the location) stands in.
    Inputs are queued in stamp order; each sample takes the latest input stamped at or
    before it (sample and hold) and is stale once that input is older than
    ``input.timeout_s``. Before the first input the static orientation stands in.
    Stamps are a stranger's data: one further than ``input.stamp_window_s`` from the
    node clock (ahead or behind) is refused and counted before it can change anything,
    so what "in order" means for the next message stays the stream's. One ordering rule:
    a message stamped before the newest one accepted so far (queued, held or already
    used) is rejected, so a message stamped ahead holds back the honest input by at most
    the window (read-only).
    The caller holds the node lock around every method.

    Parameters
    ----------
    values
        The node's live parameter values (read, never written).
    """

    def __init__(self, values):
        self._values = values
        self.pending = []
        self.held = None
        self.rejected = 0
        self.refused_stamps = 0
        self.problem = None
        self._newest_ns = None  # stamp of the newest input accepted so far [ns]
        self._odometry = None  # (time_ns, world velocity) of the previous odometry message

    @property
    def active(self):
        """Return True when the input comes from the topic."""
        return self._values['input.mode'] == 'topic'

    def _static(self):
        """Return the static body's (specific force, angular rate), each 3 floats."""
        motion = static_profile(self._values)
        k = motion.kinematics(np.zeros(1))
        return tuple(k['specific_force'][0]), tuple(k['angular_rate'][0])

    def _refused(self, time_ns, now_ns):
        """Return True (and count it) when ``time_ns`` cannot be taken at ``now_ns``."""
        window_ns = int(self._values['input.stamp_window_s'] * NS_PER_S)
        if abs(time_ns - now_ns) > window_ns:
            self.refused_stamps += 1
            self.problem = (f'ground-truth input stamped {(time_ns - now_ns) / NS_PER_S:+.3g} s '
                            f'from the node clock refused (input.stamp_window_s '
                            f'{self._values["input.stamp_window_s"]:g})')
            return True
        if self._newest_ns is not None and time_ns < self._newest_ns:
            self.rejected += 1
            self.problem = 'ground-truth input out of order rejected'
            return True
        return False

    def accept(self, time_ns, value, rate=None, now_ns=None):
        """
        Queue one input stamped ``time_ns``; refuse bad ones.

        ``value``: specific force (m/s^2, x y z); ``rate``: angular rate (rad/s, x y z)
        or None (the static body's stands in); ``now_ns``: the node clock (None: the
        stamp is not judged against it).
        """
        if self._refused(time_ns, time_ns if now_ns is None else now_ns):
            return
        value = tuple(value) + (tuple(rate) if rate is not None else (math.nan,) * 3)
        if not all(is_finite(v) and abs(v) <= MAX_SPECIFIC_FORCE for v in value[:3]) or \
                (rate is not None and not all(is_finite(v) and abs(v) <= MAX_ANGULAR_RATE
                                              for v in value[3:])):
            self.rejected += 1
            self.problem = (f'non-finite or out-of-range ground-truth input rejected (limits '
                            f'{MAX_SPECIFIC_FORCE:g} m/s^2, {MAX_ANGULAR_RATE:g} rad/s): {value}')
            return
        self.pending.append((time_ns, value))
        self._newest_ns = time_ns
        if len(self.pending) > MAX_PENDING_INPUTS:
            # Inputs stamped ahead of the stream (another clock) must not pile up.
            self.held = self.pending.pop(0)

    def accept_odometry(self, time_ns, position, orientation, linear, angular, now_ns=None):
        """
        Queue the specific force and rate implied by one ``nav_msgs/Odometry``.

        ``orientation`` (x, y, z, w): body in a local-level world frame (z up, as
        Gazebo's ENU world); ``linear``, ``angular``: twist in body axes. The world
        acceleration is the backward difference of the world velocity between
        consecutive messages (zero for the first), so it lags by half a message period;
        ``f^b = C^T (a^w + (0, 0, gamma))`` with WGS-84 normal gravity at the location,
        ``w_ib^b = w + C^T w_ie^n`` (the world frame does not rotate with the Earth).
        ``now_ns`` as in :meth:`accept`.
        """
        if self._refused(time_ns, time_ns if now_ns is None else now_ns):
            return
        values = tuple(position) + tuple(orientation) + tuple(linear) + tuple(angular)
        norm = math.sqrt(sum(q * q for q in orientation))
        if not all(is_finite(v) for v in values) or not 0.5 < norm < 1.5:
            self.rejected += 1
            self.problem = f'bad ground-truth odometry rejected: {values}'
            return
        # Hand-written, not scipy's Rotation: importing scipy.spatial costs the node's
        # start-up 0.1 s (bench/results/library_alternatives.md).
        dcm = quaternion_to_dcm(np.asarray(orientation) / norm)
        velocity = dcm @ np.asarray(linear, dtype=float)
        acceleration = np.zeros(3)
        if self._odometry is not None and time_ns > self._odometry[0]:
            acceleration = (velocity - self._odometry[1]) * NS_PER_S \
                / (time_ns - self._odometry[0])
        self._odometry = (time_ns, velocity)
        latitude = math.radians(self._values['latitude_deg'])
        gravity = float(earth.normal_gravity(latitude, self._values['height_m']))
        force = dcm.T @ (acceleration + np.array([0.0, 0.0, gravity]))
        rate = np.asarray(angular, dtype=float) + dcm.T @ earth.earth_rate_enu(latitude)
        self.accept(time_ns, force, rate, now_ns)

    def inputs(self, stamps):
        """
        Return (specific force, angular rate, stale mask) per sample in topic mode.

        Outside topic mode (None, None, None).
        """
        if not self.active:
            return None, None, None
        count = len(stamps)
        static_force, static_rate = self._static()
        fallback = self.held
        if fallback is None:
            fallback = (None, static_force + static_rate)
        if not self.pending:
            force = np.tile(fallback[1], (count, 1))
            times = np.full(count, -1 if fallback[0] is None else fallback[0], dtype=np.int64)
        else:
            times_in = np.array([t for t, _ in self.pending], dtype=np.int64)
            values_in = np.array([v for _, v in self.pending])
            index = np.searchsorted(times_in, stamps, side='right') - 1
            force = values_in[np.maximum(index, 0)]
            times = times_in[np.maximum(index, 0)]
            before = index < 0
            force[before] = fallback[1]
            times[before] = -1 if fallback[0] is None else fallback[0]
            last = int(index[-1])
            if last >= 0:
                # Keep the sample-and-hold value and every input not used yet.
                self.held = self.pending[last]
                del self.pending[:last + 1]
        timeout_ns = int(self._values['input.timeout_s'] * NS_PER_S)
        stale = (times < 0) | (stamps - times > timeout_ns)
        force = np.asarray(force, dtype=float)
        rate = force[:, 3:].copy()
        unknown = ~np.isfinite(rate)
        rate[unknown] = np.broadcast_to(static_rate, rate.shape)[unknown]
        return force[:, :3].copy(), rate, stale

    def held_inputs(self, count):
        """Return the latest (force, rate) repeated ``count`` times (topic mode), else None."""
        if not self.active:
            return None, None
        static_force, static_rate = self._static()
        value = np.asarray(self.pending[-1][1] if self.pending else (
            self.held[1] if self.held else static_force + static_rate), dtype=float)
        rate = np.where(np.isfinite(value[3:]), value[3:], static_rate)
        return np.tile(value[:3], (count, 1)), np.tile(rate, (count, 1))

    def status(self, now_ns):
        """Return ``(level, message, key values)`` for the ``input`` diagnostic."""
        mode = self._values['input.mode']
        values = [('mode', mode), ('rejected inputs', self.rejected),
                  ('refused stamps', self.refused_stamps)]
        if mode == 'profile':
            values.append(('profile', self._values['input.profile']))
        if mode != 'topic':
            return DiagnosticStatus.OK, mode, values
        latest = self.pending[-1] if self.pending else self.held
        level, message = DiagnosticStatus.OK, 'ground-truth topic'
        if latest is None:
            level, message = DiagnosticStatus.WARN, \
                'no ground-truth input yet: imu/data_raw paused'
        else:
            age = (now_ns - latest[0]) / 1e9
            values.append(('input age [s]', f'{age:.3f}'))
            if age > self._values['input.timeout_s']:
                level, message = DiagnosticStatus.WARN, \
                    f'ground-truth input stale ({age:.3f} s old): imu/data_raw paused'
        if self.problem:
            values.append(('last rejection', self.problem))
            if level == DiagnosticStatus.OK and (self.rejected or self.refused_stamps):
                level, message = DiagnosticStatus.WARN, \
                    f'ground-truth topic; {self.problem} (last value held)'
        return level, message, values
