"""Step 1 along a sampled clamp path: the paper's trail as one, rigid-motion invariance, and
the physics of every step while the clamp turns (statics, contact, no penetration, Coulomb)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vibrissa.frames import Transform
from vibrissa.paths import SampledPath
from vibrissa.status import SweepEnd
from vibrissa.surfaces import Sphere, parse_surface
from vibrissa.sweep import SLIDE, Sweep, Trail, first_contact, simulate_sweeps

PARABOLOID = "paraboloid:a=0.5,b=1,h=0.4"


def straight(x_from: float, y0: float, step: float, n: int, mu: float) -> SampledPath:
    x = x_from - step * np.arange(n)
    return SampledPath(np.column_stack([x, np.full(n, y0), np.zeros(n)]),
                       Rotation.identity(n).as_quat(), mu)


def moved(path: SampledPath, X: Transform) -> SampledPath:
    return SampledPath(X.apply(path.p_WR), (X.rotation * Rotation.from_quat(path.q_WR)).as_quat(),
                       path.mu)


def check_physics(sweep: Sweep, surface_spec: str, path: SampledPath) -> None:
    """Statics in the clamp frame, the contact on the surface, the rod outside, Coulomb."""
    surface = parse_surface(surface_spec)
    p_WC, R_WC = path.clamp_pose(sweep.x0)
    f0_W = np.einsum("nij,nj->ni", R_WC, sweep.f0)
    m0_W = np.einsum("nij,nj->ni", R_WC, sweep.m0)
    assert np.max(np.linalg.norm(f0_W + sweep.force, axis=1)) < 1e-12
    r = sweep.contact - p_WC
    np.testing.assert_allclose(m0_W + np.cross(r, sweep.force), 0.0, atol=1e-10)
    assert np.max(np.abs(sweep.m0[:, 2])) < 1e-12  # no twist about the clamp axis
    assert np.max(np.abs(surface.signed_distance(sweep.contact))) < 1e-9
    assert np.all(sweep.fn > 0)
    sliding = sweep.state == SLIDE
    assert np.all(np.abs(sweep.ft[sliding] - path.mu * sweep.fn[sliding])
                  <= 1e-7 * sweep.fn[sliding])
    stuck = ~sliding
    assert np.all(sweep.ft[stuck] <= path.mu * sweep.fn[stuck] * (1 + 1e-9))
    for i in range(0, sweep.n_steps, max(1, sweep.n_steps // 40)):
        line = sweep.elastic_line(i, 201)
        assert np.min(surface.signed_distance(line)) > -1e-9, i


def test_the_trail_as_a_sampled_path_gives_the_trails_sweep() -> None:
    surface = parse_surface(PARABOLOID)
    step = 0.002
    reference = simulate_sweeps(surface, [Trail(0.2, 0.3)], step)[0]
    touch = first_contact(surface, 0.2)
    assert touch is not None
    x_from = touch[0] + 100 * step  # the samples on the trail's grid
    path = straight(x_from, 0.2, step, 1300, 0.3)
    sweep = simulate_sweeps(surface, [path], path.h)[0]
    assert path.h == pytest.approx(step, abs=1e-15)
    assert sweep.end == reference.end == SweepEnd.DETACHMENT
    assert sweep.n_steps == reference.n_steps
    np.testing.assert_allclose(x_from + sweep.x0, reference.x0, atol=1e-9)
    for name in ("f0", "m0", "contact", "force"):
        np.testing.assert_allclose(getattr(sweep, name), getattr(reference, name), atol=1e-8,
                                   err_msg=name)
    assert [c[1:] for c in sweep.phase_changes] == [c[1:] for c in reference.phase_changes]


def test_a_rigid_motion_of_the_whole_scene_changes_no_clamp_wrench() -> None:
    rng = np.random.default_rng(5)
    X = Transform(Rotation.random(random_state=rng), rng.uniform(-2, 2, 3))
    centre = Transform(translation=[0.0, 0.0, 0.8])
    path = straight(0.6, 0.1, 0.004, 200, 0.25)
    sweep = simulate_sweeps(Sphere(0.3, centre), [path], path.h)[0]
    other = simulate_sweeps(Sphere(0.3, X @ centre), [moved(path, X)], path.h)[0]
    assert sweep.n_steps == other.n_steps > 50 and sweep.end == other.end
    np.testing.assert_allclose(other.x0, sweep.x0, atol=1e-12)
    np.testing.assert_allclose(other.f0, sweep.f0, atol=1e-12)
    np.testing.assert_allclose(other.m0, sweep.m0, atol=1e-12)
    np.testing.assert_allclose(other.contact, X.apply(sweep.contact), atol=1e-12)


@pytest.mark.parametrize(("spec", "mu", "x_from"), [
    (PARABOLOID + ",yaw=0.3", 0.2, 1.7),
    ("ellipsoid:rx=0.3,ry=0.2,rz=0.25,cx=0.1,cz=0.6,roll=0.2,yaw=0.5", 0.4, 1.1),
])
def test_a_turning_clamp_satisfies_the_physics_at_every_step(spec: str, mu: float,
                                                              x_from: float) -> None:
    """The robot drives an arc and turns: the clamp's axis tilts as it goes."""
    n = 800
    theta = np.linspace(0.0, 1.0, n)  # the robot turns by 1 rad along an arc
    radius = 1.5
    positions = np.column_stack([x_from - radius * np.sin(theta),
                                 0.15 - radius * (1 - np.cos(theta)),
                                 np.zeros(n)])
    tilt = Rotation.from_euler("y", -0.2)  # the mount tilts the rod
    rotations = Rotation.from_euler("z", -theta[:, None]) * tilt
    path = SampledPath(positions, rotations.as_quat(), mu)
    sweep = simulate_sweeps(parse_surface(spec), [path], path.h)[0]
    assert sweep.n_steps > 50, sweep.end
    check_physics(sweep, spec, path)


def test_a_path_that_ends_in_contact_ends_there() -> None:
    path = straight(0.6, 0.1, 0.004, 120, 0.25)  # stops while the rod leans on the sphere
    sweep = simulate_sweeps(parse_surface("sphere:r=0.3,cz=0.8"), [path], path.h)[0]
    assert sweep.end == SweepEnd.PATH_END
    assert sweep.x0[-1] == pytest.approx(path.x_end, abs=1e-12)


def test_clamp_poses_interpolate_and_never_extrapolate() -> None:
    rotations = Rotation.from_euler("z", [[0.0], [0.4]])
    path = SampledPath(np.array([[0.0, 0, 0], [0.1, 0, 0]]), rotations.as_quat(), 0.1)
    assert path.h == pytest.approx(0.1 + 0.4)
    p, R = path.clamp_pose(np.array([-0.25 * path.h]))
    np.testing.assert_allclose(p[0], [0.025, 0, 0], atol=1e-15)
    np.testing.assert_allclose(R[0], Rotation.from_euler("z", 0.1).as_matrix(), atol=1e-15)
    with pytest.raises(ValueError, match="outside the path"):
        path.clamp_pose(np.array([0.1]))
