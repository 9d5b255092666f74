"""Step 2: the contact point from the clamp position and the support reactions alone (eqs. 20-23).

Conventions (derived from the statics of the rod, see README "Conventions"):

* ``f0``, ``m0`` are the reactions of the clamp *on the rod*, the moment taken about the clamp
  point P0. For a single contact force F on the rod at P1: ``f0 + F = 0`` and
  ``m0 + (P1 - P0) x F = 0``. A force/torque sensor under the clamp reads the opposite wrench.
* Both are expressed in the clamp frame C, whose z axis is the rod's axis at the clamp; ``R_WC``
  rotates C into the world frame W of ``p0`` (identity when omitted, as in the paper).
* Units are the paper's (eq. 1): lengths in L, forces in EI/L^2, moments in EI/L; see
  :class:`vibrissa.units.RodScale` for SI.

The bending plane E_psi is spanned by the clamp axis e_v = e_z and e_u; its normal is
e_w = e_u x e_v. We pick e_w = -m0 / |m0| so that m0w = m0 . e_w <= 0 and the clamp curvature
kappa0 = -m0w (eq. 22) is >= 0, which is eq. 20: psi = -atan2(m0x, m0y).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple, TypeAlias

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa.compiled import compiled, inlined
from vibrissa.elastica import S1_TOLERANCE, planar_contact_scalar
from vibrissa.frames import quaternion_matrix, rotate_vector
from vibrissa.status import NO_CONTACT, ContactPhase, ContactStatus
from vibrissa.uncertainty import jacobian_into, propagate_row
from vibrissa.units import RodScale, rod_units

# ContactPhase as the plain ints compiled code uses.
PHASE_NONE, PHASE_TIP, PHASE_TANGENTIAL = (int(p) for p in ContactPhase)

# Contacts this close to the tip (units of L) are reported as tip contact.
TIP_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Reconstruction:
    """Contact points reconstructed from wrenches; one entry per sample.

    Attributes
    ----------
    point : ndarray, shape (N, 3)
        Contact point P1 in W, units of L; NaN where ``status`` has no contact.
    s1 : ndarray, shape (N,)
        Arc length of the contact along the rod, units of L.
    phase : ndarray of int, shape (N,)
        :class:`ContactPhase`: TIP (1), TANGENTIAL (2), or NONE (0) without contact.
    psi : ndarray, shape (N,)
        Orientation of the bending plane in C (eq. 20), rad.
    force : ndarray, shape (N, 3)
        Contact force on the rod, -f0, expressed in W, units of EI/L^2.
    status : ndarray of int, shape (N,)
        :class:`ContactStatus` flags.
    """

    point: NDArray[np.float64]
    s1: NDArray[np.float64]
    phase: NDArray[np.int64]
    psi: NDArray[np.float64]
    force: NDArray[np.float64]
    status: NDArray[np.int64]

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Samples with a consistent contact point."""
        return (self.status & int(NO_CONTACT)) == 0


def _as_vectors(name: str, value: ArrayLike) -> NDArray[np.float64]:
    array = np.asarray(value, dtype=float)
    if array.ndim not in (1, 2) or array.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (3,) or (N, 3), got {array.shape}")
    return np.atleast_2d(array)


def reconstruct(
    p0: ArrayLike, f0: ArrayLike, m0: ArrayLike, R_WC: ArrayLike | None = None
) -> Reconstruction:
    """Reconstruct contact points from clamp positions and support reactions (Step 2).

    Parameters
    ----------
    p0 : array_like, shape (N, 3) or (3,)
        Clamp position P0 in W, units of L.
    f0, m0 : array_like, shape (N, 3) or (3,)
        Clamp reactions on the rod, in C, units EI/L^2 and EI/L (moment about P0).
    R_WC : array_like, shape (3, 3) or (N, 3, 3), optional
        Clamp orientation; identity (C parallel to W) when omitted.

    Returns
    -------
    Reconstruction
        Arrays of length N (also for single vectors). Samples without a consistent contact
        (no force, curvature that never vanishes within the rod, non-finite input) carry NaN
        and a status flag instead of raising.
    """
    p0_W, f0_C, m0_C = (_as_vectors(n, v) for n, v in (("p0", p0), ("f0", f0), ("m0", m0)))
    try:
        if not p0_W.shape == f0_C.shape == m0_C.shape:
            p0_W, f0_C, m0_C = np.broadcast_arrays(p0_W, f0_C, m0_C)
    except ValueError:
        raise ValueError(
            f"p0, f0, m0 must have the same number of samples, got {p0_W.shape}, {f0_C.shape}, {m0_C.shape}"
        ) from None
    rotation = None
    if R_WC is not None:
        rotation = np.asarray(R_WC, dtype=float)
        if rotation.shape not in ((3, 3), (1, 3, 3), (len(p0_W), 3, 3)):
            raise ValueError(f"R_WC must have shape (3, 3) or ({len(p0_W)}, 3, 3), got {rotation.shape}")
    return reconstruct_rows(np.ascontiguousarray(p0_W), np.ascontiguousarray(f0_C),
                            np.ascontiguousarray(m0_C), rotation)


def reconstruct_rows(
    p0_W: NDArray[np.float64], f0_C: NDArray[np.float64], m0_C: NDArray[np.float64],
    R_WC: NDArray[np.float64] | None,
) -> Reconstruction:
    """:func:`reconstruct` of C-contiguous float arrays of shape (N, 3) (R_WC: (3, 3),
    (1, 3, 3) or (N, 3, 3) floats, or None), for callers that have checked them: no
    conversion, no shape checks (a wrong shape is not detected here)."""
    if R_WC is None:
        rotation = _NO_ROTATION
    else:
        rotation = np.ascontiguousarray(R_WC.reshape(-1, 3, 3))
    point, s1, phase, psi, force, status = _reconstruct_kernel(p0_W, f0_C, m0_C, rotation)
    return Reconstruction(point=point, s1=s1, phase=phase, psi=psi, force=force, status=status)


_NO_CONTACT = int(NO_CONTACT)
_NON_FINITE = int(ContactStatus.NON_FINITE_INPUT)
_BEYOND = int(ContactStatus.CONTACT_BEYOND_ROD)
_TIP_WITHIN_NOISE = int(ContactStatus.TIP_WITHIN_NOISE)
_MULTI = int(ContactStatus.MULTI_CONTACT)

MULTI_TOLERANCE = 1e-9
"""Without a noise model, the band of a single contact's m0 . f0 and m0z: this fraction of
(|f0| + |m0|)^2 and of |f0| + |m0| (units of L): round-off of an exact wrench, which Step 1's
is to about 1e-15."""

MULTI_SIGMAS = 4.0
"""With a wrench covariance, the band of a single contact's m0 . f0 and m0z: this many of
their std (each passes it with Gaussian noise at 6e-5 odds; the two: under 1.3e-4)."""

_NO_ROTATION = np.empty((0, 3, 3))  # the kernel's "C parallel to W"


@compiled
def _reconstruct_kernel(
    p0_W: NDArray[np.float64], f0_C: NDArray[np.float64], m0_C: NDArray[np.float64],
    R_WC: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.float64],
           NDArray[np.float64], NDArray[np.int64]]:
    """:func:`reconstruct_row` of every row: point, s1, phase, psi, force, status.

    R_WC has 0 rows (identity), 1 (for every row) or N.
    """
    n = p0_W.shape[0]
    point, force = np.empty((n, 3)), np.empty((n, 3))
    s1, psi = np.empty(n), np.empty(n)
    phase, status = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    identity = np.eye(3)
    rotate, per_row = R_WC.shape[0] > 0, R_WC.shape[0] > 1
    for i in range(n):
        r = R_WC[i if per_row else 0] if rotate else identity
        s1[i], phase[i], psi[i], status[i] = reconstruct_row(
            p0_W[i], f0_C[i], m0_C[i], rotate, r, point[i], force[i])
    return point, s1, phase, psi, force, status


@inlined
def reconstruct_row(
    p0_W: NDArray[np.float64], f0_C: NDArray[np.float64], m0_C: NDArray[np.float64],
    rotate: bool, R_WC: NDArray[np.float64], point: NDArray[np.float64], force: NDArray[np.float64],
    tip_band: float = 0.0, dot_band: float = -1.0, twist_band: float = -1.0,
) -> tuple[float, int, float, int]:
    """Step 2 of one sample, for compiled callers (numba): :func:`reconstruct` of one row.

    ``p0_W``, ``f0_C``, ``m0_C`` (3,) and ``R_WC`` (3, 3), used only if ``rotate``, as in
    :func:`reconstruct`; writes the contact point and the contact force (W) into ``point`` and
    ``force`` (3,) and returns s1, phase, psi and status. The one implementation of Step 2:
    every path computes each sample through it, on its own, so a sample gives the same bits
    alone or in any batch. ``tip_band`` (L, from the wrench noise: ``reconstruct_si``) is the
    tip within the noise: a first zero of the curvature past the tip by more than round-off
    but at most ``tip_band`` is a tip contact at the elastica's point there, flagged
    TIP_WITHIN_NOISE; one farther out is no contact on the rod (CONTACT_BEYOND_ROD); one
    within ``tip_band`` before the tip is a tip contact too. A wrench whose m0 . f0 or m0z
    passes ``dot_band`` or ``twist_band`` (units of L, from the wrench noise; negative: none)
    widened by round-off is no single contact: MULTI_CONTACT (`single_contact_excess`).
    """
    fx, fy, fz = -f0_C[0], -f0_C[1], -f0_C[2]  # the contact force on the rod, in C
    m_horizontal = math.hypot(m0_C[0], m0_C[1])
    # e_u = e_v x e_w with e_w = -m0/|m0| (kappa0 >= 0): (m0y, -m0x) / |m0h|; an unbent rod has
    # its plane along F (along e_x without a force).
    if m_horizontal > 0:
        e_ux, e_uy = m0_C[1] / m_horizontal, -m0_C[0] / m_horizontal
    else:
        f_horizontal = math.hypot(fx, fy)
        if f_horizontal > 0:
            e_ux, e_uy = fx / f_horizontal, fy / f_horizontal
        else:
            e_ux, e_uy = 1.0, 0.0
    u1, v1, s1, _phi1, status = planar_contact_scalar(fx * e_ux + fy * e_uy, fz, m_horizontal)
    # A non-finite m0x or m0y is flagged by the planar solver (kappa0); p0 and m0z are not.
    finite = True
    for j in range(3):
        finite = finite and math.isfinite(p0_W[j]) and math.isfinite(m0_C[j])
    if not finite:
        status |= _NON_FINITE
    if status & _NON_FINITE == 0 and single_contact_excess(f0_C, m0_C, dot_band, twist_band) > 1.0:
        status |= _MULTI
    if status & _NO_CONTACT == 0 and s1 > 1.0 + S1_TOLERANCE:
        status |= _BEYOND if s1 > 1.0 + tip_band else _TIP_WITHIN_NOISE
    p1x, p1y, p1z = u1 * e_ux, u1 * e_uy, v1  # P1 - P0 in C
    if rotate:
        p1x, p1y, p1z = rotate_vector(R_WC, p1x, p1y, p1z)
        fx, fy, fz = rotate_vector(R_WC, fx, fy, fz)
    force[0], force[1], force[2] = fx, fy, fz
    if status & _NO_CONTACT:
        point[0] = point[1] = point[2] = math.nan
        return math.nan, PHASE_NONE, math.nan, status
    point[0], point[1], point[2] = p0_W[0] + p1x, p0_W[1] + p1y, p0_W[2] + p1z
    if _overflows(point, force):
        point[0] = point[1] = point[2] = math.nan
        return math.nan, PHASE_NONE, math.nan, status | _NON_FINITE
    s1 = min(s1, 1.0)
    phase = PHASE_TIP if s1 >= 1.0 - max(TIP_TOLERANCE, tip_band) else PHASE_TANGENTIAL
    return s1, phase, math.atan2(e_uy, e_ux), status


@compiled
def single_contact_excess(f0_C: NDArray[np.float64], m0_C: NDArray[np.float64],
                          dot_band: float = -1.0, twist_band: float = -1.0) -> float:
    """How far a wrench is from any single point contact's: the larger of |m0 . f0| /
    ``dot_band`` and |m0z| / ``twist_band`` (above 1: MULTI_CONTACT). One contact force F at
    P1 bends the rod in the plane of F and the clamp's axis z: m0 = (P1 - P0) x f0 is normal
    to that plane, so m0 . f0 = 0 and m0z = 0. Two contacts give neither in general. Units
    are the caller's (L in Step 2); each band is widened by `MULTI_TOLERANCE`'s round-off
    band (a negative one is that alone)."""
    scale = math.sqrt(f0_C[0] ** 2 + f0_C[1] ** 2 + f0_C[2] ** 2) + math.sqrt(
        m0_C[0] ** 2 + m0_C[1] ** 2 + m0_C[2] ** 2)
    dot_band = max(dot_band, 0.0) + MULTI_TOLERANCE * scale * scale
    twist_band = max(twist_band, 0.0) + MULTI_TOLERANCE * scale
    dot = abs(f0_C[0] * m0_C[0] + f0_C[1] * m0_C[1] + f0_C[2] * m0_C[2])
    twist = abs(m0_C[2])
    excess = 0.0
    for value, band in ((dot, dot_band), (twist, twist_band)):
        if value > 0.0:
            excess = max(excess, value / band if band > 0.0 else math.inf)
    return excess


@compiled
def single_contact_bands(f0: NDArray[np.float64], m0: NDArray[np.float64],
                         cov: NDArray[np.float64], sigmas: float) -> tuple[float, float]:
    """The noise bands of m0 . f0 and m0z (`single_contact_excess`) for a wrench measured with
    the noise covariance ``cov`` (6, 6) of (f0, m0), in its units: ``sigmas`` std of each
    about its mean under a single contact. m0 . f0 with Gaussian noise (d_f, d_m) has mean
    tr(cov_fm) and variance a^T cov a + tr(cov_mm cov_ff) + tr(cov_mf cov_mf), a = (m0, f0)
    (the second-order terms keep the band where the wrench is as small as its noise)."""
    linear = 0.0
    for i in range(6):
        a_i = m0[i] if i < 3 else f0[i - 3]
        for j in range(6):
            linear += a_i * cov[i, j] * (m0[j] if j < 3 else f0[j - 3])
    second, mean = 0.0, 0.0
    for i in range(3):
        mean += cov[i, 3 + i]
        for j in range(3):
            second += cov[3 + i, 3 + j] * cov[j, i] + cov[3 + i, j] * cov[3 + j, i]
    dot_band = abs(mean) + sigmas * math.sqrt(max(linear + second, 0.0))
    return dot_band, sigmas * math.sqrt(max(cov[5, 5], 0.0))


@compiled
def _overflows(point: NDArray[np.float64], force: NDArray[np.float64]) -> bool:
    """Whether a contact of finite inputs has an infinite point or force (3,): inputs near the
    float limit (p0 + P1 - P0, a rotation, the rod's units) overflow; it is then flagged
    NON_FINITE_INPUT, so that a usable contact is always finite."""
    for j in range(3):
        if not (abs(point[j]) < math.inf and abs(force[j]) < math.inf):  # inf or NaN
            return True
    return False


class ReconstructionSI(NamedTuple):
    """Contact points reconstructed from SI wrenches with clamp poses; one entry per sample.

    Attributes
    ----------
    pose_ok : ndarray of bool, shape (N,)
        Whether the clamp quaternion has a finite, nonzero length; the other fields of a sample
        without it are not set.
    point_m : ndarray, shape (N, 3)
        Contact point in W, m; NaN without contact.
    s1_m : ndarray, shape (N,)
        Arc length of the contact along the rod, m.
    phase : ndarray of int32, shape (N,)
        :class:`ContactPhase`.
    force_n : ndarray, shape (N, 3)
        Contact force on the rod, -f0, in W, N.
    status : ndarray of int32, shape (N,)
        :class:`ContactStatus` flags.
    covariance_m2 : ndarray, shape (N, 3, 3), or None
        With a wrench covariance: the point's covariance in W, m^2 (first order, see
        ``vibrissa.uncertainty``); NaN where it is not defined (no contact, an axial load,
        no bending moment).
    """

    pose_ok: NDArray[np.bool_]
    point_m: NDArray[np.float64]
    s1_m: NDArray[np.float64]
    phase: NDArray[np.int32]
    force_n: NDArray[np.float64]
    status: NDArray[np.int32]
    covariance_m2: NDArray[np.float64] | None = None

    @classmethod
    def of_blocks(cls, floats: NDArray[np.float64], ints: NDArray[np.int32],
                  pose_ok: NDArray[np.bool_], with_covariance: bool) -> ReconstructionSI:
        """The compiled Step 2's two blocks and pose_ok (`vibrissa.reconstruct_rods.rows_si`)
        as its fields, each a view of its part."""
        n = len(pose_ok)
        return cls(pose_ok, floats[:3 * n].reshape(n, 3), floats[6 * n:7 * n], ints[:n],
                   floats[3 * n:6 * n].reshape(n, 3), ints[n:],
                   floats[7 * n:].reshape(n, 3, 3) if with_covariance else None)

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Samples with a usable pose and a consistent contact point."""
        return self.pose_ok & ((self.status & _NO_CONTACT) == 0)

    def tally(self, ends: NDArray[np.int64]) -> tuple[NDArray[np.bool_], NDArray[np.int64]]:
        """``valid``, and the counts of each group of samples ``ends[k-1]:ends[k]`` (a tick),
        in ``TALLY`` order; without ``covariance_m2``, no sample counts as tip within the
        noise or without a covariance. One compiled pass instead of a dozen array calls on
        a tick of a few dozen rows."""
        covariance = _NO_TALLY_COVARIANCE if self.covariance_m2 is None else self.covariance_m2
        return tally_rows(self.pose_ok, self.status, covariance, ends)


TALLY = ("pose_ok", "valid", "multi_contact", "ambiguous", "tip_within_noise", "no_covariance")
"""The counts of `ReconstructionSI.tally`, per group: samples with a usable pose; of them,
valid ones; of them, MULTI_CONTACT (not valid); valid ones flagged AMBIGUOUS_CONTACT, flagged
TIP_WITHIN_NOISE, and whose covariance is not finite."""

_AMBIGUOUS_CONTACT = int(ContactStatus.AMBIGUOUS_CONTACT)
_NO_TALLY_COVARIANCE = np.empty((0, 3, 3))


@compiled
def tally_rows(pose_ok: NDArray[np.bool_], status: NDArray[np.int32],
               covariance: NDArray[np.float64], ends: NDArray[np.int64],
               ) -> tuple[NDArray[np.bool_], NDArray[np.int64]]:
    """`ReconstructionSI.tally` of its fields (``covariance``: 0 rows without one), for
    compiled callers too."""
    valid = np.empty(pose_ok.shape[0], dtype=np.bool_)
    counts = np.zeros((ends.shape[0], len(TALLY)), dtype=np.int64)
    with_covariance = covariance.shape[0] > 0
    first = 0
    for k in range(ends.shape[0]):
        for i in range(first, ends[k]):
            flags = status[i]
            valid[i] = pose_ok[i] and flags & _NO_CONTACT == 0
            if not pose_ok[i]:
                continue
            counts[k, 0] += 1
            if flags & _MULTI:
                counts[k, 2] += 1
            if not valid[i]:
                continue
            counts[k, 1] += 1
            if flags & _AMBIGUOUS_CONTACT:
                counts[k, 3] += 1
            if with_covariance:
                if flags & _TIP_WITHIN_NOISE:
                    counts[k, 4] += 1
                if not np.isfinite(covariance[i]).all():
                    counts[k, 5] += 1
        first = ends[k]
    return valid, counts


TIP_SIGMAS = 3.0
"""With a wrench covariance, a first zero of the curvature within this many std of s1 from
the tip is a tip contact (past the tip: ContactStatus.TIP_WITHIN_NOISE)."""


def reconstruct_si(q_WC_xyzw: NDArray[np.float64], p_WC_m: NDArray[np.float64],
                   f0_C_n: NDArray[np.float64], m0_C_nm: NDArray[np.float64],
                   rod: RodScale | Sequence[RodScale] | NDArray[np.float64],
                   wrench_cov: NDArray[np.float64] | None = None,
                   tip_sigmas: float = TIP_SIGMAS, shapes: NDArray[np.float64] | None = None,
                   previous_s1_m: NDArray[np.float64] | None = None,
                   chain: NDArray[np.int64] | None = None,
                   previous_ambiguous: NDArray[np.bool_] | None = None) -> ReconstructionSI:
    """Step 2 in SI: contact points from clamp poses and wrenches as a sensor graph has them.

    Each row is converted to the paper's units with its rod (``vibrissa.units.RodScale``),
    reconstructed by :func:`reconstruct_row` and converted back, in one compiled call; a row
    gives the same bits alone or in any batch.

    Parameters
    ----------
    q_WC_xyzw : ndarray, shape (N, 4)
        Clamp orientation in W, quaternion (x, y, z, w), normalised here.
    p_WC_m : ndarray, shape (N, 3)
        Clamp position in W, m.
    f0_C_n, m0_C_nm : ndarray, shape (N, 3)
        Clamp reaction on the rod in C, N and N m (moment about the clamp point).
    rod
        L and EI of the rod: one for every row, or one per row (N) for whiskers of
        different rods, or the units of one per row (N, 3) as `vibrissa.units.rod_units`
        gives them (a caller that sees the same rows again keeps them).
    wrench_cov : ndarray, shape (6, 6) or (N, 6, 6), optional
        Covariance of the wrench noise (f0, m0) in C, N^2, N^2 m, N^2 m^2. With it, each
        row's point gets its covariance (``covariance_m2``), and a contact found within
        ``tip_sigmas`` std of s1 from the tip is a tip contact: past the tip, flagged
        TIP_WITHIN_NOISE (instead of none on the rod), before it, at the s1 found.
    tip_sigmas
        See ``wrench_cov``.
    shapes : ndarray, shape (N, 3), optional
        Each row's rod shape (``vibrissa.rods.RodShape.params``): a tapered or pre-curved
        row is the Kirchhoff rod's Step 2 (``vibrissa.reconstruct_rods``), which chooses
        among the points that fit its wrench by continuity with ``previous_s1_m`` (N,), m
        (NaN: none; ``previous_ambiguous`` (N,): whether that contact's own choice was
        ambiguous), or, where ``chain`` (N,) is >= 0, with the s1 found for that earlier row
        of the call (the same whisker's previous sample). Without: every row is straight and
        uniform.
    """
    q, p = _kernel_array(q_WC_xyzw), _kernel_array(p_WC_m)
    f0, m0 = _kernel_array(f0_C_n), _kernel_array(m0_C_nm)
    n = len(q)
    if not (q.shape[1:] == (4,) and p.shape[1:] == f0.shape[1:] == m0.shape[1:] == (3,)
            and n == len(p) == len(f0) == len(m0)):
        raise ValueError(f"q_WC_xyzw (N, 4), p_WC_m, f0_C_n, m0_C_nm (N, 3) must have the same "
                         f"number of rows, got {q.shape}, {p.shape}, {f0.shape}, {m0.shape}")
    from vibrissa.reconstruct_rods import rows_si  # (it imports this module)

    floats, ints, pose_ok = rows_si(q, p, f0, m0, *kernel_arguments(
        n, rod, wrench_cov, tip_sigmas, shapes, previous_s1_m, chain, previous_ambiguous))
    return ReconstructionSI.of_blocks(floats, ints, pose_ok, wrench_cov is not None)


KernelArguments: TypeAlias = tuple[NDArray[np.float64], NDArray[np.float64], float,
                                   NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_],
                                   NDArray[np.int64]]


def kernel_arguments(n: int, rod: RodScale | Sequence[RodScale] | NDArray[np.float64],
                     wrench_cov: NDArray[np.float64] | None = None,
                     tip_sigmas: float = TIP_SIGMAS, shapes: NDArray[np.float64] | None = None,
                     previous_s1_m: NDArray[np.float64] | None = None,
                     chain: NDArray[np.int64] | None = None,
                     previous_ambiguous: NDArray[np.bool_] | None = None) -> KernelArguments:
    """The compiled Step 2's arguments after the ``n`` rows' poses and wrenches
    (`vibrissa.reconstruct_rods.rows_si`) from those of :func:`reconstruct_si`, checked
    (ValueError): the rods' units, the wrench covariance, ``tip_sigmas``, the rods' shapes and
    each shaped row's previous contact."""
    if isinstance(rod, RodScale):
        units = rod.units  # one for every row
    else:
        units = _kernel_array(rod if isinstance(rod, np.ndarray) else rod_units(rod))
        if units.shape != (n, 3):
            raise ValueError(f"rod: {len(units)} rods for {n} rows")
    if wrench_cov is None:
        cov = _NO_COVARIANCE
    else:
        cov = np.asarray(wrench_cov, dtype=float)
        if cov.shape not in ((6, 6), (n, 6, 6)):
            raise ValueError(f"wrench_cov must have shape (6, 6) or ({n}, 6, 6), got "
                             f"{cov.shape}")
        cov = np.ascontiguousarray(cov.reshape(-1, 6, 6))
        if not (tip_sigmas >= 0.0 and math.isfinite(tip_sigmas)):
            raise ValueError(f"tip_sigmas must be a finite number >= 0, got {tip_sigmas}")
    if shapes is None:  # every row straight and uniform
        return units, cov, float(tip_sigmas), _NO_SHAPES, _NO_PREVIOUS, _NO_AMBIGUOUS, _NO_CHAIN
    params = _kernel_array(np.asarray(shapes, dtype=float))
    before = (np.full(n, np.nan) if previous_s1_m is None
              else _kernel_array(np.asarray(previous_s1_m, dtype=float)))
    links = (np.full(n, -1, dtype=np.int64) if chain is None
             else np.ascontiguousarray(chain, dtype=np.int64))
    uncertain = (np.zeros(n, dtype=np.bool_) if previous_ambiguous is None
                 else np.ascontiguousarray(previous_ambiguous, dtype=np.bool_))
    if params.shape != (n, 3):
        raise ValueError(f"shapes must have shape ({n}, 3), got {params.shape}")
    if (before.shape != (n,) or links.shape != (n,) or uncertain.shape != (n,)
            or not np.all(links < np.arange(n))):
        raise ValueError("previous_s1_m, previous_ambiguous and chain must have one entry "
                         "per row, chain pointing to earlier rows")
    return units, cov, float(tip_sigmas), params, before, uncertain, links


_NO_COVARIANCE = np.empty((0, 6, 6))  # the kernels' "no wrench covariance"
_NO_SHAPES, _NO_PREVIOUS, _NO_CHAIN = np.empty((0, 3)), np.empty(0), np.empty(0, dtype=np.int64)
_NO_AMBIGUOUS = np.empty(0, dtype=np.bool_)
"""The kernel's "every row a straight uniform rod"."""


def _kernel_array(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """``a`` as the compiled kernels take it: float64 and C-contiguous, read-only or not (the
    kernels only read their inputs, so a decoded message's arrays, read-only views of its
    bytes, go in as they are); a copy only where it is not. Cheaper than `np.require`, whose
    checks cost more than Step 2 of a small tick."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous:
        return a
    return np.array(a, dtype=np.float64, order="C")


@inlined
def _row_si(q_xyzw: NDArray[np.float64], p0: NDArray[np.float64], f0: NDArray[np.float64],
            m0: NDArray[np.float64], length_m: float, force_n: float, moment_nm: float,
            cov: NDArray[np.float64], tip_sigmas: float, point: NDArray[np.float64],
            force: NDArray[np.float64], covariance: NDArray[np.float64],
            work: NDArray[np.float64]) -> tuple[bool, float, int, int]:
    """:func:`reconstruct_si` of one row: whether the pose is usable, then s1 (m), phase and
    status, with the point (m) and force (N) written into ``point`` and ``force``, and with a
    wrench covariance ``cov`` (6, 6; else 0 rows) the point's into ``covariance`` (3, 3);
    ``work`` (19, 6) is scratch space."""
    if not row_in_rod_units(q_xyzw, p0, f0, m0, length_m, force_n, moment_nm, work):
        return False, math.nan, 0, 0
    rotation, p0_L, f0_L, m0_L = work[15:18, 0:3], work[18, 0:3], work[18, 3:6], work[17, 3:6]
    tip_band = 0.0
    dot_band = twist_band = -1.0
    known = False
    if cov.shape[0] > 0:
        dot_band, twist_band = single_contact_bands(f0, m0, cov, MULTI_SIGMAS)
        dot_band /= force_n * moment_nm  # in units of L
        twist_band /= moment_nm
        jacobian = work[0:4]
        known = jacobian_into(f0_L, m0_L, jacobian, work[4:7, 0:3])
        if known:
            s1_var = propagate_row(jacobian, rotation, length_m, force_n, moment_nm, cov,
                                   covariance, work[7:15])
            tip_band = tip_sigmas * math.sqrt(max(s1_var, 0.0))
    s1, phase, _psi, status = reconstruct_row(p0_L, f0_L, m0_L, True, rotation, point, force,
                                              tip_band, dot_band, twist_band)
    return row_in_si(s1, phase, status, length_m, force_n, point, force, cov, known, covariance)


@inlined
def row_in_rod_units(q_xyzw: NDArray[np.float64], p0: NDArray[np.float64],
                     f0: NDArray[np.float64], m0: NDArray[np.float64], length_m: float,
                     force_n: float, moment_nm: float, work: NDArray[np.float64]) -> bool:
    """A row of Step 2 in SI in its rod's units, into ``work`` (19, 6): R_WC at [15:18, 0:3],
    p0 at [18, 0:3], f0 at [18, 3:6], m0 at [17, 3:6]; False where the clamp quaternion has
    no finite, nonzero length."""
    rotation = work[15:18, 0:3]
    norm2 = quaternion_matrix(q_xyzw, rotation)
    if not (norm2 > 0.0 and norm2 < math.inf):
        return False
    for j in range(3):
        work[18, j], work[18, 3 + j] = p0[j] / length_m, f0[j] / force_n
        work[17, 3 + j] = m0[j] / moment_nm
    return True


@inlined
def row_in_si(s1: float, phase: int, status: int, length_m: float, force_n: float,
              point: NDArray[np.float64], force: NDArray[np.float64], cov: NDArray[np.float64],
              known: bool, covariance: NDArray[np.float64]) -> tuple[bool, float, int, int]:
    """A row's Step 2 in its rod's units back in SI (the point and force in place): a result
    that overflows is NON_FINITE_INPUT; the covariance NaN where it is not known."""
    for j in range(3):
        point[j] *= length_m
        force[j] *= force_n
    s1 *= length_m
    if status & _NO_CONTACT == 0 and _overflows(point, force):
        point[:] = math.nan
        s1, phase, status = math.nan, PHASE_NONE, status | _NON_FINITE
    if cov.shape[0] > 0 and not (known and status & _NO_CONTACT == 0):
        covariance[:, :] = math.nan
    return True, s1, phase, status
