"""Two point contacts on a tapered or pre-curved rod (`vibrissa.two_contacts`, the Kirchhoff
rod of `vibrissa.rods` between and beyond the contacts): the straight uniform rod through the
shaped kernel is the straight kernel's solution, with no twist; along a robot path the
``second-contact`` samples of tapered and pre-curved rods pass the independent checks of
tests/core/shaped_two_contact_check.py (scipy's `solve_ivp` of the rod with its directors, the
moment from statics, from the clamp wrench alone), and Step 2 refuses their wrenches."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.shaped_two_contact_check import shaped_leaning_scene, shaped_two_contacts_worst
from tests.core.test_scene_stream import assert_simulate_bits, fed, own_steps
from tests.core.test_two_contacts import BOTH_TANGENTIAL, objects, solved
from vibrissa import two_contacts as tc
from vibrissa.reconstruct_rods import reconstruct_rod
from vibrissa.rods import RodShape
from vibrissa.scene import simulate
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
