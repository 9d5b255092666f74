"""Two point contacts on a tapered or pre-curved rod (`vibrissa.two_contacts`, the Kirchhoff
rod of `vibrissa.rods` between and beyond the contacts): the straight uniform rod through the
shaped kernel is the straight kernel's solution, with no twist; along a robot path the
``second-contact`` samples of tapered and pre-curved rods pass the independent checks of
tests/core/shaped_two_contact_check.py (scipy's `solve_ivp` of the rod with its directors, the
moment from statics, from the clamp wrench alone), and Step 2 refuses their wrenches."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.core.shaped_two_contact_check import shaped_leaning_scene, shaped_two_contacts_worst
from tests.core.test_scene_stream import assert_simulate_bits, fed, own_steps
from tests.core.test_two_contacts import BOTH_TANGENTIAL, objects, solved
from vibrissa import two_contacts as tc
from vibrissa.frames import Transform
from vibrissa.reconstruct_rods import reconstruct_rod
from vibrissa.rods import RodShape
from vibrissa.scene import RobotPath, Scene, SceneObject, Whisker, simulate, snaps
from vibrissa.status import ContactStatus


@pytest.mark.parametrize("mu, lift", [(0.0, 0.05), (0.6, -0.04)])
def test_a_straight_uniform_rod_through_the_shaped_kernel_is_the_straight_solution(
        mu: float, lift: float) -> None:
    """Eleven unknowns (the clamp moment's twist too) for the rod the straight kernel solves
    with ten: the same contacts and forces (both fourth-order Runge-Kutta on 256 steps per
    segment, of different states), and the twist zero."""
    x, state, balls, anchors = solved(mu, lift)
    start = np.concatenate([x[:2], [0.0], x[2:]]) * 0.999
    shaped, shaped_state = tc.solve(start, np.zeros(3), np.eye(3), BOTH_TANGENTIAL, anchors, mu,
                                    RodShape(poisson_ratio=0.3).params, *objects(*balls))
    assert len(shaped) == tc.N_UNKNOWNS_SHAPED and tc.converged(shaped_state, BOTH_TANGENTIAL)
    assert abs(shaped[2]) < 1e-10
    np.testing.assert_allclose(shaped[[0, 1, *range(3, 11)]], x, atol=1e-8)
    for j in range(2):
        for mine, theirs in zip(tc.contact_info(shaped_state, j), tc.contact_info(state, j),
                                strict=True):
            np.testing.assert_allclose(mine, theirs, atol=1e-8)


def test_a_follower_refuses_unknowns_of_the_other_rod() -> None:
    with pytest.raises(ValueError, match="10 unknowns for a shaped rod"):
        tc.TwoContactFollower([], (0, 1), 1, np.zeros(10), BOTH_TANGENTIAL, np.zeros((2, 3)),
                              RodShape(taper_ratio=0.5))


@pytest.mark.slow
@pytest.mark.parametrize("taper, kappa_1pm, lift_m", [(0.5, 10.0, 0.001), (0.5, 0.0, 0.003),
                                                      (0.3, -8.0, 0.001)])
def test_tapered_and_pre_curved_rods_go_on_with_two_contacts(taper: float, kappa_1pm: float,
                                                             lift_m: float) -> None:
    scene = shaped_leaning_scene(lift_m, taper, kappa_1pm)
    (whisker,) = scene.whiskers
    (result,) = simulate(scene, workers=1)
    starts = [(e.start, e.object, e.second_object) for e in result.episodes]
    assert ("second-contact", "a", "b") in starts, starts
    two = np.flatnonzero(result.second_object >= 0)
    assert len(two) >= 20
    worst = shaped_two_contacts_worst(scene, whisker, result)
    assert worst["on"] < 1e-12 and worst["inner"] < 1e-9 and worst["chord"] < 1e-8, worst
    assert worst["outer"] < 1e-9 and worst["tangent"] < 1e-8 and worst["inside"] < 1e-9, worst
    assert worst["statics"] < 1e-12, worst
    # Step 2 from the clamp wrench alone (the rod's units): no single contact gives it
    rec, _ = reconstruct_rod(np.zeros((len(two), 3)),
                             *whisker.scale.wrench_from_si(result.f0_n[two], result.m0_nm[two]),
                             whisker.shape)
    assert np.all(rec.status & int(ContactStatus.MULTI_CONTACT)) and np.isnan(rec.point).all()


@pytest.mark.slow
def test_a_commanded_robot_gives_simulates_two_contacts() -> None:
    """The shaped rod's path fed to the stream in chunks of 1-39 samples: the same samples as
    the whole path (tests/core/test_scene_stream.py), its second contacts included."""
    scene = shaped_leaning_scene(0.001, 0.5, 10.0)
    chunks = np.random.default_rng(5).integers(1, 40, size=len(scene.path.t)).tolist()
    samples, _ = fed(scene, own_steps(scene), chunks)
    assert_simulate_bits(scene, samples)
    (want,) = simulate(scene, workers=1)
    assert np.count_nonzero(want.second_object >= 0) >= 20


def clamp_into_ball_scene() -> Scene:
    """A pre-curved rod (kappa 3 /m, taper 0.93) on a yawing robot driving along x: it leans on
    ball a, and its clamp runs into ball b, whose contact slides down to the clamp."""
    n = 700
    x = np.linspace(-0.02, 0.045, n)
    path = RobotPath(np.arange(n) / 100.0, np.column_stack([x, 0 * x, 0 * x]),
                     Rotation.from_euler("z", np.linspace(0.0, -0.13294463, n)[:, None]))
    a = SceneObject("a", "sphere", {"radius_m": 0.017308228},
                    Transform(Rotation.identity(), [0.018194131, 0.0, 0.029504144]))
    b = SceneObject("b", "sphere", {"radius_m": 0.0073677672},
                    Transform(Rotation.identity(), [0.025512558, 0.0023765554, 0.0040842449]))
    mount = Transform(Rotation.from_quat([-0.049003489, -0.010971320, -0.00053831218,
                                          0.99873820]), np.zeros(3))
    whisker = Whisker("w", 0.05, 1e-4, mount, taper_ratio=0.92804966,
                      precurvature_1pm=3.0022912, poisson_ratio=0.32613706)
    return Scene(0.38744815, (a, b), (whisker,), path)


@pytest.mark.slow
def test_a_jump_of_a_contact_in_a_pair_is_told_as_a_snap_through() -> None:
    """As b's contact nears the clamp (the clamp force grows past 100 N), the contact on a
    slides 15 mm in one sample, 40 times its move before: a snap-through of the
    ``second-contact`` episode, in `snaps`. It slides back at the next sample, the stretch's
    only other move over 10 times its median: measured against the jump, as a single contact's
    far slide is, that one is not told. (Fed to the stream, this scene's rod takes another
    state at the jump's sample: docs/LIMITS.md.)"""
    scene = clamp_into_ball_scene()
    (result,) = simulate(scene, workers=1)
    (episode,) = [e for e in result.episodes if e.start == "second-contact"]
    pair = np.flatnonzero(result.second_object >= 0)
    moves = np.array([np.linalg.norm(np.diff(points[pair], axis=0), axis=1)
                      for points in (result.p_W_m, result.second_W_m)])
    far = np.flatnonzero((moves > 10 * np.median(moves, axis=1)[:, None]).any(axis=0))
    assert len(far) == 2 and far[1] == far[0] + 1 and moves[:, far[0]].max() > 0.01, moves
    jumped = pair[far[0] + 1]
    assert episode.snap_throughs == (float(result.t[jumped]),)
    told = [(s.kind, s.after) for s in snaps(result, ["a", "b"])]
    assert ("snap-through", jumped) in told, told
