r"""
The truth of the sensor's errors: what the model holds now, as an INS filter states it.

The published output of a closed loop at rest with its input (no noise, no quantization)
is, per accelerometer axis ``i``::

    y_i = C( G_i [(1 + e_i(T)) (b_i + b_age,i(t) + a_i + k2_i a_i^2) + b_T,i(T, h)
                  + g_i - m_ref,i / K0] )          a = (I + M) f

with ``G_i = k_fb,nom / k_fb,i`` (the drifted feedback gain against the nominal output
scale: every component's drift, the DA0 word a correction wrote), ``e`` and ``b_T`` the
thermal scale-factor and zero-bias curves at the body temperature ``T`` (``h`` the
hysteresis state), ``g`` the bias-instability processes held now, ``m_ref`` the
reference moment while I_ref is switched on, and ``C`` the temperature compensation
(when on) at the noiseless temperature reading. The gyros (:mod:`qfa_ros.model.gyro`)::

    w_out = (I + S + S_T dT) (I + M_g) w + A |(I + M_g) w| + b + b_T dT + G f + s - c

with ``s`` the slow processes held now and ``c`` the bias correction the firmware
subtracts. :func:`error_truth` evaluates these maps at probe inputs and returns them as
bias, scale-factor-and-misalignment matrix and K2 (:class:`ErrorTruth`): the linear
model ``y = b + (I + N) f + k2 f^2`` of the published output around zero input.
"""

from dataclasses import dataclass

import numpy as np

from qfa_ros.model.hardware import loop_gains

PROBE_ACCEL = 1.0
"""Probe step of the accelerometer derivatives [m/s^2] (exact for the quadratic model)."""
PROBE_RATE = 0.01
"""Probe step of the gyro derivatives [rad/s]."""


@dataclass(frozen=True)
class ErrorTruth:
    """
    The errors of the published output now (body axes, SI units).

    Attributes
    ----------
    time : float
        Sensor time they hold at [s] (the triad's next sample).
    accel_bias : ndarray (3,)
        Accelerometer output at zero specific force [m/s^2].
    accel_matrix : ndarray (3, 3)
        ``N_a = dy/df - I`` at zero input: diagonal the scale-factor errors, off-diagonal
        the misalignment (cross-coupling) [1].
    accel_k2 : ndarray (3,)
        Second-order coefficient of each axis on its own input [1/(m/s^2)].
    gyro_bias : ndarray (3,)
        Gyro output at zero rate under the present specific force [rad/s] (NaN: no gyros).
    gyro_matrix : ndarray (3, 3)
        ``N_g = dw_out/dw - I`` at zero rate [1] (the asymmetry ``A`` is not in it).
    gyro_asymmetry : ndarray (3,)
        Scale-factor asymmetry ``A`` per axis [1].
    temperature : float
        Body temperature [degC] the errors hold at.
    """

    time: float
    accel_bias: np.ndarray
    accel_matrix: np.ndarray
    accel_k2: np.ndarray
    gyro_bias: np.ndarray
    gyro_matrix: np.ndarray
    gyro_asymmetry: np.ndarray
    temperature: float

    def imu_fields(self):
        """
        Return the ``truth/imu_errors`` layout: a dict of sensor_msgs/Imu field values.

        ``linear_acceleration``: accelerometer bias; ``angular_velocity``: gyro bias;
        ``linear_acceleration_covariance`` / ``angular_velocity_covariance``: ``N_a`` /
        ``N_g`` row major; ``orientation_covariance``: K2 x, y, z, gyro asymmetry x, y, z,
        body temperature, 0, 0 (``docs/ins.md``). Without gyros their fields are zero.
        """
        def floats(values):
            return [float(v) for v in np.nan_to_num(np.ravel(values))]
        return {'linear_acceleration': floats(self.accel_bias),
                'angular_velocity': floats(self.gyro_bias),
                'linear_acceleration_covariance': floats(self.accel_matrix),
                'angular_velocity_covariance': floats(self.gyro_matrix),
                'orientation_covariance': floats(np.concatenate([
                    self.accel_k2, np.nan_to_num(self.gyro_asymmetry),
                    [self.temperature, 0.0, 0.0]]))}

    def accel_output(self, force):
        """Return the published output the truth implies for specific forces (n, 3)."""
        force = np.atleast_2d(np.asarray(force, dtype=float))
        return self.accel_bias + force @ (np.eye(3) + self.accel_matrix).T \
            + self.accel_k2 * force * force


def accelerometer_transfer(triad, force):
    """
    Return the noiseless steady-state published output (n, 3) for specific forces (n, 3).

    The map of the module docstring with the triad's present state: its configuration,
    drift (steps, aging, temperature coefficients at the body temperature), loop words,
    reference-current switches, thermal terms, bias-instability state and compensation.
    """
    config = triad.config
    force = np.atleast_2d(np.asarray(force, dtype=float))
    a = force @ (np.eye(3) + np.asarray(config.misalignment, dtype=float)).T
    sensed = np.asarray(config.bias, dtype=float) + triad.drift.bias_at(triad.time) \
        + a + np.asarray(config.k2, dtype=float) * a * a
    v_temp = None
    if triad.thermal is not None:
        thermal = triad.thermal
        body = thermal.sensor_c
        sensed = sensed * (1.0 + thermal.scale_factor_error(body)) \
            + thermal.zero_bias(body, thermal.hysteresis)
        v_temp = np.full(len(force), float(thermal.voltage_at(thermal.probe_c)))
    output = np.empty_like(sensed)
    for i, loop in enumerate(triad.axes):
        # The gains the next chunk runs with (a drift just set is in them).
        gains = loop_gains(loop.hw, triad.drift.at(i, triad.time, triad.temperature),
                           loop.n_fpga, loop.n_vref, config.open_loop_cref_sensitivity)
        pendulosity = loop.hw.pendulosity
        held = float(np.sum(triad.noise.bias_state[i]))
        reference = gains.k_t * gains.i_ref / pendulosity if loop.reference_current_on \
            else 0.0
        output[:, i] = (sensed[:, i] + held - reference) * triad.scale * pendulosity \
            / gains.feedback_gain
    if triad.temperature_compensation and triad.temperature_compensator is not None \
            and v_temp is not None:
        output = triad.temperature_compensator.apply(output, v_temp)
    return output


def gyro_transfer(triad, rate, force):
    """Return the noiseless gyro output (n, 3) [rad/s] for rates and specific forces."""
    gyro = triad.gyro
    rate = np.atleast_2d(np.asarray(rate, dtype=float))
    force = np.broadcast_to(np.asarray(force, dtype=float), rate.shape)
    unit = gyro.unit
    change = triad.temperature - gyro.config.reference_c
    sensed = rate @ (np.eye(3) + unit.misalignment).T
    return sensed * (1.0 + unit.scale_factor + unit.scale_factor_tc * change) \
        + unit.asymmetry * np.abs(sensed) + unit.bias + unit.bias_tc * change \
        + force @ unit.g_sensitivity.T + gyro.in_run_bias - triad.gyro_bias_correction


def error_truth(triad, force=None):
    """
    Return the :class:`ErrorTruth` of ``triad`` now.

    ``force`` is the present specific force (3,) [m/s^2] the gyro bias's g-sensitivity
    acts with (default zero).
    """
    force = np.zeros(3) if force is None else np.asarray(force, dtype=float)
    h = PROBE_ACCEL
    probes = np.vstack([np.zeros(3), h * np.eye(3), -h * np.eye(3)])
    y = accelerometer_transfer(triad, probes)
    bias = y[0]
    jacobian = (y[1:4] - y[4:7]).T / (2 * h)
    curvature = (y[1:4] + y[4:7] - 2 * bias).diagonal() / (2 * h * h)
    nan3, nan33 = np.full(3, np.nan), np.full((3, 3), np.nan)
    gyro_bias, gyro_matrix, asymmetry = nan3, nan33, nan3
    if triad.gyro is not None:
        r = PROBE_RATE
        rates = np.vstack([np.zeros(3), r * np.eye(3), -r * np.eye(3)])
        w = gyro_transfer(triad, rates, force)
        gyro_bias = w[0]
        gyro_matrix = (w[1:4] - w[4:7]).T / (2 * r) - np.eye(3)
        asymmetry = triad.gyro.unit.asymmetry.copy()
    return ErrorTruth(time=triad.time, accel_bias=bias, accel_matrix=jacobian - np.eye(3),
                      accel_k2=curvature, gyro_bias=gyro_bias, gyro_matrix=gyro_matrix,
                      gyro_asymmetry=asymmetry, temperature=float(triad.temperature))
