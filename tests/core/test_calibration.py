"""Sensor-to-clamp calibration: the round trip, and statics rebuilt by hand (a contact force at a
known point on the rod, what the clamp and the sensor each feel)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vibrissa.calibration import clamp_to_sensor, sensor_to_clamp
from vibrissa.frames import Transform


def rotation_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' formula, by hand (not scipy's Rotation, which Transform uses)."""
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def quaternion_xyzw(axis: np.ndarray, angle: float) -> np.ndarray:
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return np.array([*(math.sin(angle / 2) * k), math.cos(angle / 2)])


POSES = [
    (np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(3)),                   # S = C
    (np.array([0.0, 0.0, 1.0]), math.pi / 2, np.array([0.0, 0.0, -0.012])),  # below the clamp
    (np.array([1.0, -2.0, 0.5]), 2.1, np.array([0.004, -0.007, -0.02])),
    (np.array([0.3, 0.3, -1.0]), -0.8, np.array([-0.05, 0.01, 0.003])),
]


@pytest.mark.parametrize(("axis", "angle", "p_CS"), POSES)
def test_round_trip_to_1e_12(axis: np.ndarray, angle: float, p_CS: np.ndarray) -> None:
    X_CS = Transform.from_quaternion(quaternion_xyzw(axis, angle), p_CS)
    rng = np.random.default_rng(7)
    f0 = rng.normal(scale=0.1, size=(200, 3))
    m0 = rng.normal(scale=0.005, size=(200, 3))
    f_S, m_S = clamp_to_sensor(f0, m0, X_CS)
    f0_back, m0_back = sensor_to_clamp(f_S, m_S, X_CS)
    np.testing.assert_allclose(f0_back, f0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m0_back, m0, rtol=0, atol=1e-12)
    # and the other way round, a single sample
    f0_one, m0_one = sensor_to_clamp(f_S[3], m_S[3], X_CS)
    np.testing.assert_allclose(clamp_to_sensor(f0_one, m0_one, X_CS), (f_S[3], m_S[3]), rtol=0, atol=1e-12)


@pytest.mark.parametrize(("axis", "angle", "p_CS"), POSES)
def test_statics_of_a_force_at_a_known_point(axis: np.ndarray, angle: float, p_CS: np.ndarray) -> None:
    """A contact force F on the rod at P1 (in C). The clamp holds the rod: f0 = -F,
    m0 = -(p_C1 x F) (README). The sensor carries the rod and clamp: the load on it is F acting
    through P1, which about S's origin, in S's axes, is f_S = R_SC F, m_S = p_S1 x f_S, with
    p_S1 = R_SC (p_C1 - p_CS). Built here from Rodrigues' matrix, not from Transform."""
    R_CS = rotation_matrix(axis, angle)
    R_SC = R_CS.T
    X_CS = Transform.from_quaternion(quaternion_xyzw(axis, angle), p_CS)
    F = np.array([0.03, -0.11, 0.02])      # N, on the rod, in C
    p_C1 = np.array([0.012, 0.004, 0.041])  # m, the contact point, in C
    f0, m0 = -F, -np.cross(p_C1, F)
    f_S = R_SC @ F
    m_S = np.cross(R_SC @ (p_C1 - p_CS), f_S)
    got_f, got_m = clamp_to_sensor(f0, m0, X_CS)
    np.testing.assert_allclose(got_f, f_S, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got_m, m_S, rtol=0, atol=1e-15)
    back_f, back_m = sensor_to_clamp(f_S, m_S, X_CS)
    np.testing.assert_allclose(back_f, f0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back_m, m0, rtol=0, atol=1e-15)


def test_a_sensor_at_the_clamp_reads_the_opposite() -> None:
    f_S, m_S = clamp_to_sensor([1.0, 2.0, 3.0], [4.0, 5.0, 0.0], Transform())
    np.testing.assert_array_equal(f_S, [-1.0, -2.0, -3.0])
    np.testing.assert_array_equal(m_S, [-4.0, -5.0, 0.0])


def test_shapes_are_checked() -> None:
    with pytest.raises(ValueError, match=r"f_S must have shape \(3,\) or \(N, 3\), got \(2,\)"):
        sensor_to_clamp([1.0, 2.0], [1.0, 2.0, 3.0], Transform())
    with pytest.raises(ValueError, match="same shape"):
        clamp_to_sensor(np.zeros((4, 3)), np.zeros((5, 3)), Transform())
