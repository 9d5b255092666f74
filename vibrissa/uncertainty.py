"""The uncertainty of a reconstructed contact point: wrench noise carried through Step 2.

Step 2 (``vibrissa.reconstruct.reconstruct_row``) puts the contact at P1 - P0 = (u1 e_u, v1)
in the clamp frame C, with the bending plane's direction e_u = (m0y, -m0x) / kappa0 and the
planar solution (u1, v1) = g(fu, fv, kappa0) of fu = -(f0x e_ux + f0y e_uy), fv = -f0z,
kappa0 = |(m0x, m0y)| (eqs. 20-23). Its Jacobian J (3 x 6) with respect to (f0, m0) is the
chain of these: the derivatives of e_u, fu and kappa0 in closed form, those of g by central
differences of the compiled planar solver (it is closed form in elliptic integrals, smooth
away from the no-contact boundaries; the step, 1e-5 of the load, keeps the truncation error
near 1e-10 and the rounding error near 1e-11 of the derivative). A wrench-noise covariance
Sigma_w (6 x 6) then gives the point's covariance J Sigma_w J^T (first order: the noise small
against the load), rotated into W and scaled to SI. m0z does not enter Step 2.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from vibrissa.compiled import compiled
from vibrissa.elastica import planar_contact_scalar
from vibrissa.frames import quaternion_matrix

FloatArray = NDArray[np.float64]

STEP = 1e-5
"""Central-difference step of the planar solver's derivatives, relative to the load."""


@compiled
def point_jacobian(f0: FloatArray, m0: FloatArray, jacobian: FloatArray) -> bool:
    """d(P1 - P0)/d(f0, m0) (3, 6) in C, paper units, written into ``jacobian``; False where
    it is not defined (no bending moment, or the planar solver finds no contact within a
    step of the load)."""
    a, b = m0[0], m0[1]
    kappa = math.hypot(a, b)
    if not (kappa > 0.0 and math.isfinite(kappa)):
        return False
    e_x, e_y = b / kappa, -a / kappa
    k3 = kappa * kappa * kappa
    # d e_u / d(m0x, m0y), d kappa0 / d(m0x, m0y)
    de_x = (-b * a / k3, a * a / k3)
    de_y = (-b * b / k3, a * b / k3)
    dk = (a / kappa, b / kappa)
    fu = -(f0[0] * e_x + f0[1] * e_y)
    fv = -f0[2]
    u1, _v1, _s1, _phi, _status = planar_contact_scalar(fu, fv, kappa)
    if not math.isfinite(u1):
        return False
    h = STEP * (abs(fu) + abs(fv) + kappa)
    q = (fu, fv, kappa)
    du = np.empty(3)
    dv = np.empty(3)
    for k in range(3):
        plus = [q[0], q[1], q[2]]
        minus = [q[0], q[1], q[2]]
        plus[k] += h
        minus[k] -= h
        up, vp, _, _, _ = planar_contact_scalar(plus[0], plus[1], plus[2])
        um, vm, _, _, _ = planar_contact_scalar(minus[0], minus[1], minus[2])
        if not (math.isfinite(up) and math.isfinite(um)):
            return False
        du[k] = (up - um) / (2.0 * h)
        dv[k] = (vp - vm) / (2.0 * h)
    # d(fu, fv, kappa0) / d(f0x, f0y, f0z, m0x, m0y, m0z)
    dq = np.zeros((3, 6))
    dq[0, 0], dq[0, 1] = -e_x, -e_y
    dq[1, 2] = -1.0
    for j in range(2):
        dq[0, 3 + j] = -(f0[0] * de_x[j] + f0[1] * de_y[j])
        dq[2, 3 + j] = dk[j]
    for j in range(6):
        d_u = du[0] * dq[0, j] + du[1] * dq[1, j] + du[2] * dq[2, j]
        d_v = dv[0] * dq[0, j] + dv[1] * dq[1, j] + dv[2] * dq[2, j]
        dex = de_x[j - 3] if 3 <= j <= 4 else 0.0
        dey = de_y[j - 3] if 3 <= j <= 4 else 0.0
        jacobian[0, j] = d_u * e_x + u1 * dex
        jacobian[1, j] = d_u * e_y + u1 * dey
        jacobian[2, j] = d_v
    return True


def point_covariance_si(q_WC_xyzw: FloatArray, f0_C_n: FloatArray, m0_C_nm: FloatArray,
                        units: FloatArray, wrench_cov: FloatArray) -> FloatArray:
    """Covariance (N, 3, 3) of the contact points, m^2 in W, from the wrench noise.

    Parameters
    ----------
    q_WC_xyzw : ndarray, shape (N, 4)
        Clamp orientation in W (x, y, z, w).
    f0_C_n, m0_C_nm : ndarray, shape (N, 3)
        Clamp reaction on the rod in C, N and N m (the README's convention).
    units : ndarray, shape (N, 3)
        L (m), EI/L^2 (N) and EI/L (N m) of each row's rod (``vibrissa.units.rod_units``).
    wrench_cov : ndarray, shape (6, 6) or (N, 6, 6)
        Covariance of (f0, m0) in C, N^2, N^2 m and N^2 m^2.

    Returns
    -------
    ndarray, shape (N, 3, 3)
        NaN where the Jacobian is not defined (see :func:`point_jacobian`).
    """
    q = np.require(q_WC_xyzw, dtype=float, requirements=["C", "W"]).reshape(-1, 4)
    f0, m0 = (np.require(a, dtype=float, requirements=["C", "W"]).reshape(-1, 3)
              for a in (f0_C_n, m0_C_nm))
    units = np.require(units, dtype=float, requirements=["C"]).reshape(-1, 3)
    cov = np.asarray(wrench_cov, dtype=float)
    if cov.shape == (6, 6):
        cov = np.broadcast_to(cov, (len(q), 6, 6))
    if cov.shape != (len(q), 6, 6):
        raise ValueError(f"wrench_cov must have shape (6, 6) or ({len(q)}, 6, 6), got "
                         f"{cov.shape}")
    if not (len(f0) == len(m0) == len(units) == len(q)):
        raise ValueError(f"q_WC_xyzw, f0, m0 and units must have the same number of rows, got "
                         f"{len(q)}, {len(f0)}, {len(m0)}, {len(units)}")
    return _covariances(q, f0, m0, units, np.ascontiguousarray(cov))


@compiled
def _covariances(q: FloatArray, f0: FloatArray, m0: FloatArray, units: FloatArray,
                 cov: FloatArray) -> FloatArray:  # pragma: no cover - numba
    """:func:`point_covariance_si` of every row."""
    n = q.shape[0]
    out = np.full((n, 3, 3), np.nan)
    jacobian = np.empty((3, 6))
    rotation = np.empty((3, 3))
    f0_L, m0_L = np.empty(3), np.empty(3)
    for i in range(n):
        length_m, force_n, moment_nm = units[i, 0], units[i, 1], units[i, 2]
        for j in range(3):
            f0_L[j], m0_L[j] = f0[i, j] / force_n, m0[i, j] / moment_nm
        norm2 = quaternion_matrix(q[i], rotation)
        if not (norm2 > 0.0 and norm2 < math.inf):
            continue
        if not point_jacobian(f0_L, m0_L, jacobian):
            continue
        # J in SI: m per N for the f0 columns, m per N m for the m0 columns, rotated into W
        j_si = rotation @ jacobian
        for j in range(6):
            scale = length_m / (force_n if j < 3 else moment_nm)
            for r in range(3):
                j_si[r, j] *= scale
        out[i] = j_si @ cov[i] @ j_si.T
    return out
