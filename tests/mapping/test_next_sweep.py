"""Where to sweep next: proposals cut the predicted uncertainty, conditioning never adds any,
and a proposal is where the map is unsure, not on the lines already swept."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tests.mapping.test_gp_surface import contact_cloud
from vibrissa.mapping import gp_surface
from vibrissa.mapping.next_sweep import propose_sections


@pytest.fixture(scope="module")
def two_lines():
    points, normals, lines, truth = contact_cloud("paraboloid:a=0.5,b=1,h=0.4", [-0.4, 0.2])
    surface = gp_surface.fit(points, normals)
    pad = 0.2 * np.linalg.norm(np.ptp(points, axis=0))
    mesh = gp_surface.mesh(surface, points.min(axis=0) - pad, points.max(axis=0) + pad)
    return points, surface, mesh


def test_conditioning_never_adds_uncertainty(two_lines):
    points, surface, mesh = two_lines
    rng = np.random.default_rng(7)
    taken = mesh.vertices[rng.choice(len(mesh.vertices), 30, replace=False)]
    _, normals = surface.evaluate(taken)
    after = gp_surface.conditioned(surface, taken, normals)
    queries = mesh.vertices[::7]
    before_std, after_std = surface.std(queries), after.std(queries)
    assert np.all(after_std <= before_std * (1 + 1e-9))
    # and it is sure where it was told: at the new points the std drops to the points' noise
    noise_m = surface.point_std * surface.scale
    assert np.all(after.std(taken) < 1.1 * np.hypot(noise_m, surface.residual_std))
    assert np.median(surface.std(taken)) > 20 * noise_m


def test_proposals_cut_the_predicted_std_and_lie_between_or_beyond_the_lines(two_lines):
    points, surface, mesh = two_lines
    proposals = propose_sections(surface, mesh.vertices, points, [0.0, 1.0, 0.0], 3)
    assert len(proposals) == 3
    lo, hi = points[:, 1].min(), points[:, 1].max()
    previous = proposals[0].std_max_before_m
    for p in proposals:
        assert lo <= p.offset_m <= hi
        assert p.std_max_after_m < p.std_max_before_m == pytest.approx(previous)
        previous = p.std_max_after_m
        assert np.allclose(p.line[:, 1], p.offset_m, atol=(hi - lo) / 40)
    # the first proposal is not on a line already swept: its section is far from the contacts
    distance = cKDTree(points).query(proposals[0].line)[0]
    assert np.median(distance) > 0.05
    # and what it proposes is less sure than what was touched
    assert proposals[0].std_on_line_m > 10 * np.median(surface.position_std(points[::50]))


def test_no_proposal_without_a_range_along_the_axis(two_lines):
    points, surface, mesh = two_lines
    flat = points.copy()
    flat[:, 2] = 0.5  # contacts all at one height: no range along z
    assert propose_sections(surface, mesh.vertices, flat, [0.0, 0.0, 1.0], 2) == []
    with pytest.raises(ValueError, match="count must be >= 1"):
        propose_sections(surface, mesh.vertices, points, [0.0, 1.0, 0.0], 0)
    with pytest.raises(ValueError, match="axis must be a nonzero vector"):
        propose_sections(surface, mesh.vertices, points, [0.0, 0.0, 0.0], 1)


@pytest.mark.slow
def test_on_the_demo_object_three_proposals_beat_three_evenly_spaced_trails():
    # the demo's 5 trails (launch/demo.yaml), then 3 more: proposed, or evenly spaced over
    # the same range; the error of each map over the reachable surface (true points in the
    # contacts' y range up to the highest contact), against the true paraboloid
    spec, demo = "paraboloid:a=0.5,b=1,h=0.4", [-0.4, -0.2, 0.0, 0.2, 0.4]
    points, normals, _, truth = contact_cloud(spec, demo)
    surface = gp_surface.fit(points, normals)
    pad = 0.2 * np.linalg.norm(np.ptp(points, axis=0))
    mesh = gp_surface.mesh(surface, points.min(axis=0) - pad, points.max(axis=0) + pad)
    proposed = [p.offset_m for p in propose_sections(surface, mesh.vertices, points,
                                                     [0.0, 1.0, 0.0], 3)]
    lo, hi = points[:, 1].min(), points[:, 1].max()
    even = list(np.linspace(lo, hi, 5)[1:-1])
    x, y = np.meshgrid(np.linspace(-1.2, 1.2, 121), np.linspace(lo, hi, 61))
    z = 0.5 * x**2 + y**2 + 0.4
    reachable = np.stack([x, y, z], axis=-1)[z <= points[:, 2].max()]
    assert np.max(np.abs(truth.value(reachable))) < 1e-12  # on the true surface

    def max_error(y0s):
        p, n, _, _ = contact_cloud(spec, y0s)
        f, g = gp_surface.fit(p, n).evaluate(reachable)
        return np.max(np.abs(f) / np.linalg.norm(g, axis=1))

    assert max_error(demo + proposed) < 0.7 * max_error(demo + even)


def test_the_std_kept_through_conditionings_is_the_conditioned_surfaces(two_lines):
    """`StdAt` solves only the new block of the factor at each conditioning: the std of the
    surface conditioned on all the sections so far, to rounding."""
    points, surface, mesh = two_lines
    queries = mesh.vertices[::5]
    at = gp_surface.StdAt.of(surface, queries)
    np.testing.assert_allclose(at.std(), surface.std(queries), rtol=1e-12)
    rng = np.random.default_rng(3)
    direct = surface
    for _ in range(3):
        taken = mesh.vertices[rng.choice(len(mesh.vertices), 40, replace=False)]
        _, normals = direct.evaluate(taken)
        at = at.conditioned(taken, normals)
        direct = gp_surface.conditioned(direct, taken, normals)
        np.testing.assert_allclose(at.std(), direct.std(queries), rtol=1e-9)
    assert at.std().max() < surface.std(queries).max()
