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
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa.elastica import S1_TOLERANCE, planar_contact_arrays, planar_contact_scalar
from vibrissa.status import NO_CONTACT, ContactStatus

PHASE_NONE, PHASE_TIP, PHASE_TANGENTIAL = 0, 1, 2
PHASE_NAMES = {PHASE_NONE: "none", PHASE_TIP: "tip", PHASE_TANGENTIAL: "tangential"}

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
        PHASE_TIP (1), PHASE_TANGENTIAL (2), or PHASE_NONE (0) without contact.
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
        and a status flag instead of raising. A single sample (three vectors of shape (3,))
        takes a scalar path with the same results, free of the array path's fixed cost.
    """
    p0_a, f0_a, m0_a = np.asarray(p0, dtype=float), np.asarray(f0, dtype=float), np.asarray(
        m0, dtype=float)
    if p0_a.shape == f0_a.shape == m0_a.shape == (3,):
        if R_WC is None:
            return _reconstruct_one(p0_a.tolist(), f0_a.tolist(), m0_a.tolist(), None)
        rotation = np.asarray(R_WC, dtype=float)
        if rotation.shape in ((3, 3), (1, 3, 3)):
            return _reconstruct_one(p0_a.tolist(), f0_a.tolist(), m0_a.tolist(),
                                    rotation.reshape(3, 3).tolist())
    return _reconstruct_arrays(p0_a, f0_a, m0_a, R_WC)


class Sample(NamedTuple):
    """One sample of a :class:`Reconstruction` in plain floats (its fields' row, same units)."""

    point: tuple[float, float, float]
    s1: float
    phase: int
    psi: float
    force: tuple[float, float, float]
    status: int


def reconstruct_sample(
    p0: Sequence[float], f0: Sequence[float], m0: Sequence[float],
    R_WC: Sequence[Sequence[float]] | None = None,
) -> Sample:
    """:func:`reconstruct` of one sample in plain floats: the array path step by step.

    Parameters and results as in :func:`reconstruct`, for one sample: three floats each for
    ``p0``, ``f0``, ``m0``, rows of R_WC (identity when omitted). No checks of the input
    shapes: this is the per-sample hot path (``reconstruct`` dispatches single samples here).
    """
    force_C = (-f0[0], -f0[1], -f0[2])
    m_horizontal = math.hypot(m0[0], m0[1])
    if m_horizontal > 0:
        e_u = (m0[1] / m_horizontal, -m0[0] / m_horizontal)
    else:
        f_horizontal = math.hypot(force_C[0], force_C[1])
        e_u = ((force_C[0] / f_horizontal, force_C[1] / f_horizontal) if f_horizontal > 0
               else (1.0, 0.0))
    fu = force_C[0] * e_u[0] + force_C[1] * e_u[1]
    u1, v1, s1, _phi1, status = planar_contact_scalar(fu, force_C[2], m_horizontal)
    if not all(map(math.isfinite, (*p0, *m0))):
        status |= _NON_FINITE
    if status & _NO_CONTACT == 0 and s1 > 1.0 + S1_TOLERANCE:
        status |= _BEYOND
    force = force_C if R_WC is None else _rotated(R_WC, force_C)
    if status & _NO_CONTACT:
        nan = math.nan
        return Sample((nan, nan, nan), nan, PHASE_NONE, nan, force, status)
    p1_C = (u1 * e_u[0], u1 * e_u[1], v1)
    p1 = p1_C if R_WC is None else _rotated(R_WC, p1_C)
    point = (p0[0] + p1[0], p0[1] + p1[1], p0[2] + p1[2])
    s1 = min(s1, 1.0)
    phase = PHASE_TIP if s1 >= 1.0 - TIP_TOLERANCE else PHASE_TANGENTIAL
    return Sample(point, s1, phase, math.atan2(e_u[1], e_u[0]), force, status)


def _rotated(rows: Sequence[Sequence[float]], v: tuple[float, float, float]
             ) -> tuple[float, float, float]:
    """The matrix with these rows times v."""
    x, y, z = (r[0] * v[0] + r[1] * v[1] + r[2] * v[2] for r in rows)
    return x, y, z


def _reconstruct_one(
    p0: list[float], f0: list[float], m0: list[float], R_WC: list[list[float]] | None
) -> Reconstruction:
    one = reconstruct_sample(p0, f0, m0, R_WC)
    return Reconstruction(
        point=np.array([one.point]), s1=np.array([one.s1]),
        phase=np.array([one.phase], dtype=np.int64), psi=np.array([one.psi]),
        force=np.array([one.force]), status=np.array([one.status], dtype=np.int64),
    )


_NO_CONTACT = int(NO_CONTACT)
_NON_FINITE = int(ContactStatus.NON_FINITE_INPUT)
_BEYOND = int(ContactStatus.CONTACT_BEYOND_ROD)


def _reconstruct_arrays(
    p0: NDArray[np.float64], f0: NDArray[np.float64], m0: NDArray[np.float64],
    R_WC: ArrayLike | None,
) -> Reconstruction:
    """:func:`reconstruct` vectorised over N samples."""
    p0_W, f0_C, m0_C = (_as_vectors(n, v) for n, v in (("p0", p0), ("f0", f0), ("m0", m0)))
    try:
        if not p0_W.shape == f0_C.shape == m0_C.shape:
            p0_W, f0_C, m0_C = np.broadcast_arrays(p0_W, f0_C, m0_C)
    except ValueError:
        raise ValueError(
            f"p0, f0, m0 must have the same number of samples, got {p0_W.shape}, {f0_C.shape}, {m0_C.shape}"
        ) from None
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # the flags say where
        return reconstruct_rows(p0_W, f0_C, m0_C, R_WC)


def reconstruct_rows(
    p0_W: NDArray[np.float64], f0_C: NDArray[np.float64], m0_C: NDArray[np.float64],
    R_WC: ArrayLike | None,
) -> Reconstruction:
    """:func:`reconstruct` of float arrays of shape (N, 3) (R_WC: (3, 3) or (N, 3, 3)), for
    callers that already ignore numpy's divide, invalid and overflow warnings
    (``np.errstate``): no conversion, no shape checks, no context.

    Column by column: on the few dozen rows of a tick, the cost is the number of numpy calls,
    so the rare cases are each found with one reduction and handled only when present.
    """
    force_C = -f0_C
    m_x, m_y = m0_C[:, 0], m0_C[:, 1]
    m_horizontal = np.hypot(m_x, m_y)
    # e_u = e_v x e_w with e_w = -m0/|m0| (kappa0 >= 0): (m0y, -m0x) / |m0h|.
    e_ux, e_uy = m_y / m_horizontal, -m_x / m_horizontal
    bent = m_horizontal > 0
    if np.count_nonzero(bent) < bent.size:  # an unbent rod has its plane along F (along e_x without a force)
        f_horizontal = np.hypot(force_C[:, 0], force_C[:, 1])
        along_force = f_horizontal > 0
        e_ux = np.where(bent, e_ux, np.where(along_force, force_C[:, 0] / f_horizontal, 1.0))
        e_uy = np.where(bent, e_uy, np.where(along_force, force_C[:, 1] / f_horizontal, 0.0))
    fu = force_C[:, 0] * e_ux + force_C[:, 1] * e_uy
    contact = planar_contact_arrays(fu, force_C[:, 2], m_horizontal)
    status = contact.status
    # A non-finite m0x or m0y is flagged by the planar solver (kappa0); p0 and m0z are not.
    if not math.isfinite(p0_W.sum() + m0_C.sum()):
        status[~(np.isfinite(p0_W).all(axis=1) & np.isfinite(m0_C).all(axis=1))] |= _NON_FINITE
    beyond_rod = contact.s1 > 1.0 + S1_TOLERANCE  # NaN where there is no contact: False
    if np.count_nonzero(beyond_rod):
        status[beyond_rod & (status & _NO_CONTACT == 0)] |= _BEYOND
    p1_C = np.empty_like(force_C)
    p1_C[:, 0] = contact.u1 * e_ux
    p1_C[:, 1] = contact.u1 * e_uy
    p1_C[:, 2] = contact.v1
    if R_WC is None:
        point, force = p0_W + p1_C, force_C
    else:
        rotation = np.asarray(R_WC, dtype=float)
        if rotation.shape == (1, 3, 3):
            rotation = rotation[0]
        rotate = "ij,nj->ni" if rotation.shape == (3, 3) else "nij,nj->ni"
        point = p0_W + np.einsum(rotate, rotation, p1_C)
        force = np.einsum(rotate, rotation, force_C)
    s1 = np.minimum(contact.s1, 1.0)
    phase = np.where(s1 >= 1.0 - TIP_TOLERANCE, PHASE_TIP, PHASE_TANGENTIAL)
    psi = np.arctan2(e_uy, e_ux)
    if np.count_nonzero(status):  # rare cases behind one reduction (see elastica)
        valid = (status & _NO_CONTACT) == 0
        if not valid.all():
            point = np.where(valid[:, None], point, np.nan)
            s1, psi = np.where(valid, s1, np.nan), np.where(valid, psi, np.nan)
            phase = np.where(valid, phase, PHASE_NONE)
    return Reconstruction(point=point, s1=s1, phase=phase.astype(np.int64, copy=False), psi=psi,
                          force=force, status=status)
