"""The reference Kirchhoff rod solver (tests/core/rod_reference.py) against closed forms."""

import numpy as np
import pytest
from scipy.integrate import quad

from tests.core.rod_reference import moment_along, solve_rod
from vibrissa.elastica import planar_contact


def stiffness(s: float, taper: float) -> float:
    return (1.0 - (1.0 - taper) * s) ** 4


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_small_tip_load_on_uniform_straight_rod_is_the_cantilever():
    eps = 1e-3
    result = solve_rod((eps, 0.0, 0.0), 1.0)
    assert abs(result.r1[0] - eps / 3.0) < eps**2
    assert result.r1[1] == pytest.approx(0.0, abs=1e-15)


@pytest.mark.parametrize("taper", [1.0, 0.6, 0.3])
@pytest.mark.parametrize("s1", [0.4, 0.75, 1.0])
def test_small_load_on_tapered_rod_is_euler_bernoulli(taper, s1):
    eps = 1e-4
    expected = quad(lambda t: (s1 - t) ** 2 * eps / stiffness(t, taper), 0.0, s1, epsabs=1e-15, epsrel=1e-13)[0]
    result = solve_rod((eps, 0.0, 0.0), s1, taper_ratio=taper)
    assert result.r1[0] == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("force, s1", [((-2.0, 0.0, -0.5), 0.8), ((1.5, 0.0, 0.8), 1.0), ((-4.0, 0.0, 1.0), 0.6),
                                       ((2.5, 0.0, -2.0), 0.9)])
def test_planar_load_on_uniform_straight_rod_is_the_closed_form_elastica(force, s1):
    result = solve_rod(force, s1)
    # Plane (u, v) = (x, z), e_w = e_u x e_v = -e_y, kappa0 = -m0 . e_w = m0_y.
    contact = planar_contact(force[0], force[2], result.m0[1])
    assert int(contact.status) == 0
    assert float(contact.s1) == pytest.approx(s1, abs=1e-8)
    assert float(contact.u1) == pytest.approx(result.r1[0], abs=1e-8)
    assert float(contact.v1) == pytest.approx(result.r1[2], abs=1e-8)
    assert result.r1[1] == pytest.approx(0.0, abs=1e-12)
    phi1 = float(contact.phi1)  # tangent angle against e_u in the plane
    np.testing.assert_allclose(result.tangent1, [np.cos(phi1), 0.0, np.sin(phi1)], atol=1e-8)


@pytest.mark.parametrize("kappa_hat", [2.0, -3.0, 0.5])
def test_unloaded_precurved_rod_is_a_circular_arc(kappa_hat):
    k = kappa_hat
    arc = lambda s: np.stack([(1.0 - np.cos(k * s)) / k, 0.0 * s, np.sin(k * s) / k], axis=-1)  # noqa: E731
    result = solve_rod((1e-12, 0.0, 0.0), 1.0, kappa_hat=k, taper_ratio=0.5)
    np.testing.assert_allclose(result.r1, arc(1.0), atol=1e-9)
    # Loaded at mid-length by a vanishing force: the free part beyond s1 is on the arc as well.
    result = solve_rod((0.0, 1e-12, 0.0), 0.5, kappa_hat=k)
    s = np.linspace(0.0, 1.0, 21)
    np.testing.assert_allclose(result.shape(s), arc(s), atol=1e-9)
    np.testing.assert_allclose(result.frame(1.0)[:, 2], [np.sin(k), 0.0, np.cos(k)], atol=1e-9)


def test_precurved_rod_loaded_out_of_its_plane_twists_and_is_in_equilibrium():
    force, s1 = np.array([0.5, 1.0, -0.3]), 0.9
    result = solve_rod(force, s1, kappa_hat=2.0, taper_ratio=0.5)
    s = np.linspace(0.0, 1.0, 101)
    points, frames, moments = result.shape(s), result.frame(s), moment_along(result, s)
    assert np.max(np.abs(points[:, 1])) > 0.05  # leaves the x-z plane
    torsion = np.einsum("ni,ni->n", moments, frames[:, :, 2])
    assert np.max(np.abs(torsion)) > 0.05
    assert result.residual < 1e-10
    np.testing.assert_allclose(result.f0 + force, 0.0, atol=1e-9)
    np.testing.assert_allclose(result.m0 + np.cross(result.r1, force), 0.0, atol=1e-9)
    np.testing.assert_allclose(result.shape(s1), result.r1, atol=1e-12)
    expected = np.where((s <= s1)[:, None], np.cross(result.r1 - points, force), 0.0)
    np.testing.assert_allclose(moments, expected, atol=1e-8)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", frames, frames), np.broadcast_to(np.eye(3), frames.shape),
                               atol=1e-9)
    # Constitutive law from the shape alone: the Darboux vector of finite-differenced frames.
    h, s_in = 1e-3, np.linspace(0.05, 0.85, 9)
    d_frame = (8.0 * (result.frame(s_in + h) - result.frame(s_in - h))
               - (result.frame(s_in + 2 * h) - result.frame(s_in - 2 * h))) / (12.0 * h)
    frames_in = result.frame(s_in)
    skew = np.einsum("nji,njk->nik", frames_in, d_frame)  # R^T R' = [u]x, material components
    u = np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], axis=-1)
    ei = stiffness(s_in, 0.5)
    m_material = np.stack([ei * u[:, 0], ei * (u[:, 1] - 2.0), ei / 1.3 * u[:, 2]], axis=-1)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", frames_in, m_material), moment_along(result, s_in), atol=1e-6)


@pytest.mark.parametrize("angle", [0.7, 2.5])
def test_rotating_the_force_about_the_axis_rotates_the_solution(angle):
    force, s1, taper = np.array([1.2, -0.4, 0.7]), 0.85, 0.4
    base = solve_rod(force, s1, taper_ratio=taper)
    turn = rotation_z(angle)
    turned = solve_rod(turn @ force, s1, taper_ratio=taper)
    np.testing.assert_allclose(turned.r1, turn @ base.r1, atol=1e-9)
    np.testing.assert_allclose(turned.m0, turn @ base.m0, atol=1e-9)
