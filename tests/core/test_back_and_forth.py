"""A path driven forth and back (`vibrissa.scene.back_and_forth`): the legs' poses and times,
and Step 1 along them: statics at every contact, the contact on the surface, Coulomb's law on
the return leg with its friction turned, so that the return leg differs from the outward one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vibrissa.scene import (
    SamplePhase,
    Scene,
    SceneObject,
    Whisker,
    WhiskerResult,
    back_and_forth,
    free_at_both_ends,
    robot_path,
    simulate,
)

L0 = 0.05
N = 300
CUP = SceneObject("cup", "paraboloid", {"a_per_m": 0.5 / L0, "b_per_m": 1 / L0, "h_m": 0.4 * L0})
PLAIN = Whisker("plain", L0, 2e-5)
# uneven sample times: a reversed leg must reverse the intervals, not reuse them
TIMES = np.cumsum(np.r_[0.0, 0.01 + 0.005 * np.sin(np.arange(N - 1))])
PATH = robot_path(TIMES, np.column_stack([np.linspace(2.0 * L0, -2.0 * L0, N), np.zeros((N, 2))]),
                  np.tile([0.0, 0.0, 0.0, 1.0], (N, 1)))
CONTACT = (SamplePhase.TIP, SamplePhase.TANGENTIAL)


def test_the_legs_run_forth_and_back_with_time_running_on() -> None:
    legs = back_and_forth(PATH, 3)
    assert len(legs.t) == 3 * N - 2
    assert np.all(np.diff(legs.t) > 0)
    np.testing.assert_array_equal(legs.p_WR[:N], PATH.p_WR)
    np.testing.assert_array_equal(legs.p_WR[N - 1:2 * N - 1], PATH.p_WR[::-1])
    np.testing.assert_array_equal(legs.p_WR[2 * N - 2:], PATH.p_WR)
    duration = PATH.t[-1] - PATH.t[0]
    # each pose is as far in time from a turn on either side of it
    np.testing.assert_allclose(legs.t[N - 1:2 * N - 1] - legs.t[N - 1],
                               PATH.t[-1] - PATH.t[::-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(legs.t[-1], 3 * duration, rtol=1e-15)
    assert back_and_forth(PATH, 1) is not PATH and np.array_equal(back_and_forth(PATH, 1).t, PATH.t)
    with pytest.raises(ValueError, match="legs must be >= 1, got 0"):
        back_and_forth(PATH, 0)


@pytest.fixture(scope="module")
def legs() -> dict[float, tuple[Scene, WhiskerResult]]:
    out = {}
    for mu in (0.0, 0.3):
        scene = Scene(mu, (CUP,), (PLAIN,), back_and_forth(PATH, 3))
        out[mu] = scene, simulate(scene, workers=1)[0]
    return out


@pytest.mark.parametrize("mu", [0.0, 0.3])
def test_every_contact_of_every_leg_obeys_statics_on_the_surface(legs, mu: float) -> None:
    scene, r = legs[mu]
    rows = np.flatnonzero(np.isin(r.phase, CONTACT))
    per_leg = [np.count_nonzero((rows >= a) & (rows < b))
               for a, b in ((0, N), (N, 2 * N - 1), (2 * N - 1, 3 * N - 2))]
    assert min(per_leg) > 20, per_leg
    p_WC = scene.path.p_WR[rows]  # the mount is the identity: C = R, parallel to W
    moment = r.m0_nm[rows] - np.cross(r.p_W_m[rows] - p_WC, r.f0_n[rows])
    assert np.max(np.abs(moment)) < 1e-9 * PLAIN.ei_nm2 / PLAIN.length_m
    gap = CUP.surface(PLAIN.length_m).signed_distance(r.p_W_m[rows] / PLAIN.length_m)
    assert np.max(np.abs(gap)) < 1e-9
    assert free_at_both_ends([r]) == []


def test_friction_makes_the_return_leg_differ_from_the_outward_one(legs) -> None:
    """Coulomb's law rebuilt from the contact force F = -f0 and the cup's normal: without
    friction F is normal on both legs; with it the contact slides on the cone |F_t| = mu F_n
    and its friction turns with the motion (+x on the way out along -x, -x on the way back),
    so the clamp's force at the same pose differs; the third leg repeats the first."""
    surface = CUP.surface(PLAIN.length_m)
    for mu, (_, r) in legs.items():
        for leg, along in ((slice(0, N), 1.0), (slice(N - 1, 2 * N - 1), -1.0)):
            rows = np.flatnonzero(np.isin(r.phase[leg], CONTACT))
            force = -r.f0_n[leg][rows]
            normal = surface.normal(r.p_W_m[leg][rows] / PLAIN.length_m)
            f_n = np.einsum("ij,ij->i", force, normal)
            f_t = force - f_n[:, None] * normal
            ratio = np.linalg.norm(f_t, axis=1) / f_n
            assert np.all(f_n > 0)
            if mu == 0.0:
                assert ratio.max() < 1e-9
            else:
                np.testing.assert_allclose(ratio, mu, rtol=0, atol=1e-9)
                assert np.all(along * f_t[:, 0] > 0)
        out, back, again = (r.f0_n[:N], r.f0_n[N - 1:2 * N - 1][::-1], r.f0_n[2 * N - 2:])
        touch_out = np.isin(r.phase[:N], CONTACT)
        np.testing.assert_allclose(again[touch_out], out[touch_out], rtol=0,
                                   atol=1e-9 * PLAIN.ei_nm2 / PLAIN.length_m**2)
    _, r = legs[0.3]
    both = np.isin(r.phase[:N], CONTACT) & np.isin(r.phase[N - 1:2 * N - 1][::-1], CONTACT)
    out, back = r.f0_n[:N][both], r.f0_n[N - 1:2 * N - 1][::-1][both]
    assert both.sum() > 20
    assert np.median(np.linalg.norm(out - back, axis=1) / np.linalg.norm(out, axis=1)) > 0.1


def test_one_leg_is_the_path_itself() -> None:
    scene = Scene(0.3, (CUP,), (PLAIN,), PATH)
    (once,) = simulate(scene, workers=1)
    (first,) = simulate(dataclasses.replace(scene, path=back_and_forth(PATH, 2)), workers=1)
    for name in ("phase", "f0_n", "m0_nm", "p_W_m"):
        np.testing.assert_array_equal(getattr(first, name)[:N], getattr(once, name), err_msg=name)
