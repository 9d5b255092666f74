"""Step 2 for tapered and pre-curved rods: the contact point from the clamp's wrench alone.

The wrench (f0, m0) gives the internal moment everywhere along the loaded part of the rod,
m(s) = r(s) x f0 - m0 (``vibrissa.rods``), and the rod's line by integrating the Kirchhoff rod
from the clamp; the contact is where the moment vanishes, the free part beyond it carrying
nothing. m(s) is normal to the force F = -f0 (a single contact has m0 . f0 = 0), and
l(s) = F x m(s) / |F|^2 is the offset of the force's line from the rod's point r(s): a contact
is a point where |l| has a local minimum (l . d3 changes sign from + to -) at which the line
passes through the rod, |l| <= ``LINE_TOL`` (L), widened by the wrench's noise where it is
known (a measured wrench's line misses the rod by about its noise over |F|). Integrated to
``S_MAX`` past the tip, so that a tip contact is found however round-off puts its zero.

A wrench may be satisfied by more than one point along the rod (a line meets a pre-curved
arc twice; the loaded line, continued past the contact, can meet the force's line again):
every such point is a candidate. One candidate is the contact. Of several, a sample alone
takes the first from the clamp; along a stream, the one nearest the previous contact. The
choice is flagged ``AMBIGUOUS_CONTACT`` where it is not determined: several candidates and no
previous contact, or a previous one whose own choice was not determined (a stream that began
ambiguous stays so while the other candidates last), or not exactly one candidate within
``CONTINUITY_L`` of it.

The straight uniform rod has its closed form (``vibrissa.reconstruct``): :func:`reconstruct_rod`
hands it there, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa.compiled import compiled
from vibrissa.elastica import S1_TOLERANCE
from vibrissa.frames import rotate_vector
from vibrissa.reconstruct import (
    MULTI_SIGMAS,
    PHASE_NONE,
    PHASE_TANGENTIAL,
    PHASE_TIP,
    TIP_TOLERANCE,
    Reconstruction,
    _as_vectors,
    _row_si,
    reconstruct,
    row_in_rod_units,
    row_in_si,
    single_contact_bands,
    single_contact_excess,
    tally_rows,
)
from vibrissa.rods import N_STEPS, RodShape, clamp_state, rk4_step
from vibrissa.status import NO_CONTACT, ContactStatus
from vibrissa.uncertainty import propagate_row

FloatArray = NDArray[np.float64]

LINE_TOL = 1e-6
"""How far (L) the force's line may pass from the rod at a contact."""
CONTINUITY_L = 0.05
"""Along a stream, a candidate this near (arc length, L) the previous contact continues it."""
TIP_STEP = 0.25 / N_STEPS
"""How far past the tip the rod is integrated (a quarter step, L): a tip contact's zero may
fall just past it by round-off, or by the noise (TIP_WITHIN_NOISE); a thin tip's rod,
continued much further, can curl through the force's line and back within one step."""
S_MAX = 1.0 + TIP_STEP
MAX_CANDIDATES = 8

_NO_CONTACT = int(NO_CONTACT)
_NO_FORCE = int(ContactStatus.NO_FORCE)
_NON_FINITE = int(ContactStatus.NON_FINITE_INPUT)
_BEYOND = int(ContactStatus.CONTACT_BEYOND_ROD)
_TIP_WITHIN_NOISE = int(ContactStatus.TIP_WITHIN_NOISE)
_MULTI = int(ContactStatus.MULTI_CONTACT)
_AMBIGUOUS = int(ContactStatus.AMBIGUOUS_CONTACT)


@compiled
def _offset(y: FloatArray, f0: FloatArray, m0: FloatArray, out: FloatArray) -> float:
    """l = F x m / |F|^2 at state ``y`` into ``out``; returns l . d3."""
    mx = y[1] * f0[2] - y[2] * f0[1] - m0[0]
    my = y[2] * f0[0] - y[0] * f0[2] - m0[1]
    mz = y[0] * f0[1] - y[1] * f0[0] - m0[2]
    f2 = f0[0] * f0[0] + f0[1] * f0[1] + f0[2] * f0[2]
    # F = -f0
    out[0] = -(f0[1] * mz - f0[2] * my) / f2
    out[1] = -(f0[2] * mx - f0[0] * mz) / f2
    out[2] = -(f0[0] * my - f0[1] * mx) / f2
    qw, qx, qy, qz = y[3], y[4], y[5], y[6]
    d3x, d3y, d3z = 2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 1 - 2 * (qx * qx + qy * qy)
    return out[0] * d3x + out[1] * d3y + out[2] * d3z


@compiled
def _side(y: FloatArray, f0: FloatArray, m0: FloatArray) -> float:
    """(F x m) . d3 at state ``y``: the sign of l . d3 (`_offset`) without its divisions."""
    mx = y[1] * f0[2] - y[2] * f0[1] - m0[0]
    my = y[2] * f0[0] - y[0] * f0[2] - m0[1]
    mz = y[0] * f0[1] - y[1] * f0[0] - m0[2]
    qw, qx, qy, qz = y[3], y[4], y[5], y[6]
    d3x, d3y, d3z = 2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 1 - 2 * (qx * qx + qy * qy)
    return -((f0[1] * mz - f0[2] * my) * d3x + (f0[2] * mx - f0[0] * mz) * d3y
             + (f0[0] * my - f0[1] * mx) * d3z)


@compiled
def contact_candidates(f0: FloatArray, m0: FloatArray, params: FloatArray,
                       s_out: FloatArray, y_out: FloatArray, line_band: float = 0.0) -> int:
    """Every point of the rod (up to ``S_MAX``) where the moment of the wrench vanishes (the
    force's line within ``LINE_TOL`` + ``line_band`` of the rod): their arc lengths into
    ``s_out`` and states into ``y_out`` (``MAX_CANDIDATES`` rows, 7), in order from the clamp;
    returns how many."""
    y = clamp_state()
    nxt, probe, offset = np.empty(7), np.empty(7), np.empty(3)
    g = _side(y, f0, m0)
    count = 0
    grid = 1.0 / N_STEPS  # `vibrissa.rods.integrate_to`'s steps
    for k in range(N_STEPS + 1):  # the rod's steps, then a quarter step past its tip
        s = k * grid
        h = grid if k < N_STEPS else TIP_STEP
        rk4_step(s, h, y, f0, m0, params, nxt)
        g_next = _side(nxt, f0, m0)
        if g > 0.0 and g_next <= 0.0 and count < MAX_CANDIDATES:
            # regula falsi (Illinois) on the length of a partial step from y
            lo, hi, g_lo, g_hi = 0.0, h, g, g_next
            t, side = h, 0
            for _ in range(40):
                t_new = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
                if abs(t_new - t) <= 1e-13 * h:
                    t = t_new
                    break
                t = t_new
                rk4_step(s, t, y, f0, m0, params, probe)
                g_t = _side(probe, f0, m0)
                if g_t > 0.0:
                    lo, g_lo = t, g_t
                    if side == 1:
                        g_hi *= 0.5
                    side = 1
                elif g_t < 0.0:
                    hi, g_hi = t, g_t
                    if side == -1:
                        g_lo *= 0.5
                    side = -1
                else:
                    break
            rk4_step(s, t, y, f0, m0, params, probe)
            _offset(probe, f0, m0, offset)
            if math.sqrt(offset[0] ** 2 + offset[1] ** 2 + offset[2] ** 2) <= LINE_TOL + line_band:
                s_out[count] = s + t
                y_out[count, :] = probe
                count += 1
        y, nxt = nxt, y
        g = g_next
    return count


@compiled
def reconstruct_rod_row(p0_W: FloatArray, f0_C: FloatArray, m0_C: FloatArray, rotate: bool,
                        R_WC: FloatArray, params: FloatArray, previous_s1: float,
                        point: FloatArray, force: FloatArray, candidates: FloatArray,
                        tip_band: float = 0.0, dot_band: float = -1.0, line_band: float = 0.0,
                        previous_ambiguous: bool = False) -> tuple[float, int, int, int]:
    """Step 2 of one sample of a rod of ``params`` (``RodShape.params``): as
    ``vibrissa.reconstruct.reconstruct_row`` (point and force in W into ``point``, ``force``),
    with the previous contact's arc length ``previous_s1`` (NaN: none) to choose among the
    candidates, whose arc lengths go into ``candidates`` (``MAX_CANDIDATES``), and whether that
    contact's own choice was ambiguous; ``line_band`` (L) the wrench noise's miss of the
    force's line (`contact_candidates`). Returns s1, phase, status and the number of
    candidates."""
    nan = math.nan
    point[:] = nan
    fx, fy, fz = -f0_C[0], -f0_C[1], -f0_C[2]
    force[0], force[1], force[2] = rotate_vector(R_WC, fx, fy, fz) if rotate else (fx, fy, fz)
    finite = True
    for j in range(3):
        finite = finite and math.isfinite(p0_W[j]) and math.isfinite(f0_C[j]) and math.isfinite(
            m0_C[j])
    if not finite:
        return nan, PHASE_NONE, _NON_FINITE, 0
    if fx == 0.0 and fy == 0.0 and fz == 0.0:
        return nan, PHASE_NONE, _NO_FORCE, 0
    if single_contact_excess(f0_C, m0_C, dot_band, math.inf) > 1.0:
        return nan, PHASE_NONE, _MULTI, 0
    states = np.empty((MAX_CANDIDATES, 7))
    found = contact_candidates(f0_C, m0_C, params, candidates, states, line_band)
    status = 0
    count = 0  # candidates on the rod (within the tip's band)
    for i in range(found):
        if candidates[i] <= 1.0 + max(S1_TOLERANCE, tip_band):
            count += 1
    if count == 0:
        return nan, PHASE_NONE, _BEYOND, 0
    chosen = 0
    if count > 1 and previous_s1 == previous_s1:  # a previous contact: the candidates near it
        near = 0
        best = math.inf
        for i in range(count):
            gap = abs(candidates[i] - previous_s1)
            if gap <= CONTINUITY_L:
                near += 1
            if gap < best:
                best, chosen = gap, i
        if near != 1 or previous_ambiguous:
            status |= _AMBIGUOUS
    elif count > 1:
        status |= _AMBIGUOUS
    s1 = candidates[chosen]
    if s1 > 1.0 + S1_TOLERANCE:
        status |= _TIP_WITHIN_NOISE
    px, py, pz = states[chosen, 0], states[chosen, 1], states[chosen, 2]
    if rotate:
        px, py, pz = rotate_vector(R_WC, px, py, pz)
    point[0], point[1], point[2] = p0_W[0] + px, p0_W[1] + py, p0_W[2] + pz
    s1 = min(s1, 1.0)
    phase = PHASE_TIP if s1 >= 1.0 - max(TIP_TOLERANCE, tip_band) else PHASE_TANGENTIAL
    return s1, phase, status, count


@compiled
def _rows(p0_W: FloatArray, f0_C: FloatArray, m0_C: FloatArray, R_WC: FloatArray,
          params: FloatArray, previous_s1: FloatArray, chain: bool
          ) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.int64], FloatArray,
                     NDArray[np.int64], FloatArray, NDArray[np.int64]]:
    """:func:`reconstruct_rod_row` of every row; with ``chain`` a row's previous contact is the
    row before it (a stream of one rod), else ``previous_s1[i]``. R_WC: 0, 1 or N rows."""
    n = p0_W.shape[0]
    point, force = np.empty((n, 3)), np.empty((n, 3))
    s1, psi = np.empty(n), np.empty(n)
    phase, status = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    candidates = np.full((n, MAX_CANDIDATES), np.nan)
    count = np.empty(n, dtype=np.int64)
    identity = np.eye(3)
    rotate, per_row = R_WC.shape[0] > 0, R_WC.shape[0] > 1
    previous = previous_s1[0] if chain and n > 0 else math.nan
    uncertain = False  # (chain) whether the previous row's choice was ambiguous
    for i in range(n):
        r = R_WC[i if per_row else 0] if rotate else identity
        before = previous if chain else previous_s1[i]
        s1[i], phase[i], status[i], count[i] = reconstruct_rod_row(
            p0_W[i], f0_C[i], m0_C[i], rotate, r, params, before, point[i], force[i],
            candidates[i], 0.0, -1.0, 0.0, chain and uncertain)
        if chain:
            contact = status[i] & _NO_CONTACT == 0
            previous = s1[i] if contact else math.nan
            uncertain = contact and status[i] & _AMBIGUOUS != 0
        psi[i] = math.nan
        if status[i] & _NO_CONTACT == 0:
            dx, dy, dz = point[i, 0] - p0_W[i, 0], point[i, 1] - p0_W[i, 1], point[i, 2] - p0_W[
                i, 2]
            if rotate:  # back into C: R^T
                dx, dy = (r[0, 0] * dx + r[1, 0] * dy + r[2, 0] * dz,
                          r[0, 1] * dx + r[1, 1] * dy + r[2, 1] * dz)
            psi[i] = math.atan2(dy, dx)
    return point, s1, psi, phase, force, status, candidates, count


def reconstruct_rod(p0: ArrayLike, f0: ArrayLike, m0: ArrayLike, shape: RodShape,
                    R_WC: ArrayLike | None = None, previous_s1: ArrayLike | None = None,
                    stream: bool = False) -> tuple[Reconstruction, FloatArray]:
    """Step 2 for a rod of ``shape``: :func:`vibrissa.reconstruct.reconstruct`'s arguments and
    result, and every candidate's arc length (N, ``MAX_CANDIDATES``; NaN-padded).

    ``previous_s1`` (N,) is each sample's previous contact (NaN: none); with ``stream`` the rows
    are one rod's samples in time order and each row's previous contact is the row before's
    (none after a row without contact; ``previous_s1``, if given, is the first row's). ``psi``
    is the contact's azimuth about the clamp axis (C). The straight uniform rod is
    :func:`reconstruct` itself (one candidate, the first zero of the curvature).
    """
    p0_W, f0_C, m0_C = (np.ascontiguousarray(_as_vectors(n, v))
                        for n, v in (("p0", p0), ("f0", f0), ("m0", m0)))
    n = len(p0_W)
    if not p0_W.shape == f0_C.shape == m0_C.shape:
        raise ValueError(f"p0, f0, m0 must have the same number of samples, got {p0_W.shape}, "
                         f"{f0_C.shape}, {m0_C.shape}")
    if shape.uniform:
        result = reconstruct(p0_W, f0_C, m0_C, R_WC)
        first = np.full((n, MAX_CANDIDATES), np.nan)
        first[:, 0] = np.where(result.valid, result.s1, np.nan)
        return result, first
    rotation = np.empty((0, 3, 3))
    if R_WC is not None:
        rotation = np.ascontiguousarray(np.asarray(R_WC, dtype=float).reshape(-1, 3, 3))
        if len(rotation) not in (1, n):
            raise ValueError(f"R_WC must have shape (3, 3) or ({n}, 3, 3), got "
                             f"{np.shape(R_WC)}")
    previous = np.full(n, np.nan) if previous_s1 is None else np.broadcast_to(
        np.asarray(previous_s1, dtype=float), (n,)).copy()
    point, s1, psi, phase, force, status, candidates, _count = _rows(
        p0_W, f0_C, m0_C, rotation, shape.params, previous, stream)
    return Reconstruction(point=point, s1=s1, phase=phase, psi=psi, force=force,
                          status=status), candidates


@compiled
def _nearest(f0: FloatArray, m0: FloatArray, params: FloatArray, s1: float, s_out: FloatArray,
             y_out: FloatArray, line_band: float) -> int:
    """The row of the candidate nearest ``s1`` in ``s_out``/``y_out`` (-1: none)."""
    found = contact_candidates(f0, m0, params, s_out, y_out, line_band)
    best, chosen = math.inf, -1
    for i in range(found):
        if abs(s_out[i] - s1) < best:
            best, chosen = abs(s_out[i] - s1), i
    return chosen


@compiled
def rod_jacobian(f0: FloatArray, m0: FloatArray, params: FloatArray, s1: float,
                 jacobian: FloatArray, line_band: float = 0.0) -> bool:
    """d(P1 - P0, s1)/d(f0, m0) (4, 6) in C, paper units, of the contact at ``s1`` (rows x, y,
    z of the point, then s1; as ``vibrissa.uncertainty.point_jacobian``), by forward
    differences of the rod's Step 2 (each column one more integration, the candidate nearest
    the contact); False where the contact is not found again (a fold of the wrench's map)."""
    s_out, y_out = np.empty(MAX_CANDIDATES), np.empty((MAX_CANDIDATES, 7))
    base = _nearest(f0, m0, params, s1, s_out, y_out, line_band)
    if base < 0:
        return False
    p, s = y_out[base, :3].copy(), s_out[base]
    f, m = f0.copy(), m0.copy()
    scale = math.sqrt(f0[0] ** 2 + f0[1] ** 2 + f0[2] ** 2 + m0[0] ** 2 + m0[1] ** 2
                      + m0[2] ** 2)
    h = 1e-7 * scale
    for j in range(6):
        f[:] = f0
        m[:] = m0
        if j < 3:
            f[j] += h
        else:
            m[j - 3] += h
        k = _nearest(f, m, params, s, s_out, y_out, line_band)
        if k < 0 or abs(s_out[k] - s) > CONTINUITY_L:
            return False
        for r in range(3):
            jacobian[r, j] = (y_out[k, r] - p[r]) / h
        jacobian[3, j] = (s_out[k] - s) / h
    return True


@compiled
def _line_band(f0_L: FloatArray, cov: FloatArray, force_n: float, moment_nm: float) -> float:
    """How far (L) the wrench noise ``cov`` (SI, C) moves the force's line: m(s) = r x f0 - m0
    with |r| <= 1 moves by at most |d f0| + |d m0|, the line's offset F x m / |F|^2 by that
    over |F|; ``MULTI_SIGMAS`` std of each."""
    force_var = (cov[0, 0] + cov[1, 1] + cov[2, 2]) / (force_n * force_n)
    moment_var = (cov[3, 3] + cov[4, 4] + cov[5, 5]) / (moment_nm * moment_nm)
    f = math.sqrt(f0_L[0] ** 2 + f0_L[1] ** 2 + f0_L[2] ** 2)
    return MULTI_SIGMAS * (math.sqrt(max(force_var, 0.0)) + math.sqrt(max(moment_var, 0.0))) / f


@compiled
def _row_si_rod(q_xyzw: FloatArray, p0: FloatArray, f0: FloatArray, m0: FloatArray,
                length_m: float, force_n: float, moment_nm: float, cov: FloatArray,
                tip_sigmas: float, params: FloatArray, previous_s1_m: float,
                previous_ambiguous: bool, point: FloatArray,
                force: FloatArray, covariance: FloatArray, work: FloatArray
                ) -> tuple[bool, float, int, int]:
    """``vibrissa.reconstruct._row_si`` of a tapered or pre-curved rod (``params``), its
    previous contact at ``previous_s1_m`` (NaN: none), itself chosen ambiguously or not; the
    covariance from `rod_jacobian`."""
    if not row_in_rod_units(q_xyzw, p0, f0, m0, length_m, force_n, moment_nm, work):
        return False, math.nan, 0, 0
    rotation, p0_L, f0_L, m0_L = work[15:18, 0:3], work[18, 0:3], work[18, 3:6], work[17, 3:6]
    dot_band = -1.0
    line_band = 0.0
    if cov.shape[0] > 0:
        dot_band = single_contact_bands(f0, m0, cov, MULTI_SIGMAS)[0] / (force_n * moment_nm)
        line_band = _line_band(f0_L, cov, force_n, moment_nm)
    candidates = np.full(MAX_CANDIDATES, math.nan)
    previous = previous_s1_m / length_m
    s1, phase, status, _count = reconstruct_rod_row(
        p0_L, f0_L, m0_L, True, rotation, params, previous, point, force, candidates, 0.0,
        dot_band, line_band, previous_ambiguous)
    known = False
    if cov.shape[0] > 0 and status & (_NO_CONTACT & ~_BEYOND) == 0:
        # the std of s1 of the contact (or, none on the rod, of the first past the tip) says
        # whether it is the tip within the noise: Step 2 again with that band
        at = s1 if status & _NO_CONTACT == 0 else candidates[0]
        jacobian = work[0:4]
        known = at == at and rod_jacobian(f0_L, m0_L, params, at, jacobian, line_band)
        if known:
            s1_var = propagate_row(jacobian, rotation, length_m, force_n, moment_nm, cov,
                                   covariance, work[7:15])
            tip_band = tip_sigmas * math.sqrt(max(s1_var, 0.0))
            if tip_band > 0.0:
                s1, phase, status, _count = reconstruct_rod_row(
                    p0_L, f0_L, m0_L, True, rotation, params, previous, point, force,
                    candidates, tip_band, dot_band, line_band, previous_ambiguous)
    return row_in_si(s1, phase, status, length_m, force_n, point, force, cov, known, covariance)


@compiled
def rows_si(q_xyzw: FloatArray, p0: FloatArray, f0: FloatArray, m0: FloatArray,
            units: FloatArray, cov: FloatArray, tip_sigmas: float, params: FloatArray,
            previous_s1_m: FloatArray, previous_ambiguous: NDArray[np.bool_],
            chain: NDArray[np.int64]) -> tuple[FloatArray, NDArray[np.int32], NDArray[np.bool_]]:
    """Step 2 in SI of every row (``vibrissa.reconstruct.reconstruct_si``), each with its rod's
    units (``units``: 1 row for every row, or N; L, EI/L^2, EI/L), the wrench covariance
    ``cov`` (0 rows: none; 1: every row's; N) and its rod's shape ``params`` (N, 3; 0 rows:
    every row straight and uniform). A straight uniform row is
    ``vibrissa.reconstruct._row_si``; any other `_row_si_rod`, its previous contact the s1 (m)
    of row ``chain[i]`` of this call (an earlier row of its whisker) or, where that is -1,
    ``previous_s1_m[i]`` (NaN: none) and ``previous_ambiguous[i]`` (whether that contact's own
    choice was ambiguous). Returns two blocks and pose_ok (N), so that a call hands three
    arrays back to Python instead of seven: floats (7 N, or 16 N with ``cov``) = point (N, 3),
    force (N, 3), s1 (N), then the covariances (N, 3, 3); int32 (2 N) = phase, status."""
    n = q_xyzw.shape[0]
    with_cov = cov.shape[0] > 0
    floats = np.empty(n * (16 if with_cov else 7))
    ints = np.empty(2 * n, dtype=np.int32)
    pose_ok = np.empty(n, dtype=np.bool_)
    point, force = floats[:3 * n].reshape((n, 3)), floats[3 * n:6 * n].reshape((n, 3))
    covariance = floats[7 * n:].reshape((n if with_cov else 0, 3, 3))
    covariance[:] = math.nan
    per_row_cov, per_row_rod = cov.shape[0] > 1, units.shape[0] > 1
    row_cov, row_out = np.empty((0, 6)), np.empty((0, 3))
    work = np.empty((19, 6))
    for i in range(n):
        if with_cov:
            row_cov, row_out = cov[i if per_row_cov else 0], covariance[i]
        rod = units[i if per_row_rod else 0]
        if params.shape[0] == 0 or (params[i, 0] == 1.0 and params[i, 1] == 0.0):
            pose_ok[i], floats[6 * n + i], ints[i], ints[n + i] = _row_si(
                q_xyzw[i], p0[i], f0[i], m0[i], rod[0], rod[1], rod[2], row_cov, tip_sigmas,
                point[i], force[i], row_out, work)
        else:
            if chain[i] < 0:
                before, uncertain = previous_s1_m[i], previous_ambiguous[i]
            else:
                before = floats[6 * n + chain[i]]
                uncertain = ints[n + chain[i]] & _AMBIGUOUS != 0
            pose_ok[i], floats[6 * n + i], ints[i], ints[n + i] = _row_si_rod(
                q_xyzw[i], p0[i], f0[i], m0[i], rod[0], rod[1], rod[2], row_cov, tip_sigmas,
                params[i], before, uncertain, point[i], force[i], row_out, work)
    return floats, ints, pose_ok


@compiled
def rows_si_tallied(q_xyzw: FloatArray, p0: FloatArray, f0: FloatArray, m0: FloatArray,
                    units: FloatArray, cov: FloatArray, tip_sigmas: float, params: FloatArray,
                    previous_s1_m: FloatArray, previous_ambiguous: NDArray[np.bool_],
                    chain: NDArray[np.int64], ends: NDArray[np.int64],
                    ) -> tuple[FloatArray, NDArray[np.int32], NDArray[np.bool_],
                               NDArray[np.int64]]:
    """`rows_si` and, in the same call, the tally of its rows in groups ``ends[k-1]:ends[k]``
    (`vibrissa.reconstruct.ReconstructionSI.tally`): floats, ints, pose_ok, counts. A stream's
    tick costs one compiled call instead of two."""
    floats, ints, pose_ok = rows_si(q_xyzw, p0, f0, m0, units, cov, tip_sigmas, params,
                                    previous_s1_m, previous_ambiguous, chain)
    n = q_xyzw.shape[0]
    covariance = floats[7 * n:].reshape((n if cov.shape[0] > 0 else 0, 3, 3))
    return floats, ints, pose_ok, tally_rows(pose_ok, ints[n:], covariance, ends)[1]
