"""Coverage against closed forms: samples on the true surfaces, uniform by area (a sphere's polar
cap, a paraboloid's bowl, a spheroid's area), cut by the workspace's reach as a plane cuts a
sphere (Archimedes: a zone's area is 2 pi r times its height), and the share covered by a mesh
of the whole sphere (1), of its upper half (1/2 up to a band of the tolerance) and of nothing
(0). Shares of random samples are checked within 5 binomial standard deviations."""

from __future__ import annotations

import numpy as np
import pytest

from vibrissa.frames import Transform
from vibrissa.mapping.coverage import box_distance, coverage, coverage_samples
from vibrissa.mapping.truth import TrueObject
from vibrissa.surfaces import Ellipsoid, Paraboloid, Sphere

R = 0.02  # m
CENTRE = np.array([0.1, -0.05, 0.03])
BIG = ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])  # a workspace holding every object here
SPACING = 5e-4  # m: about 5000 samples on the sphere


def ball(radius_m: float = R) -> TrueObject:
    return TrueObject("ball", Sphere(radius_m, Transform(None, CENTRE)))


def binomial_ok(hits: int, n: int, p: float) -> bool:
    """Whether ``hits`` of ``n`` is within 5 standard deviations of the share ``p``."""
    return abs(hits - n * p) <= 5.0 * np.sqrt(n * p * (1.0 - p)) + 1.0


def fibonacci_sphere(n: int, radius_m: float) -> np.ndarray:
    """n points spread evenly on the sphere (the golden-angle spiral), around CENTRE."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0**0.5) * k
    rho = np.sqrt(1.0 - z**2)
    return CENTRE + radius_m * np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def test_sphere_samples_lie_on_it_at_the_stated_density() -> None:
    points = coverage_samples([ball()], *BIG, reach_m=0.0, spacing_m=SPACING, seed=1)
    assert np.abs(np.linalg.norm(points - CENTRE, axis=1) - R).max() < 1e-15
    # every candidate of a sphere is kept: the count is the area over the spacing squared
    assert len(points) == int(np.ceil(4 * np.pi * R**2 / SPACING**2))


@pytest.mark.parametrize("angle", [0.3, 1.0, np.pi / 2, 2.5])
def test_sphere_samples_are_uniform_by_area_a_polar_cap_holds_its_share(angle: float) -> None:
    points = coverage_samples([ball()], *BIG, reach_m=0.0, spacing_m=SPACING, seed=2)
    in_cap = int(np.sum(points[:, 2] - CENTRE[2] > R * np.cos(angle)))
    assert binomial_ok(in_cap, len(points), (1.0 - np.cos(angle)) / 2.0)


def test_a_posed_spheroid_gets_its_exact_area_and_samples_on_its_surface() -> None:
    a, c = 0.03, 0.012  # oblate: area 2 pi a^2 (1 + (1 - e^2) atanh(e) / e), e^2 = 1 - c^2/a^2
    pose = Transform.from_xyz_rpy(CENTRE, [0.4, -0.7, 1.1])
    egg = TrueObject("egg", Ellipsoid(a, c, a, pose))
    points = coverage_samples([egg], *BIG, reach_m=0.0, spacing_m=SPACING, seed=3)
    assert np.abs(egg.distance(points)).max() < 1e-12
    e = np.sqrt(1.0 - c**2 / a**2)
    area = 2 * np.pi * a**2 * (1.0 + (1.0 - e**2) * np.arctanh(e) / e)
    # the candidates are N = area_max / SPACING^2, each kept with the probability area / area_max
    area_max = 4 * np.pi * a * c * a / c
    n = int(np.ceil(area_max / SPACING**2))
    assert binomial_ok(len(points), n, area / area_max)


def test_paraboloid_samples_are_uniform_by_area_over_its_bowl() -> None:
    a = 20.0  # 1/m; the bowl z = a r^2 up to radius r has the area pi/(6 a^2) ((1 + 4 a^2 r^2)^1.5 - 1)
    vertex = np.array([0.0, 0.0, 0.01])
    cup = TrueObject("cup", Paraboloid(a, a, 0.0, Transform(None, vertex)))
    low, high = [-0.06, -0.06, 0.0], [0.06, 0.06, 0.05]
    points = coverage_samples([cup], low, high, reach_m=0.0, spacing_m=SPACING, seed=4)
    assert np.abs(cup.distance(points)).max() < 1e-12
    assert box_distance(points, low, high).max() == 0.0
    radius = np.hypot(*(points[:, :2] - vertex[:2]).T)

    def bowl(r: float) -> float:
        return float(np.pi / (6 * a**2) * ((1 + 4 * a**2 * r**2) ** 1.5 - 1))

    r1 = 0.03  # the whole bowl within r1 lies in the box (z = 0.01 + 0.018 < 0.05)
    n_expected = bowl(r1) / SPACING**2
    inside = int(np.sum(radius <= r1))
    assert abs(inside - n_expected) <= 5 * np.sqrt(n_expected)


@pytest.mark.parametrize("reach", [0.0, 0.004, 0.01])
def test_the_workspace_reach_keeps_the_zone_a_plane_cuts_off_a_sphere(reach: float) -> None:
    # the box's floor at CENTRE_z + 0.005: kept are the points above the floor minus the reach,
    # a zone of height R - 0.005 + reach, which holds that height over 2 R of the sphere's area
    floor = CENTRE[2] + 0.005
    low, high = [-1.0, -1.0, floor], [1.0, 1.0, 1.0]
    everything = coverage_samples([ball()], *BIG, reach_m=0.0, spacing_m=SPACING, seed=5)
    kept = coverage_samples([ball()], low, high, reach_m=reach, spacing_m=SPACING, seed=5)
    assert np.array_equal(kept, everything[everything[:, 2] >= floor - reach])
    assert binomial_ok(len(kept), len(everything), (R - 0.005 + reach) / (2 * R))


def test_samples_are_the_same_for_a_seed_and_differ_between_seeds() -> None:
    objects = [ball(), TrueObject("cup", Paraboloid(30.0, 10.0, -0.02))]
    low, high = [-0.05, -0.05, -0.05], [0.05, 0.05, 0.05]
    first = coverage_samples(objects, low, high, 0.01, 1e-3, seed=7)
    assert np.array_equal(first, coverage_samples(objects, low, high, 0.01, 1e-3, seed=7))
    assert not np.array_equal(first, coverage_samples(objects, low, high, 0.01, 1e-3, seed=8))


def test_a_mesh_of_the_whole_sphere_covers_it_all() -> None:
    samples = coverage_samples([ball()], *BIG, reach_m=0.0, spacing_m=SPACING, seed=9)
    # 20 000 vertices on the sphere: neighbours ~0.5 mm apart, each sample within ~0.3 mm of one
    assert coverage(samples, fibonacci_sphere(20_000, R), tol_m=1e-3) == 1.0


def test_a_mesh_of_the_upper_half_covers_half_up_to_a_band_of_the_tolerance() -> None:
    tol = 1e-3
    samples = coverage_samples([ball()], *BIG, reach_m=0.0, spacing_m=SPACING, seed=10)
    vertices = fibonacci_sphere(20_000, R)
    upper = vertices[vertices[:, 2] >= CENTRE[2]]
    share = coverage(samples, upper, tol)
    # covered: every sample of the upper half, and some within tol below the equator, a zone
    # of height at most tol (an area share of tol / 2R)
    n = len(samples)
    upper_hits = int(np.sum(samples[:, 2] >= CENTRE[2]))
    assert share * n >= upper_hits
    assert binomial_ok(upper_hits, n, 0.5)
    assert share * n <= upper_hits + int(np.sum((samples[:, 2] < CENTRE[2])
                                                & (samples[:, 2] >= CENTRE[2] - tol)))
    assert 0.5 - 0.05 < share < 0.5 + tol / (2 * R) + 0.05


def test_nothing_covers_nothing_and_a_tolerance_below_the_gap_covers_nothing() -> None:
    samples = coverage_samples([ball()], *BIG, reach_m=0.0, spacing_m=1e-3, seed=11)
    assert coverage(samples, np.zeros((0, 3))) == 0.0
    assert coverage(np.zeros((0, 3)), samples) == 0.0
    outside = CENTRE + (samples - CENTRE) * (R + 2e-3) / R  # every vertex 2 mm off its sample
    assert coverage(samples, outside, tol_m=1e-3) == 0.0
    assert coverage(samples, outside, tol_m=2.001e-3) == 1.0


def test_bad_arguments_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="workspace_min_m"):
        coverage_samples([ball()], [0, 0, 0], [1, 0, 1], 0.0)
    with pytest.raises(ValueError, match="reach_m"):
        coverage_samples([ball()], *BIG, reach_m=-1.0)
    with pytest.raises(ValueError, match="spacing_m"):
        coverage_samples([ball()], *BIG, reach_m=0.0, spacing_m=0.0)
    with pytest.raises(ValueError, match="'ball' needs"):
        coverage_samples([ball(100.0)], *BIG, reach_m=0.0, spacing_m=1e-3)
    with pytest.raises(ValueError, match="tol_m"):
        coverage(np.zeros((1, 3)), np.zeros((1, 3)), tol_m=-1.0)


def test_the_log_keeps_a_pose_a_millimetre_or_a_turn_for_the_pictures_not_for_the_report(
        ) -> None:
    from scipy.spatial.transform import Rotation

    from vibrissa.mapping.coverage import PATH_STEP_M, PATH_TURN_RAD, ExplorationLog

    log = ExplorationLog("uncertainty", np.zeros((1, 3)))
    identity = [0.0, 0.0, 0.0, 1.0]
    for x in np.arange(0.0, 0.0101, 0.0001):  # 10 mm in 0.1 mm steps
        log.move([x, 0.0, 0.0], identity)
    for yaw in np.linspace(0.0, 1.0, 101):  # then a turn in place of 1 rad
        log.move([0.01, 0.0, 0.0], Rotation.from_euler("z", yaw).as_quat())
    log.move([0.02, 0.0, 0.0])  # no orientation: the length only
    positions, quaternions = log.result().base_path
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    moved = steps[steps > 0]
    assert len(moved) == 10 and np.all(moved >= PATH_STEP_M - 1e-12)
    assert np.all(moved <= PATH_STEP_M + 1e-4 + 1e-12)
    turns = (Rotation.from_quat(quaternions[:-1]).inv() * Rotation.from_quat(quaternions[1:])
             ).magnitude()[steps == 0]
    # each kept turn at least PATH_TURN_RAD and less than that and one yaw step of 0.01 rad
    assert np.all((turns >= PATH_TURN_RAD - 1e-9) & (turns <= PATH_TURN_RAD + 0.01 + 1e-9))
    assert len(turns) >= 1.0 / (PATH_TURN_RAD + 0.01) - 1
    assert log.result().path_length_m == pytest.approx(0.02)
    assert "base_path" not in log.result().as_dict()
