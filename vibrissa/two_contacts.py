"""Step 1 with two point contacts on one rod (an object behind an object, a rod leaning on two).

With two contact forces the rod no longer bends in one plane: it is a spatial elastica, a
Kirchhoff rod of isotropic bending stiffness (EI = 1 in units of L) without twist (point forces
act through its axis, and an isotropic rod carries its twisting moment unchanged from the free
tip, where it is zero). Arc length s from the clamp, position r, unit tangent t, internal
moment m (the moment the part beyond s exerts on the part before it, about r(s)) and internal
force n (the sum of the contact forces beyond s, F_i on the rod at s_i)::

    r' = t,    t' = m x t,    m' = n x t,    m . t = 0

from the clamp r(0) = p_WC, t(0) = C's e_z; beyond the outer contact the rod is straight and
unloaded, so m vanishes there. Integrated by classical Runge-Kutta with ``SEGMENT_STEPS``
steps on each of the two loaded segments (clamp to inner contact, inner to outer), so that
each contact is a step boundary.

Unknowns x = (m0_x, m0_y, F_0 (3), F_1 (3), s_0, s_1): the rod's internal moment at the clamp
in C (its z component is zero), the contact forces on the rod in W, and the arc lengths,
s_0 <= s_1 (contact 0 is the inner one). Ten conditions:

* m(s_1) = 0, its two components across t(s_1);
* each contact, four: sliding (``MODE_TIP`` for the outer contact only: s_1 = 1; or
  ``MODE_TANGENTIAL``: t _|_ n) with the point on its object and the force along n + mu c
  (eq. 7's Coulomb friction, c the unit chord towards the contact's previous point, ``anchor``,
  in the tangent plane: two components of F across that direction); or held (``MODE_STICK``
  at the tip, ``MODE_STICK_TANGENTIAL`` rolling over the point) at its anchor (three).

A tapered or pre-curved rod (`vibrissa.rods`: bending and torsion, its natural curvature)
twists: its state is ``vibrissa.rods``' (r and the material frame, in C) with the internal
moment from the statics of the forces beyond s, m = r x f0 - m0 between the clamp and the inner
contact and m = r x (-F_1) - (m0 + r(s_0) x F_0) between the contacts (the clamp's
reactions f0 = -(F_0 + F_1) and m0 = -m(0), all in C; the rod's own
Runge-Kutta step, ``SEGMENT_STEPS`` on each segment). Its unknowns add the clamp moment's twist
(x = (m(0) (3, C), F_0, F_1, s_0, s_1), `N_UNKNOWNS_SHAPED`), its conditions all three
components of m(s_1) = 0; beyond the outer contact it keeps its natural arc.

Units of L throughout, the objects as the quadrics of ``vibrissa.equilibrium`` (each contact
its own). Newton's method with a forward-difference Jacobian, compiled (``vibrissa.compiled``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vibrissa.compiled import compiled
from vibrissa.equilibrium import (
    DIRECTION_TOL,
    MODE_STICK,
    MODE_STICK_TANGENTIAL,
    MODE_TANGENTIAL,
    MODE_TIP,
    NEWTON_TOL,
    coulomb_direction,
    quadric_gap,
)
from vibrissa.paths import SampledPath
from vibrissa.rods import RodShape, clamp_state, frame_of, moment_at, rk4_step
from vibrissa.surfaces import Surface
from vibrissa.sweep import FAR_GROWTH, FAR_STEPS

FloatArray = NDArray[np.float64]

SEGMENT_STEPS = 256
"""Runge-Kutta steps on each loaded segment (the error falls as the fourth power of the
step: tests/core/test_two_contacts*.py give the closures against scipy's `solve_ivp`)."""
N_UNKNOWNS = 10
"""The straight uniform rod's unknowns; a shaped rod has one more (`N_UNKNOWNS_SHAPED`)."""
N_UNKNOWNS_SHAPED = 11
_CONTACT = 12
STATE_WIDTH = N_UNKNOWNS + 2 * _CONTACT
"""A solution's state (n unknowns): the n conditions 0:n, then per contact j from n + 12 j its
point, the rod's tangent there, the object's outward normal and the force on the rod (3 each);
``N_UNKNOWNS_SHAPED + 24`` wide for a shaped rod."""
STRAIGHT_ROD = RodShape()
STRAIGHT = STRAIGHT_ROD.params
"""The shape parameters of the straight uniform rod (`vibrissa.rods.RodShape.params`)."""


@compiled
def _derivative(y: FloatArray, n: FloatArray, out: FloatArray) -> None:
    """(r, t, m)' = (t, m x t, n x t) into ``out`` (9,)."""
    t0, t1, t2 = y[3], y[4], y[5]
    m0, m1, m2 = y[6], y[7], y[8]
    out[0], out[1], out[2] = t0, t1, t2
    out[3] = m1 * t2 - m2 * t1
    out[4] = m2 * t0 - m0 * t2
    out[5] = m0 * t1 - m1 * t0
    out[6] = n[1] * t2 - n[2] * t1
    out[7] = n[2] * t0 - n[0] * t2
    out[8] = n[0] * t1 - n[1] * t0


@compiled
def _segment(y: FloatArray, n: FloatArray, length: float, steps: int) -> None:
    """Integrate ``y`` = (r, t, m) in place over ``length`` of arc under the internal force
    ``n`` (classical Runge-Kutta, ``steps`` steps)."""
    h = length / steps
    k1, k2, k3, k4, tmp = np.empty(9), np.empty(9), np.empty(9), np.empty(9), np.empty(9)
    for _ in range(steps):
        _derivative(y, n, k1)
        for i in range(9):
            tmp[i] = y[i] + 0.5 * h * k1[i]
        _derivative(tmp, n, k2)
        for i in range(9):
            tmp[i] = y[i] + 0.5 * h * k2[i]
        _derivative(tmp, n, k3)
        for i in range(9):
            tmp[i] = y[i] + h * k3[i]
        _derivative(tmp, n, k4)
        for i in range(9):
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@compiled
def _shaped_segment(y: FloatArray, s_from: float, s_to: float, f0: FloatArray, m0: FloatArray,
                    params: FloatArray, steps: int) -> None:
    """Integrate the shaped rod's state ``y`` (`vibrissa.rods`: r and the frame's quaternion,
    in C) in place from ``s_from`` to ``s_to`` under the clamp wrench (f0, m0) that gives the
    internal moment there (classical Runge-Kutta, ``steps`` steps)."""
    h = (s_to - s_from) / steps
    nxt = np.empty(7)
    for k in range(steps):
        rk4_step(s_from + k * h, h, y, f0, m0, params, nxt)
        y[:] = nxt


@compiled
def _shaped_loads(x: FloatArray, R_WC: FloatArray, y_inner: FloatArray
                  ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The clamp wrenches (f0, m0, C) that give the shaped rod's internal moment
    m = r x f0 - m0 between the clamp and the inner contact and, given the inner contact's
    state ``y_inner``, between the contacts: (f0, m0, f0_between, m0_between)."""
    f0, m0 = np.empty(3), np.empty(3)
    inner, outer = np.empty(3), np.empty(3)
    for i in range(3):
        inner[i] = R_WC[0, i] * x[3] + R_WC[1, i] * x[4] + R_WC[2, i] * x[5]
        outer[i] = R_WC[0, i] * x[6] + R_WC[1, i] * x[7] + R_WC[2, i] * x[8]
        f0[i] = -(inner[i] + outer[i])
        m0[i] = -x[i]
    r = y_inner
    f0b, m0b = -outer, np.empty(3)
    m0b[0] = m0[0] + r[1] * inner[2] - r[2] * inner[1]
    m0b[1] = m0[1] + r[2] * inner[0] - r[0] * inner[2]
    m0b[2] = m0[2] + r[0] * inner[1] - r[1] * inner[0]
    return f0, m0, f0b, m0b


@compiled
def _line_steps(s: float, end: float, s0: float, s1: float) -> int:
    """Runge-Kutta steps of `rod_line` from ``s`` to ``end`` on the loaded segment holding
    them: no longer than the solve's own (`SEGMENT_STEPS` per segment), so that the line is the
    solved rod to its accuracy; 1 / `SEGMENT_STEPS` beyond the outer contact."""
    segment = s0 if s < s0 else s1 - s0 if s < s1 else 1.0
    return max(1, int(math.ceil((end - s) * SEGMENT_STEPS / segment - 1e-9)))


@compiled
def _shaped_rod_line(x: FloatArray, p_WC: FloatArray, R_WC: FloatArray, points: int,
                     params: FloatArray) -> FloatArray:
    """`rod_line` of a shaped rod: loaded to the outer contact, its unloaded (pre-curved)
    rest beyond."""
    s0, s1 = x[-2], x[-1]
    y = clamp_state()
    zero = np.zeros(3)
    f0, m0, f0b, m0b = _shaped_loads(x, R_WC, y)  # (the segment beyond: after s0, below)
    out = np.empty((points, 3))
    s = 0.0
    for k in range(points):
        target = k / (points - 1)
        while s < target:
            boundary = s0 if s < s0 else s1 if s < s1 else math.inf
            end = min(target, boundary)
            load_f, load_m = (f0, m0) if s < s0 else (f0b, m0b) if s < s1 else (zero, zero)
            _shaped_segment(y, s, end, load_f, load_m, params, _line_steps(s, end, s0, s1))
            s = end
            if s == s0:
                f0, m0, f0b, m0b = _shaped_loads(x, R_WC, y)
        for i in range(3):
            out[k, i] = p_WC[i] + R_WC[i, 0] * y[0] + R_WC[i, 1] * y[1] + R_WC[i, 2] * y[2]
    return out


@compiled
def rod_line(x: FloatArray, p_WC: FloatArray, R_WC: FloatArray, points: int,
             params: FloatArray) -> FloatArray:
    """The rod's axis (``points``, 3) in W at evenly spaced arc lengths from the clamp to the
    tip, for the unknowns ``x`` (``params``: the rod's shape, used where ``x`` is a shaped
    rod's)."""
    if len(x) == N_UNKNOWNS_SHAPED:
        return _shaped_rod_line(x, p_WC, R_WC, points, params)
    y = np.empty(9)
    for i in range(3):
        y[i] = p_WC[i]
        y[3 + i] = R_WC[i, 2]
        y[6 + i] = R_WC[i, 0] * x[0] + R_WC[i, 1] * x[1]
    s0, s1 = x[8], x[9]
    n = np.empty(3)
    out = np.empty((points, 3))
    out[0, 0], out[0, 1], out[0, 2] = y[0], y[1], y[2]
    s = 0.0
    for k in range(1, points):
        target = k / (points - 1)
        while s < target:
            boundary = s0 if s < s0 else s1 if s < s1 else math.inf
            end = min(target, boundary)
            for i in range(3):
                n[i] = x[2 + i] + x[5 + i] if s < s0 else x[5 + i] if s < s1 else 0.0
            _segment(y, n, end - s, _line_steps(s, end, s0, s1))
            s = end
        out[k, 0], out[k, 1], out[k, 2] = y[0], y[1], y[2]
    return out


@compiled
def _contact_conditions(mode: int, s: float, p: FloatArray, t: FloatArray, force: FloatArray,
                        anchor: FloatArray, mu: float, Q: FloatArray, lin: FloatArray, c: float,
                        R_WB: FloatArray, p_WB: FloatArray, out: FloatArray,
                        info: FloatArray) -> None:
    """The four conditions of one contact into ``out`` (4,), its point, tangent, normal and
    force into ``info`` (12,)."""
    normal = np.empty(3)
    gap = quadric_gap(p, Q, lin, c, R_WB, p_WB, normal)
    tangency = t[0] * normal[0] + t[1] * normal[1] + t[2] * normal[2]
    out[0] = s - 1.0 if mode == MODE_TIP or mode == MODE_STICK else tangency
    if mode == MODE_STICK or mode == MODE_STICK_TANGENTIAL:
        out[1], out[2], out[3] = p[0] - anchor[0], p[1] - anchor[1], p[2] - anchor[2]
    else:
        d = np.empty(3)
        coulomb_direction(p, anchor, normal, mu, d)
        # two directions across d: the rod's tangent made normal to d, and d x that
        td = t[0] * d[0] + t[1] * d[1] + t[2] * d[2]
        u = np.empty(3)
        for i in range(3):
            u[i] = t[i] - td * d[i]
        u_size = math.sqrt(u[0] ** 2 + u[1] ** 2 + u[2] ** 2)
        for i in range(3):
            u[i] /= u_size
        w0 = d[1] * u[2] - d[2] * u[1]
        w1 = d[2] * u[0] - d[0] * u[2]
        w2 = d[0] * u[1] - d[1] * u[0]
        out[1] = gap
        out[2] = force[0] * u[0] + force[1] * u[1] + force[2] * u[2]
        out[3] = force[0] * w0 + force[1] * w1 + force[2] * w2
    for i in range(3):
        info[i] = p[i]
        info[3 + i] = t[i]
        info[6 + i] = normal[i]
        info[9 + i] = force[i]


@compiled
def _shaped_rod(x: FloatArray, p_WC: FloatArray, R_WC: FloatArray, params: FloatArray,
                points: FloatArray, tangents: FloatArray, out: FloatArray) -> None:
    """A shaped rod's contact points and tangents (W) into ``points`` and ``tangents`` (2, 3),
    m(s_1) = 0 (its three components in C) into ``out[0:3]``."""
    y = clamp_state()
    f0, m0, _f, _m = _shaped_loads(x, R_WC, y)
    _shaped_segment(y, 0.0, x[-2], f0, m0, params, SEGMENT_STEPS)
    for j in range(2):
        if j == 1:
            _f, _m, f0b, m0b = _shaped_loads(x, R_WC, y)
            _shaped_segment(y, x[-2], x[-1], f0b, m0b, params, SEGMENT_STEPS)
            m = moment_at(y, f0b, m0b)
            out[0], out[1], out[2] = m[0], m[1], m[2]
        frame = frame_of(y)
        for i in range(3):
            points[j, i] = p_WC[i] + R_WC[i, 0] * y[0] + R_WC[i, 1] * y[1] + R_WC[i, 2] * y[2]
            tangents[j, i] = (R_WC[i, 0] * frame[0, 2] + R_WC[i, 1] * frame[1, 2]
                              + R_WC[i, 2] * frame[2, 2])


@compiled
def evaluate(x: FloatArray, p_WC: FloatArray, R_WC: FloatArray, modes: NDArray[np.int64],
             anchors: FloatArray, mu: float, params: FloatArray, Q: FloatArray, lin: FloatArray,
             c: FloatArray, R_WB: FloatArray, p_WB: FloatArray, out: FloatArray) -> None:
    """The n conditions at ``x`` (n unknowns: `N_UNKNOWNS`, or `N_UNKNOWNS_SHAPED` for the rod
    of shape ``params``) into ``out[0:n]`` and each contact's point, tangent, normal and force
    into ``out[n + 12 i : n + 12 + 12 i]``; the objects' quadrics per contact (Q (2, 3, 3),
    ...). NaN conditions where the arc lengths are out of order (a rod longer than 1 is
    evaluated: Newton probes past a tip; `admissible` keeps s_1 <= 1)."""
    n_x = len(x)
    moments = n_x - 8
    s0, s1 = x[-2], x[-1]
    if not (0.0 < s0 <= s1 < 2.0):
        out[:] = math.nan
        return
    points = np.empty((2, 3))
    tangents = np.empty((2, 3))
    if n_x == N_UNKNOWNS_SHAPED:
        _shaped_rod(x, p_WC, R_WC, params, points, tangents, out)
    else:
        _straight_rod(x, p_WC, R_WC, points, tangents, out)
    block = np.empty(4)
    for j in range(2):
        force = x[moments + 3 * j: moments + 3 + 3 * j]
        _contact_conditions(modes[j], x[n_x - 2 + j], points[j], tangents[j], force, anchors[j],
                            mu, Q[j], lin[j], c[j], R_WB[j], p_WB[j], block,
                            out[n_x + _CONTACT * j: n_x + _CONTACT * (j + 1)])
        for k in range(4):
            out[moments + 4 * j + k] = block[k]


@compiled
def _straight_rod(x: FloatArray, p_WC: FloatArray, R_WC: FloatArray, points: FloatArray,
                  tangents: FloatArray, out: FloatArray) -> None:
    """`_shaped_rod` of the straight uniform rod: m(s_1) = 0 across t(s_1) into ``out[0:2]``."""
    s0, s1 = x[8], x[9]
    y = np.empty(9)
    for i in range(3):
        y[i] = p_WC[i]
        y[3 + i] = R_WC[i, 2]
        y[6 + i] = R_WC[i, 0] * x[0] + R_WC[i, 1] * x[1]
    n = np.empty(3)
    for i in range(3):
        n[i] = x[2 + i] + x[5 + i]
    _segment(y, n, s0, SEGMENT_STEPS)
    for i in range(3):
        points[0, i], tangents[0, i] = y[i], y[3 + i]
        n[i] = x[5 + i]
    _segment(y, n, s1 - s0, SEGMENT_STEPS)
    for i in range(3):
        points[1, i], tangents[1, i] = y[i], y[3 + i]
    # m(s_1) = 0 across t(s_1): along the clamp's e_x and e_y made normal to t(s_1)
    t = tangents[1]
    for k in range(2):
        e = np.empty(3)
        et = R_WC[0, k] * t[0] + R_WC[1, k] * t[1] + R_WC[2, k] * t[2]
        for i in range(3):
            e[i] = R_WC[i, k] - et * t[i]
        out[k] = y[6] * e[0] + y[7] * e[1] + y[8] * e[2]


@compiled
def converged(state: FloatArray, modes: NDArray[np.int64]) -> bool:
    """Whether ``state``'s conditions hold: geometry to ``NEWTON_TOL``, a sliding contact's
    friction direction to ``DIRECTION_TOL`` (as for one contact)."""
    moments = len(state) - 2 * _CONTACT - 8
    for k in range(moments):
        if not abs(state[k]) < NEWTON_TOL:
            return False
    for j in range(2):
        held = modes[j] == MODE_STICK or modes[j] == MODE_STICK_TANGENTIAL
        for k in range(4):
            tol = DIRECTION_TOL if (k >= 2 and not held) else NEWTON_TOL
            if not abs(state[moments + 4 * j + k]) < tol:
                return False
    return True


@compiled
def _norm(state: FloatArray) -> float:
    worst = 0.0
    for i in range(len(state) - 2 * _CONTACT):
        value = abs(state[i])
        if value != value:
            return math.nan
        worst = max(worst, value)
    return worst


@compiled
def newton(x0: FloatArray, p_WC: FloatArray, R_WC: FloatArray, modes: NDArray[np.int64],
           anchors: FloatArray, mu: float, params: FloatArray, Q: FloatArray, lin: FloatArray,
           c: FloatArray, R_WB: FloatArray, p_WB: FloatArray, max_iter: int = 40
           ) -> tuple[FloatArray, FloatArray]:
    """Newton's method on the n conditions from ``x0`` (n unknowns, the rod's shape
    ``params``: `evaluate`): forward-difference Jacobian, step halving until the residual
    decreases; the last iterate and its state."""
    x = x0.copy()
    n_x = len(x)
    state = np.empty(n_x + 2 * _CONTACT)
    evaluate(x, p_WC, R_WC, modes, anchors, mu, params, Q, lin, c, R_WB, p_WB, state)
    norm = _norm(state)
    probe_state = np.empty(n_x + 2 * _CONTACT)
    trial_state = np.empty(n_x + 2 * _CONTACT)
    jac = np.empty((n_x, n_x))
    for _ in range(max_iter):
        if not math.isfinite(norm) or converged(state, modes):
            break
        load = 0.0
        for j in range(n_x - 2):
            load = max(load, abs(x[j]))
        for j in range(n_x):
            scale = 1e-3 * load if j < n_x - 2 else 1.0
            h = max(1e-8 * max(abs(x[j]), scale), 1e-300)
            probe = x.copy()
            probe[j] += h
            evaluate(probe, p_WC, R_WC, modes, anchors, mu, params, Q, lin, c, R_WB, p_WB,
                     probe_state)
            for i in range(n_x):
                jac[i, j] = (probe_state[i] - state[i]) / h
        rhs = -state[:n_x].copy()
        if not (np.all(np.isfinite(jac)) and np.all(np.isfinite(rhs))):
            break
        try:
            delta = np.linalg.solve(jac, rhs)
        except Exception:  # noqa: BLE001 - numba: LinAlgError for a singular matrix
            delta = np.linalg.lstsq(jac, rhs)[0]
        accepted = False
        for _halving in range(12):
            trial = x + delta
            evaluate(trial, p_WC, R_WC, modes, anchors, mu, params, Q, lin, c, R_WB, p_WB,
                     trial_state)
            trial_norm = _norm(trial_state)
            if trial_norm < norm or converged(trial_state, modes):
                x = trial
                state[:] = trial_state
                norm = trial_norm
                accepted = True
                break
            delta *= 0.5
        if not accepted:
            break
    return x, state


FRICTION_STAGES = 8


def solve(x0: FloatArray, p_WC: FloatArray, R_WC: FloatArray, modes: NDArray[np.int64],
          anchors: FloatArray, mu: float, params: FloatArray, Q: FloatArray, lin: FloatArray,
          c: FloatArray, R_WB: FloatArray, p_WB: FloatArray) -> tuple[FloatArray, FloatArray]:
    """`newton` from ``x0``; where it does not converge, again along mu = 0 -> ``mu`` in
    ``FRICTION_STAGES`` steps, each from the last (as one contact's friction continuation)."""
    x, state = newton(x0, p_WC, R_WC, modes, anchors, mu, params, Q, lin, c, R_WB, p_WB)
    if converged(state, modes) or mu == 0.0:
        return x, state
    x = x0.copy()
    for fraction in np.linspace(0.0, 1.0, FRICTION_STAGES + 1):
        x, state = newton(x, p_WC, R_WC, modes, anchors, fraction * mu, params, Q, lin, c,
                          R_WB, p_WB)
        if not converged(state, modes):
            break
    return x, state


def contact_info(state: FloatArray, j: int) -> tuple[FloatArray, FloatArray, FloatArray,
                                                      FloatArray]:
    """Contact ``j``'s point, rod tangent, object normal and force on the rod (W, units of L
    and EI/L^2) from a state of `evaluate`."""
    base = len(state) - 2 * _CONTACT + _CONTACT * j
    return (state[base:base + 3], state[base + 3:base + 6], state[base + 6:base + 9],
            state[base + 9:base + 12])


def clamp_reactions(x: FloatArray, state: FloatArray, p_WC: FloatArray, R_WC: FloatArray
                    ) -> tuple[FloatArray, FloatArray]:
    """The clamp's reaction on the rod, f0 and m0 about the clamp point, in C (units of EI/L^2
    and EI/L): the statics of the two contact forces."""
    f_W = np.zeros(3)
    m_W = np.zeros(3)
    for j in range(2):
        point, _t, _n, force = contact_info(state, j)
        f_W -= force
        m_W -= np.cross(point - p_WC, force)
    return R_WC.T @ f_W, R_WC.T @ m_W


def admissible(x: FloatArray, state: FloatArray, modes: NDArray[np.int64], mu: float
               ) -> tuple[bool, int]:
    """Whether a converged state is physical, and if not, the contact whose normal force does
    not push (-1: another reason): both contacts push (F . n > 0), their arc lengths in order
    on the rod, an outer tip's tangent not pointing out of its object, a held contact's force
    inside the friction cone (to 1e-9 of mu F_n, as for one contact)."""
    if not 0.0 < x[-2] <= x[-1] <= 1.0 + 1e-9:
        return False, -1
    for j in range(2):
        _p, tangent, normal, force = contact_info(state, j)
        fn = float(force @ normal)
        if not fn > 0.0:
            return False, j
        if modes[j] in (MODE_TIP, MODE_STICK) and float(tangent @ normal) > 1e-9:
            return False, -1
        if modes[j] in (MODE_STICK, MODE_STICK_TANGENTIAL):
            if float(np.linalg.norm(force - fn * normal)) > mu * fn * (1.0 + 1e-9):
                return False, -1
    return True, -1


STRETCH_ENDS = ("left", "snap-off", "another-object", "path-end")
"""How a stretch of two contacts ends: one contact's force went to zero (it leaves; the other
goes on alone), no equilibrium near the last one, the rod met a third object, or the path
ended."""
SUB_STEP_LEVELS = 5
"""A sample the plain step does not reach is tried in 2, 4, .. 32 sub-steps."""
CLEAR_POINTS = 129
"""Points of the rod's axis checked to lie outside every object."""
_HELD = {MODE_TIP: MODE_STICK, MODE_TANGENTIAL: MODE_STICK_TANGENTIAL}
_OTHER_PHASE = {MODE_TIP: MODE_TANGENTIAL, MODE_TANGENTIAL: MODE_TIP}


@dataclass
class StretchRow:
    """One sample of a stretch of two contacts: the moving sample ``k``, the unknowns ``x``, the
    state, the contacts' modes, the clamp's reaction f0, m0 in C (units of EI/L^2, EI/L),
    whether sub-steps reached it and whether a contact jumped there: it moved further than
    both `vibrissa.sweep.FAR_STEPS` samples of the rod's travel and `vibrissa.sweep.FAR_GROWTH`
    times its move at the sample before (a snap-through, as a single contact's far slide)."""

    k: int
    x: FloatArray
    state: FloatArray
    modes: NDArray[np.int64]
    f0: FloatArray
    m0: FloatArray
    refined: bool
    jumped: bool = False


@dataclass
class Stretch:
    """A stretch of two contacts along a path: its rows (one per sample, from the first), how
    it ended (`STRETCH_ENDS`; empty while it goes on) and, when a contact left, which (0 inner,
    1 outer)."""

    rows: list[StretchRow]
    end: str
    left: int = -1


class TwoContactFollower:
    """Two contacts followed sample by sample along a path that may grow (`advance`): contact 0
    (inner) on ``surfaces[objects[0]]``, contact 1 on ``surfaces[objects[1]]``, from moving
    sample ``k_first`` and the state ``x_start`` (the unknowns just before it, or a guess of
    them; a shaped rod's where ``shape`` is not the straight uniform one) with sliding
    ``modes`` and the contacts' last points ``anchors`` (W, units of L). The first sample is
    reached from ``x_start`` at once, or, ``from_touch``, from where the second contact has
    just touched: the first of its finest sub-steps (``SUB_STEP_LEVELS``) from the sample
    before reached at once, then on in sub-steps.

    At each sample the contacts slide, else hold (each, then both), else the outer contact
    changes between tip and tangential; each solution must converge, push at both contacts
    and keep the rod (``CLEAR_POINTS`` points of it) outside every object. A sample none of
    them reaches is tried in ever shorter sub-steps from as far as the longer ones got
    (``SUB_STEP_LEVELS``). A step is not taken onto another branch past where a contact
    leaves: a contact whose force falls so that its last decrease, carried on, reaches zero
    within the step, and that comes out of the step with more force, is taken to leave there
    (the step is tried in sub-steps, and the shortest ends the stretch there). The stretch
    (``stretch``, its ``end`` empty while it goes on) ends where a contact's force would pull
    (it leaves), where the rod would enter another object, or where no equilibrium is near
    (snap-off)."""

    def __init__(self, surfaces: Sequence[Surface], objects: tuple[int, int], k_first: int,
                 x_start: FloatArray, modes: NDArray[np.int64], anchors: FloatArray,
                 shape: RodShape = STRAIGHT_ROD, from_touch: bool = False) -> None:
        if len(x_start) != (N_UNKNOWNS if shape.uniform else N_UNKNOWNS_SHAPED):
            raise ValueError(f"{len(x_start)} unknowns for a "
                             f"{'straight' if shape.uniform else 'shaped'} rod")
        self.surfaces = surfaces
        self._params = shape.params
        self._from_touch = from_touch
        self.stretch = Stretch([], "")
        self.k = k_first  # the next sample to reach
        self._x_last, self._last_step = x_start.copy(), math.nan  # the state, the step to it
        self._x_before = x_start
        self._sliding = modes.copy()
        self._anchors = anchors.copy()
        self._moves = np.full(2, np.inf)  # each contact's move at the last sample (none yet)
        self._forces = np.full(2, np.nan)  # each contact's force at the last (sub-)step
        self._drops = np.full(2, np.nan)  # and its decrease over that step, per unit of x0
        self._kernel = [np.ascontiguousarray(np.concatenate([surfaces[j].kernel_arrays[i]
                                                             for j in objects]))
                        for i in range(5)]

    def advance(self, path: SampledPath, k_stop: int) -> None:
        """Reach the samples of ``path`` up to ``k_stop`` (exclusive), or to where the stretch
        ends."""
        rows, mu, surfaces, kernel = self.stretch.rows, path.mu, self.surfaces, self._kernel
        x_last, x_before, last_step = self._x_last, self._x_before, self._last_step
        forces, drops = self._forces, self._drops
        state, modes_now = x_last, self._sliding  # (each sample reached sets both)
        while self.k < k_stop and not self.stretch.end:
            k = self.k
            x0_k = float(path.x0_of(np.array([k]))[0])
            x0_at = float(path.x0_of(np.array([k - 1]))[0])
            span = x0_at - x0_k
            why = ""
            refined = False

            def reach(x0: float, sub: float) -> bool:
                """Take the (sub-)step to ``x0``, ``sub`` long; whether it is taken."""
                nonlocal why, drops, forces, x_before, x_last, last_step, x0_at, state
                nonlocal modes_now
                p_WC, R_WC = (a[0] for a in path.clamp_pose(np.array([x0])))
                predictor = (x_last if not last_step > 0
                             else x_last + (x_last - x_before) * (sub / last_step))
                found, why = _step(predictor, x_last, p_WC, R_WC, self._sliding,
                                   self._anchors, mu, self._params, kernel, surfaces)
                if found is None:
                    return False
                forces_now = np.array([np.linalg.norm(contact_info(found[1], j)[3])
                                       for j in range(2)])
                leaving = (drops * sub >= forces) & (forces_now > forces)
                if leaving.any():  # onto another branch past where it leaves
                    why = f"left {int(np.argmax(leaving))}"
                    return False
                drops = (forces - forces_now) / sub
                forces = forces_now
                x_before, x_last, last_step, x0_at = x_last, found[0], sub, x0
                state, modes_now = found[1], found[2]
                self._sliding = np.array([_sliding(m) for m in modes_now])
                for j in range(2):
                    self._anchors[j] = contact_info(state, j)[0]
                return True

            if not rows and not self._from_touch:
                reach(x0_k, span)  # at once: sub-steps would start before the touch
            elif not rows:  # the first of the finest sub-steps reached at once, then on
                finest = span / 2**SUB_STEP_LEVELS
                refined = any(reach(x0_at - j * finest, j * finest)
                              for j in range(1, 2**SUB_STEP_LEVELS))
            for level in range(SUB_STEP_LEVELS + 1 if rows else
                               SUB_STEP_LEVELS + 1 if refined else 0):
                sub = span / 2**level
                while x0_at - sub >= x0_k - 1e-12 * span:
                    if not reach(max(x0_at - sub, x0_k), sub):
                        break
                    refined = refined or level > 0
                if abs(x0_at - x0_k) <= 1e-12 * span:
                    break
            if abs(x0_at - x0_k) > 1e-12 * span:
                left = int(why[5:]) if why.startswith("left ") else -1
                self.stretch.end = ("left" if left >= 0 else why if why == "another-object"
                                    else "snap-off")
                self.stretch.left = left
                break
            p_WC, R_WC = (a[0] for a in path.clamp_pose(np.array([x0_k])))
            f0, m0 = clamp_reactions(x_last, state, p_WC, R_WC)
            jumped = False
            if rows:
                moves = np.array([np.linalg.norm(contact_info(state, j)[0]
                                                 - contact_info(rows[-1].state, j)[0])
                                  for j in range(2)])
                jumped = bool(np.any((moves > FAR_STEPS * span) & (moves > FAR_GROWTH
                                                                   * self._moves)))
                self._moves = moves
            rows.append(StretchRow(k, x_last, state, modes_now, f0, m0, refined, jumped))
            self.k = k + 1
        self._x_last, self._x_before, self._last_step = x_last, x_before, last_step
        self._forces, self._drops = forces, drops


def follow_two_contacts(path: SampledPath, surfaces: Sequence[Surface], objects: tuple[int, int],
                        k_first: int, x_start: FloatArray, modes: NDArray[np.int64],
                        anchors: FloatArray, shape: RodShape = STRAIGHT_ROD) -> Stretch:
    """Two contacts along the whole of ``path`` from moving sample ``k_first``
    (`TwoContactFollower`); a stretch that reaches the path's last sample ends ``path-end``."""
    follower = TwoContactFollower(surfaces, objects, k_first, x_start, modes, anchors, shape)
    follower.advance(path, path.n_samples)
    if not follower.stretch.end:
        follower.stretch.end = "path-end"
    return follower.stretch


def _sliding(mode: int) -> int:
    return MODE_TIP if mode == MODE_STICK else MODE_TANGENTIAL if mode == MODE_STICK_TANGENTIAL \
        else mode


def _step(predictor: FloatArray, last: FloatArray, p_WC: FloatArray, R_WC: FloatArray,
          sliding: NDArray[np.int64], anchors: FloatArray, mu: float, params: FloatArray,
          kernel: list[FloatArray], surfaces: Sequence[Surface]
          ) -> tuple[tuple[FloatArray, FloatArray, NDArray[np.int64]] | None, str]:
    """The first admissible state at one clamp pose over the contacts' modes (`follow_two_contacts`),
    or None and why: ``left J`` (contact J's force would pull), ``another-object`` or ``none``."""
    inner, outer = int(sliding[0]), int(sliding[1])
    combos = [(inner, outer)]
    if mu > 0:
        combos += [(_HELD[inner], outer), (inner, _HELD[outer]), (_HELD[inner], _HELD[outer])]
    combos += [(inner, _OTHER_PHASE[outer])]
    if mu > 0:
        combos += [(_HELD[inner], _OTHER_PHASE[outer])]
    why = "none"
    for combo in combos:
        modes = np.array(combo, dtype=np.int64)
        for start in (predictor, last) if predictor is not last else (last,):
            x, state = solve(start, p_WC, R_WC, modes, anchors, mu, params, *kernel)
            if not converged(state, modes):
                continue
            ok, pulls = admissible(x, state, modes, mu)
            if not ok:
                if pulls >= 0 and why == "none":
                    why = f"left {pulls}"
                continue
            line = rod_line(x, p_WC, R_WC, CLEAR_POINTS, params)
            if any(float(surface.signed_distance(line).min()) < -1e-9 for surface in surfaces):
                why = "another-object"
                continue
            return (x, state, modes), why
    return None, why


__all__ = ["MODE_STICK", "MODE_STICK_TANGENTIAL", "MODE_TANGENTIAL", "MODE_TIP", "N_UNKNOWNS",
           "SEGMENT_STEPS", "admissible", "clamp_reactions", "contact_info", "evaluate",
           "follow_two_contacts", "newton", "rod_line", "solve", "Stretch", "StretchRow",
           "STRETCH_ENDS", "TwoContactFollower"]
