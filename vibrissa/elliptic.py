"""Incomplete elliptic integrals of the first and second kind, compiled for scalar loops.

``F(phi | m)`` and ``E(phi | m)`` (parameter m = k^2, as scipy.special.ellipkinc / ellipeinc)
through Carlson's symmetric integrals R_F and R_D (DLMF 19.25.5):

    F(phi | m) = sin(phi) R_F(cos^2 phi, 1 - m sin^2 phi, 1)
    E(phi | m) = F(phi | m) - m/3 sin^3(phi) R_D(cos^2 phi, 1 - m sin^2 phi, 1)

for 0 <= phi <= pi/2, and by the symmetry about pi/2 (DLMF 19.2.10) up to pi. R_F and R_D by
the duplication theorem with the fifth-order series at the end (Carlson 1995, Numer. Algorithms
10: 13-26; Press et al., Numerical Recipes, 2nd ed., sect. 6.11); the stopping tolerances give a
relative truncation error below 1e-18, so the results are round-off limited (agreement with
scipy ~1e-15). Written for numba so that the Step 2 kernels (``vibrissa.elastica``,
``vibrissa.reconstruct``) call them per sample without numpy overhead.
"""

from __future__ import annotations

import math

from vibrissa.compiled import compiled

# Duplication stops when every argument is within this relative distance of their mean: the
# truncation error of the series is then ~ tol^6 (R_F: 0.0008^6 / 4 ~ 7e-20).
_RF_TOLERANCE = 0.0008
_RD_TOLERANCE = 0.0005
# Each duplication shrinks the spread by 4; 40 steps reach any tolerance from any finite
# arguments and bound the loop for non-finite ones (which return NaN).
_MAX_DUPLICATIONS = 40


@compiled
def carlson_rf(x: float, y: float, z: float) -> float:
    """R_F(x, y, z) for x, y, z >= 0, at most one of them zero."""
    dx = dy = dz = mean = math.nan
    for _ in range(_MAX_DUPLICATIONS):
        sx, sy, sz = math.sqrt(x), math.sqrt(y), math.sqrt(z)
        lam = sx * (sy + sz) + sy * sz
        x, y, z = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam)
        mean = (x + y + z) / 3.0
        dx, dy, dz = (mean - x) / mean, (mean - y) / mean, (mean - z) / mean
        if max(abs(dx), abs(dy), abs(dz)) <= _RF_TOLERANCE:
            break
    e2 = dx * dy - dz * dz
    e3 = dx * dy * dz
    return (1.0 + (e2 / 24.0 - 0.1 - 3.0 / 44.0 * e3) * e2 + e3 / 14.0) / math.sqrt(mean)


@compiled
def carlson_rd(x: float, y: float, z: float) -> float:
    """R_D(x, y, z) for x, y >= 0 (at most one zero) and z > 0."""
    total, scale = 0.0, 1.0
    dx = dy = dz = mean = math.nan
    for _ in range(_MAX_DUPLICATIONS):
        sx, sy, sz = math.sqrt(x), math.sqrt(y), math.sqrt(z)
        lam = sx * (sy + sz) + sy * sz
        total += scale / (sz * (z + lam))
        scale *= 0.25
        x, y, z = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam)
        mean = 0.2 * (x + y + 3.0 * z)
        dx, dy, dz = (mean - x) / mean, (mean - y) / mean, (mean - z) / mean
        if max(abs(dx), abs(dy), abs(dz)) <= _RD_TOLERANCE:
            break
    ea = dx * dy
    eb = dz * dz
    ec = ea - eb
    ed = ea - 6.0 * eb
    ee = ed + 2.0 * ec
    series = (1.0 + ed * (-3.0 / 14.0 + 9.0 / 88.0 * ed - 9.0 / 52.0 * dz * ee)
              + dz * (ee / 6.0 + dz * (-9.0 / 22.0 * ec + dz * 3.0 / 26.0 * ea)))
    return 3.0 * total + scale * series / (mean * math.sqrt(mean))


@compiled
def incomplete_f_e(phi: float, m: float) -> tuple[float, float]:
    """F(phi | m) and E(phi | m) for 0 <= phi <= pi and 0 <= m < 1."""
    s, c = math.sin(phi), math.cos(phi)
    y = 1.0 - m * s * s
    rf = carlson_rf(c * c, y, 1.0)
    f = s * rf
    e = f - m * s * s * s * carlson_rd(c * c, y, 1.0) / 3.0
    if phi > 0.5 * math.pi:  # the integrands are symmetric about pi/2: 2 K(m) - F(pi - phi)
        complete_k = carlson_rf(0.0, 1.0 - m, 1.0)
        complete_e = complete_k - m * carlson_rd(0.0, 1.0 - m, 1.0) / 3.0
        f, e = 2.0 * complete_k - f, 2.0 * complete_e - e
    return f, e
