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
def carlson_rf_rd(x: float, y: float, z: float) -> tuple[float, float]:
    """R_F(x, y, z) and R_D(x, y, z) for x, y >= 0 (at most one zero) and z > 0.

    Both by the duplication theorem from the same arguments: the duplications they share are
    made once, and each stops at its own tolerance."""
    total, scale = 0.0, 1.0  # R_D's sum over the duplications made, and the next one's weight
    fx = fy = fz = f_mean = dx = dy = dz = d_mean = math.nan
    f_done = d_done = False
    k = 0
    while k < _MAX_DUPLICATIONS:  # both
        k += 1
        sx, sy, sz = math.sqrt(x), math.sqrt(y), math.sqrt(z)
        lam = sx * (sy + sz) + sy * sz
        total += scale / (sz * (z + lam))
        scale *= 0.25
        x, y, z = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam)
        f_mean = (x + y + z) / 3.0
        fx, fy, fz = (f_mean - x) / f_mean, (f_mean - y) / f_mean, (f_mean - z) / f_mean
        d_mean = 0.2 * (x + y + 3.0 * z)
        dx, dy, dz = (d_mean - x) / d_mean, (d_mean - y) / d_mean, (d_mean - z) / d_mean
        f_done = max(abs(fx), abs(fy), abs(fz)) <= _RF_TOLERANCE
        d_done = max(abs(dx), abs(dy), abs(dz)) <= _RD_TOLERANCE
        if f_done or d_done:
            break
    while not d_done and k < _MAX_DUPLICATIONS:  # R_D's last ones
        k += 1
        sx, sy, sz = math.sqrt(x), math.sqrt(y), math.sqrt(z)
        lam = sx * (sy + sz) + sy * sz
        total += scale / (sz * (z + lam))
        scale *= 0.25
        x, y, z = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam)
        d_mean = 0.2 * (x + y + 3.0 * z)
        dx, dy, dz = (d_mean - x) / d_mean, (d_mean - y) / d_mean, (d_mean - z) / d_mean
        d_done = max(abs(dx), abs(dy), abs(dz)) <= _RD_TOLERANCE
    while not f_done and k < _MAX_DUPLICATIONS:  # R_F's last ones
        k += 1
        sx, sy, sz = math.sqrt(x), math.sqrt(y), math.sqrt(z)
        lam = sx * (sy + sz) + sy * sz
        x, y, z = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam)
        f_mean = (x + y + z) / 3.0
        fx, fy, fz = (f_mean - x) / f_mean, (f_mean - y) / f_mean, (f_mean - z) / f_mean
        f_done = max(abs(fx), abs(fy), abs(fz)) <= _RF_TOLERANCE
    e2 = fx * fy - fz * fz
    e3 = fx * fy * fz
    rf = (1.0 + (e2 / 24.0 - 0.1 - 3.0 / 44.0 * e3) * e2 + e3 / 14.0) / math.sqrt(f_mean)
    ea = dx * dy
    eb = dz * dz
    ec = ea - eb
    ed = ea - 6.0 * eb
    ee = ed + 2.0 * ec
    series = (1.0 + ed * (-3.0 / 14.0 + 9.0 / 88.0 * ed - 9.0 / 52.0 * dz * ee)
              + dz * (ee / 6.0 + dz * (-9.0 / 22.0 * ec + dz * 3.0 / 26.0 * ea)))
    return rf, 3.0 * total + scale * series / (d_mean * math.sqrt(d_mean))


@compiled
def incomplete_f_e(phi: float, m: float) -> tuple[float, float]:
    """F(phi | m) and E(phi | m) for 0 <= phi <= pi and 0 <= m < 1."""
    s, c = math.sin(phi), math.cos(phi)
    y = 1.0 - m * s * s
    rf, rd = carlson_rf_rd(c * c, y, 1.0)
    f = s * rf
    e = f - m * s * s * s * rd / 3.0
    if phi > 0.5 * math.pi:  # the integrands are symmetric about pi/2: 2 K(m) - F(pi - phi)
        complete_k, complete_rd = carlson_rf_rd(0.0, 1.0 - m, 1.0)
        complete_e = complete_k - m * complete_rd / 3.0
        f, e = 2.0 * complete_k - f, 2.0 * complete_e - e
    return f, e
