"""The compiled kernels of Step 1: the equilibrium conditions of one step and Newton's method
on them, one row (one sweep attempt) at a time (``vibrissa.compiled``).

``vibrissa.sweep`` states the conditions and drives the sweeps; these kernels evaluate them.
A row is q = (psi, Fu, Fv, kappa0) in the clamp frame C of its step, the clamp pose X_WC, the
friction mu, the anchor (previous or held contact point, W), the mode (tip, tangential, stick)
and whether psi is locked, and its object: the quadric g(p_B) = p_B' Q p_B + l' p_B + c in its
body frame B, placed at X_WB (the rows of one call may touch different objects: the whiskers of
a scene are solved together). Per row the arithmetic is that of the conditions in
``vibrissa.sweep``'s module docstring, written out for scalars: a sweep's step costs a few
microseconds of arithmetic instead of the calls of numpy array code on one row.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from vibrissa.compiled import compiled
from vibrissa.elastica import planar_contact_scalar

FloatArray = NDArray[np.float64]

MODE_TIP, MODE_TANGENTIAL, MODE_STICK, MODE_STICK_TANGENTIAL = 0, 1, 2, 3
"""Sliding at the tip, sliding tangentially, the tip held at the anchor, a tangential contact
held at the anchor (the contact point stays on the object, the rod rolls over it: s1 free)."""
NEWTON_TOL = 1e-12
DIRECTION_TOL = 1e-8
"""Tolerance of the two friction-direction residuals of a sliding row: the chord of eq. 7 can
be as short as 1e-6 (first step, nearly stuck contacts), and round-off in P1 then limits the
direction equations to about 1e-16 / |chord|."""
NEWTON_MAX_ITER = 40
STATE_WIDTH = 23
"""A row's state: residual 0:4, p1 4:7, s1 7, tangent 8:11, normal 11:14, force 14:17,
kappa0 17, e_w 18:21, status 21, converged 22 (1 or 0)."""


@compiled
def quadric_gap(p: FloatArray, Q: FloatArray, lin: FloatArray, c: float, R_WB: FloatArray,
                p_WB: FloatArray, normal: FloatArray) -> float:
    """First-order signed distance of ``p`` (W) to the object's quadric g(p_B) = p_B' Q p_B +
    lin' p_B + c placed at X_WB (g / |grad g|), its outward normal in W into ``normal``."""
    p_B = np.empty(3)
    for j in range(3):
        p_B[j] = ((p[0] - p_WB[0]) * R_WB[0, j] + (p[1] - p_WB[1]) * R_WB[1, j]
                  + (p[2] - p_WB[2]) * R_WB[2, j])
    g = c
    grad = np.empty(3)
    for j in range(3):
        qp = p_B[0] * Q[0, j] + p_B[1] * Q[1, j] + p_B[2] * Q[2, j]
        g += p_B[j] * qp + lin[j] * p_B[j]
        grad[j] = 2.0 * qp + lin[j]
    grad_norm = math.sqrt(grad[0] ** 2 + grad[1] ** 2 + grad[2] ** 2)
    for i in range(3):
        normal[i] = (R_WB[i, 0] * grad[0] + R_WB[i, 1] * grad[1] + R_WB[i, 2] * grad[2]) / grad_norm
    return g / grad_norm


@compiled
def coulomb_direction(p: FloatArray, anchor: FloatArray, normal: FloatArray, mu: float,
                      direction: FloatArray) -> None:
    """The unit direction of a sliding contact's force (eq. 7) into ``direction``: along
    n + mu t, t the unit chord from ``p`` towards ``anchor`` (its last point) in the tangent
    plane of ``normal``; n alone where the chord is zero."""
    chord = np.empty(3)
    for i in range(3):
        chord[i] = anchor[i] - p[i]
    along_n = chord[0] * normal[0] + chord[1] * normal[1] + chord[2] * normal[2]
    for i in range(3):
        chord[i] -= along_n * normal[i]
    chord_length = math.sqrt(chord[0] ** 2 + chord[1] ** 2 + chord[2] ** 2)
    for i in range(3):
        slide = chord[i] / chord_length if chord_length > 0 else 0.0
        direction[i] = normal[i] + mu * slide
    size = math.sqrt(direction[0] ** 2 + direction[1] ** 2 + direction[2] ** 2)
    for i in range(3):
        direction[i] /= size


@compiled
def evaluate_row(q: FloatArray, p_WC: FloatArray, R_WC: FloatArray, mu: float,
                 anchor: FloatArray, mode: int, locked: bool, Q: FloatArray, lin: FloatArray,
                 c: float, R_WB: FloatArray, p_WB: FloatArray, out: FloatArray) -> None:
    """The state of one row at ``q`` into ``out`` (``STATE_WIDTH``)."""
    psi, fu, fv, kappa0 = q[0], q[1], q[2], q[3]
    u1, v1, s1, phi1, status = planar_contact_scalar(fu, fv, kappa0)
    cp, sp = math.cos(psi), math.sin(psi)
    e_u = np.empty(3)
    e_w = np.empty(3)
    e_v = np.empty(3)
    for i in range(3):
        e_u[i] = R_WC[i, 0] * cp + R_WC[i, 1] * sp + R_WC[i, 2] * 0.0
        e_w[i] = R_WC[i, 0] * sp + R_WC[i, 1] * -cp + R_WC[i, 2] * 0.0
        e_v[i] = R_WC[i, 2]
    cos1, sin1 = math.cos(phi1), math.sin(phi1)
    p1 = np.empty(3)
    tangent = np.empty(3)
    force = np.empty(3)
    for i in range(3):
        p1[i] = p_WC[i] + u1 * e_u[i] + v1 * e_v[i]
        tangent[i] = cos1 * e_u[i] + sin1 * e_v[i]
        force[i] = fu * e_u[i] + fv * e_v[i]
    normal = np.empty(3)
    gap = quadric_gap(p1, Q, lin, c, R_WB, p_WB, normal)
    direction = np.empty(3)
    coulomb_direction(p1, anchor, normal, mu, direction)
    f = math.hypot(fu, fv)
    in_plane = direction[0] * e_w[0] + direction[1] * e_w[1] + direction[2] * e_w[2]
    d_u = direction[0] * e_u[0] + direction[1] * e_u[1] + direction[2] * e_u[2]
    d_v = direction[0] * e_v[0] + direction[1] * e_v[1] + direction[2] * e_v[2]
    along = (fu * d_v - fv * d_u) / f
    if locked:
        in_plane = psi
    tangential = tangent[0] * normal[0] + tangent[1] * normal[1] + tangent[2] * normal[2]
    held = mode == MODE_STICK or mode == MODE_STICK_TANGENTIAL
    if held:
        out[0] = s1 - 1.0 if mode == MODE_STICK else tangential
        out[1], out[2], out[3] = p1[0] - anchor[0], p1[1] - anchor[1], p1[2] - anchor[2]
    else:
        out[0] = tangential if mode == MODE_TANGENTIAL else s1 - 1.0
        out[1], out[2], out[3] = gap, in_plane, along
    for i in range(3):
        out[4 + i] = p1[i]
        out[8 + i] = tangent[i]
        out[11 + i] = normal[i]
        out[14 + i] = force[i]
        out[18 + i] = e_w[i]
    out[7] = s1
    out[17] = kappa0
    out[21] = status
    # converged: strict geometry; a sliding row's friction direction to DIRECTION_TOL only
    direction_tol = NEWTON_TOL if held else DIRECTION_TOL
    converged = (abs(out[0]) < NEWTON_TOL and abs(out[1]) < NEWTON_TOL
                 and abs(out[2]) < direction_tol and abs(out[3]) < direction_tol)
    out[22] = 1.0 if converged else 0.0


@compiled
def _residual_norm(state: FloatArray) -> float:
    """max |residual|, NaN if any is NaN (as numpy's max)."""
    worst = 0.0
    for i in range(4):
        value = abs(state[i])
        if value != value:
            return math.nan
        worst = max(worst, value)
    return worst


@compiled
def newton_row(q0: FloatArray, p_WC: FloatArray, R_WC: FloatArray, mu: float,
               anchor: FloatArray, mode: int, locked: bool, Q: FloatArray, lin: FloatArray,
               c: float, R_WB: FloatArray, p_WB: FloatArray, q: FloatArray,
               state: FloatArray) -> None:
    """Newton's method on one row from ``q0``: forward-difference Jacobian (loads perturbed
    relative to the row's load), at most 0.3 rad of psi per step, step halving until the
    residual decreases; the solution into ``q`` and its state into ``state``."""
    for j in range(4):
        q[j] = q0[j]
    evaluate_row(q, p_WC, R_WC, mu, anchor, mode, locked, Q, lin, c, R_WB, p_WB, state)
    norm = _residual_norm(state)
    probe_state = np.empty(STATE_WIDTH)
    trial_state = np.empty(STATE_WIDTH)
    probe = np.empty(4)
    trial = np.empty(4)
    jac = np.empty((4, 4))
    rhs = np.empty(4)
    h = np.empty(4)
    for _ in range(NEWTON_MAX_ITER):
        if norm < NEWTON_TOL or not math.isfinite(norm):
            return
        load = max(abs(q[1]), abs(q[2]), abs(q[3]))
        for j in range(4):
            scale = 1.0 if j == 0 else 1e-3 * load
            h[j] = max(1e-8 * max(abs(q[j]), scale), 1e-300)
        for j in range(4):
            for k in range(4):
                probe[k] = q[k]
            probe[j] += h[j]
            evaluate_row(probe, p_WC, R_WC, mu, anchor, mode, locked, Q, lin, c, R_WB, p_WB,
                         probe_state)
            for i in range(4):
                jac[i, j] = (probe_state[i] - state[i]) / h[j]
        for i in range(4):
            rhs[i] = -state[i]
        delta = _solve(jac, rhs)
        limit = min(1.0, 0.3 / max(abs(delta[0]), 1e-300))  # keep the plane from spinning
        for j in range(4):
            delta[j] *= limit
        accepted = False
        for _halving in range(10):
            for j in range(4):
                trial[j] = q[j] + delta[j]
            evaluate_row(trial, p_WC, R_WC, mu, anchor, mode, locked, Q, lin, c, R_WB, p_WB,
                         trial_state)
            trial_norm = _residual_norm(trial_state)
            if trial_norm < norm or trial_norm < NEWTON_TOL:
                for j in range(4):
                    q[j] = trial[j]
                for k in range(STATE_WIDTH):
                    state[k] = trial_state[k]
                norm = trial_norm
                accepted = True
                break
            for j in range(4):
                delta[j] *= 0.5
        if not accepted:
            return  # stalled: no further progress on this row


@compiled
def _solve(jac: FloatArray, rhs: FloatArray) -> FloatArray:
    """jac^-1 rhs; least squares where jac is singular; NaN where either is not finite (the
    Newton step then fails as a stall; LAPACK refuses such input, and numba cannot raise
    again inside ``except``)."""
    if not (np.all(np.isfinite(jac)) and np.all(np.isfinite(rhs))):
        return np.full(rhs.shape[0], np.nan)
    try:
        x = np.linalg.solve(jac, rhs)
    except Exception:  # noqa: BLE001 - numba: LinAlgError for a singular matrix
        x = np.linalg.lstsq(jac, rhs)[0]
    return x.astype(np.float64)


@compiled
def evaluate_rows(q: FloatArray, p_WC: FloatArray, R_WC: FloatArray, mu: FloatArray,
                  anchor: FloatArray, mode: NDArray[np.int64], locked: NDArray[np.bool_],
                  Q: FloatArray, lin: FloatArray, c: FloatArray, R_WB: FloatArray,
                  p_WB: FloatArray) -> FloatArray:
    """``evaluate_row`` of every row, each with its object (Q (n, 3, 3), lin (n, 3), c (n,),
    R_WB (n, 3, 3), p_WB (n, 3)): states (n, ``STATE_WIDTH``)."""
    n = q.shape[0]
    out = np.empty((n, STATE_WIDTH))
    for r in range(n):
        evaluate_row(q[r], p_WC[r], R_WC[r], mu[r], anchor[r], mode[r], locked[r], Q[r], lin[r],
                     c[r], R_WB[r], p_WB[r], out[r])
    return out


@compiled
def newton_rows(q0: FloatArray, p_WC: FloatArray, R_WC: FloatArray, mu: FloatArray,
                anchor: FloatArray, mode: NDArray[np.int64], locked: NDArray[np.bool_],
                Q: FloatArray, lin: FloatArray, c: FloatArray, R_WB: FloatArray, p_WB: FloatArray
                ) -> tuple[FloatArray, FloatArray]:
    """``newton_row`` of every row, each with its object (as ``evaluate_rows``): solutions
    q (n, 4) and their states."""
    n = q0.shape[0]
    q = np.empty((n, 4))
    out = np.empty((n, STATE_WIDTH))
    for r in range(n):
        newton_row(q0[r], p_WC[r], R_WC[r], mu[r], anchor[r], mode[r], locked[r], Q[r], lin[r],
                   c[r], R_WB[r], p_WB[r], q[r], out[r])
    return q, out


@compiled
def admissible_rows(state: FloatArray, mode: NDArray[np.int64], mu: FloatArray,
                    previous: FloatArray, jump: FloatArray) -> NDArray[np.bool_]:
    """Which states (n, ``STATE_WIDTH``) are physically acceptable (n,): the contact pushes
    (F . n > 0), it is at most its row's ``jump`` (n,) from the previous contact point (n, 3),
    the rod stays outside the object (at the tip its tangent does not point out of the object; a
    tangential contact lies on the rod, 0 < s1 <= 1) and a sticking contact's force is inside
    the friction cone |F_t| <= mu F_n."""
    n = state.shape[0]
    ok = np.empty(n, dtype=np.bool_)
    for r in range(n):
        row = state[r]
        fn = row[14] * row[11] + row[15] * row[12] + row[16] * row[13]
        dx, dy, dz = row[4] - previous[r, 0], row[5] - previous[r, 1], row[6] - previous[r, 2]
        good = row[21] == 0 and fn > 0 and math.sqrt(dx * dx + dy * dy + dz * dz) <= jump[r]
        if mode[r] == MODE_TANGENTIAL or mode[r] == MODE_STICK_TANGENTIAL:
            good = good and row[7] <= 1.0 and row[7] > 0.0
        else:
            good = good and row[8] * row[11] + row[9] * row[12] + row[10] * row[13] <= 1e-9
        if mode[r] == MODE_STICK or mode[r] == MODE_STICK_TANGENTIAL:
            tx, ty, tz = row[14] - fn * row[11], row[15] - fn * row[12], row[16] - fn * row[13]
            good = good and math.sqrt(tx * tx + ty * ty + tz * tz) <= mu[r] * fn * (1.0 + 1e-9)
        ok[r] = good
    return ok
