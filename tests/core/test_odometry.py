"""The drifting odometry (vibrissa.odometry): its error is the transform map -> odom (truth =
error composed with the odometry, checked with scipy's rotations), its statistics those of the
random walk (closed form of a straight run), nothing drifts without motion or with D = 0."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vibrissa.odometry import OdometryDrift


def _arc(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """A base driving a 0.6 m arc, tilted a little about x (a sloped floor's pose)."""
    s = np.linspace(0.0, 0.6, n)
    yaw = 1.5 * s
    p = np.column_stack([np.sin(yaw) / 1.5, (1 - np.cos(yaw)) / 1.5, np.full(n, 0.02)])
    q = (Rotation.from_euler("z", yaw[:, None]) * Rotation.from_euler("x", 0.1)).as_quat()
    return p, q


def test_truth_is_map_to_odom_composed_with_the_odometry() -> None:
    p, q = _arc()
    p_o, q_o, error = OdometryDrift(0.05, np.random.default_rng(3)).odom(p, q)
    assert np.abs(error[-1, :2]).max() > 1e-3  # it drifted
    R_e = Rotation.from_euler("z", error[:, 2:3])
    t_e = np.column_stack([error[:, :2], np.zeros(len(p))])
    np.testing.assert_allclose(R_e.apply(p_o) + t_e, p, atol=1e-14)
    composed = (R_e * Rotation.from_quat(q_o)).as_quat()
    np.testing.assert_allclose(np.abs(np.sum(composed * q, axis=1)), 1.0, atol=1e-14)
    assert np.all(p_o[:, 2] == p[:, 2])  # height exact
    np.testing.assert_allclose(error[0], 0.0, atol=0)  # the odometry starts at the truth


def test_without_drift_or_motion_the_odometry_is_the_truth_bit_for_bit() -> None:
    p, q = _arc()
    p_o, q_o, error = OdometryDrift(0.0, np.random.default_rng(1)).odom(p, q)
    assert np.array_equal(p_o, p) and np.array_equal(q_o, q) and not error.any()
    still = OdometryDrift(0.05, np.random.default_rng(1))
    p_o, q_o, error = still.odom(np.repeat(p[:1], 50, axis=0), np.repeat(q[:1], 50, axis=0))
    assert not error.any() and np.allclose(p_o, p[0], atol=0)


def test_poses_in_pieces_drift_as_in_one_call() -> None:
    p, q = _arc()
    whole = OdometryDrift(0.05, np.random.default_rng(7)).odom(p, q)
    pieces = OdometryDrift(0.05, np.random.default_rng(7))
    parts = [pieces.odom(p[a:b], q[a:b]) for a, b in ((0, 1), (1, 170), (170, 400))]
    for k in range(3):
        np.testing.assert_array_equal(np.concatenate([part[k] for part in parts]), whole[k])


@pytest.mark.slow
def test_a_straight_run_drifts_as_the_random_walk_says() -> None:
    """1 m along x in 1 cm steps, 3 000 seeds: heading error std D sqrt(L); the odometry's
    position error std D sqrt(L) along the run and D sqrt(L + L^3/3) across it (the heading
    errors' lever), to first order in D."""
    drift, length, seeds = 0.02, 1.0, 3000
    x = np.linspace(0.0, length, 101)
    p = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(x), 1))
    ends = []
    for seed in range(seeds):
        p_o, _, error = OdometryDrift(drift, np.random.default_rng(seed)).odom(p, q)
        ends.append([*(p_o[-1, :2] - p[-1, :2]), error[-1, 2]])
    ends = np.array(ends)
    tol = 4 / np.sqrt(2 * seeds)  # 4 standard errors of a standard deviation
    std = ends.std(axis=0)
    assert std[2] == pytest.approx(drift * np.sqrt(length), rel=tol)
    assert std[0] == pytest.approx(drift * np.sqrt(length), rel=tol)
    assert std[1] == pytest.approx(drift * np.sqrt(length + length**3 / 3), rel=tol)
    assert np.abs(ends.mean(axis=0)).max() < 4 * std.max() / np.sqrt(seeds)


def test_a_bad_drift_is_refused() -> None:
    for bad in (-0.01, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="drift_per_m"):
            OdometryDrift(bad, np.random.default_rng(0))
