"""Step 1 for tapered and pre-curved rods (the Kirchhoff rod of ``vibrissa.rods``): every
equilibrium checked by statics, contact, non-penetration, Coulomb's law and the independent
reference rod (``rod_reference``), and against the closed-form elastica where they meet."""

import numpy as np
import pytest

from tests.core.rod_reference import solve_rod
from vibrissa import parse_surface, simulate_sweep
from vibrissa.reconstruct_rods import reconstruct_rod
from vibrissa.rods import RodShape
from vibrissa.status import ContactStatus
from vibrissa.sweep import STICK

SPHERE = "sphere:r=0.3,cx=0,cy=0,cz=0.6"


@pytest.fixture(scope="module")
def curved_sweep():
    """A tapered (0.6), pre-curved (2 / L) rod past a sphere off its plane (y0 = 0.12) with
    mu 0.3: the contact force leaves the rod's plane, the rod bends and twists in 3D."""
    shape = RodShape(taper_ratio=0.6, precurvature=2.0, poisson_ratio=0.3)
    return simulate_sweep(parse_surface(SPHERE), 0.12, 0.3, 0.002, shape=shape)


def test_the_sweep_runs_from_touch_to_detachment(curved_sweep):
    sweep = curved_sweep
    assert sweep.end == "detachment"
    assert sweep.n_steps > 200
    assert (sweep.phase > 0).all()


def test_every_equilibrium_satisfies_statics_contact_and_coulomb(curved_sweep):
    sweep = curved_sweep
    surface = parse_surface(SPHERE)
    p0 = sweep.p0
    force_C = sweep.force  # the trail's C has W's axes
    np.testing.assert_allclose(sweep.f0 + force_C, 0.0, atol=1e-15)
    moment = sweep.m0 + np.cross(sweep.contact - p0, force_C)
    assert np.abs(moment).max() < 1e-10 * np.abs(sweep.m0).max()
    assert np.abs(surface.signed_distance(sweep.contact)).max() < 1e-10
    fn, ft = sweep.fn, sweep.ft
    assert (fn > 0).all()
    sliding = sweep.state != STICK
    assert np.abs(ft[sliding] - 0.3 * fn[sliding]).max() < 1e-7 * fn.max()
    assert (ft[~sliding] <= 0.3 * fn[~sliding] * (1 + 1e-9)).all()
    # friction opposes the slip of each sliding step (eq. 7's chord)
    slip = np.diff(sweep.contact, axis=0)
    tangential = sweep.force - fn[:, None] * sweep.normal
    moved = sliding[1:] & (np.linalg.norm(slip, axis=1) > 1e-6)
    assert moved.sum() > 100
    cosine = np.einsum("ni,ni->n", tangential[1:][moved], slip[moved]) / (
        np.linalg.norm(tangential[1:][moved], axis=1) * np.linalg.norm(slip[moved], axis=1))
    assert cosine.max() < -0.99


def test_no_point_of_the_rod_enters_the_sphere(curved_sweep):
    sweep = curved_sweep
    surface = parse_surface(SPHERE)
    rows = np.arange(0, sweep.n_steps, 7)
    lines = sweep.elastic_lines(rows, 201)
    distance = surface.signed_distance(lines.reshape(-1, 3)).reshape(len(rows), -1)
    assert distance.min() > -1e-9
    # and the rod's line ends where the contact is, at s1
    s = np.linspace(0.0, 1.0, 201)
    for k, row in enumerate(rows):
        at = np.argmin(np.abs(s - sweep.s1[row]))
        if abs(s[at] - sweep.s1[row]) < 1e-12:
            np.testing.assert_allclose(lines[k, at], sweep.contact[row], atol=1e-12)


def test_the_rod_leaves_its_plane_and_twists(curved_sweep):
    """A pre-curved rod loaded out of its plane: its line leaves the plane y = y0 and the clamp
    feels a torque about the rod's axis (zero for any straight rod)."""
    sweep = curved_sweep
    lines = sweep.elastic_lines(np.arange(sweep.n_steps), 51)
    assert np.abs(lines[:, :, 1] - 0.12).max() > 0.02
    assert np.abs(sweep.m0[:, 2]).max() > 0.05 * np.linalg.norm(sweep.m0, axis=1).max()


def test_equilibria_match_the_independent_reference_rod(curved_sweep):
    """The contact force and s1 of some rows, handed to the reference (DOP853 shooting): the
    same contact point and clamp moment, within the rod's discretisation error."""
    sweep, shape = curved_sweep, curved_sweep.shape
    for row in np.linspace(0, sweep.n_steps - 1, 7).astype(int):
        reference = solve_rod(sweep.force[row], sweep.s1[row], shape.taper_ratio,
                              shape.precurvature, shape.poisson_ratio)
        np.testing.assert_allclose(sweep.contact[row] - sweep.p0[row], reference.r1, atol=2e-6)
        np.testing.assert_allclose(sweep.m0[row], reference.m0, atol=2e-6)


def test_step2_gives_the_sweeps_contacts_back(curved_sweep):
    sweep = curved_sweep
    result, _ = reconstruct_rod(sweep.p0, sweep.f0, sweep.m0, sweep.shape,
                                previous_s1=sweep.s1[0], stream=True)
    assert (result.status == 0).all()
    assert np.abs(result.point - sweep.contact).max() < 1e-6
    assert np.abs(result.s1 - sweep.s1).max() < 1e-6


def test_a_tapered_straight_rod_stays_in_its_plane():
    """A tapered straight rod on the sphere's plane of symmetry: planar, its contacts on the
    plane; the elastica of the uniform rod stiffer (deflects less) on the same trail."""
    surface = parse_surface(SPHERE)
    tapered = simulate_sweep(surface, 0.0, 0.3, 0.004, shape=RodShape(taper_ratio=0.5))
    uniform = simulate_sweep(surface, 0.0, 0.3, 0.004)
    # the thin tip slides off the ball where its tangential contact reaches the tip, at the
    # same place at half the step
    finer = simulate_sweep(surface, 0.0, 0.3, 0.002, shape=RodShape(taper_ratio=0.5))
    assert tapered.end == finer.end == "snap-off"
    assert abs(tapered.x0_end - finer.x0_end) < 1e-12
    assert np.abs(tapered.contact[:, 1]).max() < 1e-9
    assert np.abs(tapered.m0[:, [1, 2]]).max() < 1e-9 * np.abs(tapered.m0).max() + 1e-15 or (
        np.abs(tapered.m0[:, 0]).max() < 1e-9 * np.abs(tapered.m0).max())
    # at the same clamp position the softer rod pushes less
    common = np.intersect1d(np.round(tapered.x0, 9), np.round(uniform.x0, 9))
    assert len(common) > 50
    f_t = np.linalg.norm(tapered.force[np.isin(np.round(tapered.x0, 9), common)], axis=1)
    f_u = np.linalg.norm(uniform.force[np.isin(np.round(uniform.x0, 9), common)], axis=1)
    assert (f_t < f_u).mean() > 0.9


def test_the_kirchhoff_rod_meets_the_closed_form_elastica():
    """A rod a hair from uniform (taper 1 - 1e-9) goes through the Kirchhoff rod; its sweep
    matches the closed-form elastica's sweep of the uniform rod, row for row."""
    surface = parse_surface(SPHERE)
    near = simulate_sweep(surface, 0.1, 0.3, 0.004, shape=RodShape(taper_ratio=1.0 - 1e-9))
    exact = simulate_sweep(surface, 0.1, 0.3, 0.004)
    assert near.end == exact.end
    assert near.n_steps == exact.n_steps
    np.testing.assert_array_equal(near.phase, exact.phase)
    assert np.abs(near.contact - exact.contact).max() < 1e-5
    assert np.abs(near.f0 - exact.f0).max() < 1e-5 * np.abs(exact.f0).max()


def _shaped_scene():
    """Tapered and pre-curved whiskers on a yawing robot path past a ball and an ellipsoid."""
    from scipy.spatial.transform import Rotation

    from vibrissa.frames import Transform
    from vibrissa.scene import Scene, SceneObject, Whisker, robot_path

    n = 500
    t = np.arange(n) * 0.002
    p = np.column_stack([np.linspace(0.0, -0.07, n), np.linspace(0.0, 0.004, n), np.zeros(n)])
    q = Rotation.from_euler("z", np.linspace(0.0, 0.2, n)[:, None]).as_quat()
    objects = (SceneObject("ball", "sphere", {"radius_m": 0.01},
                           Transform(Rotation.identity(), [-0.03, 0.004, 0.03])),
               SceneObject("egg", "ellipsoid", {"semi_axes_m": [0.008, 0.012, 0.01]},
                           Transform(Rotation.from_euler("x", 0.4), [-0.05, -0.012, 0.032])))
    whiskers = (Whisker("thin", 0.04, 1e-5, taper_ratio=0.3, precurvature_1pm=40.0),
                Whisker("bent", 0.05, 2e-5, X_RC=Transform(Rotation.from_euler("z", 0.5),
                                                           [0.0, -0.01, 0.0]),
                        taper_ratio=0.5, precurvature_1pm=-20.0, poisson_ratio=0.45))
    return Scene(0.3, objects, whiskers, robot_path(t, p, q))


def test_shaped_whiskers_in_a_scene_touch_stick_slide_and_come_free():
    """Tapered and pre-curved whiskers on a robot path past a ball and an ellipsoid: every
    contact sample's wrench is the statics of its contact point (m0 = (P1 - P0) x f0 in C),
    the point is on its object, and Step 2 of the wrench alone gives it back."""
    from vibrissa.scene import simulate

    scene = _shaped_scene()
    objects, whiskers = scene.objects, scene.whiskers
    results = simulate(scene)
    touching = 0
    for whisker, result in zip(whiskers, results, strict=True):
        contact = np.flatnonzero(result.phase > 0)
        touching += len(contact)
        covered, p_WR, R_WR = scene.path.at(result.t[contact])
        R_WC = (R_WR * whisker.X_RC.rotation).as_matrix()
        p_WC = p_WR + R_WR.apply(np.array(whisker.X_RC.translation))
        r1_C = np.einsum("nji,nj->ni", R_WC, result.p_W_m[contact] - p_WC)
        moment = np.cross(r1_C, result.f0_n[contact])
        scale = np.abs(result.m0_nm[contact]).max()
        assert np.abs(moment - result.m0_nm[contact]).max() < 1e-9 * scale
        for k, obj in enumerate(objects):
            on = result.object[contact] == k
            distance = obj.surface(1.0).signed_distance(result.p_W_m[contact][on])
            assert np.abs(distance).max(initial=0.0) < 1e-12
        L = whisker.length_m
        f0, m0 = whisker.scale.wrench_from_si(result.f0_n[contact], result.m0_nm[contact])
        back, _ = reconstruct_rod(p_WC / L, f0, m0, whisker.shape, R_WC,
                                  previous_s1=result.s1_m[contact] / L)
        assert np.abs(back.point * L - result.p_W_m[contact]).max() < 1e-6 * L
        assert result.episodes and all(e.end in ("detachment", "snap-off", "path-end")
                                       for e in result.episodes)
    assert touching > 100


def test_a_stream_that_begins_ambiguous_stays_flagged_while_the_choice_lasts():
    """A tip poked into a paraboloid at mu 0.8 by a pre-curved rod: from its first sample the
    wrench fits the tip and a point mid-rod. Step 2 of the sweep as one stream, knowing
    nothing before it, takes the first and stays on it by continuity; every such point is
    flagged AMBIGUOUS_CONTACT, and the tip is always among the candidates."""
    shape = RodShape(taper_ratio=0.6, precurvature=-0.4633, poisson_ratio=0.3166)
    sweep = simulate_sweep(parse_surface("paraboloid:a=0.5,b=1,h=0.4"), 0.1066, 0.8, 0.005,
                           shape=shape)
    assert sweep.n_steps > 20
    result, candidates = reconstruct_rod(sweep.p0, sweep.f0, sweep.m0, shape, stream=True)
    wrong = np.linalg.norm(result.point - sweep.contact, axis=1) > 1e-6
    assert wrong[0]  # the first sample cannot tell
    assert (result.status[wrong] & int(ContactStatus.AMBIGUOUS_CONTACT)).all()
    assert np.all(np.nanmin(np.abs(candidates - sweep.s1[:, None]), axis=1) < 1e-6)


def test_shaped_whiskers_streamed_in_chunks_are_simulate():
    """The commanded robot's Step 1 (`SceneStream`, the path fed as it comes) of tapered and
    pre-curved whiskers: the phases and wrenches of `simulate` on the whole path."""
    from tests.core.test_scene_stream import assert_simulate_bits, fed, own_steps

    scene = _shaped_scene()
    rng = np.random.default_rng(5)
    samples, _ = fed(scene, own_steps(scene), rng.integers(1, 40, size=60).tolist())
    assert_simulate_bits(scene, samples)
    assert (samples.phase > 0).sum() > 100


def test_small_deflection_of_a_tapered_rod_is_euler_bernoulli():
    """A force 1e-5 EI/L^2 across a straight tapered rod at s1: the deflection there is
    int_0^s1 (s1 - t)^2 F / EI(t) dt (quad), to 1e-4 of it (the load's own nonlinearity is
    1e-10 of it; the rest is the Runge-Kutta rod's)."""
    from scipy.integrate import quad

    from vibrissa.rods import integrate_to, loaded_rod, stiffness

    for taper in (1.0, 0.6, 0.3, 0.1):
        shape = RodShape(taper_ratio=taper)
        for s1 in (0.4, 0.75, 1.0):
            force = np.array([1e-5, 0.0, 0.0])
            m0 = loaded_rod(shape, force, s1)
            deflection = integrate_to(s1, -force, m0, shape.params)[0]
            beam = quad(lambda t, s1=s1, shape=shape: (s1 - t) ** 2 * 1e-5
                        / float(stiffness(shape, t)), 0.0, s1, epsabs=1e-16)[0]
            assert abs(deflection - beam) < 1e-4 * beam, (taper, s1, deflection, beam)
