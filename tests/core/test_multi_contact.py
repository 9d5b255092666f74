"""Step 2 refuses wrenches no single contact gives (MULTI_CONTACT): two contacts on one rod,
built here from their forces and points by statics alone; single contacts pass, exact and at
the noise model's level."""

from __future__ import annotations

import numpy as np
import pytest

from vibrissa import reconstruct
from vibrissa.reconstruct import MULTI_SIGMAS, reconstruct_si, single_contact_excess
from vibrissa.reconstruct_rods import reconstruct_rod
from vibrissa.rods import RodShape
from vibrissa.status import NO_CONTACT, ContactStatus
from vibrissa.units import RodScale

ROD = RodScale(0.05, 2e-5)  # 50 mm, EI 2e-5 N m^2: forces ~ EI/L^2 = 8 mN
MULTI = int(ContactStatus.MULTI_CONTACT)


def two_contacts(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Clamp wrenches (C, SI) of two point forces on a rod along +z: each at a point within
    the rod's length of the clamp, near its axis (a bent rod), of any direction and size 0.1-10
    EI/L^2. Statics: f0 = -(F1 + F2), m0 = -(p1 x F1 + p2 x F2)."""
    rng = np.random.default_rng(seed)
    L, F = ROD.length_m, ROD.force_n
    xy = rng.uniform(-0.3, 0.3, (n, 2, 2)) * L
    z = rng.uniform(0.05, 1.0, (n, 2, 1)) * L
    points = np.concatenate([xy, z], axis=2)  # (n, 2 contacts, 3)
    forces = rng.normal(size=(n, 2, 3)) * F * 10.0 ** rng.uniform(-1, 1, (n, 2, 1))
    f0 = -forces.sum(axis=1)
    m0 = -np.cross(points, forces).sum(axis=1)
    return f0, m0


def one_contact(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clamp wrenches of one point force F on a rod bent in a plane through its axis z: the
    contact at P = (u cos psi, u sin psi, v), F in the same plane (any direction in it)."""
    rng = np.random.default_rng(seed)
    L, F = ROD.length_m, ROD.force_n
    psi = rng.uniform(-np.pi, np.pi, n)
    e_u = np.stack([np.cos(psi), np.sin(psi), np.zeros(n)], axis=1)
    e_z = np.array([0.0, 0.0, 1.0])
    point = e_u * rng.uniform(0.01, 0.5, (n, 1)) * L + e_z * rng.uniform(0.5, 0.95, (n, 1)) * L
    theta = rng.uniform(-np.pi, np.pi, (n, 1))
    force = (e_u * np.cos(theta) + e_z * np.sin(theta)) * F * 10.0 ** rng.uniform(-1, 1, (n, 1))
    return -force, -np.cross(point, force), point


def test_single_contact_wrenches_are_exactly_orthogonal_and_pass():
    f0, m0, _point = one_contact(2000, 1)
    excess = np.array([single_contact_excess(f, m) for f, m in zip(f0, m0, strict=True)])
    assert excess.max() < 1e-3  # round-off, well inside the band
    rec = reconstruct_si(np.tile([0, 0, 0, 1.0], (len(f0), 1)), np.zeros_like(f0), f0, m0, ROD)
    assert not np.any(rec.status & MULTI)


def test_two_contacts_get_no_point():
    """0 of 10 000 two-contact wrenches gives a point, with or without a noise model (the
    noise here a tenth of a percent of EI/L^2 and EI/L, the band 4 std of it)."""
    f0, m0 = two_contacts(10_000, 2)
    q = np.tile([0, 0, 0, 1.0], (len(f0), 1))
    exact = reconstruct_si(q, np.zeros_like(f0), f0, m0, ROD)
    assert not exact.valid.any()
    assert np.all(exact.status & MULTI)  # whatever else the planar solver says of them
    sigma = np.repeat([1e-3 * ROD.force_n, 1e-3 * ROD.moment_nm], 3)
    noisy = reconstruct_si(q, np.zeros_like(f0), f0, m0, ROD, np.diag(sigma**2))
    flagged = (noisy.status & MULTI) != 0
    assert flagged.mean() > 0.99  # the few within the band: two contacts that look like one
    # those passed are single-contact wrenches within the noise: their statistic is small
    for i in np.flatnonzero(~flagged)[:50]:
        dot = abs(f0[i] @ m0[i])
        std = np.sqrt(m0[i] ** 2 @ sigma[:3] ** 2 + f0[i] ** 2 @ sigma[3:] ** 2)
        assert dot <= MULTI_SIGMAS * std * 1.01 + 1e-30 and abs(m0[i, 2]) <= MULTI_SIGMAS * sigma[5] * 1.01


def test_single_contacts_at_the_noise_model_are_rarely_flagged():
    """Single contacts plus Gaussian noise of the model's std on all six axes: under 0.1 %
    flagged MULTI_CONTACT (the band is 4 std of each statistic)."""
    f0, m0, _point = one_contact(20_000, 3)
    rng = np.random.default_rng(4)
    sigma = np.repeat([2e-3 * ROD.force_n, 2e-3 * ROD.moment_nm], 3)
    noisy = np.c_[f0, m0] + rng.standard_normal((len(f0), 6)) * sigma
    rec = reconstruct_si(np.tile([0, 0, 0, 1.0], (len(f0), 1)), np.zeros_like(f0),
                         noisy[:, :3], noisy[:, 3:], ROD, np.diag(sigma**2))
    rate = np.mean((rec.status & MULTI) != 0)
    assert rate < 1e-3
    # without the noise model the same wrenches are taken as exact: nearly all refused
    exact = reconstruct_si(np.tile([0, 0, 0, 1.0], (len(f0), 1)), np.zeros_like(f0),
                           noisy[:, :3], noisy[:, 3:], ROD)
    assert np.mean((exact.status & MULTI) != 0) > 0.99


def test_the_band_holds_where_the_wrench_is_as_small_as_its_noise():
    """A free rod's wrench is pure noise: m0 . f0 is then a product of two noises (the band's
    second-order term); flagged at most at the stated odds."""
    rng = np.random.default_rng(5)
    sigma = np.repeat([1e-3, 1e-5], 3)
    noise = rng.standard_normal((50_000, 6)) * sigma
    excess = np.array([single_contact_excess(w[:3], w[3:], *_bands(w, sigma)) for w in noise[:5000]])
    assert np.mean(excess > 1.0) < 2e-3


def _bands(wrench: np.ndarray, sigma: np.ndarray) -> tuple[float, float]:
    from vibrissa.reconstruct import single_contact_bands

    return single_contact_bands(wrench[:3], wrench[3:], np.diag(sigma**2), MULTI_SIGMAS)


def test_the_bands_variance_is_the_sampled_one():
    """single_contact_bands' variance of m0 . f0 against samples of a correlated noise."""
    rng = np.random.default_rng(6)
    a = rng.normal(size=(6, 6))
    cov = a @ a.T * 1e-4
    f0, m0 = rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.05
    draws = rng.multivariate_normal(np.zeros(6), cov, 400_000)
    dots = np.sum((f0 + draws[:, :3]) * (m0 + draws[:, 3:]), axis=1)
    dot_band, twist_band = _bands_of(f0, m0, cov)
    mean = np.trace(cov[:3, 3:])
    assert dot_band == pytest.approx(abs(mean) + np.std(dots), rel=0.01)
    assert twist_band == pytest.approx(np.sqrt(cov[5, 5]), rel=1e-12)


def _bands_of(f0: np.ndarray, m0: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    from vibrissa.reconstruct import single_contact_bands

    return single_contact_bands(f0, m0, cov, 1.0)


def test_the_status_is_a_no_contact_flag_and_reconstruct_reports_it():
    assert ContactStatus.MULTI_CONTACT & NO_CONTACT
    rec = reconstruct([0, 0, 0], [0.3, -0.2, 0.1], [0.1, 0.4, 0.0])  # m0 . f0 = -0.05
    assert rec.status[0] & MULTI and np.isnan(rec.point).all() and not rec.valid[0]
    twisted = reconstruct([0, 0, 0], [0.3, 0.0, 0.0], [0.0, 0.4, 0.01])  # m0 . f0 = 0, m0z != 0
    assert twisted.status[0] & MULTI


def test_two_contacts_on_a_tapered_pre_curved_rod_get_no_point():
    """The same 10 000 two-contact wrenches, Step 2 of a tapered (0.4), pre-curved (2 / L) rod
    (`vibrissa.reconstruct_rods`): none gives a point."""
    f0, m0 = two_contacts(10_000, 2)
    rec, _ = reconstruct_rod(np.zeros_like(f0), f0 / ROD.force_n, m0 / ROD.moment_nm,
                             RodShape(taper_ratio=0.4, precurvature=2.0))
    assert not rec.valid.any() and np.isnan(rec.point).all()
    assert np.all(rec.status & MULTI)
