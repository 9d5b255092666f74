"""The compiled kernels of Step 1: the equilibrium conditions of one step and Newton's method
on them, one row (one sweep attempt) at a time (``vibrissa.compiled``).

``vibrissa.sweep`` states the conditions and drives the sweeps; these kernels evaluate them.
A row is q in the clamp frame C of its step (``Q_WIDTH`` wide: (psi, Fu, Fv, kappa0) for the
straight uniform rod, the planar elastica in closed form; (s1, F, m0) for a tapered or
pre-curved rod, the Kirchhoff rod of ``vibrissa.rods``, whose three extra conditions say that
the rod's moment vanishes at s1), the rod's ``RodShape.params``, the clamp pose X_WC, the
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
from vibrissa.rods import N_STEPS, clamp_state, frame_of, moment_at, rk4_step

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
Q_WIDTH = 7
"""A row's unknowns: (psi, Fu, Fv, kappa0, 0, 0, 0) of the planar elastica, (s1, F (3), m0
(3)) of the Kirchhoff rod."""
STATE_WIDTH = 27
"""A row's state: residual 0:7 (4:7 the Kirchhoff rod's moment at s1 over |F|, L; 0 for the
elastica), p1 7:10, s1 10, tangent 11:14, normal 14:17, force 17:20, kappa0 20 (the
elastica's), e_w 21:24 (the elastica's), status 24, converged 25 (1 or 0), the least gap of
the rod away from its contact 26 (the Kirchhoff rod's: its integration's nodes before the
contact and its free part beyond; NaN otherwise)."""
FREE_PART_POINTS = 4
"""Points of the unloaded arc beyond a Kirchhoff rod's tangential contact checked against the
object: a pre-curved rod's free part may curve into it (then the tip touches instead). Before
the contact the integration's nodes are checked: a thin tip bent hard can cross the object
just before its contact."""
MAX_S1 = 1.5
"""The largest s1 a Kirchhoff row is evaluated at (a tangential contact past the tip is
refused, `admissible_rows`; the taper's law holds to 1 / (1 - r) >= 1.05)."""


@compiled
def quadric_gap(p: FloatArray, Q: FloatArray, lin: FloatArray, c: float, R_WB: FloatArray,
                p_WB: FloatArray, normal: FloatArray) -> float:
    """First-order signed distance of ``p`` (W) to the object's quadric g(p_B) = p_B' Q p_B +
    lin' p_B + c placed at X_WB (g / |grad g|), its outward normal in W into ``normal``."""
    d0, d1, d2 = p[0] - p_WB[0], p[1] - p_WB[1], p[2] - p_WB[2]
    b0 = d0 * R_WB[0, 0] + d1 * R_WB[1, 0] + d2 * R_WB[2, 0]  # p_B (scalars: no allocation,
    b1 = d0 * R_WB[0, 1] + d1 * R_WB[1, 1] + d2 * R_WB[2, 1]  # it is called along the rod)
    b2 = d0 * R_WB[0, 2] + d1 * R_WB[1, 2] + d2 * R_WB[2, 2]
    q0 = b0 * Q[0, 0] + b1 * Q[1, 0] + b2 * Q[2, 0]
    q1 = b0 * Q[0, 1] + b1 * Q[1, 1] + b2 * Q[2, 1]
    q2 = b0 * Q[0, 2] + b1 * Q[1, 2] + b2 * Q[2, 2]
    g = c
    g += b0 * q0 + lin[0] * b0
    g += b1 * q1 + lin[1] * b1
    g += b2 * q2 + lin[2] * b2
    g0, g1, g2 = 2.0 * q0 + lin[0], 2.0 * q1 + lin[1], 2.0 * q2 + lin[2]
    grad_norm = math.sqrt(g0 ** 2 + g1 ** 2 + g2 ** 2)
    for i in range(3):
        normal[i] = (R_WB[i, 0] * g0 + R_WB[i, 1] * g1 + R_WB[i, 2] * g2) / grad_norm
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
    held = _contact_residuals(mode, s1, tangential, gap, p1, anchor, out)
    if not held:
        out[2], out[3] = in_plane, along
    out[4] = out[5] = out[6] = 0.0
    _write_state(p1, s1, tangent, normal, force, status, held, out)
    out[20] = kappa0
    out[26] = math.nan
    for i in range(3):
        out[21 + i] = e_w[i]


@compiled
def _contact_residuals(mode: int, s1: float, tangential: float, gap: float, p1: FloatArray,
                       anchor: FloatArray, out: FloatArray) -> bool:
    """The contact's residuals of a row in ``mode`` into ``out``: a held contact's four
    (s1 = 1 at the tip or tangency, the point at the anchor), a sliding one's first two (tip
    s1 = 1 or tangency, the point on the object; its friction direction is the rod model's);
    whether it is held."""
    held = mode == MODE_STICK or mode == MODE_STICK_TANGENTIAL
    if held:
        out[0] = s1 - 1.0 if mode == MODE_STICK else tangential
        out[1], out[2], out[3] = p1[0] - anchor[0], p1[1] - anchor[1], p1[2] - anchor[2]
    else:
        out[0] = tangential if mode == MODE_TANGENTIAL else s1 - 1.0
        out[1] = gap
    return held


@compiled
def _write_state(p1: FloatArray, s1: float, tangent: FloatArray, normal: FloatArray,
                 force: FloatArray, status: int, held: bool, out: FloatArray) -> None:
    """The geometry of a row's state and whether its residuals ``out[0:7]`` have converged:
    strict geometry; a sliding row's friction direction to DIRECTION_TOL only."""
    for i in range(3):
        out[7 + i] = p1[i]
        out[11 + i] = tangent[i]
        out[14 + i] = normal[i]
        out[17 + i] = force[i]
    out[10] = s1
    out[24] = status
    direction_tol = NEWTON_TOL if held else DIRECTION_TOL
    converged = (abs(out[0]) < NEWTON_TOL and abs(out[1]) < NEWTON_TOL
                 and abs(out[2]) < direction_tol and abs(out[3]) < direction_tol
                 and abs(out[4]) < NEWTON_TOL and abs(out[5]) < NEWTON_TOL
                 and abs(out[6]) < NEWTON_TOL)
    out[25] = 1.0 if converged else 0.0


@compiled
def evaluate_rod_row(q: FloatArray, p_WC: FloatArray, R_WC: FloatArray, mu: float,
                     anchor: FloatArray, mode: int, Q: FloatArray, lin: FloatArray, c: float,
                     R_WB: FloatArray, p_WB: FloatArray, params: FloatArray,
                     out: FloatArray) -> None:
    """The state of one Kirchhoff row at q = (s1, F, m0) (C) into ``out`` (``STATE_WIDTH``).

    The rod is integrated from the clamp under the wrench (-F, m0) to s1; its moment there
    (three residuals) vanishes at a contact. The contact conditions are the elastica's; the
    friction direction's two equations are F / |F| and the Coulomb direction alike along two
    axes normal to the object's normal at the anchor (both have a positive part along it)."""
    s1 = q[0]
    if not (s1 > 0.0 and s1 <= MAX_S1):
        for i in range(STATE_WIDTH):
            out[i] = math.nan
        out[24] = 1.0
        out[25] = 0.0
        return
    f0 = np.empty(3)
    m0 = np.empty(3)
    for i in range(3):
        f0[i] = -q[1 + i]
        m0[i] = q[4 + i]
    y, least = _loaded_rod(s1, f0, m0, params, p_WC, R_WC, Q, lin, c, R_WB, p_WB)
    moment = moment_at(y, f0, m0)
    frame = frame_of(y)
    p1, tangent, force, bent = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for i in range(3):
        p1[i] = p_WC[i] + R_WC[i, 0] * y[0] + R_WC[i, 1] * y[1] + R_WC[i, 2] * y[2]
        tangent[i] = R_WC[i, 0] * frame[0, 2] + R_WC[i, 1] * frame[1, 2] + R_WC[i, 2] * frame[2, 2]
        bent[i] = R_WC[i, 0] * frame[0, 0] + R_WC[i, 1] * frame[1, 0] + R_WC[i, 2] * frame[2, 0]
        force[i] = -(R_WC[i, 0] * f0[0] + R_WC[i, 1] * f0[1] + R_WC[i, 2] * f0[2])
    f = math.sqrt(force[0] ** 2 + force[1] ** 2 + force[2] ** 2)
    normal = np.empty(3)
    gap = quadric_gap(p1, Q, lin, c, R_WB, p_WB, normal)
    tangential = tangent[0] * normal[0] + tangent[1] * normal[1] + tangent[2] * normal[2]
    held = _contact_residuals(mode, s1, tangential, gap, p1, anchor, out)
    if not held:
        direction = np.empty(3)
        coulomb_direction(p1, anchor, normal, mu, direction)
        n_anchor = np.empty(3)
        quadric_gap(anchor, Q, lin, c, R_WB, p_WB, n_anchor)
        a, b = _normal_basis(n_anchor)
        out[2] = sum_product(force, a) / f - sum_product(direction, a)
        out[3] = sum_product(force, b) / f - sum_product(direction, b)
    for i in range(3):
        out[4 + i] = moment[i] / f
    _write_state(p1, s1, tangent, normal, force, 0, held, out)
    out[20] = math.nan
    for i in range(3):
        out[21 + i] = math.nan
    # beyond the contact the rod is its unloaded arc: curvature kappa_hat towards d1
    kappa, free = params[1], 1.0 - s1
    point, probe_normal = np.empty(3), np.empty(3)
    for k in range(1, FREE_PART_POINTS + 1 if free > 0.0 else 1):
        sigma = free * k / FREE_PART_POINTS
        across = 0.5 * kappa * sigma * sigma if kappa == 0.0 else (
            1.0 - math.cos(kappa * sigma)) / kappa
        along = sigma if kappa == 0.0 else math.sin(kappa * sigma) / kappa
        for i in range(3):
            point[i] = p1[i] + across * bent[i] + along * tangent[i]
        least = min(least, quadric_gap(point, Q, lin, c, R_WB, p_WB, probe_normal))
    out[26] = least


@compiled
def _loaded_rod(s1: float, f0: FloatArray, m0: FloatArray, params: FloatArray,
                p_WC: FloatArray, R_WC: FloatArray, Q: FloatArray, lin: FloatArray, c: float,
                R_WB: FloatArray, p_WB: FloatArray) -> tuple[FloatArray, float]:
    """`vibrissa.rods.integrate_to` s1 (the same steps and arithmetic) and the least gap to the
    object of the rod before s1 (inf: none): at the integration's nodes, at each whole step's
    middle (cubic Hermite interpolation of the points and tangents at its ends) and at five
    points of the step that ends at the contact (integrated to), the last 3 % of it before
    the contact: a rod curving into the object harder than the object curves away enters it
    there."""
    h = 1.0 / N_STEPS
    y = clamp_state()
    nxt, start = np.empty(7), np.empty(7)
    before, after, t0, t1 = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    work = np.empty(6)  # `_gap`'s scratch
    _node(y, p_WC, R_WC, before, t0)
    least = math.inf
    k = 0
    while (k + 1) * h <= s1:
        start[:] = y
        rk4_step(k * h, h, y, f0, m0, params, nxt)
        y[:] = nxt
        k += 1
        _node(y, p_WC, R_WC, after, t1)
        if k * h < s1:
            least = min(least, _gap(after, Q, lin, c, R_WB, p_WB, work),
                        _hermite_gap(before, t0, after, t1, h, 0.5, Q, lin, c, R_WB, p_WB,
                                     work))
        before[:], t0[:] = after, t1
    rest = s1 - k * h
    # the step that ends at the contact: a partial one, or the whole step before it
    last_from, last_length, y_last = (k * h, rest, y) if rest > 0 else ((k - 1) * h, h, start)
    for fraction in (0.25, 0.5, 0.75, 0.9, 0.97):  # the rod's own points (a thin tip bends hard)
        rk4_step(last_from, fraction * last_length, y_last, f0, m0, params, nxt)
        _node(nxt, p_WC, R_WC, after, t1)
        least = min(least, _gap(after, Q, lin, c, R_WB, p_WB, work))
    if rest > 0:
        rk4_step(k * h, rest, y, f0, m0, params, nxt)
        y[:] = nxt
    return y, least


@compiled
def _node(y: FloatArray, p_WC: FloatArray, R_WC: FloatArray, point: FloatArray,
          tangent: FloatArray) -> None:
    """The rod's point and tangent d3 in W at state ``y`` into ``point`` and ``tangent``."""
    qw, qx, qy, qz = y[3], y[4], y[5], y[6]
    d3 = (2.0 * (qx * qz + qw * qy), 2.0 * (qy * qz - qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy))
    for i in range(3):
        point[i] = p_WC[i] + R_WC[i, 0] * y[0] + R_WC[i, 1] * y[1] + R_WC[i, 2] * y[2]
        tangent[i] = R_WC[i, 0] * d3[0] + R_WC[i, 1] * d3[1] + R_WC[i, 2] * d3[2]


@compiled
def _gap(point: FloatArray, Q: FloatArray, lin: FloatArray, c: float, R_WB: FloatArray,
         p_WB: FloatArray, work: FloatArray) -> float:
    """`quadric_gap` without its normal (``work`` (6,): scratch)."""
    return quadric_gap(point, Q, lin, c, R_WB, p_WB, work[3:6])


@compiled
def _hermite_gap(a: FloatArray, ta: FloatArray, b: FloatArray, tb: FloatArray, length: float,
                 fraction: float, Q: FloatArray, lin: FloatArray, c: float, R_WB: FloatArray,
                 p_WB: FloatArray, work: FloatArray) -> float:
    """The gap of the cubic Hermite curve from point ``a`` (tangent ``ta``) to ``b`` (``tb``)
    over an arc of ``length``, at ``fraction`` of it (``work`` (6,): scratch)."""
    t = fraction
    h00, h10 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t
    h01, h11 = -2 * t**3 + 3 * t**2, t**3 - t**2
    point = work[0:3]
    for i in range(3):
        point[i] = h00 * a[i] + h10 * length * ta[i] + h01 * b[i] + h11 * length * tb[i]
    return _gap(point, Q, lin, c, R_WB, p_WB, work)


@compiled
def sum_product(a: FloatArray, b: FloatArray) -> float:
    """a . b of two 3-vectors."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@compiled
def _normal_basis(n: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors spanning the plane normal to the unit vector ``n``, continuous in n
    except where n_z = -1 changes side (Duff et al. 2017, "Building an orthonormal basis,
    revisited")."""
    sign = 1.0 if n[2] >= 0.0 else -1.0
    a_ = -1.0 / (sign + n[2])
    b_ = n[0] * n[1] * a_
    e1 = np.array([1.0 + sign * n[0] * n[0] * a_, sign * b_, -sign * n[0]])
    e2 = np.array([b_, sign + n[1] * n[1] * a_, -n[1]])
    return e1, e2


@compiled
def evaluate_any(q: FloatArray, p_WC: FloatArray, R_WC: FloatArray, mu: float,
                 anchor: FloatArray, mode: int, locked: bool, Q: FloatArray, lin: FloatArray,
                 c: float, R_WB: FloatArray, p_WB: FloatArray, params: FloatArray,
                 out: FloatArray) -> None:
    """`evaluate_row` for the straight uniform rod (``params`` (1, 0, .)), `evaluate_rod_row`
    for any other."""
    if params[0] == 1.0 and params[1] == 0.0:
        evaluate_row(q, p_WC, R_WC, mu, anchor, mode, locked, Q, lin, c, R_WB, p_WB, out)
    else:
        evaluate_rod_row(q, p_WC, R_WC, mu, anchor, mode, Q, lin, c, R_WB, p_WB, params, out)


@compiled
def _residual_norm(state: FloatArray) -> float:
    """max |residual|, NaN if any is NaN (as numpy's max)."""
    worst = 0.0
    for i in range(7):
        value = abs(state[i])
        if value != value:
            return math.nan
        worst = max(worst, value)
    return worst


@compiled
def newton_row(q0: FloatArray, p_WC: FloatArray, R_WC: FloatArray, mu: float,
               anchor: FloatArray, mode: int, locked: bool, Q: FloatArray, lin: FloatArray,
               c: float, R_WB: FloatArray, p_WB: FloatArray, params: FloatArray, q: FloatArray,
               state: FloatArray) -> None:
    """Newton's method on one row from ``q0`` (`evaluate_any`: 4 unknowns of the elastica, 7
    of the Kirchhoff rod): forward-difference Jacobian (loads perturbed relative to the row's
    load), at most 0.3 of q[0] (psi, rad, or s1, L) per step, step halving until the residual
    decreases; the solution into ``q`` and its state into ``state``."""
    n = 4 if params[0] == 1.0 and params[1] == 0.0 else 7
    for j in range(Q_WIDTH):
        q[j] = q0[j]
    evaluate_any(q, p_WC, R_WC, mu, anchor, mode, locked, Q, lin, c, R_WB, p_WB, params, state)
    norm = _residual_norm(state)
    probe_state = np.empty(STATE_WIDTH)
    trial_state = np.empty(STATE_WIDTH)
    probe = np.empty(Q_WIDTH)
    trial = np.empty(Q_WIDTH)
    jac = np.empty((n, n))
    rhs = np.empty(n)
    h = np.empty(n)
    for _ in range(NEWTON_MAX_ITER):
        if norm < NEWTON_TOL or not math.isfinite(norm):
            return
        load = 0.0
        for j in range(1, n):
            load = max(load, abs(q[j]))
        for j in range(n):
            scale = 1.0 if j == 0 else 1e-3 * load
            h[j] = max(1e-8 * max(abs(q[j]), scale), 1e-300)
        for j in range(n):
            for k in range(Q_WIDTH):
                probe[k] = q[k]
            probe[j] += h[j]
            evaluate_any(probe, p_WC, R_WC, mu, anchor, mode, locked, Q, lin, c, R_WB, p_WB,
                         params, probe_state)
            for i in range(n):
                jac[i, j] = (probe_state[i] - state[i]) / h[j]
        for i in range(n):
            rhs[i] = -state[i]
        delta = _solve(jac, rhs)
        limit = min(1.0, 0.3 / max(abs(delta[0]), 1e-300))  # keep the plane from spinning
        for j in range(n):
            delta[j] *= limit
        accepted = False
        for _halving in range(10):
            for j in range(Q_WIDTH):
                trial[j] = q[j] + delta[j] if j < n else q[j]
            evaluate_any(trial, p_WC, R_WC, mu, anchor, mode, locked, Q, lin, c, R_WB, p_WB,
                         params, trial_state)
            trial_norm = _residual_norm(trial_state)
            if trial_norm < norm or trial_norm < NEWTON_TOL:
                for j in range(Q_WIDTH):
                    q[j] = trial[j]
                for k in range(STATE_WIDTH):
                    state[k] = trial_state[k]
                norm = trial_norm
                accepted = True
                break
            for j in range(n):
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
                  p_WB: FloatArray, params: FloatArray) -> FloatArray:
    """``evaluate_any`` of every row, each with its object (Q (n, 3, 3), lin (n, 3), c (n,),
    R_WB (n, 3, 3), p_WB (n, 3)) and rod (params (n, 3)): states (n, ``STATE_WIDTH``)."""
    n = q.shape[0]
    out = np.empty((n, STATE_WIDTH))
    for r in range(n):
        evaluate_any(q[r], p_WC[r], R_WC[r], mu[r], anchor[r], mode[r], locked[r], Q[r], lin[r],
                     c[r], R_WB[r], p_WB[r], params[r], out[r])
    return out


@compiled
def newton_rows(q0: FloatArray, p_WC: FloatArray, R_WC: FloatArray, mu: FloatArray,
                anchor: FloatArray, mode: NDArray[np.int64], locked: NDArray[np.bool_],
                Q: FloatArray, lin: FloatArray, c: FloatArray, R_WB: FloatArray, p_WB: FloatArray,
                params: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``newton_row`` of every row, each with its object and rod (as ``evaluate_rows``):
    solutions q (n, ``Q_WIDTH``) and their states."""
    n = q0.shape[0]
    q = np.empty((n, Q_WIDTH))
    out = np.empty((n, STATE_WIDTH))
    for r in range(n):
        newton_row(q0[r], p_WC[r], R_WC[r], mu[r], anchor[r], mode[r], locked[r], Q[r], lin[r],
                   c[r], R_WB[r], p_WB[r], params[r], q[r], out[r])
    return q, out


FREE_GAP_TOL = 1e-12
"""How far (L) a Kirchhoff rod away from its contact may dip into the object (round-off)."""


@compiled
def admissible_rows(state: FloatArray, mode: NDArray[np.int64], mu: FloatArray,
                    previous: FloatArray, jump: FloatArray) -> NDArray[np.bool_]:
    """Which states (n, ``STATE_WIDTH``) are physically acceptable (n,): the contact pushes
    (F . n > 0), it is at most its row's ``jump`` (n,) from the previous contact point (n, 3),
    the rod stays outside the object (at the tip its tangent does not point out of the object; a
    tangential contact lies on the rod, 0 < s1 <= 1; a Kirchhoff rod's nodes before the contact
    and its free part beyond it outside the object) and a sticking contact's force is inside
    the friction cone |F_t| <= mu F_n."""
    n = state.shape[0]
    ok = np.empty(n, dtype=np.bool_)
    for r in range(n):
        row = state[r]
        fn = row[17] * row[14] + row[18] * row[15] + row[19] * row[16]
        dx, dy, dz = row[7] - previous[r, 0], row[8] - previous[r, 1], row[9] - previous[r, 2]
        good = row[24] == 0 and fn > 0 and math.sqrt(dx * dx + dy * dy + dz * dz) <= jump[r]
        good = good and not row[26] < -FREE_GAP_TOL  # (NaN: the elastica's)
        if mode[r] == MODE_TANGENTIAL or mode[r] == MODE_STICK_TANGENTIAL:
            good = good and row[10] <= 1.0 and row[10] > 0.0
        else:
            good = good and row[11] * row[14] + row[12] * row[15] + row[13] * row[16] <= 1e-9
        if mode[r] == MODE_STICK or mode[r] == MODE_STICK_TANGENTIAL:
            tx, ty, tz = row[17] - fn * row[14], row[18] - fn * row[15], row[19] - fn * row[16]
            good = good and math.sqrt(tx * tx + ty * ty + tz * tz) <= mu[r] * fn * (1.0 + 1e-9)
        ok[r] = good
    return ok
