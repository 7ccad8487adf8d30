"""
Gyro bias at rest: average the gyros, remove the Earth rate, correct the published rate.

The lab practice of a gyro bias calibration (phidgets_spatial's ``imu/calibrate``): with
the sensor still, the mean gyro output is the bias plus the Earth rate seen in the body
axes. The schedule knows only what the sensor knows: its output (gyros and
accelerometers), the configured location and heading. Over ``duration_s`` it averages
both triads, levels the body from the accelerometer mean (roll, pitch) and takes the
heading from the configuration, then::

    C_b^n = R_z(yaw) R_y(pitch) R_x(roll),   roll = atan2(f_y, f_z),
                                             pitch = atan2(-f_x, sqrt(f_y^2 + f_z^2))
    w_ie^b = (C_b^n)^T Omega (0, cos(lat), sin(lat))          (ENU, REP-103)
    b = mean(y) + c_old - w_ie^b

with ``y`` the published rate (already corrected by ``c_old``). ``b`` becomes the new
correction the firmware subtracts. An error ``d`` in the configured heading leaves
``Omega cos(lat) |sin(d)|`` of Earth rate in the estimate (0.19 deg/h per degree at
45 deg); the level error of a biased accelerometer (100 ug: 0.1 mrad) adds 0.0015 deg/h.

Blocks of ``block_s`` whose gyro or accelerometer mean departs from the run's mean by
more than the motion limits mean the input moved: the schedule refuses and applies
nothing.
"""

from dataclasses import asdict, dataclass
import math

import numpy as np

from qfa_ros.calibration.schedule import EstimationError, Phase, require_closed, SensorPort
from qfa_ros.model.checks import is_finite
from qfa_ros.model.constants import DEG_PER_HOUR, MICRO_G
from qfa_ros.model.earth import earth_rate_enu
from qfa_ros.model.triad import AXES

BLOCK_S = 1.0
"""Averaging block of the motion check and the standard error [s]."""


@dataclass(frozen=True)
class GyroBiasSettings:
    """
    Settings of the gyro bias schedule.

    Attributes
    ----------
    duration_s : float
        Averaged sensor time [s] (at least two blocks of ``BLOCK_S``).
    latitude_deg : float
        Configured latitude [deg].
    yaw : float
        Configured heading [rad], REP-103 ENU yaw (pi/2: x north).
    rate_limit : float
        A block's gyro mean departing from the run's mean by more than this is a
        moving input [rad/s].
    accel_limit : float
        The same for the accelerometer block means [m/s^2].
    """

    duration_s: float = 10.0
    latitude_deg: float = 45.0
    yaw: float = math.pi / 2
    rate_limit: float = 10.0 * DEG_PER_HOUR
    accel_limit: float = 100.0 * MICRO_G

    def __post_init__(self):
        if not is_finite(self.duration_s, bool_ok=False) or self.duration_s < 2 * BLOCK_S:
            raise ValueError(f'duration_s must be at least {2 * BLOCK_S:g} s, '
                             f'got {self.duration_s!r}')
        if not is_finite(self.latitude_deg, bool_ok=False) or abs(self.latitude_deg) > 90.0:
            raise ValueError(f'latitude_deg must be in [-90, 90], got {self.latitude_deg!r}')
        if not is_finite(self.yaw, bool_ok=False):
            raise ValueError(f'yaw must be finite, got {self.yaw!r}')
        for name in ('rate_limit', 'accel_limit'):
            value = getattr(self, name)
            if not is_finite(value, bool_ok=False) or value <= 0:
                raise ValueError(f'{name} must be positive, got {value!r}')

    @property
    def blocks(self):
        """Return the blocks of :data:`BLOCK_S` averaged: ``duration_s`` rounded, at least two."""
        return max(2, int(round(self.duration_s / BLOCK_S)))

    def sensor_time_s(self):
        """Return the sensor time of one schedule [s]: its whole blocks."""
        return self.blocks * BLOCK_S


@dataclass
class GyroBiasResult:
    """
    What one gyro bias run measured and applied (trace and service answer).

    Attributes
    ----------
    kind : str
        ``gyro_bias``.
    settings : dict
        The schedule settings.
    estimate, std_error : float64[3]
        Bias per axis and its standard error from the block scatter [rad/s].
    earth_rate : float64[3]
        Earth rate in the body axes that was removed [rad/s].
    roll, pitch : float
        Levelled attitude from the accelerometer mean [rad].
    points : dict
        Block means: ``time_ns`` (block end), ``rate_x, rate_y, rate_z`` [rad/s],
        ``accel_x, accel_y, accel_z`` [m/s^2].
    residuals : float64[n, 3]
        Block gyro means minus the run's mean [rad/s].
    words_before, words_after : float64[3]
        Correction before and after [rad/s].
    applied : bool
        Whether the correction was written.
    start_ns, end_ns : int
        Sensor time span [ns].
    """

    kind: str
    settings: dict
    estimate: np.ndarray
    std_error: np.ndarray
    earth_rate: np.ndarray
    roll: float
    pitch: float
    points: dict
    residuals: np.ndarray
    words_before: np.ndarray
    words_after: np.ndarray
    applied: bool
    start_ns: int
    end_ns: int

    def to_mapping(self):
        """Return the scalar and per-axis fields as a mapping (trace result)."""
        per_axis = {name: {axis: float(v) for axis, v in zip(AXES, getattr(self, name))}
                    for name in ('estimate', 'std_error', 'earth_rate', 'words_before',
                                 'words_after')}
        return {**per_axis, 'roll': self.roll, 'pitch': self.pitch,
                'applied': bool(self.applied), 'start_ns': int(self.start_ns),
                'end_ns': int(self.end_ns), 'units': 'rad/s, rad'}

    def summary(self):
        """Return a one-line summary in deg/h."""
        bias = ', '.join(f'{a} {b / DEG_PER_HOUR:+.4f}±{e / DEG_PER_HOUR:.4f}'
                         for a, b, e in zip(AXES, self.estimate, self.std_error))
        earth = ', '.join(f'{a} {w / DEG_PER_HOUR:+.3f}' for a, w in zip(AXES, self.earth_rate))
        return (f'gyro bias [deg/h] {bias} (Earth rate removed {earth}; level roll '
                f'{math.degrees(self.roll):.3f} deg, pitch {math.degrees(self.pitch):.3f} deg)'
                f'{", applied" if self.applied else ""}')


def earth_rate_body(latitude_deg, roll, pitch, yaw):
    """Return the Earth rate in the body axes [rad/s] (ENU, C_b^n = R_z R_y R_x)."""
    w_n = earth_rate_enu(math.radians(latitude_deg))
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    r_z = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    r_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return (r_z @ r_y @ r_x).T @ w_n


def gyro_bias_schedule(sensor, state, settings=GyroBiasSettings()):
    """
    Average the gyros at rest and correct their bias (generator schedule).

    Yields the number of samples it needs and receives them; returns a
    :class:`GyroBiasResult`. Stores the correction in ``state.gyro_bias`` [rad/s].

    Raises
    ------
    EstimationError
        No gyros, a loop open, or the input moved.
    """
    port = SensorPort.of(sensor)
    if not port.has_gyros:
        raise EstimationError('the sensor has no gyros (gyro.enabled is false)')
    require_closed(port)
    start_ns = port.sensor_time_ns()
    block = port.samples_for(BLOCK_S)
    blocks = settings.blocks
    yield Phase('averaging', f'{blocks} blocks of {BLOCK_S:g} s', settings.sensor_time_s())
    samples = port.view((yield block * blocks))
    if not samples.valid.all() or np.any(samples.saturated):
        raise EstimationError('output invalid or saturated while averaging: nothing applied')
    rate = samples.gyro.reshape(blocks, block, 3).mean(axis=1)
    accel = samples.accel.reshape(blocks, block, 3).mean(axis=1)
    rate_mean, accel_mean = rate.mean(axis=0), accel.mean(axis=0)
    worst_rate = float(np.max(np.abs(rate - rate_mean)))
    worst_accel = float(np.max(np.abs(accel - accel_mean)))
    if worst_rate > settings.rate_limit or worst_accel > settings.accel_limit:
        raise EstimationError(
            f'input is moving: a {BLOCK_S:g} s mean departs {worst_rate / DEG_PER_HOUR:.2f} '
            f'deg/h (limit {settings.rate_limit / DEG_PER_HOUR:.2f}) and '
            f'{worst_accel / MICRO_G:.1f} ug (limit {settings.accel_limit / MICRO_G:.1f}) '
            'from the run mean; hold the sensor still')
    roll = math.atan2(accel_mean[1], accel_mean[2])
    pitch = math.atan2(-accel_mean[0], math.hypot(accel_mean[1], accel_mean[2]))
    earth = earth_rate_body(settings.latitude_deg, roll, pitch, settings.yaw)
    before = port.gyro_bias_correction()
    estimate = rate_mean + before - earth
    port.set_gyro_bias_correction(estimate)
    state.gyro_bias = [float(v) for v in estimate]
    end_ns = port.sensor_time_ns()
    times = samples.stamps_ns[block - 1::block]
    return GyroBiasResult(
        kind='gyro_bias', settings=asdict(settings), estimate=estimate,
        std_error=rate.std(axis=0, ddof=1) / math.sqrt(blocks), earth_rate=earth,
        roll=roll, pitch=pitch,
        points={'time_ns': times, **{f'rate_{a}': rate[:, i] for i, a in enumerate(AXES)},
                **{f'accel_{a}': accel[:, i] for i, a in enumerate(AXES)}},
        residuals=rate - rate_mean, words_before=before, words_after=estimate.copy(),
        applied=True, start_ns=start_ns, end_ns=end_ns)
