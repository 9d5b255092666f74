"""Closed form of the planar elastica of a clamped rod loaded by one point force (eq. 11).

Frame and units: the bending plane E_psi with coordinates (u, v); the rod is clamped at the
origin with tangent e_v (phi(0) = pi/2). Lengths in L, forces in EI/L^2, curvature in 1/L
(eq. 1). ``F = (fu, fv)`` is the contact force acting *on the rod* at arc length s1, and
``kappa0`` the curvature at the clamp. Moment balance of the part [s, s1] gives

    kappa(s) = ((r1 - r(s)) x F) . e_w,     so    kappa0 = (r1 x F) . e_w,

and the first integral of eq. 11, kappa^2 / 2 = f (cos(beta) - cos(beta1)) with
beta = phi - alpha - pi/2, is the pendulum. With sin(beta / 2) = k sn(sqrt(f) s + c | k^2), the
contact s1 is the first zero of kappa after the clamp, where sn = 1 (amplitude pi/2); all
integrals are incomplete elliptic integrals (``vibrissa.elliptic``).

One implementation per load case, :func:`planar_contact_scalar`, compiled with numba; the
array form :func:`planar_contact` loops over it in compiled code, so a sample's result does not
depend on the others in its array.

Only curvatures kappa0 >= 0 are solved directly; kappa0 < 0 is the mirror image u -> -u.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa.compiled import compiled
from vibrissa.elliptic import incomplete_f_e
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


_NON_FINITE = int(ContactStatus.NON_FINITE_INPUT)
_NO_FORCE = int(ContactStatus.NO_FORCE)
_NEVER_VANISHES = int(ContactStatus.CURVATURE_NEVER_VANISHES)
_AXIAL = int(ContactStatus.AXIAL_LOAD)


@compiled
def _pendulum(fu: float, fv: float, kappa0: float
              ) -> tuple[float, float, float, float, float, float, float, float, bool]:
    """Pendulum constants of a finite load case in the kappa0 >= 0 half (mirror applied).

    Returns ``(f, sqrt_f, fu, kappa0, alpha, b0, c0, k, mirrored)``: ``fu``
    and ``kappa0`` after mirroring, ``alpha`` the signed angle between F and -e_v (eq. 12),
    and with sin(beta / 2) = k sn(sqrt(f) s + c), theta0 = am(c) the amplitude at the clamp,
    ``b0`` = k sin(theta0) = sin(beta0 / 2) (beta0 = -alpha) and ``c0`` = k cos(theta0).
    """
    mirrored = kappa0 < 0
    if mirrored:
        fu = -fu
    kappa0 = abs(kappa0)  # also -0.0, which would turn chi = atan2(c0, .) into -pi
    f = math.hypot(fu, fv)
    sqrt_f = math.sqrt(f)
    alpha = math.atan2(fu, -fv)
    b0 = -math.sin(0.5 * alpha)
    c0 = kappa0 / (2.0 * sqrt_f)
    return f, sqrt_f, fu, kappa0, alpha, b0, c0, math.hypot(b0, c0), mirrored


@compiled
def planar_contact_scalar(fu: float, fv: float, kappa0: float) -> tuple[float, float, float, float, int]:
    """:func:`planar_contact` of one load case in plain floats (compiled; the one implementation).

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
        return nan, nan, nan, nan, _NON_FINITE
    f, sqrt_f, fu, kappa0, alpha, b0, c0, k, mirrored = _pendulum(fu, fv, kappa0)
    if f == 0:
        return nan, nan, nan, nan, _NO_FORCE
    if k >= 1.0:
        return nan, nan, nan, nan, _NEVER_VANISHES
    if k == 0.0:  # axial load: the straight rod, touching with its tip
        u1, v1, s1, phi1, status = 0.0, 1.0, 1.0, 0.5 * math.pi, _AXIAL
    else:
        m = k * k
        chi = _amplitude_to_zero(b0, c0, m)
        f_chi, e_chi = incomplete_f_e(chi, m)
        u1, v1, s1 = _reach(fu, fv, kappa0, f, sqrt_f, b0, k, chi, f_chi, e_chi)
        phi1 = 2.0 * math.asin(k) + alpha + 0.5 * math.pi
        status = 0
    if mirrored:
        u1, phi1 = -u1, math.pi - phi1
    return u1, v1, s1, phi1, status


@compiled
def _amplitude_to_zero(b0: float, c0: float, m: float) -> float:
    """chi = am(K - c) = atan2(cos theta0, k' sin theta0): the amplitude still to go from the
    clamp to the zero of kappa (k > 0 cancels from both arguments)."""
    return math.atan2(c0, math.sqrt(1.0 - m) * b0)


@compiled
def _reach(fu: float, fv: float, kappa0: float, f: float, sqrt_f: float, b0: float, k: float,
           chi: float, f_chi: float, e_chi: float) -> tuple[float, float, float]:
    """u1, v1, s1 of the pendulum (kappa0 >= 0 half) from F(chi), E(chi)."""
    # E(am K) - E(am c) = e_chi - m sin(theta0) sin(chi) by the addition theorem, free of
    # cancellation for small loads; m sin(theta0) = k b0. ``along`` is the reach along
    # -F/f and ``across`` the reach along (fv, -fu)/f, each divided by f once more.
    # (Divided one factor at a time: sqrt_f * f underflows to 0 for tiny loads.)
    along = (2.0 * (e_chi - k * b0 * math.sin(chi)) - f_chi) / sqrt_f / f
    across = kappa0 / f / f
    return across * fv - along * fu, -(along * fv + across * fu), f_chi / sqrt_f


SMALL_M = 1e-4
"""Below this elliptic parameter the m-derivatives of F and E are taken from their series (the
closed forms divide by m)."""


@compiled
def planar_contact_tangent(fu: float, fv: float, kappa0: float, d: NDArray[np.float64]
                           ) -> tuple[float, float, float, int]:
    """:func:`planar_contact_scalar` with its derivatives, in closed form.

    Returns u1, v1, s1 and the status as :func:`planar_contact_scalar` (the same bits) and
    writes d(u1, v1, s1) / d(fu, fv, kappa0) into ``d`` (3, 3) where the status is 0 (an
    axial load, the one contact without them, leaves ``d`` as it was). Forward mode through
    the pendulum constants, with dF/dchi = 1/Delta, dE/dchi = Delta (Delta^2 = 1 - m sin^2
    chi), dF/dm = E / (2 m (1 - m)) - F / (2 m) - sin chi cos chi / (2 (1 - m) Delta) and
    dE/dm = (E - F) / (2 m) (DLMF 19.4.1-2; series below ``SMALL_M``).
    """
    nan = math.nan
    if not (math.isfinite(fu) and math.isfinite(fv) and math.isfinite(kappa0)):
        return nan, nan, nan, _NON_FINITE
    f, sqrt_f, fu_h, kappa_h, alpha, b0, c0, k, mirrored = _pendulum(fu, fv, kappa0)
    if f == 0:
        return nan, nan, nan, _NO_FORCE
    if k >= 1.0:
        return nan, nan, nan, _NEVER_VANISHES
    if k == 0.0:
        return 0.0, 1.0, 1.0, _AXIAL
    m = k * k
    chi = _amplitude_to_zero(b0, c0, m)
    f_chi, e_chi = incomplete_f_e(chi, m)
    u1, v1, s1 = _reach(fu_h, fv, kappa_h, f, sqrt_f, b0, k, chi, f_chi, e_chi)
    sin_chi, cos_chi = math.sin(chi), math.cos(chi)
    delta = math.sqrt(1.0 - m * sin_chi * sin_chi)
    if m < SMALL_M:  # F = int 1 + m s^2 / 2 + ..., E = int 1 - m s^2 / 2 - m^2 s^4 / 8 + ...
        i2 = 0.5 * chi - 0.25 * math.sin(2.0 * chi)
        i4 = 0.375 * chi - 0.25 * math.sin(2.0 * chi) + math.sin(4.0 * chi) / 32.0
        f_m, e_m = 0.5 * i2 + 0.75 * m * i4, -0.5 * i2 - 0.25 * m * i4
    else:
        f_m = (e_chi / (2.0 * m * (1.0 - m)) - f_chi / (2.0 * m)
               - sin_chi * cos_chi / (2.0 * (1.0 - m) * delta))
        e_m = (e_chi - f_chi) / (2.0 * m)
    k_prime = math.sqrt(1.0 - m)
    along = (2.0 * (e_chi - k * b0 * sin_chi) - f_chi) / sqrt_f / f
    across = kappa_h / f / f
    half = 0.5 * alpha
    for j in range(3):  # the tangent along fu_h, fv, kappa_h
        d_fu, d_fv, d_kappa = (1.0 if j == 0 else 0.0), (1.0 if j == 1 else 0.0), (
            1.0 if j == 2 else 0.0)
        d_f = (fu_h * d_fu + fv * d_fv) / f
        d_sqrt_f = 0.5 * d_f / sqrt_f
        d_alpha = (-fv * d_fu + fu_h * d_fv) / (f * f)
        d_b0 = -0.5 * math.cos(half) * d_alpha
        d_c0 = d_kappa / (2.0 * sqrt_f) - c0 * d_f / (2.0 * f)
        d_m = 2.0 * (b0 * d_b0 + c0 * d_c0)
        d_k = 0.5 * d_m / k
        d_k_prime = -0.5 * d_m / k_prime
        x = k_prime * b0
        d_x = k_prime * d_b0 + b0 * d_k_prime
        d_chi = (x * d_c0 - c0 * d_x) / (x * x + c0 * c0)
        d_f_chi = d_chi / delta + f_m * d_m
        d_e_chi = delta * d_chi + e_m * d_m
        d_num = (2.0 * (d_e_chi - (d_k * b0 * sin_chi + k * d_b0 * sin_chi
                                   + k * b0 * cos_chi * d_chi)) - d_f_chi)
        d_along = d_num / sqrt_f / f - 1.5 * along * d_f / f
        d_across = d_kappa / (f * f) - 2.0 * across * d_f / f
        d_u = d_across * fv + across * d_fv - d_along * fu_h - along * d_fu
        d_v = -(d_along * fv + along * d_fv + d_across * fu_h + across * d_fu)
        d_s = d_f_chi / sqrt_f - s1 * d_sqrt_f / sqrt_f
        # back to the caller's (fu, fv, kappa0): mirrored, u1 = -u1(-fu, fv, -kappa0)
        sign = -1.0 if mirrored and j != 1 else 1.0
        d[0, j] = (-sign if mirrored else sign) * d_u
        d[1, j] = sign * d_v
        d[2, j] = sign * d_s
    if mirrored:
        u1 = -u1
    return u1, v1, s1, 0


@compiled
def _planar_contact_loop(fu: NDArray[np.float64], fv: NDArray[np.float64],
                         kappa0: NDArray[np.float64]
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                    NDArray[np.float64], NDArray[np.int64]]:
    """:func:`planar_contact_scalar` over 1-D arrays of one length: u1, v1, s1, phi1, status."""
    n = fu.size
    u1, v1, s1, phi1 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    status = np.empty(n, dtype=np.int64)
    for i in range(n):
        u1[i], v1[i], s1[i], phi1[i], status[i] = planar_contact_scalar(fu[i], fv[i], kappa0[i])
    return u1, v1, s1, phi1, status


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
        Contact point, s1 and tangent angle per sample, in the broadcast shape of the inputs.
        An axial load (straight rod pushed along its axis) is taken as tip contact of the
        straight rod, flagged AXIAL_LOAD; samples without a contact carry NaN and a flag.
    """
    fu_a, fv_a, kappa0_a = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (fu, fv, kappa0)))
    shape = fu_a.shape
    u1, v1, s1, phi1, status = _planar_contact_loop(
        np.ravel(fu_a), np.ravel(fv_a), np.ravel(kappa0_a))  # contiguous copies of broadcast views
    return PlanarContact(u1=u1.reshape(shape), v1=v1.reshape(shape), s1=s1.reshape(shape),
                         phi1=phi1.reshape(shape), status=status.reshape(shape))


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
    f, sqrt_f, fu, _kappa0, _alpha, b0, c0, k, mirrored = _pendulum(float(fu), float(fv), float(kappa0))
    m = k * k
    s1 = float(contact.s1)
    s_bent = np.minimum(s, s1)
    theta0 = math.atan2(b0, c0)
    c, e0 = incomplete_f_e(theta0, m)
    arg = sqrt_f * s_bent + c
    from scipy import special  # for drawing only: not imported with the solvers (start-up time)

    _sn, cn, _dn, amplitude = special.ellipj(arg, m)
    along = (2.0 * (special.ellipeinc(amplitude, m) - e0) - sqrt_f * s_bent) / sqrt_f
    across = 2.0 * (c0 - k * cn) / sqrt_f  # k (cos(theta0) - cn)
    u = (-along * fu + across * fv) / f
    v = (-along * fv - across * fu) / f
    if mirrored:
        u = -u
    beyond = s > s1
    u = np.where(beyond, float(contact.u1) + (s - s1) * np.cos(float(contact.phi1)), u)
    v = np.where(beyond, float(contact.v1) + (s - s1) * np.sin(float(contact.phi1)), v)
    return u, v
