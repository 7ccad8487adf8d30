"""Sample means of the trajectories against the exact kinematics integrated per sample."""

import numpy as np
from numpy.testing import assert_allclose
import pytest

from qfa_ros.model import trajectory
from qfa_ros.model.trajectory_means import FORCE_TOLERANCE, RATE_TOLERANCE, RELATIVE_TOLERANCE


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
    trajectory.save_csv(path, trajectory.vehicle_drive().shifted(0.0), rate_hz=100.0)
    return trajectory.load_csv(path)


MOTIONS = {
    'drive': trajectory.vehicle_drive,
    'coning': lambda: trajectory.coning(duration_s=2.0),
    'sculling': lambda: trajectory.sculling(duration_s=2.0),
    'rate-table': trajectory.rate_table_turn,
    'tumble': trajectory.six_position_tumble,
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
    motion = trajectory.vehicle_drive()
    start, period = 29.9876, 1e-3
    force, rate = motion.sample_means(start, period, 2000)
    again = trajectory.vehicle_drive()
    parts = [again.sample_means(start + k * 500 * period, period, 500) for k in range(4)]
    assert_allclose(np.concatenate([p[0] for p in parts]), force, rtol=0, atol=1e-12)
    assert_allclose(np.concatenate([p[1] for p in parts]), rate, rtol=0, atol=1e-15)
    repeat = trajectory.vehicle_drive().sample_means(start, period, 2000)
    assert np.array_equal(repeat[0], force) and np.array_equal(repeat[1], rate)


def test_a_long_dwell_keeps_its_precision():
    # A 600 s dwell: 1 ms samples on one long segment, near its end.
    motion = trajectory.six_position_tumble(dwell_s=600.0)
    start = motion.start + 599.5
    force, rate = motion.sample_means(start, 1e-3, 200)
    expected_force, expected_rate = reference_means(motion, start, 1e-3, 200)
    assert_allclose(force, expected_force, rtol=0, atol=FORCE_TOLERANCE)
    assert_allclose(rate, expected_rate, rtol=0, atol=RATE_TOLERANCE)
