"""The contact point's covariance from the wrench noise, checked by Monte Carlo, and the tip
within the noise."""

import numpy as np
import pytest

from vibrissa import RodScale, parse_surface, simulate_sweep
from vibrissa.elastica import planar_contact_scalar, planar_contact_tangent
from vibrissa.reconstruct import reconstruct_si
from vibrissa.status import ContactPhase, ContactStatus

L_M, EI_NM2 = 0.05, 2e-5


@pytest.fixture(scope="module")
def sweep_si():
    sweep = simulate_sweep(parse_surface("paraboloid:a=0.5,b=1,h=0.4"), 0.2, 0.2, 0.001)
    rod = RodScale(L_M, EI_NM2)
    f0, m0 = sweep.f0 * rod.force_n, sweep.m0 * rod.moment_nm
    return sweep, rod, f0, m0


def test_planar_derivatives_match_central_differences():
    # the closed-form derivatives of (u1, v1, s1) against central differences of the planar
    # solver, over loads of every direction and size, both signs of kappa0 (the mirror)
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(2000):
        fu, fv = rng.normal(size=2) * rng.choice([0.1, 1.0, 5.0])
        kappa0 = rng.normal() * rng.choice([0.01, 0.5, 2.0])
        d = np.zeros((3, 3))
        u1, v1, s1, status = planar_contact_tangent(fu, fv, kappa0, d)
        value = planar_contact_scalar(fu, fv, kappa0)
        np.testing.assert_array_equal([u1, v1, s1, status], [*value[:3], value[4]])
        if status != 0:
            continue
        x = np.array([fu, fv, kappa0])
        fd = np.empty((3, 3))
        for j in range(3):
            h = 1e-6 * abs(x[j])
            plus, minus = x.copy(), x.copy()
            plus[j] += h
            minus[j] -= h
            a, b = planar_contact_scalar(*plus), planar_contact_scalar(*minus)
            if a[4] or b[4]:
                break
            fd[:, j] = (np.array(a[:3]) - np.array(b[:3])) / (2 * h)
        else:
            checked += 1
            # each column scaled by its input: the change for a relative change of the load
            np.testing.assert_allclose(d * np.abs(x), fd * np.abs(x),
                                       atol=1e-5 * np.abs(fd * np.abs(x)).max())
    assert checked > 1000


def peak_sigma(f0, m0, fraction):
    """Per-component noise std: ``fraction`` of the peak force and of the peak moment."""
    return fraction * np.repeat([np.linalg.norm(f0, axis=1).max(),
                                 np.linalg.norm(m0, axis=1).max()], 3)


@pytest.mark.parametrize("phase", [ContactPhase.TIP, ContactPhase.TANGENTIAL])
def test_contacts_scatter_as_predicted(sweep_si, phase):
    # 1000 noisy wrenches (1e-4 of the sweep's peak per component) at contacts along the
    # sweep: the empirical covariance of the points, seen along the predicted principal axes,
    # within 10 % of the prediction in std; at the tip half the draws put the first zero of
    # the curvature past the tip, and all are tip contacts within the noise
    sweep, rod, f0, m0 = sweep_si
    sigma = peak_sigma(f0, m0, 1e-4)
    cov_w = np.diag(sigma**2)
    rng = np.random.default_rng(3)
    R = np.array([0.3, -0.2, 0.5, 0.78])
    R /= np.linalg.norm(R)  # a tilted clamp: the covariance is rotated into W
    rows = np.flatnonzero(sweep.phase == phase)
    rows = rows[(rows > rows[0] + 20) & (rows < rows[-1] - 20)][::120]  # away from the ends
    assert len(rows) >= 5
    # the prediction: the covariance Step 2 gives the noise-free wrench
    predicted = reconstruct_si(np.tile(R, (len(rows), 1)), np.zeros((len(rows), 3)), f0[rows],
                               m0[rows], rod, cov_w).covariance_m2
    for k, cov in zip(rows, predicted, strict=True):
        draws = rng.normal(size=(1000, 6)) * sigma
        out = reconstruct_si(np.tile(R, (1000, 1)), np.zeros((1000, 3)), f0[k] + draws[:, :3],
                             m0[k] + draws[:, 3:], rod, cov_w)
        # (one-sided: 0.13 % of the draws lie past the tip by more than 3 sigma)
        assert out.valid.mean() >= 0.99
        if phase == ContactPhase.TIP:
            within = (out.status & ContactStatus.TIP_WITHIN_NOISE) > 0
            assert 0.2 < within.mean() < 0.8
            assert np.mean(out.phase[out.valid] == ContactPhase.TIP) >= 0.99
            past = out.s1_m[within]
            assert (past == L_M).all()
        first = np.flatnonzero(out.valid)[0]
        np.testing.assert_allclose(out.covariance_m2[first], cov, rtol=0.05, atol=1e-3 * cov.max())
        empirical = np.cov(out.point_m[out.valid].T)
        values, axes = np.linalg.eigh(cov)
        seen = np.einsum("ji,jk,ki->i", axes, empirical, axes)
        np.testing.assert_allclose(np.sqrt(seen), np.sqrt(values), rtol=0.10)


@pytest.mark.parametrize("y0, mu", [(0.2, 0.2), (0.0, 0.5), (0.35, 0.0)])
def test_noise_of_1e_4_leaves_a_point_at_99_percent_of_contacts(y0, mu):
    # issue 18: with Gaussian noise of 1e-4 of the peak wrench, at least 99 % of the contact
    # samples of a paper sweep give a point (without the tip decision, a third did not), and
    # the points lie within their 3-sigma ellipsoid at 99 % of the samples
    sweep = simulate_sweep(parse_surface("paraboloid:a=0.5,b=1,h=0.4"), y0, mu, 0.001)
    rod = RodScale(L_M, EI_NM2)
    f0, m0 = sweep.f0 * rod.force_n, sweep.m0 * rod.moment_nm
    sigma = peak_sigma(f0, m0, 1e-4)
    n = len(f0)
    rng = np.random.default_rng(5)
    noisy = np.c_[f0, m0] + rng.normal(size=(n, 6)) * sigma
    q, p0 = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), sweep.p0 * L_M
    contact = sweep.phase > 0
    plain = reconstruct_si(q, p0, noisy[:, :3], noisy[:, 3:], rod)
    out = reconstruct_si(q, p0, noisy[:, :3], noisy[:, 3:], rod, np.diag(sigma**2))
    assert out.valid[contact].mean() >= 0.99
    assert out.valid[contact].sum() > plain.valid[contact].sum()
    error = out.point_m - sweep.contact * L_M
    kept = contact & out.valid & np.isfinite(out.covariance_m2).all(axis=(1, 2))
    assert kept.sum() >= 0.99 * contact.sum()
    d2 = np.einsum("ni,nij,nj->n", error[kept], np.linalg.inv(out.covariance_m2[kept]),
                   error[kept])
    assert np.mean(d2 <= 14.16) >= 0.99  # chi^2 with 3 dof: 14.16 at 99.73 % (3 sigma)


def test_without_noise_model_nothing_changes(sweep_si):
    # the covariance path gives the same bits for every row not past the tip (the phase
    # differs only within the noise of the tip)
    sweep, rod, f0, m0 = sweep_si
    n = len(f0)
    q, p0 = np.tile([0.1, 0.2, -0.3, 0.9], (n, 1)), sweep.p0 * L_M
    plain = reconstruct_si(q, p0, f0, m0, rod)
    assert plain.covariance_m2 is None
    with_cov = reconstruct_si(q, p0, f0, m0, rod, np.eye(6) * 1e-12)
    same = (plain.status & ContactStatus.CONTACT_BEYOND_ROD) == 0
    for field in ("point_m", "s1_m", "force_n", "status"):
        np.testing.assert_array_equal(getattr(plain, field)[same], getattr(with_cov, field)[same])
    far = plain.s1_m < 0.9 * L_M
    np.testing.assert_array_equal(plain.phase[far], with_cov.phase[far])


def test_bad_shapes_are_clear_errors(sweep_si):
    _, rod, f0, m0 = sweep_si
    q = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    with pytest.raises(ValueError, match="the same number of rows"):
        reconstruct_si(q, np.zeros((3, 3)), f0[:2], m0[:3], rod, np.eye(6))
    with pytest.raises(ValueError, match=r"wrench_cov must have shape \(6, 6\) or \(3, 6, 6\)"):
        reconstruct_si(q, np.zeros((3, 3)), f0[:3], m0[:3], rod, np.eye(5))
    with pytest.raises(ValueError, match="tip_sigmas"):
        reconstruct_si(q, np.zeros((3, 3)), f0[:3], m0[:3], rod, np.eye(6), tip_sigmas=-1.0)


def test_no_bending_moment_gives_nan_not_an_error(sweep_si):
    _, rod, f0, _ = sweep_si
    out = reconstruct_si(np.array([[0.0, 0.0, 0.0, 1.0]]), np.zeros((1, 3)), f0[:1],
                         np.zeros((1, 3)), rod, np.eye(6))
    assert out.covariance_m2 is not None and np.isnan(out.covariance_m2).all()
