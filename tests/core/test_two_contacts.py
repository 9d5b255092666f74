"""Two point contacts on one rod (`vibrissa.two_contacts`) against formulations of their own:
the planar elastica's closed form where the second contact carries nothing, and, loaded out of
the plane, the rod integrated by scipy's `solve_ivp` with the moment written as the moment
balance of the contact forces beyond each point (not the solver's moment equation), the
objects' geometry from the spheres' centres and radii, Coulomb's law from its definition and
the statics of the clamp."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from vibrissa import two_contacts as tc
from vibrissa.elastica import planar_contact_scalar, planar_line
from vibrissa.frames import Transform
from vibrissa.surfaces import Sphere

TANGENTIAL_TIP = np.array([tc.MODE_TANGENTIAL, tc.MODE_TIP])
BOTH_TANGENTIAL = np.array([tc.MODE_TANGENTIAL, tc.MODE_TANGENTIAL])


def objects(*spheres: Sphere) -> list[np.ndarray]:
    """The spheres as the solver's per-contact quadric rows."""
    return [np.concatenate(rows) for rows in zip(*(s.kernel_arrays for s in spheres),
                                                   strict=True)]


def sphere(radius: float, centre: np.ndarray) -> Sphere:
    return Sphere(radius, Transform(Rotation.identity(), centre))


def tip_load_case(fu: float, fv: float) -> tuple[float, np.ndarray, np.ndarray]:
    """The clamp curvature that puts the planar elastica's contact at the tip for the force
    (fu, fv) on it, its tip point and tangent (x, 0, z: the rod clamped along z)."""
    def past_tip(k: float) -> float:
        return planar_contact_scalar(fu, fv, k)[2] - 1.0

    grid = np.linspace(1e-6, 5.0, 501)
    below = [k for k in grid if past_tip(k) < 0]
    above = [k for k in grid if past_tip(k) > 0]
    kappa0 = brentq(past_tip, max(below), min(k for k in above if k > max(below)),
                    xtol=1e-15, rtol=1e-15)
    u1, v1, s1, phi1, _status = planar_contact_scalar(fu, fv, kappa0)
    assert abs(s1 - 1.0) < 1e-12
    return kappa0, np.array([u1, 0.0, v1]), np.array([math.cos(phi1), 0.0, math.sin(phi1)])


def test_a_second_contact_that_carries_nothing_leaves_the_closed_form_tip_equilibrium() -> None:
    """A ball touching the planar elastica's side at s = 0.4 from across the plane: the
    two-contact equilibrium is the single one, the tip and its force as the closed form gives
    them, the second force zero."""
    fu, fv = -0.8, -0.5
    _kappa0, tip, _tangent = tip_load_case(fu, fv)
    force = np.array([fu, 0.0, fv])
    u, v = planar_line(fu, fv, _kappa0, np.array([0.4]))
    side = np.array([u[0], 0.0, v[0]])
    ball_b = sphere(0.3, tip - 0.3 * force / np.linalg.norm(force))
    ball_a = sphere(0.1, side - 0.1 * np.array([0.0, 1.0, 0.0]))  # touching from -y
    exact = np.array([*np.cross(tip, force)[:2], 0.0, 0.0, 0.0, fu, 0.0, fv, 0.4, 1.0])
    rows = objects(ball_a, ball_b)
    state = np.empty(tc.STATE_WIDTH)
    tc.evaluate(exact, np.zeros(3), np.eye(3), TANGENTIAL_TIP, np.array([side, tip]), 0.0,
                tc.STRAIGHT, *rows, state)
    assert np.abs(state[:10]).max() < 1e-12  # the closed form satisfies the ten conditions
    x, state = tc.newton(0.98 * exact, np.zeros(3), np.eye(3), TANGENTIAL_TIP,
                         np.array([side, tip]), 0.0, tc.STRAIGHT, *rows)
    assert tc.converged(state, TANGENTIAL_TIP)
    p_a, _t, _n, f_a = tc.contact_info(state, 0)
    p_b, _t, _n, f_b = tc.contact_info(state, 1)
    assert np.linalg.norm(f_a) < 1e-12
    np.testing.assert_allclose(p_b, tip, atol=1e-12)
    np.testing.assert_allclose(f_b, force, atol=1e-11)
    np.testing.assert_allclose(p_a, side, atol=1e-12)


def solved(mu: float, lift: float) -> tuple[np.ndarray, np.ndarray, list[Sphere], np.ndarray]:
    """A rod clamped at W's origin along z, its tip on a ball and its side on another one
    moved by ``lift`` out of the plane of the first: the solution, its state, the balls and
    the anchors (each contact's previous point, for eq. 7's chord)."""
    ball_a, ball_b = sphere(0.2, np.array([-0.22, lift, 0.5])), sphere(0.5, np.array([0.4, 0.0, 1.0]))
    anchors = np.array([[-0.02, lift, 0.51], [-0.1, 0.0, 0.99]])
    x0 = np.array([0.0, -0.25, 0.1, 0.0, 0.0, -0.3, 0.0, 0.0, 0.5, 0.9])
    x, state = tc.solve(x0, np.zeros(3), np.eye(3), BOTH_TANGENTIAL, anchors, mu, tc.STRAIGHT,
                        *objects(ball_a, ball_b))
    assert tc.converged(state, BOTH_TANGENTIAL)
    assert tc.admissible(x, state, BOTH_TANGENTIAL, mu)[0]
    return x, state, [ball_a, ball_b], anchors


@pytest.mark.parametrize("mu, lift", [(0.0, 0.0), (0.0, 0.05), (0.3, 0.05), (0.6, -0.04)])
def test_two_contacts_against_an_independent_integration_the_balls_and_coulomb(
        mu: float, lift: float) -> None:
    x, state, balls, anchors = solved(mu, lift)
    contacts = [tc.contact_info(state, j) for j in range(2)]
    points = np.array([c[0] for c in contacts])
    forces = np.array([c[3] for c in contacts])
    s = x[8:10]

    def moment(arc: float, r: np.ndarray) -> np.ndarray:
        """The moment balance of the forces beyond ``arc``: sum (p_i - r) x F_i."""
        return sum((np.cross(points[j] - r, forces[j]) for j in range(2) if s[j] > arc),
                   np.zeros(3))

    def rod(arc: float, y: np.ndarray) -> np.ndarray:
        r, t = y[:3], y[3:]
        return np.concatenate([t, np.cross(moment(arc, r), t)])

    # the clamp moment is the statics of the two forces (the solver's unknowns x[0:2], C = W)
    np.testing.assert_allclose(moment(-1.0, np.zeros(3))[:2], x[:2], atol=1e-9)
    assert abs(moment(-1.0, np.zeros(3))[2]) < 1e-9  # no twist at the clamp
    y = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    for j in range(2):  # segment by segment, the contacts as breakpoints
        start = 0.0 if j == 0 else s[0]
        y = solve_ivp(rod, (start, s[j]), y, method="DOP853", rtol=1e-12, atol=1e-13).y[:, -1]
        np.testing.assert_allclose(y[:3], points[j], atol=2e-9)
        ball = balls[j]
        normal = (points[j] - ball.pose.translation) / ball.radii[0]
        assert abs(np.linalg.norm(points[j] - ball.pose.translation) - ball.radii[0]) < 1e-11
        assert abs(y[3:] @ normal) < 1e-8  # the rod is tangent to the ball there
        fn = forces[j] @ normal
        assert fn > 0  # the ball pushes
        chord = anchors[j] - points[j]
        chord -= (chord @ normal) * normal
        along = normal + mu * chord / np.linalg.norm(chord)
        np.testing.assert_allclose(forces[j] / np.linalg.norm(forces[j]),
                                   along / np.linalg.norm(along), atol=1e-8)
    # the clamp's reaction balances both forces
    f0, m0 = tc.clamp_reactions(x, state, np.zeros(3), np.eye(3))
    np.testing.assert_allclose(f0, -forces.sum(axis=0), atol=1e-14)
    np.testing.assert_allclose(m0, -np.cross(points, forces).sum(axis=0), atol=1e-14)
    # the rod stays outside both balls along its whole length
    line = tc.rod_line(x, np.zeros(3), np.eye(3), 401, tc.STRAIGHT)
    for ball in balls:
        assert np.min(np.linalg.norm(line - ball.pose.translation, axis=1)) > ball.radii[0] - 1e-9


def test_out_of_the_plane_the_rod_leaves_it_and_the_mirror_image_is_the_mirrored_solution(
        ) -> None:
    flat = solved(0.3, 0.0)[1]
    assert max(abs(tc.contact_info(flat, j)[0][1]) for j in range(2)) < 1e-12
    x_up, up = solved(0.3, 0.05)[:2]
    x_down, down = solved(0.3, -0.05)[:2]
    assert abs(tc.contact_info(up, 0)[0][1]) > 1e-3
    mirror = np.array([1.0, -1.0, 1.0])
    for j in range(2):
        for a, b in zip(tc.contact_info(up, j), tc.contact_info(down, j), strict=True):
            np.testing.assert_allclose(a * mirror, b, atol=1e-10)
    np.testing.assert_allclose(x_up[8:], x_down[8:], atol=1e-10)
