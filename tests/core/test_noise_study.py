"""The noise study: Step 2's error against wrench noise and against errors in L and EI, checked
against scaling laws, the statics of the contact and the first-order covariance."""

import numpy as np
import pytest

from vibrissa import RodScale, parse_surface, simulate_sweeps
from vibrissa.noise_study import (
    ContactSamples,
    gaussian_norms,
    noise_errors,
    rod_errors,
)
from vibrissa.study import PAPER_SURFACE
from vibrissa.sweep import Trail

L_M, EI_NM2 = 0.05, 2e-5


@pytest.fixture(scope="module")
def samples():
    """Two paper trails through tip and tangential contact, at a coarse step (speed)."""
    sweeps = simulate_sweeps(parse_surface(PAPER_SURFACE), [Trail(0.0, 0.2), Trail(0.2, 0.2)],
                             step=0.004)
    out = ContactSamples.from_sweeps(sweeps, RodScale(L_M, EI_NM2))
    assert np.sum(out.phase == 1) > 200 and np.sum(out.phase == 2) > 200
    return out


def stats(rows, key, phase):
    """The ErrorStats of ``phase`` at a noise fraction or (parameter, relative error)."""
    for row in rows:
        row_key = (row.noise_fraction if hasattr(row, "noise_fraction")
                   else (row.parameter, row.relative_error))
        if row_key == key and row.stats.phase == phase:
            return row.stats
    raise KeyError(key)


def test_without_noise_the_points_are_exact(samples):
    rows = noise_errors(samples, [0.0], draws=1)
    for phase in ("tip", "tangential"):
        s = stats(rows, 0.0, phase)
        assert s.points_fraction == 1.0
        assert s.error_p95_mm < 1e-6  # 1e-9 m
        assert s.predicted_p95_mm == 0.0  # a zero covariance


@pytest.mark.parametrize("phase", ["tip", "tangential"])
def test_error_grows_linearly_with_the_noise(samples, phase):
    # first order: the point moves by J dw, so the error distribution scales with sigma;
    # a slope of 1 +- 0.1 on log-log over two decades
    rows = noise_errors(samples, [1e-4, 1e-2], draws=2)
    low, high = stats(rows, 1e-4, phase), stats(rows, 1e-2, phase)
    for field in ("error_median_mm", "error_p95_mm"):
        slope = np.log10(getattr(high, field) / getattr(low, field)) / 2.0
        assert 0.9 < slope < 1.1, (field, slope)
    assert low.points_fraction > 0.99


@pytest.mark.parametrize("fraction", [1e-5, 1e-4, 1e-3])
@pytest.mark.parametrize("phase", ["tip", "tangential"])
def test_predicted_error_matches_the_measured_one_at_small_noise(samples, phase, fraction):
    # the covariance (closed-form Jacobian) against the nonlinear Step 2 on noisy wrenches
    s = stats(noise_errors(samples, [fraction], draws=2), fraction, phase)
    for measured, predicted in ((s.error_median_mm, s.predicted_median_mm),
                                (s.error_p95_mm, s.predicted_p95_mm)):
        assert 0.75 < predicted / measured < 1.33


def test_tip_errors_exceed_tangential_ones_and_stay_below_the_rod(samples):
    # a tip contact's position along the rod is set by the small clamp moment of a barely
    # bent rod: less well conditioned than a tangential contact
    rows = noise_errors(samples, [1e-4], draws=2)
    tip, tangential = stats(rows, 1e-4, "tip"), stats(rows, 1e-4, "tangential")
    assert tip.error_p95_mm > tangential.error_p95_mm
    assert tip.error_p95_mm < 1e-2 * L_M * 1e3


def test_same_seed_same_table(samples):
    a = noise_errors(samples, [1e-3], draws=1, seed=7)
    b = noise_errors(samples, [1e-3], draws=1, seed=7)
    c = noise_errors(samples, [1e-3], draws=1, seed=8)
    assert a == b
    assert a != c


def test_gaussian_norms_follow_the_chi_distribution():
    # |z| for N(0, diag(a^2, 0, 0)): median 0.6745 a (half-normal); for sigma^2 I: the chi
    # distribution with 3 dof, median 1.5382 sigma; a rotated covariance changes nothing
    rng = np.random.default_rng(0)
    n = 200_000
    line = np.zeros((n, 3, 3))
    line[:, 0, 0] = 4.0
    assert np.median(gaussian_norms(line, rng)) == pytest.approx(0.6745 * 2.0, rel=0.01)
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    ball = np.tile(rot @ np.diag([9.0, 9.0, 9.0]) @ rot.T, (n, 1, 1))
    assert np.median(gaussian_norms(ball, rng)) == pytest.approx(1.5382 * 3.0, rel=0.01)
    undefined = np.full((2, 3, 3), np.nan)
    assert np.isnan(gaussian_norms(undefined, rng)).all()


def test_exact_rod_gives_exact_points(samples):
    rows = rod_errors(samples, [0.0])
    for parameter in ("L", "EI"):
        for phase in ("tip", "tangential"):
            s = stats(rows, (parameter, 0.0), phase)
            assert s.points_fraction == 1.0
            assert s.error_p95_mm < 1e-6


def test_wrong_length_moves_no_point_and_loses_the_tip(samples):
    # the elastica from the clamp to the contact is set by F, M and EI alone (the moment
    # balance and EI kappa = M along the rod): a wrong L moves no point, to round-off; a rod
    # assumed 1 % short puts every tip contact past its tip (no noise model: no point), one
    # assumed longer keeps them all
    rows = rod_errors(samples, [-0.01, 0.01, 0.05])
    for e in (-0.01, 0.01, 0.05):
        for phase in ("tip", "tangential"):
            s = stats(rows, ("L", e), phase)
            if s.points:
                assert s.error_p95_mm < 1e-6
                assert s.predicted_p95_mm < 1e-6  # the first order agrees: zero
    assert stats(rows, ("L", -0.01), "tip").points == 0
    assert stats(rows, ("L", 0.01), "tip").points_fraction == 1.0
    assert stats(rows, ("L", 0.05), "tangential").points_fraction == 1.0


def test_wrong_stiffness_moves_points_along_the_force(samples):
    # the moment balance m0 + (P1 - P0) x F = 0 holds whatever EI Step 2 assumes, so a wrong
    # EI slides the point along the contact force's line of action
    wrong = samples.reconstruct(samples.f0_n, samples.m0_nm, RodScale(L_M, EI_NM2 * 0.97))
    moved = wrong.point_m[wrong.valid] - samples.contact_m[wrong.valid]
    along = -samples.f0_n[wrong.valid] / np.linalg.norm(samples.f0_n[wrong.valid], axis=1)[:, None]
    across = np.linalg.norm(np.cross(moved, along), axis=1)
    assert np.linalg.norm(moved, axis=1).max() > 1e-4  # it does move (0.1 mm)
    assert across.max() < 1e-12


@pytest.mark.parametrize("phase, e", [("tip", -0.01), ("tangential", -0.01),
                                      ("tangential", 0.01)])
def test_stiffness_error_scales_the_deflection(samples, phase, e):
    # beam theory: the lateral deflection of the contact is ~ F / EI, so EI (1 + e) moves the
    # point by ~ |e| times the contact's distance from the clamp axis (within 30 %); the first
    # order of the Jacobian within 10 %
    rows = rod_errors(samples, [e])
    s = stats(rows, ("EI", e), phase)
    in_phase = samples.phase == (1 if phase == "tip" else 2)
    deflection_mm = 1e3 * np.linalg.norm((samples.contact_m - samples.p0_m)[in_phase, :2], axis=1)
    ratio = s.error_median_mm / (abs(e) * np.median(deflection_mm))
    assert 0.7 < ratio < 1.3
    assert s.predicted_median_mm == pytest.approx(s.error_median_mm, rel=0.1)
    assert s.points_fraction > 0.95


def test_stiffness_error_is_symmetric_in_sign(samples):
    rows = rod_errors(samples, [-0.02, 0.02])
    low, high = stats(rows, ("EI", -0.02), "tangential"), stats(rows, ("EI", 0.02), "tangential")
    assert high.error_median_mm == pytest.approx(low.error_median_mm, rel=0.15)


def test_bad_arguments_are_clear_errors(samples):
    with pytest.raises(ValueError, match="draws"):
        noise_errors(samples, [1e-3], draws=0)
    with pytest.raises(ValueError, match="fractions"):
        noise_errors(samples, [-1e-3])
    with pytest.raises(ValueError, match="relative_errors"):
        rod_errors(samples, [-1.0])
