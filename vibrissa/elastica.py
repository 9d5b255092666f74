"""Closed form of the planar elastica of a clamped rod loaded by one point force (eq. 11).

Frame and units: the bending plane E_psi with coordinates (u, v); the rod is clamped at the
origin with tangent e_v (phi(0) = pi/2). Lengths in L, forces in EI/L^2, curvature in 1/L
(eq. 1). ``F = (fu, fv)`` is the contact force acting *on the rod* at arc length s1, and
``kappa0`` the curvature at the clamp. Moment balance of the part [s, s1] gives

    kappa(s) = ((r1 - r(s)) x F) . e_w,     so    kappa0 = (r1 x F) . e_w,

and the first integral of eq. 11, kappa^2 / 2 = f (cos(beta) - cos(beta1)) with
beta = phi - alpha - pi/2, is the pendulum. With sin(beta / 2) = k sn(sqrt(f) s + c | k^2), the
contact s1 is the first zero of kappa after the clamp, where sn = 1 (amplitude pi/2); all
integrals are incomplete elliptic integrals (scipy.special.ellipkinc / ellipeinc).

Only curvatures kappa0 >= 0 are solved directly; kappa0 < 0 is the mirror image u -> -u.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

from vibrissa.status import ContactStatus

# s1 may exceed the rod length by this much (round-off) and still count as the tip.
S1_TOLERANCE = 1e-9


@dataclass(frozen=True)
class PlanarContact:
    """Where the curvature of a loaded planar elastica first vanishes.

    Attributes
    ----------
    u1, v1 : ndarray, shape (N,)
        Point of the rod at s1 in the bending plane, units of L.
    s1 : ndarray, shape (N,)
        Arc length of the first zero of the curvature, units of L (not clipped to 1).
    phi1 : ndarray, shape (N,)
        Tangent angle at s1 against e_u, rad.
    status : ndarray of int, shape (N,)
        ``ContactStatus`` flags; 0 where the numbers are meaningful.
    """

    u1: NDArray[np.float64]
    v1: NDArray[np.float64]
    s1: NDArray[np.float64]
    phi1: NDArray[np.float64]
    status: NDArray[np.int64]


class _Pendulum(NamedTuple):
    """Pendulum constants of load cases, in the kappa0 >= 0 half (mirror already applied).

    With sin(beta / 2) = k sn(sqrt(f) s + c), theta0 = am(c) is the amplitude at the clamp:
    ``b0`` = k sin(theta0) and ``c0`` = k cos(theta0).
    """

    f: NDArray[np.float64]
    sqrt_f: NDArray[np.float64]
    fu: NDArray[np.float64]  # force component along e_u after mirroring
    fv: NDArray[np.float64]
    kappa0: NDArray[np.float64]
    alpha: NDArray[np.float64]  # eq. 12: signed angle between F and -e_v
    b0: NDArray[np.float64]
    c0: NDArray[np.float64]
    k: NDArray[np.float64]  # elliptic modulus
    mirrored: NDArray[np.bool_]
    any_mirrored: bool


def _float_arrays(
    fu: ArrayLike, fv: ArrayLike, kappa0: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The load case as float arrays of one (broadcast) shape."""
    fu_a, fv_a, kappa0_a = (np.asarray(x, dtype=float) for x in (fu, fv, kappa0))
    if not fu_a.shape == fv_a.shape == kappa0_a.shape:
        fu_a, fv_a, kappa0_a = np.broadcast_arrays(fu_a, fv_a, kappa0_a)
    return fu_a, fv_a, kappa0_a


_NON_FINITE = int(ContactStatus.NON_FINITE_INPUT)
_NO_FORCE = int(ContactStatus.NO_FORCE)
_NEVER_VANISHES = int(ContactStatus.CURVATURE_NEVER_VANISHES)
_AXIAL = int(ContactStatus.AXIAL_LOAD)


def _pendulum_arrays(fu: NDArray[np.float64], fv: NDArray[np.float64], kappa0: NDArray[np.float64]) -> _Pendulum:
    """The pendulum of equal-shape float arrays; the caller ignores divide, invalid, overflow."""
    mirrored = kappa0 < 0
    any_mirrored = bool(np.count_nonzero(mirrored))
    if any_mirrored:
        fu = np.where(mirrored, -fu, fu)
        kappa0 = np.abs(kappa0)
    f = np.hypot(fu, fv)
    sqrt_f = np.sqrt(f)
    alpha = np.arctan2(fu, -fv)
    b0 = -np.sin(0.5 * alpha)  # sin(beta0 / 2), beta0 = -alpha at the clamp
    c0 = kappa0 / (2.0 * sqrt_f)
    k = np.hypot(b0, c0)
    return _Pendulum(f, sqrt_f, fu, fv, kappa0, alpha, b0, c0, k, mirrored, any_mirrored)


def _flags(p: _Pendulum) -> NDArray[np.int64]:
    """``ContactStatus`` flags of each load case (0 for an ordinary one)."""
    status = np.zeros(p.f.shape, dtype=np.int64)
    finite = np.isfinite(p.fu) & np.isfinite(p.fv) & np.isfinite(p.kappa0)
    status[~finite] |= _NON_FINITE
    status[finite & (p.f == 0)] |= _NO_FORCE
    status[(status == 0) & (p.k >= 1.0)] |= _NEVER_VANISHES
    status[(status == 0) & (p.k == 0.0)] |= _AXIAL
    return status


def planar_contact(fu: ArrayLike, fv: ArrayLike, kappa0: ArrayLike) -> PlanarContact:
    """First zero of the curvature of the elastica with clamp curvature ``kappa0`` under ``F``.

    Parameters
    ----------
    fu, fv : array_like
        Contact force on the rod in the bending plane (u, v), units of EI/L^2.
    kappa0 : array_like
        Curvature at the clamp, 1/L (equals -m0w, eq. 22).

    Returns
    -------
    PlanarContact
        Contact point, s1 and tangent angle per sample. An axial load (straight rod pushed
        along its axis) is taken as tip contact of the straight rod, flagged AXIAL_LOAD.
    """
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return planar_contact_arrays(*_float_arrays(fu, fv, kappa0))


def planar_contact_arrays(
    fu: NDArray[np.float64], fv: NDArray[np.float64], kappa0: NDArray[np.float64]
) -> PlanarContact:
    """:func:`planar_contact` of float arrays of one shape, for callers that already ignore
    numpy's divide, invalid and overflow warnings (``np.errstate``): no conversion,
    no context."""
    p = _pendulum_arrays(fu, fv, kappa0)
    k, b0, c0, sqrt_f, f = p.k, p.b0, p.c0, p.sqrt_f, p.f
    m = k * k
    # chi = am(K - c) = atan2(cos theta0, k' sin theta0): the amplitude still to go from the
    # clamp to the zero of kappa (k > 0 cancels from both arguments).
    chi = np.arctan2(c0, np.sqrt(1.0 - m) * b0)
    f_chi = special.ellipkinc(chi, m)
    e_chi = special.ellipeinc(chi, m)
    s1 = f_chi / sqrt_f
    # E(am K) - E(am c) = e_chi - m sin(theta0) sin(chi) by the addition theorem, free of
    # cancellation for small loads; m sin(theta0) = k b0. ``along`` is the reach along -F/f
    # and ``across`` the reach along (fv, -fu)/f, each divided by f once more.
    # (Divided one factor at a time: sqrt_f * f underflows to 0 for tiny loads.)
    along = (2.0 * (e_chi - k * b0 * np.sin(chi)) - f_chi) / sqrt_f / f
    across = p.kappa0 / f / f
    u1 = across * p.fv - along * p.fu
    v1 = -(along * p.fv + across * p.fu)
    phi1 = 2.0 * np.arcsin(k) + p.alpha + 0.5 * np.pi
    # The rare cases (non-finite input, no force, k >= 1, k = 0) all leave this product
    # outside (0, inf): one screen, and the exact flags only where it finds something.
    ordinary = k * (1.0 - k) * f
    if np.count_nonzero((ordinary > 0.0) & (ordinary < np.inf)) == ordinary.size:
        status = np.zeros(ordinary.shape, dtype=np.int64)
    else:
        status = _flags(p)
        axial = status == _AXIAL
        u1 = np.where(axial, 0.0, u1)
        v1 = np.where(axial, 1.0, v1)
        s1 = np.where(axial, 1.0, s1)
        phi1 = np.where(axial, 0.5 * np.pi, phi1)
        good = (status == 0) | axial
        u1, v1, s1, phi1 = (np.where(good, value, np.nan) for value in (u1, v1, s1, phi1))
    if p.any_mirrored:
        u1 = np.where(p.mirrored, -u1, u1)
        phi1 = np.where(p.mirrored, np.pi - phi1, phi1)
    return PlanarContact(u1=u1, v1=v1, s1=s1, phi1=phi1, status=status)


def planar_line(
    fu: float, fv: float, kappa0: float, s: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points of the elastic line at arc lengths ``s`` for one load case.

    The rod follows the elastica up to s1 and is straight (no load beyond the contact) after it.

    Parameters
    ----------
    fu, fv, kappa0 : float
        As in :func:`planar_contact`.
    s : array_like, shape (M,)
        Arc lengths in [0, 1], units of L.

    Returns
    -------
    u, v : ndarray, shape (M,)
        Coordinates in the bending plane, units of L.
    """
    s = np.asarray(s, dtype=float)
    contact = planar_contact(fu, fv, kappa0)
    if int(contact.status) != ContactStatus.OK:
        return np.zeros_like(s), s.copy()  # no bending load: the straight rod
    with np.errstate(divide="ignore", invalid="ignore"):
        p = _pendulum_arrays(*_float_arrays(fu, fv, kappa0))
    m = float(p.k) ** 2
    s1 = float(contact.s1)
    s_bent = np.minimum(s, s1)
    theta0 = np.arctan2(p.b0, p.c0)
    c = special.ellipkinc(theta0, m)
    e0 = special.ellipeinc(theta0, m)
    arg = p.sqrt_f * s_bent + c
    _sn, cn, _dn, amplitude = special.ellipj(arg, m)
    along = (2.0 * (special.ellipeinc(amplitude, m) - e0) - p.sqrt_f * s_bent) / p.sqrt_f
    across = 2.0 * (p.c0 - p.k * cn) / p.sqrt_f  # k (cos(theta0) - cn)
    u = (-along * p.fu + across * p.fv) / p.f
    v = (-along * p.fv - across * p.fu) / p.f
    if p.mirrored:
        u = -u
    beyond = s > s1
    u = np.where(beyond, float(contact.u1) + (s - s1) * np.cos(float(contact.phi1)), u)
    v = np.where(beyond, float(contact.v1) + (s - s1) * np.sin(float(contact.phi1)), v)
    return u, v


def planar_contact_scalar(fu: float, fv: float, kappa0: float) -> tuple[float, float, float, float, int]:
    """:func:`planar_contact` of one load case in plain floats (no per-call numpy overhead).

    Same formulas, order of operations and flags as the array version, for the per-sample hot
    path (one wrench at a time); the two agree to round-off.

    Parameters
    ----------
    fu, fv : float
        Contact force on the rod in the bending plane (u, v), units of EI/L^2.
    kappa0 : float
        Curvature at the clamp, 1/L.

    Returns
    -------
    u1, v1, s1, phi1, status
        As the fields of :class:`PlanarContact` (L, L, L, rad, ``ContactStatus`` flags); NaN
        where the status leaves no contact.
    """
    nan = math.nan
    if not (math.isfinite(fu) and math.isfinite(fv) and math.isfinite(kappa0)):
        return nan, nan, nan, nan, int(ContactStatus.NON_FINITE_INPUT)
    mirrored = kappa0 < 0
    if mirrored:
        fu = -fu
    kappa0 = abs(kappa0)
    f = math.hypot(fu, fv)
    if f == 0:
        return nan, nan, nan, nan, int(ContactStatus.NO_FORCE)
    sqrt_f = math.sqrt(f)
    alpha = math.atan2(fu, -fv)
    b0 = -math.sin(0.5 * alpha)
    c0 = kappa0 / (2.0 * sqrt_f)
    k = math.hypot(b0, c0)
    if k >= 1.0:
        return nan, nan, nan, nan, int(ContactStatus.CURVATURE_NEVER_VANISHES)
    if k == 0.0:
        u1, v1, s1, phi1, status = 0.0, 1.0, 1.0, 0.5 * math.pi, int(ContactStatus.AXIAL_LOAD)
    else:
        m = k * k
        chi = math.atan2(c0, math.sqrt(1.0 - m) * b0)
        f_chi = float(special.ellipkinc(chi, m))
        e_chi = float(special.ellipeinc(chi, m))
        s1 = f_chi / sqrt_f
        along = (2.0 * (e_chi - k * b0 * math.sin(chi)) - f_chi) / sqrt_f / f
        across = kappa0 / f / f
        u1 = across * fv - along * fu
        v1 = -(along * fv + across * fu)
        phi1 = 2.0 * math.asin(k) + alpha + 0.5 * math.pi
        status = int(ContactStatus.OK)
    if mirrored:
        u1, phi1 = -u1, math.pi - phi1
    return u1, v1, s1, phi1, status
