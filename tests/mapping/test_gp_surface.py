"""The Gaussian-process implicit surface: accuracy against the true object where it was
touched, calibration of its std, "unknown" away from the data, determinism, rigid motions."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from scipy.spatial import Delaunay, cKDTree
from scipy.spatial.transform import Rotation

from vibrissa import Trail, parse_surface, simulate_sweeps
from vibrissa.mapping import contact_normals, gp_surface
from vibrissa.sweep import contact_lines

DEMO_TRAILS = (-0.4, -0.2, 0.0, 0.2, 0.4)  # launch/demo.yaml


def contact_cloud(spec: str, y0s, mu: float = 0.2, step: float = 0.001):
    """Contact points (L = 1 m, so m) in line order, normals from the contact forces as the
    mapper takes them, the line of each point, the true surface."""
    surface = parse_surface(spec)
    points, forces, lines = contact_lines(simulate_sweeps(surface, [Trail(y0, mu) for y0 in y0s],
                                                          step))
    return points, contact_normals(points, forces, lines), lines, surface


@pytest.fixture(scope="module")
def paraboloid():
    return contact_cloud("paraboloid:a=0.5,b=1,h=0.4", DEMO_TRAILS)


@pytest.fixture(scope="module")
def sphere():
    return contact_cloud("sphere:r=0.3,cx=0,cy=0,cz=0.8", DEMO_TRAILS)


@pytest.fixture(scope="module")
def one_line():
    return contact_cloud("paraboloid:a=0.5,b=1,h=0.4", [0.2])


def fitted(cloud, margin: float = 0.2, cells: int = 64):
    points, normals, _, _ = cloud
    surface = gp_surface.fit(points, normals)
    pad = margin * np.linalg.norm(np.ptp(points, axis=0))
    return surface, gp_surface.mesh(surface, points.min(axis=0) - pad,
                                    points.max(axis=0) + pad, cells)


def in_touched_region(points, normals, queries, truth):
    """Queries (Q, 3) on the touched side of the true object whose projection along the
    cloud's mean normal falls inside the convex hull of the projected contact points: the
    region between and along the lines."""
    axis = normals.mean(axis=0)
    axis /= np.linalg.norm(axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    hull = Delaunay(np.c_[points @ e1, points @ e2])
    facing = truth.normal(truth.closest_point(queries)) @ axis > 0
    return facing & (hull.find_simplex(np.c_[queries @ e1, queries @ e2]) >= 0)


def known_vertices(mesh):
    known = np.zeros(len(mesh.vertices), dtype=bool)
    known[np.unique(mesh.triangles[mesh.known])] = True
    return known


@pytest.mark.parametrize("cloud, limit_m", [("paraboloid", 5e-3), ("sphere", 10e-3)])
@pytest.mark.slow
def test_touched_region_is_within_the_limit_and_known(cloud, limit_m, request):
    # the targets: 5 mm on the demo's paraboloid, 10 mm on the 0.3 m sphere (L = 1 m)
    points, normals, _, truth = request.getfixturevalue(cloud)
    _, mesh = fitted(request.getfixturevalue(cloud))
    inside = in_touched_region(points, normals, mesh.vertices, truth)
    assert inside.sum() > 1000
    error = np.abs(truth.signed_distance(mesh.vertices[inside]))
    assert error.max() < limit_m
    # and it is meshed as known there, not left out
    assert known_vertices(mesh)[inside].mean() > 0.95


@pytest.mark.parametrize("cloud", ["paraboloid", "sphere", "one_line"])
@pytest.mark.slow
def test_true_surface_is_inside_three_sigma(cloud, request):
    points, normals, _, truth = request.getfixturevalue(cloud)
    surface, mesh = fitted(request.getfixturevalue(cloud))
    # test points on the true surface over the touched region, between and on the lines
    queries = truth.closest_point(mesh.vertices[in_touched_region(points, normals,
                                                                  mesh.vertices, truth)])
    f, _ = surface.evaluate(queries)
    assert np.mean(np.abs(f) <= 3 * surface.std(queries)) >= 0.99


def test_one_line_gives_a_narrow_known_strip_and_unknown_elsewhere(one_line):
    points, _, _, truth = one_line
    _, mesh = fitted(one_line, margin=0.3)
    known = known_vertices(mesh)
    distance = cKDTree(points).query(mesh.vertices)[0]
    length = np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1))
    assert known.any() and (~known).any()
    assert distance[known].max() < 0.25 * length  # a strip along the line
    assert distance[~known].min() > 0.05 * length  # not unknown right at the line
    # what is known is right; the unknown part is where it is wrong
    assert np.abs(truth.signed_distance(mesh.vertices[known])).max() < 2e-3
    assert mesh.std[~known].min() > mesh.max_std * 0.99


def test_std_grows_away_from_the_lines(paraboloid):
    points, normals, _, truth = paraboloid
    surface = gp_surface.fit(points, normals)
    on_line = truth.closest_point(points[::500])
    away = truth.closest_point(points[::500] + [0.0, 0.0, 0.0])
    away[:, 1] += 0.6  # beyond the outer lines at y0 = +-0.4 the rod touched up to |y| 0.73
    away = truth.closest_point(away)
    assert np.all(surface.position_std(on_line) < surface.position_std(away))


@pytest.mark.slow
def test_same_points_give_the_same_bits(paraboloid):
    first_surface, first = fitted(paraboloid)
    second_surface, second = fitted(paraboloid)
    for a, b in [(first.vertices, second.vertices), (first.triangles, second.triangles),
                 (first.std, second.std), (first.known, second.known)]:
        assert a.tobytes() == b.tobytes()
    assert first_surface.log_likelihood == second_surface.log_likelihood


def test_threads_may_evaluate_one_surface_side_by_side(paraboloid):
    """The mean's parallel loop takes one caller at a time (numba's workqueue pool aborts the
    process on a second): threads evaluating at once get what one thread gets."""
    surface, mesh = fitted(paraboloid, cells=16)
    queries = mesh.vertices + 0.01
    alone = surface.evaluate(queries)
    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(lambda _: surface.evaluate(queries), range(40)))
    for f, g in results:
        assert f.tobytes() == alone[0].tobytes() and g.tobytes() == alone[1].tobytes()


def test_a_rigid_motion_moves_the_surface_with_the_cloud(sphere):
    points, normals, _, truth = sphere
    R = Rotation.from_euler("xyz", [0.4, -1.1, 2.3])
    p = np.array([0.7, -0.2, 1.5])
    surface = gp_surface.fit(points, normals)
    moved = gp_surface.fit(R.apply(points) + p, R.apply(normals))
    queries = truth.closest_point(points[::50] + np.random.default_rng(1).normal(
        scale=0.05, size=(len(points[::50]), 3)))
    f, g = surface.evaluate(queries)
    f_moved, g_moved = moved.evaluate(R.apply(queries) + p)
    np.testing.assert_allclose(f_moved, f, atol=1e-9)
    np.testing.assert_allclose(g_moved, R.apply(g), atol=1e-7)
    np.testing.assert_allclose(moved.std(R.apply(queries) + p), surface.std(queries),
                               rtol=1e-6, atol=1e-12)


def test_exact_sphere_data_give_the_sphere():
    # three arcs on a sphere with exact normals: the quadric trend is the sphere itself
    radius, center = 0.05, np.array([0.01, -0.02, 0.03])
    t = np.linspace(0.2, 1.3, 300)
    arcs = [np.c_[np.cos(t), np.sin(t), np.zeros_like(t)],
            np.c_[np.cos(t), np.zeros_like(t), np.sin(t)],
            np.c_[np.zeros_like(t), np.cos(t), np.sin(t)]]
    normals = np.concatenate(arcs)
    surface = gp_surface.fit(center + radius * normals, normals)
    directions = np.random.default_rng(2).normal(size=(100, 3))
    directions = np.abs(directions) / np.linalg.norm(directions, axis=1, keepdims=True)
    f, g = surface.evaluate(center + radius * directions)
    assert np.abs(f).max() < 1e-3 * radius  # on the sphere between the arcs
    cos = np.einsum("ni,ni->n", g / np.linalg.norm(g, axis=1, keepdims=True), directions)
    assert cos.min() > 1 - 1e-4
    outside, _ = surface.evaluate(center + 1.2 * radius * directions)
    inside, _ = surface.evaluate(center + 0.8 * radius * directions)
    assert np.all(outside > 0) and np.all(inside < 0)


@pytest.mark.parametrize("points, normals, match", [
    (np.zeros((3, 3)), np.ones((3, 3)), r"points must have shape \(N >= 4, 3\)"),
    (np.zeros((5, 2)), np.ones((5, 2)), r"points must have shape"),
    (np.zeros((5, 3)), np.ones((4, 3)), r"normals must have the shape of points"),
    (np.full((5, 3), np.nan), np.ones((5, 3)), "must be finite"),
    (np.ones((5, 3)), np.ones((5, 3)), "all 5 points at one place"),
])
def test_bad_input_is_a_clear_error(points, normals, match):
    with pytest.raises(ValueError, match=match):
        gp_surface.fit(points, normals)


def test_bad_parameters_are_clear_errors():
    with pytest.raises(ValueError, match="length_scales must be one or more positive"):
        gp_surface.GPParams(length_scales=())
    with pytest.raises(ValueError, match="max_active must be >= 4"):
        gp_surface.GPParams(max_active=2)
    with pytest.raises(ValueError, match="point_std_m must be > 0"):
        gp_surface.GPParams(point_std_m=-1.0)


def test_points_are_weighted_by_their_variance(paraboloid):
    # one of the five lines comes from a noisy whisker: its points lie 3 mm out along the
    # normal. Told their variance (3 mm)^2 against 1 um^2 for the rest, the fit leans on the
    # good lines 0.2 m to either side; told nothing, it goes through the bad one.
    points, normals, lines, truth = paraboloid
    bad = lines == np.unique(lines)[2]  # the middle trail, y0 = 0
    moved = points.copy()
    moved[bad] += 3e-3 * normals[bad]
    var = np.where(bad, 3e-3**2, 1e-12)
    weighted = gp_surface.fit(moved, normals, point_var_m2=var)
    unweighted = gp_surface.fit(moved, normals)
    on_truth = points[bad]  # where the bad line should have been
    error_weighted = np.abs(weighted.evaluate(on_truth)[0])
    error_unweighted = np.abs(unweighted.evaluate(on_truth)[0])
    assert np.median(error_unweighted) > 2e-3
    assert np.median(error_weighted) < 0.5 * np.median(error_unweighted)  # 0.83 vs 2.27 mm
    # the variances change the std where the bad line was: it is less sure there
    assert np.median(weighted.std(on_truth)) > np.median(unweighted.std(on_truth))
    with pytest.raises(ValueError, match=r"point_var_m2 must have shape"):
        gp_surface.fit(points, normals, point_var_m2=var[:-1])
