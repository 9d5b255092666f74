"""The closed-form elastica against independent solutions: ODE integration, beam theory, tables."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from vibrissa.elastica import planar_contact, planar_line
from vibrissa.status import ContactStatus


def integrate_to_zero_curvature(fu: float, fv: float, kappa0: float) -> np.ndarray:
    """Eq. 11 with the initial conditions of eq. 23, integrated to the first zero of kappa."""
    f, alpha = np.hypot(fu, fv), np.arctan2(fu, -fv)

    def rhs(_s, y):
        return [np.cos(y[2]), np.sin(y[2]), y[3], f * np.cos(y[2] - alpha)]

    def kappa_zero(_s, y):
        return y[3]

    kappa_zero.terminal = True
    sol = solve_ivp(rhs, [0.0, 50.0], [0.0, 0.0, np.pi / 2, kappa0], events=kappa_zero, rtol=1e-12, atol=1e-12)
    s1 = sol.t_events[0][0]
    u1, v1, phi1, _ = sol.y_events[0][0]
    return np.array([s1, u1, v1, phi1])


def test_closed_form_matches_ode_integration():
    rng = np.random.default_rng(1)
    checked = 0
    for fu, fv, kappa0 in rng.normal(scale=[3.0, 3.0, 2.0], size=(40, 3)):
        contact = planar_contact(fu, fv, kappa0)
        if contact.status[()] != ContactStatus.OK:
            continue
        s1, u1, v1, phi1 = integrate_to_zero_curvature(fu, fv, kappa0)
        assert float(contact.s1) == pytest.approx(s1, abs=1e-8)
        assert float(contact.u1) == pytest.approx(u1, abs=1e-8)
        assert float(contact.v1) == pytest.approx(v1, abs=1e-8)
        assert np.cos(float(contact.phi1) - phi1) == pytest.approx(1.0, abs=1e-12)
        checked += 1
    assert checked >= 20


def test_elastic_line_matches_ode_integration():
    fu, fv, kappa0 = 1.3, -0.8, -1.1
    s = np.linspace(0.0, 1.0, 11)
    u, v = planar_line(fu, fv, kappa0, s)
    f, alpha = np.hypot(fu, fv), np.arctan2(fu, -fv)
    s1 = float(planar_contact(fu, fv, kappa0).s1)
    bent = s[s <= s1]
    sol = solve_ivp(
        lambda _s, y: [np.cos(y[2]), np.sin(y[2]), y[3], f * np.cos(y[2] - alpha)],
        [0.0, s1], [0.0, 0.0, np.pi / 2, kappa0], t_eval=bent, rtol=1e-12, atol=1e-12,
    )
    np.testing.assert_allclose(u[: len(bent)], sol.y[0], atol=1e-9)
    np.testing.assert_allclose(v[: len(bent)], sol.y[1], atol=1e-9)


def tip_load_state(p: float) -> tuple[float, float]:
    """Tip deflection and tip rotation of the cantilever under a dead tip load p _|_ the clamp axis."""
    # kappa0 < sqrt(2 p): beyond it the elliptic modulus reaches 1 and kappa never vanishes
    kappa0 = brentq(lambda k: float(planar_contact(p, 0.0, -k).s1) - 1.0, 1e-12, np.sqrt(2 * p) * (1 - 1e-12))
    contact = planar_contact(p, 0.0, -kappa0)
    return float(contact.u1), np.pi / 2 - float(contact.phi1)


@pytest.mark.parametrize(
    "p, deflection, angle",
    [(1.0, 0.30172, 0.46135), (2.0, 0.49346, 0.78175), (5.0, 0.71379, 1.21537), (10.0, 0.81061, 1.43029)],
)
def test_large_deflection_cantilever_bisshopp_drucker(p, deflection, angle):
    tip_deflection, tip_angle = tip_load_state(p)
    assert tip_deflection == pytest.approx(deflection, abs=1e-5)
    assert tip_angle == pytest.approx(angle, abs=1e-5)


def test_small_tip_load_follows_linear_beam_theory():
    p = 1e-4
    tip_deflection, tip_angle = tip_load_state(p)
    assert tip_deflection == pytest.approx(p / 3.0, rel=1e-4)  # P L^3 / (3 EI)
    assert tip_angle == pytest.approx(p / 2.0, rel=1e-4)  # P L^2 / (2 EI)


def test_mirror_symmetry_of_the_load():
    a = planar_contact(0.7, -0.4, 0.9)
    b = planar_contact(-0.7, -0.4, -0.9)
    assert float(b.u1) == pytest.approx(-float(a.u1), abs=1e-14)
    assert float(b.v1) == pytest.approx(float(a.v1), abs=1e-14)
    assert float(b.s1) == pytest.approx(float(a.s1), abs=1e-14)


def test_degenerate_loads_are_flagged():
    statuses = planar_contact([0.0, np.nan, 0.0, 0.0], [0.0, 1.0, -1.0, 0.001], [0.0, 0.0, 0.0, 3.0]).status
    assert statuses[0] == ContactStatus.NO_FORCE
    assert statuses[1] == ContactStatus.NON_FINITE_INPUT
    assert statuses[2] == ContactStatus.AXIAL_LOAD
    assert statuses[3] == ContactStatus.CURVATURE_NEVER_VANISHES
