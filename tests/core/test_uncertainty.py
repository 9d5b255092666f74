"""The contact point's covariance from the wrench noise, checked by Monte Carlo."""

import numpy as np
import pytest

from vibrissa import RodScale, parse_surface, simulate_sweep
from vibrissa.reconstruct import reconstruct_si
from vibrissa.uncertainty import point_covariance_si

L_M, EI_NM2 = 0.05, 2e-5


@pytest.fixture(scope="module")
def sweep_si():
    sweep = simulate_sweep(parse_surface("paraboloid:a=0.5,b=1,h=0.4"), 0.2, 0.2, 0.001)
    rod = RodScale(L_M, EI_NM2)
    f0, m0 = sweep.f0 * rod.force_n, sweep.m0 * rod.moment_nm
    return sweep, rod, f0, m0


def test_tangential_contacts_scatter_as_predicted(sweep_si):
    # 2000 noisy wrenches (1e-4 of the sweep's peak per component) at tangential contacts
    # along the sweep: the empirical covariance of the points, seen along the predicted
    # principal axes, within 10 % of the prediction in std
    sweep, rod, f0, m0 = sweep_si
    sigma = 1e-4 * np.abs(np.c_[f0, m0]).max(axis=0)
    rng = np.random.default_rng(3)
    R = np.array([0.3, -0.2, 0.5, 0.78])
    R /= np.linalg.norm(R)  # a tilted clamp: the covariance is rotated into W
    # (away from the tip: within the noise of s1 = 1 half the draws land beyond the rod, the
    # tip case of issue 18's item 4, not handled here)
    rows = np.flatnonzero((sweep.phase == 2) & (sweep.s1 < 0.95))[::150]
    assert len(rows) >= 5
    predicted = point_covariance_si(np.tile(R, (len(rows), 1)), f0[rows], m0[rows],
                                    np.tile([rod.length_m, rod.force_n, rod.moment_nm],
                                            (len(rows), 1)), np.diag(sigma**2))
    for k, cov in zip(rows, predicted, strict=True):
        draws = rng.normal(size=(2000, 6)) * sigma
        out = reconstruct_si(np.tile(R, (2000, 1)), np.zeros((2000, 3)), f0[k] + draws[:, :3],
                             m0[k] + draws[:, 3:], rod)
        assert out.valid.all()
        empirical = np.cov(out.point_m.T)
        values, axes = np.linalg.eigh(cov)
        seen = np.einsum("ji,jk,ki->i", axes, empirical, axes)
        np.testing.assert_allclose(np.sqrt(seen), np.sqrt(values), rtol=0.10)


def test_bad_shapes_are_clear_errors(sweep_si):
    _, rod, f0, m0 = sweep_si
    units = np.tile([rod.length_m, rod.force_n, rod.moment_nm], (3, 1))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    with pytest.raises(ValueError, match=r"wrench_cov must have shape \(6, 6\) or \(3, 6, 6\)"):
        point_covariance_si(q, f0[:3], m0[:3], units, np.eye(3))
    with pytest.raises(ValueError, match="the same number of rows"):
        point_covariance_si(q, f0[:2], m0[:3], units, np.eye(6))


def test_no_bending_moment_gives_nan_not_an_error(sweep_si):
    _, rod, f0, _ = sweep_si
    cov = point_covariance_si(np.array([[0.0, 0.0, 0.0, 1.0]]), f0[:1], np.zeros((1, 3)),
                              np.array([[rod.length_m, rod.force_n, rod.moment_nm]]), np.eye(6))
    assert np.isnan(cov).all()
