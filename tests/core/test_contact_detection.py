"""Contact detection with hysteresis against the free-rod noise."""

import numpy as np
import pytest

from vibrissa.contact_detection import ContactDetector, wrench_covariance

SIGMA_F, SIGMA_M = 2e-4, 5e-6


def _rows(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Wrenches whose Mahalanobis norm is ``d``: along f0x alone."""
    f0 = np.zeros((len(d), 3))
    f0[:, 0] = d * SIGMA_F
    return f0, np.zeros((len(d), 3))


def test_a_free_rods_noise_never_starts_a_contact():
    # 10^6 samples of a free rod with correlated noise: P(chi^2_6 >= 49) = 1.5e-8 per sample
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 6)) * np.r_[[SIGMA_F] * 3, [SIGMA_M] * 3]
    cov = a.T @ a + np.diag(np.r_[[SIGMA_F] * 3, [SIGMA_M] * 3]) ** 2
    noise = rng.multivariate_normal(np.zeros(6), cov, size=1_000_000)
    detector = ContactDetector(cov)
    touching, d = detector.update(["w"] * len(noise), noise[:, :3], noise[:, 3:])
    assert not touching.any()
    # d is the chi distribution with 6 dof: mean 2.350, P(d >= 5) = 3.4e-4
    assert 2.34 < d.mean() < 2.36
    assert 2.5e-4 < np.mean(d >= 5.0) < 4.5e-4


def test_hysteresis_enters_at_on_and_leaves_below_off():
    detector = ContactDetector(wrench_covariance(SIGMA_F, SIGMA_M), on_sigmas=7.0,
                               off_sigmas=5.0)
    d = np.array([0.0, 6.9, 7.0, 6.0, 5.1, 5.0, 8.0, 4.99, 6.0, 7.5, 0.0])
    touching, norm = detector.update(["w"] * len(d), *_rows(d))
    np.testing.assert_allclose(norm, d, rtol=1e-12)
    assert touching.tolist() == [False, False, True, True, True, True, True, False, False,
                                 True, False]


def test_each_whisker_has_its_own_state_and_it_lasts_between_calls():
    detector = ContactDetector(wrench_covariance(SIGMA_F, SIGMA_M))
    touching, _ = detector.update(["a", "b"], *_rows(np.array([9.0, 6.0])))
    assert touching.tolist() == [True, False]
    assert detector.in_contact(["a", "b", "c"]) == [True, False, False]
    # a in the band stays in contact; b in the band does not enter; NaN leaves a as it was
    f0, m0 = _rows(np.array([6.0, 6.0, np.nan]))
    touching, _ = detector.update(["a", "b", "a"], f0, m0)
    assert touching.tolist() == [True, False, False]
    assert detector.in_contact(["a", "b"]) == [True, False]


def test_invented_names_do_not_grow_the_state_without_bound():
    from vibrissa.contact_detection import MAX_WHISKERS

    detector = ContactDetector(wrench_covariance(SIGMA_F, SIGMA_M))
    names = [f"w{i}" for i in range(MAX_WHISKERS + 10)]
    touching, _ = detector.update(names, *_rows(np.full(len(names), 8.0)))
    assert touching.all() and len(detector._index) == MAX_WHISKERS
    # past the limit a name has no state: in the band it is not in contact
    touching, _ = detector.update(["w0", names[-1]], *_rows(np.array([6.0, 6.0])))
    assert touching.tolist() == [True, False]


def test_bad_settings_are_clear_errors():
    with pytest.raises(ValueError, match="force_std_n"):
        wrench_covariance(0.0, 1.0)
    with pytest.raises(ValueError, match="positive definite"):
        ContactDetector(np.diag([1.0, 1, 1, 1, 1, -1]))
    with pytest.raises(ValueError, match=r"\(6, 6\)"):
        ContactDetector(np.eye(3))
    with pytest.raises(ValueError, match="off_sigmas"):
        ContactDetector(np.eye(6), on_sigmas=3.0, off_sigmas=4.0)
