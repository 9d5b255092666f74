"""Rigid transforms (vibrissa.frames) against hand-derived cases and statics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vibrissa.frames import (
    PoseSamples,
    Transform,
    interpolate,
    quaternion_matrices,
    quaternion_matrix,
    quaternion_turns,
)

RNG = np.random.default_rng(7)


def random_transform() -> Transform:
    return Transform(Rotation.random(random_state=RNG), RNG.normal(size=3))


def test_quaternion_order_is_x_y_z_w() -> None:
    # 90 degrees about z: (0, 0, sin 45, cos 45) in x y z w; e_x goes to e_y.
    X = Transform.from_quaternion([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])
    np.testing.assert_allclose(X.apply([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(X.quaternion_xyzw, [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)],
                               atol=1e-15)


def test_roll_pitch_yaw_is_rz_ry_rx() -> None:
    roll, pitch, yaw = 0.3, -0.7, 1.1
    c, s = math.cos, math.sin
    Rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    Ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    Rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    X = Transform.from_xyz_rpy([1.0, 2.0, 3.0], [roll, pitch, yaw])
    np.testing.assert_allclose(X.R, Rz @ Ry @ Rx, atol=1e-15)
    np.testing.assert_allclose(X.rpy, [roll, pitch, yaw], atol=1e-14)
    np.testing.assert_array_equal(X.translation, [1.0, 2.0, 3.0])


def test_compose_invert_and_apply_round_trip() -> None:
    X_AB, X_BC = random_transform(), random_transform()
    p_C = RNG.normal(size=(5, 3))
    X_AC = X_AB @ X_BC
    np.testing.assert_allclose(X_AC.apply(p_C), X_AB.apply(X_BC.apply(p_C)), atol=1e-14)
    np.testing.assert_allclose((X_AC @ X_AC.inv()).matrix, np.eye(4), atol=1e-14)
    np.testing.assert_allclose(X_AC.inv().apply(X_AC.apply(p_C)), p_C, atol=1e-14)
    np.testing.assert_allclose(X_AC.apply_inverse(X_AC.apply(p_C)), p_C, atol=1e-14)
    np.testing.assert_allclose(X_AC.matrix, X_AB.matrix @ X_BC.matrix, atol=1e-14)


def test_wrench_transfer_is_the_same_load() -> None:
    # A force F at point r_B (in B) has, about B's origin, the moment r_B x F. Expressed in A
    # about A's origin it must be the same force acting at the same point: r_A x F_A.
    X_AB = random_transform()
    r_B, F_B = RNG.normal(size=3), RNG.normal(size=3)
    f_A, m_A = X_AB.apply_wrench(F_B, np.cross(r_B, F_B))
    F_A = X_AB.R @ F_B
    np.testing.assert_allclose(f_A, F_A, atol=1e-14)
    np.testing.assert_allclose(m_A, np.cross(X_AB.apply(r_B), F_A), atol=1e-13)
    # a pure couple does not change with the reference point, only with the axes
    f_A, m_A = X_AB.apply_wrench(np.zeros(3), [0.0, 0.0, 2.0])
    np.testing.assert_allclose(m_A, X_AB.R @ [0.0, 0.0, 2.0], atol=1e-15)


def test_interpolation_is_linear_in_position_and_slerp_in_orientation() -> None:
    X_a = Transform.from_xyz_rpy([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    X_b = Transform.from_xyz_rpy([2.0, -4.0, 6.0], [0.0, 0.0, math.pi / 2])
    mid = interpolate(X_a, X_b, 0.5)
    np.testing.assert_allclose(mid.translation, [1.0, -2.0, 3.0], atol=1e-15)
    np.testing.assert_allclose(mid.rpy, [0.0, 0.0, math.pi / 4], atol=1e-15)
    np.testing.assert_allclose(interpolate(X_a, X_b, 1.0).matrix, X_b.matrix, atol=1e-15)
    np.testing.assert_allclose(interpolate(X_a, X_b, 0.0).matrix, X_a.matrix, atol=1e-15)
    with pytest.raises(ValueError, match="no extrapolation"):
        interpolate(X_a, X_b, 1.5)


def test_compiled_quaternion_kernel_matches_scipy() -> None:
    q = Rotation.random(20, random_state=RNG).as_quat()
    q[1] *= 3.0  # not unit: normalised first
    R, norm2 = quaternion_matrices(q)
    np.testing.assert_allclose(R, Rotation.from_quat(q).as_matrix(), atol=2e-15)
    np.testing.assert_allclose(norm2, np.sum(q * q, axis=1), rtol=1e-15)
    zero = np.empty((3, 3))
    assert quaternion_matrix(np.zeros(4), zero) == 0.0
    assert not np.isfinite(zero).all()  # not a rotation: callers check |q|^2


def test_turns_between_samples_are_scipys_relative_magnitudes_whatever_the_sign() -> None:
    rotations = Rotation.random(50, random_state=RNG)
    q = rotations.as_quat()
    q[::3] *= -1.0  # the same rotations
    small = Rotation.from_rotvec([[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [0.0, 0.0, math.pi]])
    for rots, quats in ((rotations, q), (small, small.as_quat())):
        expected = (rots[:-1].inv() * rots[1:]).magnitude()
        np.testing.assert_allclose(quaternion_turns(quats), expected, rtol=1e-12, atol=1e-15)
    assert quaternion_turns(q[:1]).shape == (0,)


def test_pose_samples_interpolate_between_uneven_samples_and_never_extrapolate() -> None:
    samples = PoseSamples(np.array([0.0, 1.0, 3.0]),
                          np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 2.0, 0]]),
                          Rotation.from_euler("z", [[0.0], [0.5], [1.5]]))
    p, R = samples.at([0.5, 2.0, 3.0])
    np.testing.assert_allclose(p, [[0.5, 0, 0], [1.0, 1.0, 0], [1.0, 2.0, 0]], atol=1e-15)
    np.testing.assert_allclose(R[1], Rotation.from_euler("z", 1.0).as_matrix(), atol=1e-15)
    for outside in (-1e-9, 3.0 + 1e-9, float("nan")):
        with pytest.raises(ValueError, match="no extrapolation"):
            samples.at([outside])
    with pytest.raises(ValueError, match="strictly increasing"):
        PoseSamples(np.array([0.0, 0.0]), np.zeros((2, 3)), Rotation.identity(2))


def test_pose_samples_of_random_rotations_are_scipys_slerp_and_linear_positions() -> None:
    """Against scipy's Slerp (an independent implementation: log and exp of the relative
    rotation) on uneven times, including rotations of opposite quaternion sign."""
    from scipy.spatial.transform import Slerp

    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.1, 2.0, 12))
    rotations = Rotation.random(12, random_state=8)
    q = rotations.as_quat()
    q[::3] *= -1.0  # the same rotations, the other sign
    p = rng.normal(size=(12, 3))
    samples = PoseSamples(t, p, Rotation.from_quat(q))
    at = np.concatenate([t, rng.uniform(t[0], t[-1], 200)])
    got_p, got_R = samples.at(at)
    np.testing.assert_allclose(got_R, Slerp(t, rotations)(at).as_matrix(), atol=1e-14)
    k = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
    share = (at - t[k]) / (t[k + 1] - t[k])
    np.testing.assert_allclose(got_p, p[k] + share[:, None] * (p[k + 1] - p[k]), atol=1e-14)
    assert np.allclose(samples.poses_at(at)[1].as_matrix(), got_R, atol=1e-15)
