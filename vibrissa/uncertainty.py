"""The uncertainty of a reconstructed contact point: wrench noise carried through Step 2.

Step 2 (``vibrissa.reconstruct.reconstruct_row``) puts the contact at P1 - P0 = (u1 e_u, v1)
in the clamp frame C, with the bending plane's direction e_u = (m0y, -m0x) / kappa0 and the
planar solution (u1, v1, s1) = g(fu, fv, kappa0) of fu = -(f0x e_ux + f0y e_uy), fv = -f0z,
kappa0 = |(m0x, m0y)| (eqs. 20-23). Its Jacobian J with respect to (f0, m0) is the chain of
these, all in closed form: the derivatives of e_u, fu and kappa0, and those of g through the
elliptic integrals (``vibrissa.elastica.planar_contact_tangent``). A wrench-noise covariance
Sigma_w (6 x 6) then gives the point's covariance J Sigma_w J^T (first order: the noise small
against the load), rotated into W and scaled to SI, and the std of s1, with which Step 2
decides whether a contact found past the tip is the tip within the noise
(``vibrissa.reconstruct.reconstruct_si``). m0z does not enter Step 2.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from vibrissa.compiled import compiled
from vibrissa.elastica import planar_contact_tangent

FloatArray = NDArray[np.float64]


@compiled
def point_jacobian(f0: FloatArray, m0: FloatArray, jacobian: FloatArray) -> bool:
    """d(P1 - P0, s1)/d(f0, m0) (4, 6) in C, paper units, written into ``jacobian`` (rows x,
    y, z of the point, then s1); False where it is not defined (no bending moment, an axial
    load, or no contact at all: see ``vibrissa.elastica.planar_contact_tangent``)."""
    return jacobian_into(f0, m0, jacobian, np.empty((3, 3)))


@compiled
def jacobian_into(f0: FloatArray, m0: FloatArray, jacobian: FloatArray, dg: FloatArray) -> bool:
    """:func:`point_jacobian` with the planar derivatives' space ``dg`` (3, 3) given: a
    per-row kernel allocates nothing."""
    a, b = m0[0], m0[1]
    kappa = math.hypot(a, b)
    if not (kappa > 0.0 and math.isfinite(kappa)):
        return False
    e_x, e_y = b / kappa, -a / kappa
    k3 = kappa * kappa * kappa
    fu = -(f0[0] * e_x + f0[1] * e_y)
    fv = -f0[2]
    u1, _v1, _s1, status = planar_contact_tangent(fu, fv, kappa, dg)
    if status != 0:
        return False
    for j in range(6):
        # d(e_u, fu, fv, kappa0) / d(f0x, f0y, f0z, m0x, m0y, m0z)_j
        dex = dey = d_fu = d_fv = d_kappa = 0.0
        if j == 0:
            d_fu = -e_x
        elif j == 1:
            d_fu = -e_y
        elif j == 2:
            d_fv = -1.0
        elif j == 3:
            dex, dey, d_kappa = -b * a / k3, -b * b / k3, a / kappa
        elif j == 4:
            dex, dey, d_kappa = a * a / k3, a * b / k3, b / kappa
        if j >= 3:
            d_fu = -(f0[0] * dex + f0[1] * dey)
        d_u = dg[0, 0] * d_fu + dg[0, 1] * d_fv + dg[0, 2] * d_kappa
        jacobian[0, j] = d_u * e_x + u1 * dex
        jacobian[1, j] = d_u * e_y + u1 * dey
        for r in (1, 2):  # v1 -> z, s1
            jacobian[r + 1, j] = dg[r, 0] * d_fu + dg[r, 1] * d_fv + dg[r, 2] * d_kappa
    return True


@compiled
def propagate_row(jacobian: FloatArray, rotation: FloatArray, length_m: float, force_n: float,
                  moment_nm: float, cov: FloatArray, out: FloatArray, work: FloatArray) -> float:
    """The point's covariance in W, m^2, into ``out`` (3, 3), and the variance of s1 in
    units of L^2 (returned), from ``jacobian`` (:func:`point_jacobian`, paper units, C) and
    the SI wrench covariance ``cov`` (6, 6) in C; ``work`` (8, 6) is scratch space."""
    # J in SI: m (rows 0-2, rotated into W) and L (row 3) per N or N m; then J cov J^T, in
    # loops (a matrix product per row would cost more than the row's Step 2)
    for j in range(6):
        scale = 1.0 / (force_n if j < 3 else moment_nm)
        for r in range(3):
            work[r, j] = length_m * scale * (rotation[r, 0] * jacobian[0, j]
                                             + rotation[r, 1] * jacobian[1, j]
                                             + rotation[r, 2] * jacobian[2, j])
        work[3, j] = scale * jacobian[3, j]
    for r in range(4):  # rows 4-7: J cov
        for c in range(6):
            total = 0.0
            for k in range(6):
                total += work[r, k] * cov[k, c]
            work[4 + r, c] = total
    for r in range(3):
        for c in range(r, 3):
            total = 0.0
            for k in range(6):
                total += work[4 + r, k] * work[c, k]
            out[r, c] = out[c, r] = total
    s1_var = 0.0
    for k in range(6):
        s1_var += work[7, k] * work[3, k]
    return s1_var
