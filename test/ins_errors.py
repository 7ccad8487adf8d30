"""The linear error model of a stationary INS, with the configured noise, for the tests.

A standard psi-angle error-state model (Titterton & Weston 2004 §12.3, Groves 2013 §14.2)
for an ENU local-level mechanization at rest with its height held, written apart from the
emulator: it takes an error budget in the configuration's own terms (biases, spreads,
noise coefficients) and returns the mean and standard deviation of the navigation errors.

Navigation error states ``x_n = (dp_E, dp_N, dv_E, dv_N, psi_E, psi_N, psi_U)`` with
``C_est = (I - [psi x]) C_true`` and, at rest (v = 0)::

    dp' = dv
    dv' = f^n x psi - 2 w_ie x dv + C b_a                  (east, north rows)
    psi' = -w_ie x psi + dw_en(dv) + dw_ie(dlat) - C b_g

``b_a``, ``b_g`` are body-axis error states: a constant (its mean the configured bias,
its variance the spreads of the unit draw), the rate random walk (``b' = w``,
intensity K^2) and one first-order Gauss-Markov state per correlation time
(``b' = -b / T + w``, intensity ``2 q^2 / T``, started stationary). White accelerometer
noise (intensity N_a^2, Allan deviation N_a / sqrt(tau)) drives ``dv``, the angle random
walk (intensity N_g^2) drives ``psi``. The mean and the covariance are propagated
exactly between the output instants with the matrix exponential (Van Loan 1978).
"""

import math

import numpy as np
from scipy.linalg import expm

from qfa_ros.model import earth
from qfa_ros.model.noise import flicker_component_variance

NAV = 7


def _navigation_matrix(latitude):
    """Return the 7x7 dynamics of the navigation error states (the equations above)."""
    g = float(earth.normal_gravity(latitude))
    r_n, r_e = earth.radii_of_curvature(latitude)
    w_ie = earth.earth_rate_enu(latitude)
    f_n = np.array([0.0, 0.0, g])

    def rates(x):
        dv, psi = np.array([x[2], x[3], 0.0]), x[4:7]
        dlat = x[1] / r_n
        dv_dot = np.cross(f_n, psi) - 2 * np.cross(w_ie, dv)
        dw_en = np.array([-dv[1] / r_n, dv[0] / r_e, dv[0] * math.tan(latitude) / r_e])
        dw_ie = earth.EARTH_RATE * np.array([0.0, -math.sin(latitude),
                                             math.cos(latitude)]) * dlat
        return np.concatenate([dv[:2], dv_dot[:2], -np.cross(w_ie, psi) + dw_en + dw_ie])

    return np.column_stack([rates(e) for e in np.eye(NAV)])


def gyro_constant_variance(gyro, rate_b, force_b, delta_t=0.0):
    """
    Return the variance per body axis [(rad/s)^2] of the gyro unit draw's constant error.

    The IEEE 952 terms of :mod:`qfa_ros.model.gyro` at a constant rate ``rate_b`` and
    specific force ``force_b``: turn-on bias, g-sensitivity (each element of G),
    misalignment (off-diagonal), scale factor and asymmetry, and the temperature
    coefficients at ``delta_t`` from the reference temperature.
    """
    rate_b, force_b = np.asarray(rate_b, float), np.asarray(force_b, float)
    off_diagonal = np.array([np.sum(np.delete(rate_b, i) ** 2) for i in range(3)])
    return (gyro.turn_on_bias ** 2 + gyro.g_sensitivity ** 2 * np.sum(force_b ** 2)
            + gyro.misalignment ** 2 * off_diagonal
            + (gyro.scale_factor ** 2 + gyro.scale_factor_asymmetry ** 2
               + (gyro.scale_factor_tc * delta_t) ** 2) * rate_b ** 2
            + (gyro.bias_tc * delta_t) ** 2)


class StaticErrorModel:
    """
    Mean and standard deviation of the free-inertial errors at rest (height held).

    Parameters
    ----------
    latitude : float
        Geodetic latitude [rad].
    body_to_nav : array_like, (3, 3)
        Attitude C_b^n.
    accel_bias : array_like, (3,)
        Known accelerometer bias, body axes [m/s^2].
    gyro_bias : array_like, (3,)
        Known gyro bias, body axes [rad/s] (the mean of the constant state).
    gyro_bias_variance : array_like, (3,)
        Variance of the gyro's random constant error per body axis [(rad/s)^2].
    gyro : GyroConfig or None
        Gyro noise (ARW, bias instability, rate random walk); None: noise-free.
    accel_noise : NoiseConfig or None
        Accelerometer noise (density, bias instability); None: noise-free.
    """

    def __init__(self, latitude, body_to_nav, accel_bias, gyro_bias, gyro_bias_variance,
                 gyro=None, accel_noise=None):
        c = np.asarray(body_to_nav, dtype=float)
        blocks = []  # (error of, decay rate, intensity, initial variance, mean) per 3 states

        def add(target, decay, intensity, variance, mean=np.zeros(3)):
            blocks.append((target, decay, intensity, np.asarray(variance, float) * np.ones(3),
                           np.asarray(mean, float)))

        add('accel', 0.0, 0.0, 0.0, accel_bias)
        add('gyro', 0.0, 0.0, gyro_bias_variance, gyro_bias)
        for config, target in ((gyro, 'gyro'), (accel_noise, 'accel')):
            if config is None:
                continue
            q2 = flicker_component_variance(config)
            if q2 > 0:
                for tau in config.correlation_times:
                    add(target, 1.0 / tau, 2.0 * q2 / tau, q2)
        if gyro is not None and gyro.rate_random_walk > 0:
            add('gyro', 0.0, gyro.rate_random_walk ** 2, 0.0)
        size = NAV + 3 * len(blocks)
        f = np.zeros((size, size))
        f[:NAV, :NAV] = _navigation_matrix(latitude)
        q = np.zeros((size, size))
        self.mean0 = np.zeros(size)
        self.covariance0 = np.zeros((size, size))
        for k, (target, decay, intensity, variance, mean) in enumerate(blocks):
            s = slice(NAV + 3 * k, NAV + 3 * k + 3)
            if target == 'accel':
                f[2:4, s] = c[0:2]
            else:
                f[4:7, s] = -c
            f[s, s] = -decay * np.eye(3)
            q[s, s] = intensity * np.eye(3)
            self.covariance0[s, s] = np.diag(variance)
            self.mean0[s] = mean
        if accel_noise is not None:
            q[2:4, 2:4] = accel_noise.noise_density ** 2 * np.eye(2)
        if gyro is not None:
            q[4:7, 4:7] = gyro.arw ** 2 * np.eye(3)
        self.dynamics, self.intensity = f, q

    def _discrete(self, step):
        """
        Return (Phi, Q_d) over ``step`` [s]: Van Loan on a short step, then doubling.

        ``Q_d(2h) = Q_d(h) + Phi(h) Q_d(h) Phi(h)^T``: exact, and stable where the
        fast Gauss-Markov states would overflow Van Loan's ``exp(-F step)``.
        """
        size = len(self.mean0)
        doublings = max(0, math.ceil(math.log2(
            step * np.abs(self.dynamics).max() / 0.01)))
        h = step / 2 ** doublings
        van_loan = np.zeros((2 * size, 2 * size))
        van_loan[:size, :size] = -self.dynamics
        van_loan[:size, size:] = self.intensity
        van_loan[size:, size:] = self.dynamics.T
        big = expm(van_loan * h)
        phi = big[size:, size:].T
        q_d = phi @ big[:size, size:]
        for _ in range(doublings):
            q_d = q_d + phi @ q_d @ phi.T
            phi = phi @ phi
        return phi, q_d

    def propagate(self, times):
        """
        Return (mean, std), each (len(times), 5): east, north position [m], psi [rad].

        ``times`` [s] increasing from 0 in equal steps.
        """
        times = np.asarray(times, dtype=float)
        step = times[0] if len(times) == 1 else times[1] - times[0]
        if not np.allclose(np.diff(np.concatenate([[0.0], times])), step):
            raise ValueError('times must be equal steps from 0')
        phi, q_d = self._discrete(step)
        mean, covariance = self.mean0.copy(), self.covariance0.copy()
        means, stds = [], []
        keep = [0, 1, 4, 5, 6]
        for _ in times:
            mean = phi @ mean
            covariance = phi @ covariance @ phi.T + q_d
            means.append(mean[keep])
            stds.append(np.sqrt(np.diag(covariance)[keep]))
        return np.array(means), np.array(stds)
