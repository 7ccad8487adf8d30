"""The hand-written rotation conversions against scipy's Rotation, half turns included."""

import numpy as np
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from qfa_ros.model.trajectory import dcm_to_quaternion, euler_to_dcm, quaternion_to_dcm


def rotations(rng, count=5000):
    """Return random rotations, exact half turns and the identity, as scipy Rotations."""
    axes = rng.normal(size=(count, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    half_turns = Rotation.from_rotvec(np.pi * axes)
    # Uniform on SO(3): normalized Gaussian quaternions (Rotation.random's rng= needs
    # scipy 1.15; the floor is 1.11).
    return Rotation.concatenate([Rotation.from_quat(rng.normal(size=(count, 4))), half_turns,
                                 Rotation.identity(), Rotation.from_rotvec([0.0, 0.0, np.pi])])


def test_dcm_to_quaternion_is_scipys_quaternion_with_w_positive():
    reference = rotations(np.random.default_rng(31))
    matrices = reference.as_matrix()
    q = dcm_to_quaternion(matrices)
    assert np.all(q[:, 3] >= 0.0)
    # The same rotation (the copysign formula gave another one for a third of the half
    # turns), and the same quaternion where it is unique (w > 0).
    assert_allclose(Rotation.from_quat(q).as_matrix(), matrices, atol=1e-15)
    expected = reference.as_quat(canonical=True)
    unique = expected[:, 3] > 1e-12
    assert_allclose(q[unique], expected[unique], atol=1e-15)
    assert_allclose(np.linalg.norm(q, axis=1), 1.0, rtol=1e-15)


def test_quaternion_to_dcm_is_scipys_matrix():
    reference = rotations(np.random.default_rng(32))
    assert_allclose(quaternion_to_dcm(reference.as_quat()), reference.as_matrix(), atol=2e-15)


def test_euler_round_trip_keeps_a_rolled_over_sensor():
    rng = np.random.default_rng(33)
    roll, pitch, yaw = np.pi, rng.uniform(-1.5, 1.5, 100), rng.uniform(-np.pi, np.pi, 100)
    matrices = euler_to_dcm(roll, pitch, yaw)
    assert_allclose(quaternion_to_dcm(dcm_to_quaternion(matrices)), matrices, atol=2e-15)
