"""Sample means of the trajectories against the exact kinematics integrated per sample."""

import numpy as np
from numpy.testing import assert_allclose
import pytest

from qfa_ros.model import earth, motion_scripts, trajectory
from qfa_ros.model.trajectory_means import (
    FAST_REACH,
    FORCE_TOLERANCE,
    PiecewiseMeans,
    RATE_TOLERANCE,
    RELATIVE_TOLERANCE,
)


def reference_means(motion, start, period, n):
    """Return 8-point Gauss-Legendre means of f^b and w_ib^b per sample, cut at the knots."""
    nodes, weights = np.polynomial.legendre.leggauss(8)
    edges = start + period * np.arange(n + 1)
    knots = motion.poly.x
    times, factors, rows = [], [], []
    for k in range(n):
        a, b = edges[k], edges[k + 1]
        cuts = np.concatenate([[a], knots[(knots > a) & (knots < b)], [b]])
        for low, high in zip(cuts[:-1], cuts[1:]):
            times.append(0.5 * (low + high) + 0.5 * (high - low) * nodes)
            factors.append(0.5 * (high - low) / (b - a) * weights)
            rows.append(np.full(8, k))
    kinematics = motion.kinematics(np.concatenate(times))
    factors, rows = np.concatenate(factors)[:, None], np.concatenate(rows)
    force, rate = np.zeros((n, 3)), np.zeros((n, 3))
    np.add.at(force, rows, factors * kinematics['specific_force'])
    np.add.at(rate, rows, factors * kinematics['angular_rate'])
    return force, rate


def csv_drive(tmp_path):
    path = tmp_path / 'drive.csv'
    motion_scripts.save_csv(path, motion_scripts.vehicle_drive().shifted(0.0), rate_hz=100.0)
    return motion_scripts.load_csv(path)


MOTIONS = {
    'drive': motion_scripts.vehicle_drive,
    'coning': lambda: motion_scripts.coning(duration_s=2.0),
    'sculling': lambda: motion_scripts.sculling(duration_s=2.0),
    'rate-table': motion_scripts.rate_table_turn,
    'tumble': motion_scripts.six_position_tumble,
}


@pytest.mark.parametrize('name', [*MOTIONS, 'csv'])
def test_sample_means_are_the_exact_means(name, tmp_path):
    motion = csv_drive(tmp_path) if name == 'csv' else MOTIONS[name]()
    knots = motion.poly.x
    period = 1e-3
    # The start (rest before it), a stretch of knots, the middle, the end (rest after).
    windows = [motion.start - 0.1003, knots[len(knots) // 3] - 0.0507,
               0.5 * (motion.start + motion.end), motion.end - 0.2001]
    for start in windows:
        force, rate = motion.sample_means(start, period, 300)
        expected_force, expected_rate = reference_means(motion, start, period, 300)
        scale_force = np.abs(expected_force).max()
        scale_rate = np.abs(expected_rate).max()
        assert_allclose(force, expected_force, rtol=0,
                        atol=max(FORCE_TOLERANCE, RELATIVE_TOLERANCE * scale_force))
        assert_allclose(rate, expected_rate, rtol=0,
                        atol=max(RATE_TOLERANCE, RELATIVE_TOLERANCE * scale_rate))


def test_sample_means_do_not_depend_on_chunking():
    motion = motion_scripts.vehicle_drive()
    start, period = 29.9876, 1e-3
    force, rate = motion.sample_means(start, period, 2000)
    again = motion_scripts.vehicle_drive()
    parts = [again.sample_means(start + k * 500 * period, period, 500) for k in range(4)]
    assert_allclose(np.concatenate([p[0] for p in parts]), force, rtol=0, atol=1e-12)
    assert_allclose(np.concatenate([p[1] for p in parts]), rate, rtol=0, atol=1e-15)
    repeat = motion_scripts.vehicle_drive().sample_means(start, period, 2000)
    assert np.array_equal(repeat[0], force) and np.array_equal(repeat[1], rate)


def test_a_long_dwell_keeps_its_precision():
    # A 600 s dwell: 1 ms samples on one long segment, near its end.
    motion = motion_scripts.six_position_tumble(dwell_s=600.0)
    start = motion.start + 599.5
    force, rate = motion.sample_means(start, 1e-3, 200)
    expected_force, expected_rate = reference_means(motion, start, 1e-3, 200)
    assert_allclose(force, expected_force, rtol=0, atol=FORCE_TOLERANCE)
    assert_allclose(rate, expected_rate, rtol=0, atol=RATE_TOLERANCE)


def straight_drive(duration_s=1000.0, speed=20.0):
    """Return one quintic piece: a drive due east at constant speed, 45 deg N."""
    latitude = np.radians(45.0)
    _, r_e = earth.radii_of_curvature(latitude)
    rate = speed / (r_e * np.cos(latitude))
    values = [[latitude, 0.0, 0.0, 0.0, 0.0, 0.0],
              [latitude, rate * duration_s, 0.0, 0.0, 0.0, 0.0]]
    rates = [[0.0, rate, 0.0, 0.0, 0.0, 0.0]] * 2
    return trajectory.Trajectory(
        trajectory.quintic_coefficients([0.0, duration_s], values, rates, np.zeros((2, 6))),
        'straight drive')


@pytest.mark.parametrize('name', ['drive', 'dwell', 'straight'])
def test_mean_polynomials_equal_the_integrals(name):
    # Samples inside one segment take its mean polynomial; the integral path and the
    # 8-point reference agree with them, also on a 600 s dwell and a 1000 s piece.
    period, n = 1e-3, 200
    if name == 'drive':
        motion, start = motion_scripts.vehicle_drive(), 30.0103
    elif name == 'dwell':
        motion = motion_scripts.six_position_tumble(dwell_s=600.0)
        start = motion.start + 599.7
    else:
        motion = straight_drive()
        start = motion.end - 0.5
    means = PiecewiseMeans(motion.poly.c, motion.poly.x)
    fast = means.sample_means(start, period, n)
    integrated = PiecewiseMeans(motion.poly.c, motion.poly.x, fast=False).sample_means(
        start, period, n)
    reference = reference_means(motion, start, period, n)
    # Most samples lie inside a segment short enough in samples for the fast path.
    bounds, degree = means.segments
    edges = start + period * np.arange(n + 1)
    inside = np.zeros(n, dtype=bool)
    for (low, high), d in zip(bounds, degree):
        if 2.0 * period * d * d <= FAST_REACH * (high - low):
            inside |= (edges[:-1] >= low) & (edges[1:] <= high)
    assert inside.mean() > 0.9
    for k, tolerance in enumerate((FORCE_TOLERANCE, RATE_TOLERANCE)):
        scale = np.abs(reference[k]).max()
        bound = max(tolerance, RELATIVE_TOLERANCE * scale)
        assert_allclose(fast[k], reference[k], rtol=0, atol=bound)
        assert_allclose(fast[k], integrated[k], rtol=0, atol=bound)
        assert np.array_equal(motion.sample_means(start, period, n)[k], fast[k])
