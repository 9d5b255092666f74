"""Clusters that are patches of one convex object are joined; two objects are not
(`vibrissa.mapping.join_convex`). The geometry is built here with numpy: spheres,
their outward normals (p - c) / r."""

from __future__ import annotations

import numpy as np
import pytest

from vibrissa.mapping import cluster_points, join_convex, whisker_lines


def patch(center: list[float], radius: float, direction: list[float], spread: float,
          n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A contact line on a sphere: n points within ``spread`` rad of ``direction``, swept
    across it, and their outward normals."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    side = np.cross(d, [0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.cross(d, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    angle = np.linspace(-spread, spread, n)
    normals = np.cos(angle)[:, None] * d + np.sin(angle)[:, None] * side
    return np.asarray(center, float) + radius * normals, normals


def cloud(*patches: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points, normals and one label per patch."""
    points = np.vstack([p for p, _ in patches])
    normals = np.vstack([n for _, n in patches])
    labels = np.repeat(np.arange(len(patches)), [len(p) for p, _ in patches])
    return points, normals, labels


BALL = ([0.0, 0.0, 0.0], 0.02)
NEIGHBOUR = ([0.06, 0.005, 0.0], 0.02)  # beside the ball, its face 5 mm further back


def test_patches_of_one_ball_are_joined_and_a_neighbour_is_not() -> None:
    """Three patches of the ball touched from the robot's side (-y) and from behind, and the
    neighbour's front: the ball's become one object, the neighbour stays its own."""
    points, normals, labels = cloud(
        patch(*BALL, [0.0, -1.0, 0.0], 0.2), patch(*NEIGHBOUR, [0.0, -1.0, 0.0], 0.2),
        patch(*BALL, [1.0, -1.0, 0.5], 0.2), patch(*BALL, [-0.3, 1.0, 0.0], 0.3))
    joined, groups = join_convex(points, normals, labels)
    assert groups == [[0, 2, 3]]
    assert np.array_equal(joined, np.where(labels == 1, 1, 0))


def test_objects_side_by_side_facing_the_robot_stay_apart_at_any_gap() -> None:
    """Two balls in a row, each touched on its front: their faces are not behind each other's
    tangent planes, from touching (gap 0) to far apart."""
    for gap in (0.0, 0.001, 0.01, 0.2):
        other = ([0.04 + gap, 0.0, 0.0], 0.02)
        points, normals, labels = cloud(patch(*BALL, [0.0, -1.0, 0.0], 0.4),
                                        patch(*other, [0.0, -1.0, 0.0], 0.4))
        assert join_convex(points, normals, labels)[1] == []


def test_two_objects_touched_only_on_their_far_sides_are_joined() -> None:
    """The known limit: contacts on the sides of two balls that face away from each other are
    those of one convex body around both; the test cannot tell them apart (the report names
    such an object when the scene is known)."""
    points, normals, labels = cloud(patch(*BALL, [-1.0, 0.0, 0.0], 0.3),
                                    patch([0.06, 0.0, 0.0], 0.02, [1.0, 0.0, 0.0], 0.3))
    assert join_convex(points, normals, labels)[1] == [[0, 1]]


def test_the_normals_error_and_the_points_std_set_the_tolerance() -> None:
    """Two patches of the ball 20 deg apart (their closest points 8.6 deg apart, so a tangent
    plane of one has the other 0.075 rad behind it): normals of one tilted towards the other by
    0.1 rad put it 0.025 rad in front, which the default tolerance (0.05 rad) allows and 0 does
    not; tilted by 0.3 rad they are not joined. Two balls join only when their points' std is
    as large as their gap."""
    points, normals, labels = cloud(patch(*BALL, [0.0, -1.0, 0.0], 0.1),
                                    patch(*BALL, [np.sin(0.35), -np.cos(0.35), 0.0], 0.1))
    assert join_convex(points, normals, labels)[1] == [[0, 1]]
    for tilt, tol_rad, joined in ((0.1, 0.05, True), (0.1, 0.0, False), (0.3, 0.05, False)):
        # tilt every normal of the first patch towards the second patch (its worst direction)
        towards = np.array([1.0, 0.0, 0.0])
        tilted = normals.copy()
        first = labels == 0
        tilted[first] = np.cos(tilt) * normals[first] + np.sin(tilt) * towards
        assert (join_convex(points, tilted, labels, tol_rad=tol_rad)[1] == [[0, 1]]) is joined

    points, normals, labels = cloud(patch(*BALL, [0.0, -1.0, 0.0], 0.4),
                                    patch([0.045, 0.0, 0.0], 0.02, [0.0, -1.0, 0.0], 0.4))
    assert join_convex(points, normals, labels)[1] == []
    assert join_convex(points, normals, labels, np.full(len(points), 0.05 ** 2))[1] == [[0, 1]]


def test_a_group_is_joined_only_where_every_pair_of_its_clusters_passes() -> None:
    """A ball's front patch, a second ball's front patch, and a patch between them on the
    first ball's side that is behind the tangent planes of both fronts: it joins its own ball;
    the second ball stays apart although the side patch alone would pass with it."""
    other = ([0.07, 0.0, 0.0], 0.02)
    points, normals, labels = cloud(patch(*BALL, [0.0, -1.0, 0.0], 0.2),
                                    patch(*other, [0.0, -1.0, 0.0], 0.2),
                                    patch(*BALL, [1.0, 0.05, 0.0], 0.1))
    joined, groups = join_convex(points, normals, labels)
    assert groups == [[0, 2]]
    assert np.array_equal(joined, np.where(labels == 1, 1, 0))


def test_noise_points_stay_noise_and_labels_follow_the_first_point() -> None:
    points, normals, labels = cloud(patch(*NEIGHBOUR, [0.0, -1.0, 0.0], 0.2),
                                    patch(*BALL, [0.0, -1.0, 0.0], 0.2),
                                    patch(*BALL, [-1.0, 0.0, 0.0], 0.2))
    labels = labels.copy()
    labels[5] = -1
    joined, groups = join_convex(points, normals, labels)
    assert groups == [[1, 2]]
    assert joined[5] == -1 and joined[0] == 0 and set(joined[40:]) == {1}


def test_dbscan_splits_a_ball_touched_far_apart_and_the_join_makes_it_one() -> None:
    """Whisker lines on a 20 mm ball 30 mm apart and on a neighbour 60 mm away: DBSCAN (eps
    from the lines' extent) gives three clusters, the join two objects."""
    parts = [patch(*BALL, [0.0, -1.0, 0.0], 0.25), patch(*BALL, [0.0, -0.2, 1.0], 0.25),
             patch(*NEIGHBOUR, [0.0, -1.0, 0.0], 0.25)]
    points, normals, _ = cloud(*parts)
    whiskers = [name for name, (p, _) in zip("abc", parts, strict=True) for _ in p]
    lines = whisker_lines(points, whiskers)
    clusters = cluster_points(points, lines)
    assert clusters.n_clusters == 3
    joined, groups = join_convex(points, normals, clusters.labels)
    assert groups == [[0, 1]] and int(joined.max()) == 1


@pytest.mark.parametrize("clusters", [1, 65])
def test_one_cluster_or_too_many_are_returned_as_they_are(clusters: int) -> None:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(clusters * 4, 3))
    labels = np.repeat(np.arange(clusters), 4)
    joined, groups = join_convex(points, points / np.linalg.norm(points, axis=1)[:, None], labels)
    assert groups == [] and np.array_equal(joined, labels)


def test_labels_that_are_not_clusters_are_refused() -> None:
    points, normals, _ = cloud(patch(*BALL, [0.0, -1.0, 0.0], 0.2))
    with pytest.raises(ValueError, match="labels must be 0 ... 2"):
        join_convex(points, normals, np.repeat([0, 2], 20))
