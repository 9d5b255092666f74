"""Step 1 checked by physics: statics, Coulomb's law, contact, no penetration, symmetry, round trip."""

import numpy as np
import pytest

from vibrissa.reconstruct import PHASE_TANGENTIAL, PHASE_TIP, reconstruct
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import SLIDE, STICK, Trail, first_contact, simulate_sweeps

PAPER_Y0 = (-0.4, -0.2, 0.0, 0.2, 0.4)  # as in the conftest fixture `paper_sweeps`
PAPER_MU = (0.0, 0.1, 0.2, 0.3, 0.4)
SURFACE = parse_surface("paraboloid:a=0.5,b=1,h=0.4")
KEYS = [(y0, mu) for y0 in PAPER_Y0 for mu in PAPER_MU]


@pytest.mark.parametrize("key", KEYS)
def test_statics_of_the_rod_at_every_step(paper_sweeps, key):
    sweep = paper_sweeps[key]
    assert sweep.n_steps > 1000
    r = sweep.contact - sweep.p0
    # m0 comes from the elastica's clamp curvature, F from the contact: m0 + r x F = 0 checks both.
    np.testing.assert_allclose(sweep.m0 + np.cross(r, sweep.force), 0.0, atol=1e-10)
    # f0 + F = 0 with F rebuilt from Coulomb's law alone: fn (n + mu t), t along the chord of eq. 7
    rows = np.flatnonzero((sweep.state[1:] == SLIDE) & ~sweep.refined[1:]) + 1
    n = sweep.normal[rows]
    chord = sweep.contact[rows - 1] - sweep.contact[rows]
    chord -= np.einsum("ni,ni->n", chord, n)[:, None] * n
    t = chord / np.linalg.norm(chord, axis=1)[:, None]
    coulomb = sweep.fn[rows, None] * (n + sweep.trail.mu * t)
    assert np.max(np.linalg.norm(sweep.f0[rows] + coulomb, axis=1) / sweep.fn[rows]) < 1e-6
    assert np.max(np.abs(sweep.m0[:, 2])) < 1e-15  # no moment about the clamp axis (no twist)


@pytest.mark.parametrize("key", KEYS)
def test_coulomb_friction_and_contact_geometry(paper_sweeps, key):
    sweep = paper_sweeps[key]
    mu = sweep.trail.mu
    assert np.all(sweep.fn > 0)
    sliding = sweep.state == SLIDE
    # |F_t| = mu F_n while sliding, to the solver's direction tolerance (1e-8 rad)
    assert np.all(np.abs(sweep.ft[sliding] - mu * sweep.fn[sliding]) <= 1e-7 * sweep.fn[sliding])
    assert np.all(sweep.ft[sweep.state == STICK] <= mu * sweep.fn[sweep.state == STICK] * (1 + 1e-9))
    # contact points on the surface, normal = the surface's outward normal there
    assert np.max(np.abs(SURFACE.signed_distance(sweep.contact))) < 1e-9
    np.testing.assert_allclose(sweep.normal, SURFACE.normal(sweep.contact), atol=1e-12)
    # friction opposes the motion of the contact point (eq. 7): along P_{k-1} - P_k in the tangent plane
    if mu > 0:
        moving = np.flatnonzero(sliding[1:] & ~sweep.refined[1:]) + 1
        chord = sweep.contact[moving - 1] - sweep.contact[moving]
        n = sweep.normal[moving]
        chord -= np.einsum("ni,ni->n", chord, n)[:, None] * n
        friction = sweep.force[moving] - sweep.fn[moving, None] * n
        cosine = np.einsum("ni,ni->n", chord, friction) / (
            np.linalg.norm(chord, axis=1) * np.linalg.norm(friction, axis=1)
        )
        assert np.min(cosine) > 1 - 1e-6


@pytest.mark.parametrize("key", [(0.0, 0.0), (0.2, 0.0), (0.2, 0.4), (-0.4, 0.3), (0.0, 0.4)])
def test_the_rod_never_enters_the_object(paper_sweeps, key):
    sweep = paper_sweeps[key]
    worst = min(
        SURFACE.signed_distance(sweep.elastic_line(i, 201)).min() for i in range(0, sweep.n_steps, 7)
    )
    assert worst > -1e-9


@pytest.mark.parametrize("mu", PAPER_MU)
def test_symmetric_trail_stays_in_its_plane(paper_sweeps, mu):
    sweep = paper_sweeps[(0.0, mu)]
    assert np.all(sweep.f0[:, 1] == 0.0)
    assert np.all(sweep.m0[:, 0] == 0.0)
    assert np.all(sweep.m0[:, 2] == 0.0)


def _stick_slip_onset(sweep, run: int = 8) -> int:
    """First step of ``run`` in a row whose contact displacement differs from the one before by
    more than 2x (creeps and jumps alternate), n_steps if there is none."""
    chords = np.linalg.norm(np.diff(sweep.contact, axis=0), axis=1)
    ratio = chords[1:] / chords[:-1]
    uneven = ((ratio > 2.0) | (ratio < 0.5)).astype(int)
    runs = np.convolve(uneven, np.ones(run, dtype=int), mode="valid")
    starts = np.flatnonzero(runs == run)
    return int(starts[0]) + 2 if len(starts) else sweep.n_steps


# The object is its own mirror image across y = 0, and so is Coulomb's law: the sweeps at +y0 and
# -y0 mirror each other for every mu. In a stick-slip stretch (the paper's |y0| = 0.2, mu = 0.4)
# each jump amplifies round-off, so the two sample the same creep-jump cycle at a different
# phase: there they agree to within the cycle's own step-to-step change, not to round-off.
@pytest.mark.parametrize("mu", PAPER_MU)
@pytest.mark.parametrize("y0", [0.2, 0.4])
def test_sweeps_at_plus_and_minus_y0_are_mirror_images(paper_sweeps, y0, mu):
    plus, minus = paper_sweeps[(y0, mu)], paper_sweeps[(-y0, mu)]
    assert plus.n_steps == minus.n_steps
    onset = min(_stick_slip_onset(plus), _stick_slip_onset(minus))
    assert (onset < plus.n_steps) == ((y0, mu) == (0.2, 0.4))  # stick-slip only there
    onset = max(onset - 25, 0) if onset < plus.n_steps else onset  # where the alternation grows
    mirror = np.array([1.0, -1.0, 1.0])
    pairs = {"f0": (minus.f0, plus.f0 * mirror), "m0": (minus.m0, -plus.m0 * mirror),  # m0: pseudovector
             "contact": (minus.contact, plus.contact * mirror)}
    for name, (a, b) in pairs.items():
        np.testing.assert_allclose(a[:onset], b[:onset], atol=1e-9, err_msg=name)
        if onset < plus.n_steps:
            cycle = np.abs(np.diff(b[onset - 1:], axis=0)).max()
            assert np.abs(a[onset:] - b[onset:]).max() <= cycle, name


@pytest.mark.parametrize("key", KEYS)
def test_round_trip_recovers_every_contact_point_whatever_mu(paper_sweeps, key):
    sweep = paper_sweeps[key]
    result = reconstruct(sweep.p0, sweep.f0, sweep.m0)
    assert result.valid.all()
    assert np.max(np.linalg.norm(result.point - sweep.contact, axis=1)) < 1e-7
    assert np.max(np.abs(SURFACE.signed_distance(result.point))) < 1e-7
    np.testing.assert_array_equal(result.phase, sweep.phase)


def test_symmetric_trail_snaps_off_later_with_more_friction(paper_sweeps):
    ends = [paper_sweeps[(0.0, mu)] for mu in PAPER_MU]
    assert all(s.end == "snap-off" for s in ends)
    x0_end = [s.x0_end for s in ends]
    assert all(a > b for a, b in zip(x0_end, x0_end[1:], strict=False)), x0_end
    # a snap-off happens at finite force
    assert all(np.linalg.norm(s.f0[-1]) > 1.0 for s in ends)


@pytest.mark.parametrize("key", [k for k in KEYS if k[0] != 0.0])
def test_off_centre_trails_detach_smoothly(paper_sweeps, key):
    sweep = paper_sweeps[key]
    assert sweep.end == "detachment"
    peak = np.max(np.linalg.norm(sweep.f0, axis=1))
    assert np.linalg.norm(sweep.f0[-1]) < 0.02 * peak
    assert np.linalg.norm(sweep.m0[-1]) < 0.02 * np.max(np.linalg.norm(sweep.m0, axis=1))


@pytest.mark.parametrize("mu", PAPER_MU)
def test_phases_of_the_paper(paper_sweeps, mu):
    for y0 in (-0.2, 0.2):
        phases = set(paper_sweeps[(y0, mu)].phase)
        assert phases == {PHASE_TIP, PHASE_TANGENTIAL}
    for y0 in (-0.4, 0.4):
        assert set(paper_sweeps[(y0, mu)].phase) == {PHASE_TIP}


@pytest.mark.parametrize(
    "spec", ["sphere:r=0.3,cx=0,cy=0,cz=0.8", "ellipsoid:rx=0.4,ry=0.3,rz=0.2,cx=0.1,cy=0.05,cz=0.9,yaw=0.5,roll=0.2"]
)
def test_other_objects_obey_statics_contact_and_round_trip(spec):
    surface = parse_surface(spec)
    for sweep in simulate_sweeps(surface, [Trail(0.1, 0.0), Trail(0.1, 0.3)], step=0.005):
        assert sweep.n_steps > 50
        _assert_statics_contact_and_round_trip(surface, sweep, round_trip_tol=1e-7)


def _assert_statics_contact_and_round_trip(surface, sweep, round_trip_tol: float) -> None:
    """m0 + r x F = 0, contacts on the surface, no rod point inside, Step 2 recovers P1."""
    r = sweep.contact - sweep.p0
    np.testing.assert_allclose(sweep.m0 + np.cross(r, sweep.force), 0.0, atol=1e-10)
    assert np.max(np.abs(surface.signed_distance(sweep.contact))) < 1e-9
    lines = (sweep.elastic_line(i, 101) for i in range(0, sweep.n_steps, 5))
    assert min(surface.signed_distance(line).min() for line in lines) > -1e-9
    result = reconstruct(sweep.p0, sweep.f0, sweep.m0)
    assert np.max(np.linalg.norm(result.point - sweep.contact, axis=1)) < round_trip_tol


def _fold_fit(sweep, last: int = 6) -> tuple[float, float]:
    """Fit the square-root law of a saddle-node fold to the last steps of a sweep.

    Near a fold at x0*, the wrench changes like |d(f0, m0)/dx0| ~ |x0 - x0*|^(-1/2), so
    1 / rate^2 is linear in x0 and vanishes at x0*. Returns (x0*, R^2 of the linear fit).
    """
    wrench = np.column_stack([sweep.f0, sweep.m0]) / np.max(np.abs(sweep.f0[-1]))
    rate = np.linalg.norm(np.diff(wrench, axis=0), axis=1) / np.abs(np.diff(sweep.x0))
    x0, y = sweep.x0[1:][-last:], 1.0 / rate[-last:] ** 2
    slope, intercept = np.polyfit(x0, y, 1)
    r2 = 1.0 - np.sum((slope * x0 + intercept - y) ** 2) / np.sum((y - y.mean()) ** 2)
    return -intercept / slope, r2


def _assert_snap_off_is_a_fold(sweep) -> None:
    x0_fold, r2 = _fold_fit(sweep)
    assert r2 > 0.98
    # the fold lies just beyond the last equilibrium, within the few steps refinement resolves
    assert sweep.x0_end - 3 * sweep.step <= x0_fold <= sweep.x0_end


@pytest.mark.parametrize("mu", PAPER_MU)
def test_paper_snap_off_is_a_fold_of_the_equilibrium_branch(paper_sweeps, mu):
    _assert_snap_off_is_a_fold(paper_sweeps[(0.0, mu)])


def test_mid_sweep_snap_off_on_a_posed_ellipsoid_is_a_fold():
    # A tilted ellipsoid where friction ends the sweep early: mu = 0 and 0.2 detach smoothly at
    # x0 = -0.18, mu = 0.4 snaps off at x0 = 0.19 from the largest force of the sweep.
    surface = parse_surface("ellipsoid:rx=0.4,ry=0.3,rz=0.2,cx=0.1,cy=0.05,cz=0.9,yaw=0.5,roll=0.2")
    frictionless, sticky = simulate_sweeps(surface, [Trail(0.2, 0.0), Trail(0.2, 0.4)], step=0.001)
    assert frictionless.end == "detachment"
    assert sticky.end == "snap-off" and sticky.x0_end > frictionless.x0_end + 0.3
    _assert_snap_off_is_a_fold(sticky)


def test_coarse_steps_tell_detachment_from_snap_off():
    # At a step of 0.05 the last equilibrium before detachment still carries 3-7 % of the peak
    # force; the end is told by where the force was heading, as at the paper's step.
    trails = [Trail(y0, mu) for y0 in (0.0, 0.2, 0.4) for mu in (0.0, 0.4)]
    for sweep in simulate_sweeps(SURFACE, trails, step=0.05):
        assert sweep.end == ("snap-off" if sweep.trail.y0 == 0.0 else "detachment"), sweep.trail


def test_a_steep_tip_touch_with_strong_friction_runs_at_fine_steps():
    # Over the first steps after a tip touch the tip slips only by the rod's axial shortening,
    # ~1e-7 at a step of 5e-4: too short to resolve the friction direction of eq. 7. Such a
    # step is taken as a longer one on the same grid. This trail used to find no equilibrium.
    surface = parse_surface("paraboloid:a=0.926,b=0.807,h=0.536,yaw=0.464,pitch=-0.140")
    trail = Trail(0.196, 0.6)
    fine = simulate_sweeps(surface, [trail], step=5e-4, max_steps=200)[0]
    coarse = simulate_sweeps(surface, [trail], step=1e-3, max_steps=100)[0]
    assert fine.end == "max-steps" and fine.n_steps == 200
    # Longer steps only within 0.01 L of the touch (how many of them is up to round-off), all
    # of them on the grid; plain steps after that.
    early = fine.x_touch - fine.x0 < 0.01
    assert fine.refined[0] and not fine.refined[~early].any() and early.sum() < 25
    steps = np.diff(fine.x0) / -5e-4
    np.testing.assert_allclose(steps, np.round(steps), rtol=0, atol=1e-6)
    assert (np.round(steps) >= 1).all() and (np.round(steps)[~early[1:]] == 1).all()
    r = fine.contact - fine.p0
    np.testing.assert_allclose(fine.m0 + np.cross(r, fine.force), 0.0, atol=1e-12)
    assert np.max(np.abs(surface.signed_distance(fine.contact))) < 1e-9
    assert min(surface.signed_distance(fine.elastic_line(i, 101)).min() for i in range(0, 200, 10)) > -1e-9
    assert np.max(np.linalg.norm(reconstruct(fine.p0, fine.f0, fine.m0).point - fine.contact, axis=1)) < 1e-9
    # Same trail at twice the step: the friction of eq. 7 is discretised to first order in the
    # step, so the reactions agree to well within the step (1e-3) at the common positions.
    common, i, j = np.intersect1d(np.round(fine.x0, 9), np.round(coarse.x0, 9), return_indices=True)
    assert len(common) >= 90
    difference = np.linalg.norm(fine.f0[i] - coarse.f0[j], axis=1) / np.linalg.norm(coarse.f0[j], axis=1)
    assert difference.max() < 1e-3


def test_trails_on_a_shared_grid_move_as_one_array():
    # The whiskers of a rigid array share the clamp's x: every sweep steps on x_grid - k step
    # from a partial first step after its own touch, and obeys the same physics.
    step = 0.005
    trails = [Trail(y0, mu) for y0 in (-0.4, 0.0, 0.25) for mu in (0.0, 0.3)]
    x_grid = max(first_contact(SURFACE, t.y0)[0] for t in trails)
    shared = simulate_sweeps(SURFACE, trails, step=step, x_grid=x_grid)
    own = simulate_sweeps(SURFACE, trails, step=step)
    for sweep, alone in zip(shared, own, strict=True):
        assert sweep.end == alone.end and sweep.n_steps > 100
        k = (x_grid - sweep.x0) / step
        np.testing.assert_allclose(k, np.round(k), rtol=0, atol=1e-9)
        assert 0 < sweep.x_touch - sweep.x0[0] <= step * (1 + 1e-9) or sweep.refined[0]
        _assert_statics_contact_and_round_trip(SURFACE, sweep, round_trip_tol=1e-9)
        if sweep.x_touch == x_grid:  # its own grid: the same sweep
            np.testing.assert_allclose(sweep.f0, alone.f0, rtol=0, atol=1e-12)
        if sweep.trail.mu == 0:  # frictionless: the state depends on x0 alone, not on the path
            inside = (sweep.x0 < alone.x0[0]) & (sweep.x0 > alone.x0[-1])
            for axis in range(3):
                expected = np.interp(-sweep.x0[inside], -alone.x0, alone.f0[:, axis])
                scale = np.linalg.norm(alone.f0, axis=1).max()
                assert np.max(np.abs(sweep.f0[inside, axis] - expected)) < 1e-3 * scale
