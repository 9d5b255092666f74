"""The compiled incomplete elliptic integrals against scipy, identities and the m -> 1 limit."""

import math

import numpy as np
import pytest
from scipy import special

from vibrissa.elliptic import carlson_rf_rd, incomplete_f_e


def _complete(m: float) -> tuple[float, float]:
    """K(m), E(m) from R_F, R_D (DLMF 19.25.1); math.pi / 2 as phi would be 6e-17 short."""
    k, rd = carlson_rf_rd(0.0, 1.0 - m, 1.0)
    return k, k - m * rd / 3.0


def _f_e(phi: np.ndarray, m: np.ndarray) -> np.ndarray:
    return np.array([incomplete_f_e(float(a), float(b)) for a, b in zip(phi, m, strict=True)])


def test_agrees_with_scipy_over_the_whole_range():
    rng = np.random.default_rng(0)
    phi = np.r_[rng.uniform(0.0, np.pi, 4000), 0.0, np.pi / 2, np.pi, 1e-300, np.pi - 1e-12]
    m = np.r_[rng.uniform(0.0, 1.0, 4000) ** rng.uniform(0.1, 3.0, 4000), 0.5, 0.9, 0.3, 0.7, 0.99]
    m = np.minimum(m, 1.0 - 1e-9)  # closer to 1 scipy itself loses digits (see the limit test)
    got = _f_e(phi, m)
    np.testing.assert_allclose(got[:, 0], special.ellipkinc(phi, m), rtol=1e-13, atol=1e-300)
    np.testing.assert_allclose(got[:, 1], special.ellipeinc(phi, m), rtol=1e-13, atol=1e-300)


def test_carlson_integrals_agree_with_scipy():
    """R_F and R_D of one call against scipy's (its own algorithm, DLMF 19.36), from arguments
    that need a few duplications to ones that need many (one of them 0, or far apart)."""
    rng = np.random.default_rng(1)
    x, y = 10.0 ** rng.uniform(-12, 3, (2, 3000))
    z = 10.0 ** rng.uniform(-6, 3, 3000)
    x[:300] = 0.0
    got = np.array([carlson_rf_rd(a, b, c) for a, b, c in zip(x, y, z, strict=True)])
    np.testing.assert_allclose(got[:, 0], special.elliprf(x, y, z), rtol=1e-14)
    np.testing.assert_allclose(got[:, 1], special.elliprd(x, y, z), rtol=1e-14)


def test_circular_case_and_legendre_relation():
    phi = np.linspace(0.0, np.pi, 9)
    np.testing.assert_allclose(_f_e(phi, np.zeros(9)), np.column_stack([phi, phi]), rtol=1e-15)
    # E(m) K(1 - m) + E(1 - m) K(m) - K(m) K(1 - m) = pi / 2 (DLMF 19.7.1)
    for m in (1e-6, 0.1, 0.5, 0.8, 0.999999):
        k, e = _complete(m)
        k1, e1 = _complete(1.0 - m)
        assert e * k1 + e1 * k - k * k1 == pytest.approx(math.pi / 2, rel=1e-14)
        # past pi/2 by symmetry: F(pi | m) = 2 K(m), E(pi | m) = 2 E(m)
        np.testing.assert_allclose(incomplete_f_e(math.pi, m), [2.0 * k, 2.0 * e], rtol=1e-15)


def test_complete_integral_near_the_separatrix():
    # K(m) = L + (1 - m) (L - 1) / 4 + O((1 - m)^2 L), L = ln(4 / sqrt(1 - m)) (DLMF 19.12.1)
    for m in (1.0 - 1e-10, 1.0 - 1e-12, 1.0 - 2.0**-45):
        one_minus_m = 1.0 - m  # exact (Sterbenz): the m actually passed
        log_term = math.log(4.0 / math.sqrt(one_minus_m))
        assert _complete(m)[0] == pytest.approx(log_term + one_minus_m * (log_term - 1.0) / 4.0, rel=1e-14)


def test_non_finite_input_gives_nan_and_returns():
    for phi, m in ((math.nan, 0.5), (1.0, math.nan), (math.inf, 0.5)):
        assert all(math.isnan(v) for v in incomplete_f_e(phi, m))
