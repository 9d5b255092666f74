"""Step 1: quasi-static frictional sweeps of the clamped rod past a convex object (Sec. II-E).

The clamp P0 = (x0, y0, 0) moves in steps of ``step`` along -x; its axis is e_z. Every step is an
equilibrium of the planar elastica (eq. 11) in the plane E_psi through P0 spanned by e_z and
e_u = (cos psi, sin psi, 0). The unknowns of a step are q = (psi, Fu, Fv, kappa0): the plane, the
contact force on the rod in that plane and the clamp curvature; the closed-form elastica
(:mod:`vibrissa.elastica`) turns q into the contact P1, s1 and the rod's tangent there.

Frames: q lives in the clamp frame C of its step (the rod leaves along C's e_z, E_psi contains
it); the object, the contact P1, its normal and force live in W, where the object is fixed.
Every equation is evaluated with the step's clamp pose X_WC (``Trail.clamp_pose``: on the
paper's trail the identity rotation at (x0, y0, 0)), so that the friction chord of eq. 7
joins two contact points on the object whatever the clamp does between them.
Conditions (four equations, solved by Newton's method with a finite-difference Jacobian,
batched over all sweeps solved together: a study's, or a scene's whiskers, each past its own
object with its own step):

* tip contact (eq. 14): s1 = 1; tangential contact (eq. 15): rod tangent _|_ surface normal;
* P1 on the surface;
* Coulomb sliding (eqs. 4-7): F is parallel to n + mu t, with n the outward normal at P1 and t the
  unit vector from P1 towards the previous contact point (eq. 7), projected into the tangent
  plane so that the friction force is exactly tangential; two equations: the direction lies in
  E_psi, and F points along it within E_psi.

Phases change by themselves: a tip solution whose rod would enter the object just before the
tip (rod tangent pointing out of the object at P1) becomes tangential, and a tangential solution
with s1 > 1 becomes tip contact.

Sticking (not in the paper): with larger mu there are clamp positions where no sliding
equilibrium exists near the previous one, because the friction direction of eq. 7 depends on
where the contact goes. Coulomb's law then allows the contact to stick: the rod's tip stays at
the previous contact point (three equations) with s1 = 1, and the state is accepted when the
resulting contact force lies inside the friction cone, |F_t| <= mu F_n. Sliding is tried first
at every step, as in the paper. A tangential contact may hold too: its contact point stays on
the object (three equations) with the rod tangent to it there, the rod rolling over the point
(s1 free); tried when nothing else holds the step.

Turning back (not in the paper): where the path reverses, the friction must turn through its
cone. A slide that would move the contact against its last slide is taken only where the
contact cannot hold (the force of the held state is outside the cone), and a held tangential
contact slides again only once it cannot hold any longer. Slides shorter than 1e-6 L have no
direction to turn back from (a nearly stuck tip slips by 1e-8). On an arc that reverses (mu
0.6) a tangential contact so holds for 11 samples while its friction turns from one edge of
the cone to the other, |F_t| down to 0.24 F_n, then slides back; sliding back at once, it had
jumped 0.091 L over the object in one sample.

Stick-slip (not in the paper): on the paper's object with mu = 0.4 and |y0| = 0.2 the tip's
sliding branch folds again and again from x0 ~ -0.79 on: the tip creeps ever faster (measured
0.36 -> 0.5 L per L of clamp travel at a step of 2.5e-4) until no nearby sliding state is left,
and it jumps ~2.2e-3 L along the surface, friction opposing the jump along its chord
(eq. 7), to where it holds again. The cycle repeats every ~1.8e-3 L of clamp travel at steps of
1e-3, 5e-4 and 2.5e-4 alike (a property of the rod, not of the step); at a step of 1e-3 it shows
as slides that alternate between short creeps and long jumps. The predictor follows such a
stretch by extrapolating every other state.

Early steps (not in the paper): right after a tip touch the tip slips only by the rod's axial
shortening (the rod is inextensible and cannot reach where it touched), ~1e-7 per step at
steps below 1e-3, too short to resolve the direction of eq. 7. Within 0.01 L of the touch a
step that fails is retried as 2, 4, 8, 16 or 32 steps on the same grid, as far as they stay within
0.01 L of the touch, before it is refined.

Symmetric trails: when the object is its own mirror image across the vertical plane of the trail
(the paper's y0 = 0), the symmetric branch is kept exactly by fixing psi = 0 and dropping the
out-of-plane equation; otherwise round-off grows out of the plane from step to step.

The sweep starts at the first contact of the straight rod with the object (or, given a
`Landing`, from a contact state found otherwise: a rod that landed after a snap-off) and ends at
detachment (the reactions have gone to zero smoothly, and the straight rod clears the object or
is on its way out: less of it inside than at the last equilibrium) or at snap-off (no
equilibrium near the previous one even with the step refined, the straight rod still inside the
object).
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa.elastica import planar_line
from vibrissa.equilibrium import (
    MODE_STICK,
    MODE_STICK_TANGENTIAL,
    MODE_TANGENTIAL,
    MODE_TIP,
    Q_WIDTH,
    admissible_rows,
    evaluate_rows,
    newton_rows,
)
from vibrissa.rods import UNIFORM, RodShape, rod_line, unloaded_points, unloaded_segments
from vibrissa.status import ContactPhase, SweepEnd
from vibrissa.surfaces import Surface

FloatArray = NDArray[np.float64]

SLIDE, STICK = 0, 1
STATE_NAMES = {SLIDE: "slide", STICK: "stick"}

_E_Z = np.array([0.0, 0.0, 1.0])
_IDENTITY = np.eye(3)
_IDENTITY.flags.writeable = False
_DETACHMENT_FRACTION = 0.02  # last force / peak force below which the sweep ended smoothly
_DETACHMENT_STEPS = 1.5  # ... or steps within which the last decrease of the force reaches zero
EARLY_TRAVEL_L = 0.01
"""Clamp travel from the touch (units of L) within which a failed step tries longer ones
(`SweepRun.early`)."""
EARLY_MULTIPLES = (2, 4, 8, 16, 32)
"""The longer steps a failed early step tries, in steps: a sweep looks this far ahead."""
CLAMP_TOUCH_L = 1e-6
"""A first touch nearer the clamp than this (arc length, units of L) is the object meeting the
clamp itself: no equilibrium of the rod holds it off (the sweep ends ``no-equilibrium``)."""
_REFINEMENTS = 10  # a failed step is retried with up to 2**10 sub-steps before it counts as snap-off


class ClampPath(Protocol):
    """A clamp's path as Step 1 follows it, with the friction ``mu`` of its contacts.

    The path is parametrised by a coordinate x0 that decreases along it, in units of L (the
    clamp's x on the paper's trail); the steps of a sweep are x0 = x_grid - k step. ``x_end``
    is where the path ends (-inf: never).
    """

    @property
    def mu(self) -> float:
        """Coulomb friction coefficient of the contacts."""
        ...

    @property
    def x_end(self) -> float:
        """Where the path ends, units of L (-inf: never)."""
        ...

    @property
    def x_grid(self) -> float | None:
        """The path's own grid of steps x_grid - k step (its samples), or None: each sweep's
        grid starts at its first contact."""
        ...

    def clamp_pose(self, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Clamp poses X_WC at ``x0`` (n,): origins p_WC (n, 3), rotations R_WC (n, 3, 3)."""
        ...

    def travel(self, x_from: float, x_to: float) -> float:
        """How far the straight rod's points move from ``x_from`` to ``x_to`` <= ``x_from``,
        units of L: at most ``x_from - x_to`` (the coordinate advances at least as fast as the
        rod moves)."""
        ...

    def travel_end(self, x_from: float, travel: float) -> float:
        """The x0 <= ``x_from`` at which the rod has moved ``travel`` (units of L, as `travel`
        measures it) since ``x_from``; ``x_end`` where it never does."""
        ...

    def first_contact(self, surface: Surface, shape: RodShape = UNIFORM
                      ) -> tuple[float, FloatArray] | None:
        """The first x0 at which the unloaded rod of ``shape`` (straight by default) touches
        the object, and the touch point in W; None when it never does."""
        ...

    def symmetric(self, surface: Surface) -> bool:
        """Whether the object is its own mirror image across the path's bending-plane of
        symmetry (then psi stays 0 exactly)."""
        ...


@dataclass(frozen=True)
class Trail:
    """A straight clamp trail parallel to x at lateral offset ``y0`` with friction ``mu``: the
    paper's path (Sec. II-E), x0 the clamp's x."""

    y0: float
    mu: float
    x_end: float = -math.inf
    x_grid: float | None = None

    def first_contact(self, surface: Surface, shape: RodShape = UNIFORM
                      ) -> tuple[float, FloatArray] | None:
        """See :func:`first_contact`."""
        return first_contact(surface, self.y0, shape)

    def symmetric(self, surface: Surface) -> bool:
        """Whether the object is symmetric across the vertical plane y = y0 of the trail."""
        return surface.is_mirror_symmetric([0.0, self.y0, 0.0], [0.0, 1.0, 0.0])

    def travel(self, x_from: float, x_to: float) -> float:
        """``x_from - x_to``: x0 is the clamp's x."""
        return x_from - x_to

    def travel_end(self, x_from: float, travel: float) -> float:
        """``x_from - travel``: x0 is the clamp's x."""
        return x_from - travel

    def clamp_pose(self, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The clamp poses X_WC at positions ``x0`` (n,) of the trail: origins p_WC (n, 3) =
        (x0, y0, 0) and rotations R_WC (n, 3, 3) = identity (the rod leaves along W's e_z)."""
        x0 = np.asarray(x0, dtype=float).reshape(-1)
        p_WC = np.zeros((len(x0), 3))
        p_WC[:, 0], p_WC[:, 1] = x0, self.y0
        return p_WC, _IDENTITY[None].repeat(len(x0), axis=0)


@dataclass
class Sweep:
    """Equilibria of one sweep, one entry per step, in the paper's units (eq. 1).

    ``end`` says how it ended (:class:`vibrissa.status.SweepEnd`): a detachment or a snap-off
    (see the module docstring), no contact (the trail misses the object), no equilibrium (none
    found for the first step after the first contact: the object meets the clamp itself,
    ``s_touch`` 0; a tip poked into the object within the friction cone, which sticks while the
    rod could only buckle; or a solver failure, reported rather than hidden) or the step cap.

    Frames: ``f0``, ``m0`` are the clamp's reactions on the rod (moment about P0) in the clamp
    frame C; ``contact`` and ``force`` (the contact force on the rod) and ``normal`` (the
    surface's outward unit normal at the contact) are in W; ``fn`` = F . n >= 0 and
    ``ft`` = |F - fn n| the normal and friction magnitudes. On a trail C and W have the same
    axes (clamp axis e_z).

    Rows are one per step of ``step`` along the grid x_grid - k step (x_grid: the first contact,
    or the grid shared by the trails of an array, see :func:`simulate_sweeps`), except that a step
    just after the first contact that finds no equilibrium is taken as 2-32 steps (the positions
    in between are missing, the row is ``refined``): see ``_longer_step``. ``refined`` also marks
    steps reached through sub-steps (the chord of eq. 7 is then a sub-step's). ``jumped`` marks
    rows the contact jumped to: a far slide (``FAR_STEPS``), taken where no nearer state was
    found, or a jump of the contact force inside a step retaken in sub-steps
    (`_through_steep_step`): a snap-through to another branch.
    """

    trail: ClampPath
    step: float
    x0: FloatArray
    phase: NDArray[np.int64]
    state: NDArray[np.int64]
    s1: FloatArray
    psi: FloatArray
    f0: FloatArray
    m0: FloatArray
    contact: FloatArray
    normal: FloatArray
    force: FloatArray
    fn: FloatArray
    ft: FloatArray
    refined: NDArray[np.bool_]  # not one plain step: sub-steps, or a longer step after the touch
    jumped: NDArray[np.bool_]  # the contact jumped there (a snap-through)
    end: SweepEnd
    x0_end: float
    phase_changes: list[tuple[float, str, str]]
    x_touch: float  # clamp x0 at the first contact (NaN: none), units of L
    s_touch: float  # where the straight rod touched, arc length from the clamp (NaN: none;
    # a sweep that starts from a `Landing`: the landed contact's s1), L
    _q: FloatArray = field(repr=False)
    shape: RodShape = field(default_factory=RodShape)  # the rod (``vibrissa.rods``)

    @property
    def n_steps(self) -> int:
        return len(self.x0)

    @property
    def y0(self) -> float:
        """The lateral offset of a trail (NaN on another path), units of L."""
        return self.trail.y0 if isinstance(self.trail, Trail) else math.nan

    @property
    def p0(self) -> FloatArray:
        """Clamp positions p_WC (N, 3)."""
        return self.trail.clamp_pose(self.x0)[0]

    def elastic_line(self, index: int, n_points: int = 101) -> FloatArray:
        """Points (n_points, 3) of the rod's axis at step ``index``, from the clamp to the tip,
        in W."""
        return self.elastic_lines([index], n_points)[0]

    def elastic_lines(self, indices: ArrayLike, n_points: int = 101) -> FloatArray:
        """Points (n, n_points, 3) of the rod's axis at steps ``indices`` (n,), from the clamp
        to the tip, in W."""
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        s = np.linspace(0.0, 1.0, n_points)
        if not self.shape.uniform:
            p_WC, R_WC = self.trail.clamp_pose(self.x0[indices])
            lines_C = np.array([rod_line(self.shape, -q[1:4], q[4:7], q[0], s)
                                for q in self._q[indices]]).reshape(len(indices), n_points, 3)
            return p_WC[:, None] + np.einsum("nij,nkj->nki", R_WC, lines_C)
        uv = np.array([planar_line(fu, fv, kappa0, s) for _psi, fu, fv, kappa0 in self._q[indices, :4]])
        e_u_C = bending_plane(self._q[indices, 0])[0]
        p_WC, R_WC = self.trail.clamp_pose(self.x0[indices])
        e_u_W, e_v_W = np.einsum("nij,nj->ni", R_WC, e_u_C), R_WC[:, :, 2]
        return (p_WC[:, None] + uv[:, 0, :, None] * e_u_W[:, None]
                + uv[:, 1, :, None] * e_v_W[:, None]).reshape(len(indices), n_points, 3)

    def landing(self, index: int, x0: float) -> Landing:
        """Step ``index``'s state as a `Landing` at ``x0`` of another trail whose clamp pose
        there is this step's."""
        return Landing(x0, self._q[index].copy(), ContactPhase(self.phase[index]),
                       self.contact[index].copy(), self.normal[index].copy(),
                       self.force[index].copy(), float(self.s1[index]))

    def summary(self) -> dict[str, object]:
        """How the sweep went, JSON-ready."""
        return {
            "y0": self.trail.y0 if isinstance(self.trail, Trail) else None,
            "mu": self.trail.mu,
            "step": self.step,
            "n_steps": self.n_steps,
            "x0_start": float(self.x0[0]) if self.n_steps else None,
            "x0_end": self.x0_end,
            "end": self.end,
            "phase_changes": [
                {"x0": x0, "from": old, "to": new} for x0, old, new in self.phase_changes
            ],
            "stick_steps": int(np.sum(self.state == STICK)),
        }


# ---------------------------------------------------------------------------------------------
# One batched evaluation of the equilibrium conditions


_MODE_TIP, _MODE_TANGENTIAL, _MODE_STICK = MODE_TIP, MODE_TANGENTIAL, MODE_STICK
_MODE_HELD = MODE_STICK_TANGENTIAL
_STUCK = (MODE_STICK, MODE_STICK_TANGENTIAL)


def _stuck(modes: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Whether each mode is one of `_STUCK` (np.isin's result, without its cost per call)."""
    return (modes == MODE_STICK) | (modes == MODE_STICK_TANGENTIAL)


@dataclass
class _Batch:
    """Fixed data of the rows solved together (one row per sweep attempt): the clamp pose
    (origin p_WC (n, 3), rotation R_WC (n, 3, 3)), friction, where the contact was, the mode,
    and the row's object (its ``Surface.kernel_arrays``, stacked)."""

    p_WC: FloatArray
    R_WC: FloatArray
    mu: FloatArray
    anchor: FloatArray  # previous contact point (sliding) or the held point (sticking), (n, 3)
    mode: NDArray[np.int64]
    locked: NDArray[np.bool_]
    Q: FloatArray  # (n, 3, 3)
    lin: FloatArray  # (n, 3)
    c: FloatArray  # (n,)
    R_WB: FloatArray  # (n, 3, 3)
    p_WB: FloatArray  # (n, 3)
    params: FloatArray  # (n, 3): each row's rod, `RodShape.params`

    def take(self, rows: NDArray[np.int64]) -> _Batch:
        return _Batch(*(getattr(self, name)[rows] for name in _BATCH_FIELDS))


_BATCH_FIELDS = ("p_WC", "R_WC", "mu", "anchor", "mode", "locked", "Q", "lin", "c", "R_WB", "p_WB",
                 "params")


@dataclass
class _State:
    """Geometry and forces of evaluated q's: the kernels' states (n, ``STATE_WIDTH``) by name
    (``vibrissa.equilibrium``)."""

    rows: FloatArray

    @property
    def p1(self) -> FloatArray:
        return self.rows[:, 7:10]

    @property
    def tangent(self) -> FloatArray:
        return self.rows[:, 11:14]

    @property
    def normal(self) -> FloatArray:
        return self.rows[:, 14:17]

    @property
    def force(self) -> FloatArray:
        return self.rows[:, 17:20]

    @property
    def s1(self) -> FloatArray:
        return self.rows[:, 10]

    @property
    def converged(self) -> NDArray[np.bool_]:
        """Whether Newton's method converged (strict geometry; friction direction only as well
        as the chord of eq. 7 resolves it)."""
        return self.rows[:, 25] != 0.0


def bending_plane(psi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The bending plane E_psi of eq. 9 for angles psi (N,): its in-plane axis e_u = (cos psi,
    sin psi, 0) and its normal e_w = e_u x e_v = (sin psi, -cos psi, 0) (e_v = e_z), (N, 3)
    each, in the clamp frame."""
    cos_psi, sin_psi, zeros = np.cos(psi), np.sin(psi), np.zeros_like(psi)
    return np.column_stack([cos_psi, sin_psi, zeros]), np.column_stack([sin_psi, -cos_psi, zeros])


def _evaluate(q: FloatArray, batch: _Batch) -> _State:
    """The residuals of q (``vibrissa.equilibrium``) in the clamp frames C of the rows; geometry
    and forces of the state in W, where the objects are."""
    return _State(evaluate_rows(np.ascontiguousarray(q, dtype=float), *_row_arrays(batch)))


def _newton(q0: FloatArray, batch: _Batch) -> tuple[FloatArray, _State, NDArray[np.bool_]]:
    """Solve each row's conditions (four of the elastica, seven of the Kirchhoff rod) from q0;
    returns q, state, converged."""
    q, out = newton_rows(np.ascontiguousarray(q0, dtype=float), *_row_arrays(batch))
    state = _State(out)
    return q, state, state.converged


def _row_arrays(batch: _Batch) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray,
                                        NDArray[np.int64], NDArray[np.bool_], FloatArray,
                                        FloatArray, FloatArray, FloatArray, FloatArray,
                                        FloatArray]:
    """The batch as the kernels take it; the object arrays are contiguous float64 already
    (``Surface.kernel_arrays``, stacked or indexed)."""
    return (np.ascontiguousarray(batch.p_WC, dtype=float),
            np.ascontiguousarray(batch.R_WC, dtype=float),
            np.ascontiguousarray(batch.mu, dtype=float),
            np.ascontiguousarray(batch.anchor, dtype=float),
            np.ascontiguousarray(batch.mode, dtype=np.int64),
            np.ascontiguousarray(batch.locked, dtype=np.bool_),
            batch.Q, batch.lin, batch.c, batch.R_WB, batch.p_WB,
            np.ascontiguousarray(batch.params, dtype=float))


def _tangent_basis(normal: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors (N, 3) spanning the tangent planes of the unit normals (N, 3)."""
    e1 = _cross(normal, _E_Z)
    flat = np.linalg.norm(e1, axis=1) < 1e-12
    e1[flat] = _cross(normal[flat], np.array([1.0, 0.0, 0.0]))
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    return e1, _cross(normal, e1)


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """Rows a x b (N, 3) of a (N, 3) and b (N, 3) or (3,): np.cross's arithmetic, without its
    25 us of overhead a call on a few rows."""
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    return np.column_stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _held_at_slip(
    surface: Surface, z: FloatArray, q: FloatArray, batch: _Batch,
    basis: tuple[FloatArray, FloatArray]
) -> tuple[FloatArray, FloatArray, _State, NDArray[np.bool_]]:
    """Hold the tip at the slip z = (log r, theta) from the anchor; return the Coulomb mismatch.

    ``basis`` spans the tangent plane at the anchor, (N, 3) each (``_tangent_basis``). The
    mismatch F_t / F_n - mu t (t per eq. 7) in two tangent components is zero for a sliding
    equilibrium. Also returns the held q, its state and whether holding converged.
    """
    e1, e2 = basis
    r, theta = np.exp(z[:, 0:1]), z[:, 1:2]
    held = surface.closest_point(batch.anchor + r * (np.cos(theta) * e1 + np.sin(theta) * e2))
    q_held, state, converged = _newton(q, replace(batch, anchor=held,
                                                  mode=np.full(len(z), _MODE_STICK)))
    fn = np.einsum("ni,ni->n", state.force, state.normal)
    chord = batch.anchor - state.p1
    chord -= np.einsum("ni,ni->n", chord, state.normal)[:, None] * state.normal
    t = chord / np.linalg.norm(chord, axis=1)[:, None]
    mismatch = (state.force - fn[:, None] * state.normal) / fn[:, None] - batch.mu[:, None] * t
    f1, f2 = _tangent_basis(state.normal)
    residual = np.column_stack([np.einsum("ni,ni->n", mismatch, f1), np.einsum("ni,ni->n", mismatch, f2)])
    return residual, q_held, state, converged


def _small_slip(
    surface: Surface, q_stuck: FloatArray, stuck: _State, batch: _Batch
) -> tuple[FloatArray, _State, NDArray[np.bool_]]:
    """Tip slide by a short slip from the anchor, found from a stuck state outside the cone.

    A nearly stuck tip may slip by 1e-8 or less (the rod is inextensible along its axis), too
    short to resolve through the chord of eq. 7 with the plain unknowns. Here the slip itself is
    the unknown, in polar coordinates around the anchor, and every trial holds the tip there.
    """
    e1, e2 = basis = _tangent_basis(surface.normal(batch.anchor))
    fn = np.einsum("ni,ni->n", stuck.force, stuck.normal)
    slip = -(stuck.force - fn[:, None] * stuck.normal)  # the friction on the rod opposes the slip
    theta = np.arctan2(np.einsum("ni,ni->n", slip, e2), np.einsum("ni,ni->n", slip, e1))
    z = np.column_stack([np.full(len(q_stuck), np.log(1e-7)), theta])
    q = q_stuck.copy()
    # Coarse probes: the held states are only solved to 1e-12, and the slip may be ~1e-8.
    steps = np.array([0.05, 0.01])
    for _ in range(15):
        mismatch, q, state, converged = _held_at_slip(surface, z, q, batch, basis)
        if np.all(np.max(np.abs(mismatch), axis=1) < 1e-11) or not converged.all():
            break
        jac = np.empty((len(z), 2, 2))
        for j in range(2):
            probe = z.copy()
            probe[:, j] += steps[j]
            jac[:, :, j] = (_held_at_slip(surface, probe, q, batch, basis)[0] - mismatch) / steps[j]
        if not np.isfinite(jac).all():
            break  # a probe found no held state (LAPACK refuses it): on from the last state
        delta = np.stack([np.linalg.lstsq(j, -m, rcond=None)[0] for j, m in zip(jac, mismatch, strict=False)])
        z += np.clip(delta, -1.0, 1.0)
    # The slip iteration ends near the sliding state (its mismatch limited by the held states'
    # tolerance); from there the plain unknowns converge.
    return _newton(q, replace(batch, mode=np.full(len(z), _MODE_TIP)))


def _small_slip_by_object(
    surfaces: Sequence[Surface], q_stuck: FloatArray, stuck: _State, batch: _Batch
) -> tuple[FloatArray, _State, NDArray[np.bool_]]:
    """``_small_slip`` of the rows of each object (``surfaces``, one per row) apart, results in
    row order: its closest-point searches and its slip iteration run over one object's rows
    together, so that a scene's whisker slips as it would alone."""
    groups: dict[int, list[int]] = {}
    for k, surface in enumerate(surfaces):
        groups.setdefault(id(surface), []).append(k)
    if len(groups) == 1:
        return _small_slip(surfaces[0], q_stuck, stuck, batch)
    q, rows = np.empty_like(q_stuck), np.empty_like(stuck.rows)
    for members in groups.values():
        group = np.array(members, dtype=np.int64)
        q[group], part, _ = _small_slip(surfaces[members[0]], q_stuck[group],
                                        _State(stuck.rows[group]), batch.take(group))
        rows[group] = part.rows
    state = _State(rows)
    return q, state, state.converged


# ---------------------------------------------------------------------------------------------
# Sweep driver


def first_contact(surface: Surface, y0: float, shape: RodShape = UNIFORM
                  ) -> tuple[float, FloatArray] | None:
    """Largest x0 at which the unloaded rod on the trail touches the object, and the touch point.

    The rod's point at arc length s, (X(s), 0, Z(s)) from the clamp (`unloaded_points`),
    touches at x0 = x_max(Z(s)) - X(s), x_max the object's reach along x in the trail's plane
    at height Z: the first touch is the largest over s. Returns None when the trail never
    touches the object.
    """
    def reach(s: FloatArray) -> FloatArray:
        points = unloaded_points(shape, s)
        return _slice_x_max(surface, y0, points[:, 2]) - points[:, 0]

    z = np.linspace(0.0, 1.0, 2001)
    x_max = reach(z)
    if not np.isfinite(x_max).any():
        return None
    i = int(np.nanargmax(x_max))
    lo, hi = z[max(i - 1, 0)], z[min(i + 1, len(z) - 1)]
    # The reach along x of a convex object's slices is concave in z: golden-section search.
    golden = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(80):
        a, b = hi - golden * (hi - lo), lo + golden * (hi - lo)
        fa, fb = reach(np.array([a, b]))
        fa, fb = (np.nan_to_num(v, nan=-np.inf) for v in (fa, fb))
        if fa >= fb:
            hi = b
        else:
            lo = a
    candidates = np.array([lo, hi, z[i], 0.0, 1.0])
    values = np.nan_to_num(reach(candidates), nan=-np.inf)
    best = int(np.argmax(values))
    point = unloaded_points(shape, candidates[best:best + 1])[0]
    return float(values[best]), np.array([values[best] + point[0], y0, point[2]])


def _slice_x_max(surface: Surface, y0: float, z: FloatArray) -> FloatArray:
    starts = np.column_stack([np.zeros_like(z), np.full_like(z, y0), z])
    _lo, hi = surface.line_interval(starts, np.tile([1.0, 0.0, 0.0], (len(z), 1)))
    return hi


@dataclass
class _Track:
    """Mutable progress of one sweep: past ``surface`` along ``trail`` in steps of ``step``."""

    surface: Surface
    trail: ClampPath
    step: float
    max_steps: int
    locked: bool
    x0: float
    q: FloatArray
    mode: int
    p1: FloatArray
    anchor: FloatArray
    rows: list[tuple[float, int, int, FloatArray, FloatArray, FloatArray, FloatArray, float,
                     bool]] = field(default_factory=list)
    phase_changes: list[tuple[float, str, str]] = field(default_factory=list)
    end: SweepEnd | None = None
    x0_end: float = float("nan")
    smooth: bool = True  # the last two steps were alike plain slides (the predictor may extrapolate)
    chord: float = 0.0  # length of the last step's contact displacement, units of L
    chord_before: float = 0.0  # ... and of the step before it
    slid: FloatArray | None = None  # the contact's last displacement by a slide, units of L
    pending: tuple[FloatArray, FloatArray, FloatArray, float] = ()  # type: ignore[assignment]  # p1, normal, force, s1 of the last accepted state
    history: list[FloatArray] = field(default_factory=list)  # the last accepted q, newest last
    history_x: list[float] = field(default_factory=list)  # ... and the clamp x0 of each
    trace: list[FloatArray] = field(default_factory=list)  # the slide's last contact points, newest last
    jumped: bool = False  # the last step jumped (a far slide, or the force inside the step)
    pace: float = math.nan  # the contact force's change per unit of clamp travel in the last row
    x_touch: float = float("nan")  # clamp x0 at the first contact, units of L
    s_touch: float = float("nan")  # arc length of the straight rod's touching point, units of L
    x_grid: float = float("nan")  # the steps' grid is x_grid - k step, units of L
    x_early: float = float("nan")  # where EARLY_TRAVEL_L of travel after the touch ends (NaN: not known yet)
    shape: RodShape = field(default_factory=RodShape)


ProgressCallback = Callable[[int, int], None]


@dataclass(frozen=True)
class SweepProgress:
    """Where one sweep of a `SweepRun` stands.

    Attributes
    ----------
    n_steps : int
        Equilibria found so far.
    x0 : float
        Clamp position of the last equilibrium (or of the first contact), units of L; NaN on
        a trail that misses the object.
    x_touch : float
        Clamp x0 at the first contact, units of L (NaN: no contact).
    end : SweepEnd or None
        How the sweep ended; None while it goes on.
    s_touch : float
        Where the straight rod touched, arc length from the clamp, units of L (NaN: no
        contact; 0: the object meets the clamp itself, which no equilibrium of the rod holds
        off).
    """

    n_steps: int
    x0: float
    x_touch: float
    end: SweepEnd | None
    s_touch: float = math.nan


@dataclass(frozen=True)
class Landing:
    """A contact state a sweep starts from instead of a touch: a rod that snapped off one
    equilibrium and landed on the object again (`vibrissa.scene`), at clamp position ``x0``.

    ``q`` = (psi, Fu, Fv, kappa0) in the clamp frame there; ``phase`` tip or tangential;
    ``contact``, ``normal`` and ``force`` (on the rod) in W; ``s1`` the contact's arc length.
    The sweep's first row is this state, held where it landed (a stuck tip, a held tangential
    contact) when the trail has friction: its force, normal to the object, is inside the cone.
    """

    x0: float
    q: FloatArray
    phase: ContactPhase
    contact: FloatArray
    normal: FloatArray
    force: FloatArray
    s1: float


class SweepRun:
    """Several sweeps past one object, solved together one step at a time.

    ``simulate_sweeps`` runs it to the end; a consumer that wants equilibria as they are
    solved (a live sensor stream) calls ``advance`` itself and reads ``reactions``;
    `advance_together` steps several runs (each its own object and step) as one batch.

    Parameters
    ----------
    surface : Surface
        The object, in the trail's frame.
    trails : sequence of Trail
        Lateral offsets y0 (units of L) and friction coefficients.
    step : float
        Clamp displacement per step along -x, units of L.
    max_steps : int
        Safety cap on the steps of one sweep (ends with ``SweepEnd.MAX_STEPS``).
    x_grid : float, optional
        One grid of clamp positions x0 = x_grid - k step (k integer) for every trail, as for
        the whiskers of a rigid array moving together: each sweep's first step goes from its
        touch to the next grid point, a partial step. By default each trail's grid starts at
        its own first contact.
    landings : sequence of Landing or None, optional
        Per trail, a state to start from instead of the trail's first contact.
    shape : RodShape, optional
        The rod (``vibrissa.rods``): the straight uniform cylinder by default, the planar
        elastica in closed form; a tapered or pre-curved one is the Kirchhoff rod.
    """

    def __init__(self, surface: Surface, trails: Sequence[ClampPath], step: float = 0.001,
                 max_steps: int = 100_000, x_grid: float | None = None,
                 landings: Sequence[Landing | None] | None = None,
                 shape: RodShape = UNIFORM) -> None:
        if not step > 0:
            raise ValueError(f"step must be > 0, got {step}")
        for trail in trails:
            if not trail.mu >= 0:
                raise ValueError(f"mu must be >= 0, got {trail.mu}")
        self.surface = surface
        self.trails = list(trails)
        self.step = step
        self.max_steps = max_steps
        self.x_grid = x_grid
        starts = list(landings) if landings is not None else [None] * len(self.trails)
        if len(starts) != len(self.trails):
            raise ValueError(f"{len(starts)} landings for {len(self.trails)} trails")
        self._tracks = [_start(surface, trail, step, max_steps, x_grid, shape) if landing is None
                        else _land(surface, trail, step, max_steps, x_grid, landing, shape)
                        for trail, landing in zip(self.trails, starts, strict=True)]

    @property
    def done(self) -> bool:
        """Whether every sweep has ended."""
        return all(track.end is not None for track in self._tracks)

    def advance(self) -> None:
        """Move every sweep that goes on by one step (no-op once ``done``)."""
        advance_together([self])

    def progress(self, index: int) -> SweepProgress:
        """Where sweep ``index`` stands."""
        track = self._tracks[index]
        x0 = track.rows[-1][0] if track.rows else track.x0
        return SweepProgress(len(track.rows), float(x0), float(track.x_touch), track.end,
                             float(track.s_touch))

    def reactions(self, index: int, start: int = 0) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Clamp positions x0 (n,) and reactions f0, m0 (n, 3) in the clamp frame of sweep
        ``index``'s equilibria ``start``, ``start + 1``, ... found so far, units of L, EI/L^2,
        EI/L."""
        track = self._tracks[index]
        rows = track.rows[start:]
        n = len(rows)
        q = np.array([r[3] for r in rows]).reshape(n, Q_WIDTH)
        x0 = np.array([r[0] for r in rows], dtype=float)
        f0, m0 = _clamp_reactions(q, np.array([r[6] for r in rows]).reshape(n, 3),
                                  track.trail.clamp_pose(x0)[1], track.shape)
        return x0, f0, m0

    def early(self, index: int) -> bool:
        """Whether sweep ``index``'s clamp has travelled less than `EARLY_TRAVEL_L` since its
        touch: a failed step then tries longer ones, up to `EARLY_MULTIPLES` steps ahead."""
        return _early(self._tracks[index])

    def follow(self, index: int, trail: ClampPath) -> None:
        """Sweep ``index`` goes on along ``trail``: its trail with more samples after its end
        (a path that grows as it is commanded, `vibrissa.scene.SceneStream`); the steps taken
        stay as they are."""
        self.trails[index] = trail
        self._tracks[index].trail = trail

    def sweeps(self) -> list[Sweep]:
        """Every sweep as it stands (complete once ``done``)."""
        return [_finish(track) for track in self._tracks]


def advance_together(runs: Sequence[SweepRun]) -> None:
    """Move every sweep of ``runs`` that goes on by one step, all in one batched attempt (the
    runs may differ in object, path and step: the whiskers of a scene). Every sweep takes the
    same steps as it would alone, to the bit."""
    active = [t for run in runs for t in run._tracks if t.end is None]
    if active:
        _advance(active)


def simulate_sweeps(
    surface: Surface,
    trails: Sequence[ClampPath],
    step: float = 0.001,
    max_steps: int = 100_000,
    progress: ProgressCallback | None = None,
    x_grid: float | None = None,
    shape: RodShape = UNIFORM,
) -> list[Sweep]:
    """Simulate several sweeps past one object, solved together step by step (`SweepRun`,
    whose parameters these are).

    ``progress``, if given, is called as ``progress(finished_sweeps, total_sweeps)`` at the
    start and whenever a sweep ends.
    """
    run = SweepRun(surface, trails, step, max_steps, x_grid, shape=shape)
    done = sum(run.progress(i).end is not None for i in range(len(run.trails)))
    if progress:
        progress(done, len(run.trails))
    while not run.done:
        run.advance()
        finished = sum(run.progress(i).end is not None for i in range(len(run.trails)))
        if progress and finished != done:
            progress(finished, len(run.trails))
        done = finished
    return run.sweeps()


def simulate_sweep(surface: Surface, y0: float, mu: float, step: float = 0.001,
                   shape: RodShape = UNIFORM) -> Sweep:
    """One sweep at lateral offset ``y0`` with friction ``mu``; see :func:`simulate_sweeps`."""
    return simulate_sweeps(surface, [Trail(y0, mu)], step, shape=shape)[0]


def contact_lines(sweeps: Sequence[Sweep]) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """The contact cloud of sweeps: the contact point (N, 3) and the contact force on the rod
    (N, 3), in W, and the sweep (N,) of every step in contact, in sweep then step order (each
    sweep's contacts are one line on the object)."""
    touching = [sweep.phase > 0 for sweep in sweeps]
    empty = [np.zeros((0, 3))]
    return (np.concatenate([s.contact[t] for s, t in zip(sweeps, touching, strict=True)]
                           or empty),
            np.concatenate([s.force[t] for s, t in zip(sweeps, touching, strict=True)] or empty),
            np.concatenate([np.full(int(t.sum()), k, dtype=np.int64)
                            for k, t in enumerate(touching)] or [np.zeros(0, dtype=np.int64)]))


def _start(surface: Surface, trail: ClampPath, step: float, max_steps: int,
           x_grid: float | None, shape: RodShape) -> _Track:
    locked = shape.uniform and trail.symmetric(surface)
    touch = trail.first_contact(surface, shape)
    if touch is None:
        track = _Track(surface, trail, step, max_steps, locked, np.nan, np.zeros(Q_WIDTH),
                       _MODE_TIP, np.zeros(3), np.zeros(3), shape=shape)
        track.end = SweepEnd.NO_CONTACT
        return track
    x_start, p_touch = touch
    p_WC, R_WC = (a[0] for a in trail.clamp_pose(np.array([x_start])))
    n_W = surface.normal(p_touch)[0]
    normal = R_WC.T @ n_W  # in C
    x_grid = _grid(x_grid, trail, x_start)
    p_next, R_next = (a[0] for a in trail.clamp_pose(
        np.array([max(next_grid_point(x_start, x_grid, step), trail.x_end)])))
    q = np.zeros(Q_WIDTH)
    # Small-deflection guess for the first step: the touching point of the unloaded rod would
    # go into the object by ``depth`` along n; a load P at s deflects it by P s^3 / 3.
    if shape.precurvature == 0.0:
        s_touch = float((p_touch - p_WC) @ R_WC[:, 2])
        along = R_WC[:, 2]
        depth = abs((p_next + s_touch * R_next[:, 2] - p_touch) @ n_W)
    else:
        s_touch = _unloaded_arc_length(shape, R_WC.T @ (p_touch - p_WC))
        angle = shape.precurvature * s_touch
        along = R_WC @ np.array([math.sin(angle), 0.0, math.cos(angle)])
        depth = abs((p_next + R_next @ unloaded_points(shape, np.array([s_touch]))[0]
                     - p_touch) @ n_W)
    if shape.uniform:
        psi = 0.0 if locked or np.hypot(normal[0], normal[1]) == 0 else float(
            np.arctan2(normal[1], normal[0]))
        n_u = normal[0] * np.cos(psi) + normal[1] * np.sin(psi)
        magnitude = 3.0 * depth / (max(n_u * n_u, 0.05) * max(s_touch, 0.05) ** 3)
        fu, fv = magnitude * n_u, magnitude * normal[2]
        q[:4] = psi, fu, fv, -s_touch * fu
    else:
        across = 1.0 - float(n_W @ along) ** 2
        magnitude = 3.0 * depth / (max(across, 0.05) * max(s_touch, 0.05) ** 3)
        force = magnitude * normal
        r_touch = unloaded_points(shape, np.array([s_touch]))[0]
        q[0], q[1:4], q[4:7] = s_touch, force, -np.cross(r_touch, force)
    mode = _MODE_TIP if s_touch >= 1.0 - 1e-9 else _MODE_TANGENTIAL
    return _Track(surface, trail, step, max_steps, locked, x_start, q, mode, p_touch,
                  p_touch.copy(), x_touch=x_start, s_touch=s_touch, x_grid=x_grid, shape=shape)


def _unloaded_arc_length(shape: RodShape, point_C: FloatArray) -> float:
    """The arc length (L) of the unloaded pre-curved rod's point nearest ``point_C`` (C)."""
    kappa = shape.precurvature
    # the arc is the circle of radius 1 / kappa about (1 / kappa, 0, 0) in the x-z plane
    angle = math.atan2(point_C[2] * kappa, (1.0 - kappa * point_C[0]))
    return float(min(max(angle / kappa, 0.0), 1.0))


def _grid(x_grid: float | None, trail: ClampPath, x_start: float) -> float:
    """The steps' grid of a sweep from ``x_start``: the run's, else the trail's, else its own."""
    return x_grid if x_grid is not None else trail.x_grid if trail.x_grid is not None else x_start


def _land(surface: Surface, trail: ClampPath, step: float, max_steps: int,
          x_grid: float | None, landing: Landing, shape: RodShape) -> _Track:
    """A track whose first row is ``landing``: held where it landed when there is friction."""
    sliding = _MODE_TIP if landing.phase is ContactPhase.TIP else _MODE_TANGENTIAL
    held = _MODE_STICK if sliding == _MODE_TIP else _MODE_HELD
    mode = held if trail.mu > 0 else sliding
    x_grid = _grid(x_grid, trail, landing.x0)
    track = _Track(surface, trail, step, max_steps, shape.uniform and trail.symmetric(surface),
                   landing.x0, landing.q.copy(), mode, landing.contact.copy(),
                   landing.contact.copy(), x_touch=landing.x0, s_touch=landing.s1,
                   x_grid=x_grid, shape=shape)
    track.pending = (landing.contact.copy(), landing.normal.copy(), landing.force.copy(),
                     landing.s1)
    track.history, track.history_x = [track.q], [landing.x0]
    track.smooth = False
    _record(track, refined=False)
    return track


def carried_on(surface: Surface, trail: ClampPath, f0_C: FloatArray, m0_C: FloatArray,
               s1: float, contact: FloatArray, phase: ContactPhase, sliding_first: bool,
               jump: float, shape: RodShape = UNIFORM) -> Landing | None:
    """The state at the start of ``trail`` (x0 = 0) of a contact that goes on alone from
    ``contact`` (W, units of L), where it was at the sample before with the clamp reactions
    ``f0_C``, ``m0_C`` (C, units of EI/L^2 and EI/L; the guess) and the arc length ``s1``:
    sliding from it (eq. 7's chord) or held there in ``phase``, the one ``sliding_first``
    says first; None where neither converges to an admissible state within ``jump`` of
    ``contact``. A `Landing` whose first row is this state (a contact of two whose other one
    left, `vibrissa.scene`)."""
    if shape.uniform:
        psi = -math.atan2(m0_C[0], m0_C[1])
        e_u, e_w = (a[0] for a in bending_plane(np.array([psi])))
        force = -f0_C
        q0 = np.array([psi, force @ e_u, force[2], -(m0_C @ e_w), 0.0, 0.0, 0.0])
    else:
        q0 = np.concatenate([[s1], -f0_C, m0_C])
    p_WC, R_WC = trail.clamp_pose(np.zeros(1))
    sliding = _MODE_TIP if phase is ContactPhase.TIP else _MODE_TANGENTIAL
    held = _MODE_STICK if phase is ContactPhase.TIP else _MODE_HELD
    mu = np.array([trail.mu])
    for mode in (sliding, held) if sliding_first else (held, sliding):
        if mode == held and trail.mu <= 0:
            continue
        modes = np.array([mode], dtype=np.int64)
        batch = _Batch(p_WC, R_WC, mu, contact[None], modes,
                       np.array([shape.uniform and trail.symmetric(surface)]),
                       *surface.kernel_arrays, shape.params[None])
        q, state, converged = _newton(q0[None], batch)
        if converged[0] and admissible_rows(state.rows, modes, mu, contact[None],
                                            np.array([jump]))[0]:
            return Landing(0.0, q[0], phase, state.p1[0].copy(), state.normal[0].copy(),
                           state.force[0].copy(), float(state.s1[0]))
    return None


def next_grid_point(x0: float, x_grid: float, step: float) -> float:
    """The first x_grid - k step (k integer) below x0 by more than 1e-9 step."""
    k = math.floor((x_grid - x0) / step + 1e-9) + 1
    return x_grid - k * step


def _advance(tracks: list[_Track]) -> None:
    """Move every track one step of its own, in one batched attempt; a track that fails is
    retried on its own, with longer steps or refined sub-steps."""
    for track in tracks:
        if next_grid_point(track.x0, track.x_grid, track.step) < track.trail.x_end - 1e-9 * track.step:
            track.end, track.x0_end = SweepEnd.PATH_END, track.x0
    tracks = [t for t in tracks if t.end is None]
    if not tracks:
        return
    targets = np.array([next_grid_point(t.x0, t.x_grid, t.step) for t in tracks])
    before = [_Undo(t) for t in tracks]
    reached = _attempt(tracks, targets, np.array([t.step for t in tracks]))
    for track, target, ok, undo in zip(tracks, targets, reached, before, strict=False):
        if ok:
            if _turned_over(track):
                track.jumped, retaken = True, False
            else:
                retaken = (not track.jumped and _steep(track)
                           and _through_steep_step(track, undo, float(target)))
            _record(track, refined=retaken)
        elif not (_unresolved_slip(track) and _longer_step(track)):
            _refine(track, target)
        if track.end is None and len(track.rows) >= track.max_steps:
            track.end, track.x0_end = SweepEnd.MAX_STEPS, track.x0


_SLOW_GROWTH = 4.0
"""Past ``EARLY_TRAVEL_L``, a longer step is taken only where it moves the contact at most this
many times as fast as the slide before it (`_longer_step`)."""


_STEEP_GROWTH = 3.0
"""A plain step whose contact force changes more than this many times as much per unit of
clamp travel as in the step before is retaken in sub-steps (`_through_steep_step`)."""
_SMOOTH_GROWTH = 1.5
"""... and each sub-step of it again while its rate grows more than this many times over the
sub-step before it; at the finest level, a growth beyond ``_STEEP_GROWTH`` is a jump (a branch
that steepens towards its fold grows its rate by at most 2.4 times a step)."""
_STEEP_FLOOR = 1e-6
"""... and more than this, units of EI/L^2 (changes of round-off size are no jump)."""
FOLD_LEVELS = 6
"""A steep step is bisected at most this many times: a fold inside it is located to 1/64 of it."""


def _force_change(a: FloatArray, b: FloatArray) -> float:
    d = a - b
    return math.sqrt(d.dot(d))


def _steep(track: _Track) -> bool:
    """Whether the step just taken (to ``track.x0``, its state pending) changed the contact
    force per unit of clamp travel by more than ``_STEEP_GROWTH`` times the step before it
    (``track.pace``)."""
    if not track.pace >= 0.0:
        return False
    x_b, f_b = track.rows[-1][0], track.rows[-1][6]
    change = _force_change(track.pending[2], f_b)
    return change > max(_STEEP_FLOOR, _STEEP_GROWTH * track.pace * (x_b - track.x0))


def _turned_over(track: _Track) -> bool:
    """Whether the step just taken (its state pending) goes on with the jump of the row before
    it: that row jumped, the one before it did not, and the step changes the contact force by
    more than ``_STEEP_GROWTH`` times the pace of the step before the jump. A slide that runs
    far lands with the friction against it, and the next step turns the friction over at once,
    by as much at any sampling: a jump, told with the one before it (not retaken in sub-steps,
    whose chords too short for eq. 7 keep the far slide's friction direction)."""
    rows = track.rows
    if len(rows) < 3 or not rows[-1][8] or rows[-2][8]:
        return False
    pace = _force_change(rows[-2][6], rows[-3][6]) / max(rows[-3][0] - rows[-2][0], 1e-300)
    change = _force_change(track.pending[2], rows[-1][6])
    return change > max(_STEEP_FLOOR, _STEEP_GROWTH * pace * (rows[-1][0] - track.x0))


def _through_steep_step(track: _Track, before: _Undo, target: float) -> bool:
    """Retake a steep step (`_steep`) from ``before`` to ``target`` in halves, each half
    bisected again while it is steep against the sub-step before it, down to
    ``FOLD_LEVELS`` levels: so the path follows its branch as far as the branch goes, instead
    of the whole step's Newton landing on another branch before the first ends. A change of
    the contact force at the finest level that does not shrink with the sub-step (`_bisected`)
    is a jump (``track.jumped``), located to 1/2**FOLD_LEVELS of the step; a smooth but steep
    stretch is followed without one. Where a sub-step finds no equilibrium (a phase change
    the sub-steps do not resolve) the step stays as it was taken. Whether it was retaken."""
    taken = _Undo(track)
    changes = list(track.phase_changes)
    x_b, rate = track.rows[-1][0], track.pace
    before.restore(track)
    q_start, p_start, chord_start = track.q, track.p1, track.chord
    reached, _rate, jumped = _bisected(track, target, rate, 1,
                                       max(_STEEP_FLOOR, rate * (x_b - target)))
    if reached:
        # the step's own chord and predictor, not its last sub-step's: the next step is whole
        track.jumped = jumped
        track.chord_before, track.chord = chord_start, _chord(track.p1, p_start)
        track.history, track.history_x = [q_start, track.q], [before.x0, track.x0]
        return True
    taken.restore(track)
    track.phase_changes[:] = changes
    return False


def _bisected(track: _Track, target: float, rate: float, level: int, allowed: float,
              coarse: float = 0.0) -> tuple[bool, float, bool]:
    """Move ``track`` to ``target`` in two halves at bisection ``level`` (`_through_steep_step`);
    whether it got there, the force's rate of change of its last sub-step, and whether a jump
    was taken: a finest sub-step that changes the force by more than ``allowed`` and by more
    than half of what its half of the step changed it by at once (``coarse``): a jump does not
    shrink with the sub-step, the square-root onset of a branch (a tip rolling onto the rod's
    side) shrinks 5.7 times from the half step to 1/64."""
    jumped = False
    x_mid = 0.5 * (track.x0 + target)
    for x_to in (x_mid, target):
        x_from, f_from, undo = track.x0, track.pending[2], _Undo(track)
        ok = _attempt([track], np.array([x_to]), np.array([x_from - x_to]))[0]
        if ok:
            change = _force_change(track.pending[2], f_from)
            growth = change / max(rate * (x_from - x_to), 1e-300)
            if change <= _STEEP_FLOOR or growth <= _SMOOTH_GROWTH or level >= FOLD_LEVELS:
                # a jump: more in the finest sub-step than the branch's pace before the step
                # allows in the whole step (a kink, where only the pace changes, is none);
                # past it, the far branch sets the pace
                jumped = jumped or (level >= FOLD_LEVELS and change > allowed
                                    and change > 0.5 * coarse)
                rate = change / (x_from - x_to)
                continue
            undo.restore(track)
            if level == 1:
                coarse = change
        elif level >= FOLD_LEVELS:
            return False, rate, jumped
        elif level == 1:
            coarse = 0.0
        reached, rate, deeper = _bisected(track, x_to, rate, level + 1, allowed, coarse)
        if not reached:
            return False, rate, jumped
        jumped = jumped or deeper
    return True, rate, jumped


def _slow_slide(track: _Track) -> bool:
    """Whether the track slides with its last step moving the contact less than
    ``RESOLVED_CHORD_L``."""
    return track.mode not in _STUCK and 0.0 < track.chord < RESOLVED_CHORD_L


def _early_end(track: _Track) -> float:
    """The x0 at which the clamp has travelled ``EARLY_TRAVEL_L`` since the touch (the trail's
    end while it has not yet: a path that grows, `SweepRun.follow`)."""
    if math.isnan(track.x_early):
        end = track.trail.travel_end(track.x_touch, EARLY_TRAVEL_L)
        if end > track.trail.x_end:
            track.x_early = end
        return end
    return track.x_early


def _early(track: _Track) -> bool:
    """Whether the clamp has travelled less than ``EARLY_TRAVEL_L`` since the touch. The path
    coordinate advances at least as fast as the clamp: a robot slower than its path's step
    (a commanded robot below its limits) is early for more than ``EARLY_TRAVEL_L`` of it."""
    return track.x_touch - track.x0 < EARLY_TRAVEL_L or track.x0 > _early_end(track)


def _unresolved_slip(track: _Track) -> bool:
    """Whether a failed step may be taken as a longer one (`_longer_step`): `_early` after the
    touch, or a slow slide."""
    return _early(track) or _slow_slide(track)


class _Undo:
    """What an attempt changes of a track, to take the step back."""

    _FIELDS = ("x0", "q", "mode", "p1", "anchor", "smooth", "chord", "chord_before", "slid",
               "pending", "history", "history_x", "trace", "jumped")
    _get = operator.attrgetter(*_FIELDS)  # one call: every step of every track takes one

    def __init__(self, track: _Track) -> None:
        self.values = self._get(track)
        self.changes = len(track.phase_changes)

    @property
    def x0(self) -> float:
        """The track's clamp position then."""
        return float(self.values[0])

    def restore(self, track: _Track) -> None:
        for name, value in zip(self._FIELDS, self.values, strict=True):
            setattr(track, name, value)
        del track.phase_changes[self.changes:]


def _longer_step(track: _Track) -> bool:
    """Take a failed early step as 2, 4, 8, 16 or 32 steps; whether one succeeded.

    Just after a tip touch the tip slips only by the rod's axial shortening (the tip cannot stay
    put: the clamp moved and the rod is inextensible), about 1.2 d dx for a deflection d and a
    step dx: ~1e-7 over the first steps below 1e-3, too short for the direction of the chord of
    eq. 7, hence the friction, to be resolved. A longer step has a resolvable chord; the sweep
    stays on its grid and skips the positions in between (marked ``refined``). Longer steps end
    within 0.01 L of the touch while the slide moves its contact ``RESOLVED_CHORD_L`` a step:
    past that they would only skip over where the touch's own branch ends (a steep poke with
    strong friction jams the tip: 16 samples of 0.009 L on after such a touch, Newton found a
    tip state 0.125 L from it, on no branch from the touch). A slower slide (finely sampled
    paths: 3e-6 L a step 0.01 L after the touch) takes them past it too, where each must move
    the contact at most ``_SLOW_GROWTH`` times as fast as the slide before it.
    """
    step = track.step
    before = track.history[-1] if track.history else None
    next_point = next_grid_point(track.x0, track.x_grid, step)
    window = min(track.x_touch - EARLY_TRAVEL_L, _early_end(track))
    last_chord = max(track.chord, RESOLVED_CHORD_L)
    slow = _slow_slide(track)
    # Still at the touch, the guess of the loads was for the span to the next grid point
    # (`_start`): a longer step pushes the rod in further, the loads in proportion.
    touch_guess = None if track.history else track.q.copy()
    for multiple in EARLY_MULTIPLES:
        target = next_point - (multiple - 1) * step
        if target < max(track.trail.x_end, -math.inf if slow else window) - 1e-9 * step:
            break
        if touch_guess is not None:
            scale = (track.x0 - target) / (track.x0 - next_point)
            track.q = np.concatenate([touch_guess[:1], touch_guess[1:] * scale])
        undo = _Undo(track)
        if _attempt([track], np.array([target]), np.array([multiple * step]))[0]:
            if target < window and track.chord > _SLOW_GROWTH * multiple * last_chord:
                undo.restore(track)  # not the slow slide it was: a jump
                return False
            _record(track, refined=True)
            # The loads grow about linearly here: the state one step back on the line from
            # the state before (zero load at the touch) lets the predictor take the next step.
            after = track.q
            if before is None:
                before = np.zeros(Q_WIDTH)
                before[0] = after[0]
            track.history = [before + (after - before) * (multiple - 1) / multiple, after]
            track.history_x = [target + step, target]
            track.smooth = True
            return True
    if touch_guess is not None:
        track.q = touch_guess
    return False


def _refine(track: _Track, target: float) -> None:
    """Reach ``target`` in ever smaller sub-steps; if impossible the sweep has ended.

    A smooth detachment needs no refinement: once the reactions have faded and the straight
    rod at ``target`` clears the object, the unloaded rod is the equilibrium there.
    """
    step = track.step
    if (_ending(track) is SweepEnd.DETACHMENT
            and _unloaded_rod_clears(track.surface, track.trail, target, track.shape)):
        track.end, track.x0_end = SweepEnd.DETACHMENT, track.x0
        return
    span = track.x0 - target  # one step, or less for the partial first step onto a shared grid
    # Still at the touch, the guess of the loads was for the whole span (`_start`): a sub-step
    # pushes the rod in less, the loads in proportion (a coarse path's sample: 2 L at once).
    touch_guess = None if track.history else track.q.copy()
    for level in range(1, _REFINEMENTS + 1):
        sub = span / 2**level
        if touch_guess is not None and not track.history:
            track.q = np.concatenate([touch_guess[:1], touch_guess[1:] / 2**level])
        while track.x0 - sub >= target - 1e-12 * step:
            # Every sub-step tries all stages: after a stuck sub-step the tip may slip by too
            # little for the plain unknowns (a tip on a ball at mu 0.8, refined with plain
            # Newton below half steps and to 1/64, snapped off 0.18 of a step in, where sliding
            # states went on to a smooth detachment).
            if not _attempt([track], np.array([track.x0 - sub]), np.array([sub]))[0]:
                break
        if abs(track.x0 - target) <= 1e-12 * step:
            track.x0 = target
            _record(track, refined=True)
            return
    track.end = _ending(track)
    if track.end is SweepEnd.DETACHMENT:
        # The reactions fade, but a rod that comes free must be on its way out of the object:
        # a straight rod deeper in at the target than at the last equilibrium is no free rod
        # (a tip whose force halved in a sub-step before a fold, on an independent check).
        inside = _unloaded_rod_inside(track.surface, track.trail, np.array([track.x0, target]),
                                      track.shape)
        if inside[1] > 0.0 and inside[1] >= inside[0]:
            track.end = SweepEnd.SNAP_OFF
    track.x0_end = track.rows[-1][0] if track.rows else track.x0


def _unloaded_rod_clears(surface: Surface, trail: ClampPath, x0: float, shape: RodShape
                         ) -> bool:
    """Whether the unloaded rod, clamped at x0 on the trail, lies outside the object."""
    return bool(_unloaded_rod_inside(surface, trail, np.array([x0]), shape)[0] == 0.0)


def _unloaded_rod_inside(surface: Surface, trail: ClampPath, x0: FloatArray, shape: RodShape
                         ) -> FloatArray:
    """The length of the unloaded rod inside the object (n,), L, clamped at each x0 (n,): of
    its `unloaded_polyline`."""
    p_WC, R_WC = trail.clamp_pose(x0)
    starts, chords = unloaded_segments(shape, p_WC, R_WC)
    t_in, t_out = surface.line_interval(starts, chords)
    with np.errstate(invalid="ignore"):  # NaN: the line misses the object
        part = np.minimum(t_out, 1.0) - np.maximum(t_in, 0.0)
    part = np.where(part > 0.0, part, 0.0) * np.linalg.norm(chords, axis=1)
    return part.reshape(len(p_WC), -1).sum(axis=1)


def _ending(track: _Track) -> SweepEnd:
    """Detachment when the reactions had gone to zero continuously, snap-off at finite force.

    Near a smooth detachment the contact force falls linearly to zero: the last equilibrium
    carries a force of the order (slope * step), a small fraction of the sweep's peak, and the
    last decrease extrapolates to zero within about a step. At a snap-off (a fold of the
    equilibrium branch) the force is finite and often rising.
    """
    forces = np.array([np.linalg.norm(row[6]) for row in track.rows])
    if len(forces) == 0:
        return SweepEnd.NO_EQUILIBRIUM  # not even the first step after the first contact was solved
    if forces[-1] <= _DETACHMENT_FRACTION * forces.max():
        return SweepEnd.DETACHMENT
    if len(forces) >= 2 and forces[-1] <= _DETACHMENT_STEPS * (forces[-2] - forces[-1]):
        return SweepEnd.DETACHMENT
    return SweepEnd.SNAP_OFF


def _attempt(tracks: list[_Track], targets: FloatArray, steps: FloatArray) -> NDArray[np.bool_]:
    """Try to move each track by ``steps`` (n,) to its target x0 (n,): slide in its phase, the
    other phase, then stick, then the slower searches for far or barely slipping states.

    What every stage needs of the tracks (clamp poses at the targets, friction, contact points, predictors,
    objects) is gathered once: most steps are one stage of one row, whose cost is these calls.
    """
    n = len(tracks)
    success = np.zeros(n, dtype=bool)
    # the contact's largest move: 20 times the rod's in the step (the coordinate's step on a
    # path the robot follows at its step's speed, less where it goes slower: a commanded robot
    # below its limits), at least 0.01 L
    jump = np.maximum(20.0 * steps, 0.01)
    for i in np.flatnonzero(jump > 0.01).tolist():
        jump[i] = max(20.0 * tracks[i].trail.travel(targets[i] + steps[i], targets[i]), 0.01)
    objects: tuple[FloatArray, ...]  # each row's object (`Surface.kernel_arrays`) and rod
    if n == 1:
        p_WC, R_WC = tracks[0].trail.clamp_pose(targets)
        objects = (*tracks[0].surface.kernel_arrays, tracks[0].shape.params[None])
    else:
        poses = [t.trail.clamp_pose(targets[i : i + 1]) for i, t in enumerate(tracks)]
        p_WC, R_WC = np.concatenate([p for p, _ in poses]), np.concatenate([R for _, R in poses])
        objects = tuple(np.concatenate(rows) for rows in zip(
            *((*t.surface.kernel_arrays, t.shape.params[None]) for t in tracks), strict=True))
    mu = np.array([t.trail.mu for t in tracks])
    locked = np.array([t.locked for t in tracks])
    p1 = np.array([t.p1 for t in tracks])
    anchor = np.array([t.anchor for t in tracks])
    predictors = np.array([_predict(t, float(x)) for t, x in zip(tracks, targets, strict=True)])
    sliding_mode = np.array([_sliding(t.mode) for t in tracks])
    stuck: dict[int, tuple[FloatArray, _State, int]] = {}
    far: dict[int, tuple[FloatArray, _State, int, str]] = {}  # the first far slide of each row

    def solve_stage(modes: NDArray[np.int64], kind: str) -> None:
        rows = np.flatnonzero(~success)
        if kind != "slide":
            rows = rows[mu[rows] > 0]
        if kind == "alternating":
            alternates = np.array([_predict_alternating(tracks[i]) for i in rows]).reshape(
                -1, Q_WIDTH)
            finite = np.isfinite(alternates[:, 0])
            rows, alternates = rows[finite], alternates[finite]
        if kind == "anchored":
            rows = np.array([i for i in rows if i in stuck], dtype=np.int64)
        if kind == "continuation":
            # for rows where no slide was found; a far slide is one
            rows = np.array([i for i in rows if i not in far], dtype=np.int64)
        origin = p1[rows]  # where eq. 7's chord starts
        if kind == "secant":  # only here: a slide too short for its chord
            origin = np.array([_chord_origin(tracks[i], float(targets[i]))
                               for i in rows]).reshape(-1, 3)
            further = np.any(origin != p1[rows], axis=1)
            rows, origin = rows[further], origin[further]
        if len(rows) == 0:
            return
        batch = _Batch(p_WC[rows], R_WC[rows], mu[rows],
                       np.where(_stuck(modes[rows])[:, None], anchor[rows], origin),
                       modes[rows], locked[rows],
                       *(objects if len(rows) == n else (a[rows] for a in objects)))
        if kind == "anchored":
            q_stuck = np.array([stuck[int(i)][0] for i in rows])
            stuck_state = _State(np.concatenate([stuck[int(i)][1].rows for i in rows]))
            q, state, converged = _small_slip_by_object([tracks[i].surface for i in rows],
                                                        q_stuck, stuck_state, batch)
        elif kind == "continuation":
            q, state, converged = _newton_friction_continuation(predictors[rows], batch)
        elif kind == "alternating":
            q, state, converged = _newton(alternates, batch)
        else:
            q, state, converged = _newton(predictors[rows], batch)
        ok = converged & admissible_rows(state.rows, batch.mode, batch.mu, p1[rows], jump[rows])
        if kind in ("slide", "alternating", "continuation", "secant"):
            # Coulomb's friction turns back through its cone: a slide against the last one is
            # taken only where the contact cannot hold, and a held tangential contact slides
            # only once it cannot hold any longer.
            back = [k for k in np.flatnonzero(ok)
                    if tracks[int(rows[k])].mode == _MODE_HELD
                    or _turns_back(tracks[int(rows[k])], state.rows[k, 7:10])]
            if back:
                ok[back] = ~hold(rows[back])
            # A far slide waits for the later stages: the contact may hold or slip a little
            # from where it holds (`FAR_STEPS`).
            for k in np.flatnonzero(ok):
                i = int(rows[k])
                if mu[i] > 0 and _far(tracks[i], _chord(state.rows[k, 7:10], p1[i]), targets[i],
                                          steps[i]):
                    far.setdefault(i, (q[k].copy(), _take_state(state, int(k)), int(modes[i]), kind))
                    ok[k] = False
        for k in np.flatnonzero(ok):
            i = int(rows[k])
            take(i, q[k], _take_state(state, int(k)), int(modes[i]), kind)
        if kind == "stick":
            for k in np.flatnonzero(converged & ~ok):
                stuck[int(rows[k])] = (q[k], _take_state(state, int(k)), int(k))

    def take(i: int, q_i: FloatArray, state_i: _State, mode: int, kind: str) -> None:
        chord = _chord(state_i.rows[0, 7:10], p1[i])
        _accept(tracks[i], float(targets[i]), q_i, state_i, 0, mode)
        # Extrapolate only along an even stretch: in stick-slip the slides alternate in length.
        tracks[i].smooth = kind == "slide" and 0.5 * tracks[i].chord <= chord <= 2.0 * tracks[i].chord
        tracks[i].chord_before, tracks[i].chord = tracks[i].chord, chord
        success[i] = True

    def hold(rows: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Hold the contacts of ``rows`` where they are (a tip at its point, a tangential
        contact with the rod rolling over it); accept those whose force is inside the cone."""
        modes = np.where(sliding_mode[rows] == _MODE_TIP, _MODE_STICK, _MODE_HELD)
        batch = _Batch(p_WC[rows], R_WC[rows], mu[rows], anchor[rows], modes, locked[rows],
                       *(objects if len(rows) == n else (a[rows] for a in objects)))
        # from the last state, not the predictor: a hold goes on from where the contact is
        q, state, converged = _newton(np.array([tracks[i].q for i in rows]), batch)
        ok = converged & admissible_rows(state.rows, modes, mu[rows], p1[rows], jump[rows])
        for k in np.flatnonzero(ok):
            i = int(rows[k])
            _accept(tracks[i], float(targets[i]), q[k], state, int(k), int(modes[k]))
            tracks[i].smooth = False
            tracks[i].chord_before, tracks[i].chord = tracks[i].chord, 0.0
            success[i] = True
        return ok

    other_mode = np.where(sliding_mode == _MODE_TIP, _MODE_TANGENTIAL, _MODE_TIP)
    stages = [
        (sliding_mode, "slide"),
        # In stick-slip the slides alternate between creeps and jumps: predict from two back.
        (sliding_mode, "alternating"),
        (other_mode, "slide"),
        # Where no sliding state is near, the contact may stick (inside the friction cone) ...
        (np.full(n, _MODE_STICK), "stick"),
        # ... or slip only slightly from where it was: a tip slide in polar coordinates around
        # the held point, from the stuck state (well conditioned for any slip).
        (np.full(n, _MODE_TIP), "anchored"),
        # A slide whose last steps moved the contact too little to resolve eq. 7's chord: its
        # friction direction from further back along the slide (`RESOLVED_CHORD_L`).
        (sliding_mode, "secant"),
        # Friction continuation (mu from 0 up) for steps whose sliding state is far from the
        # predictor.
        (sliding_mode, "continuation"),
        (other_mode, "continuation"),
        # Last, a contact may hold where it is, the rod rolling over it: a tangential one (a
        # path that turns back: the force turns inside the cone), or a tip that rolls onto the
        # rod's side (s1 just below L, the force inside the cone).
        (np.full(n, _MODE_HELD), "held"),
    ]
    for modes, kind in stages:
        if success.all():
            break  # the later stages take only the rows still unsolved
        solve_stage(modes, kind)
    for i, (q_i, state_i, mode, kind) in far.items():
        if not success[i]:
            take(i, q_i, state_i, mode, kind)  # no nearer state: the contact jumps
            tracks[i].jumped = True
    return success


def _take_state(state: _State, k: int) -> _State:
    return _State(state.rows[k:k + 1].copy())


def _newton_friction_continuation(
    q0: FloatArray, batch: _Batch, stages: int = 16
) -> tuple[FloatArray, _State, NDArray[np.bool_]]:
    """Newton's method along mu = 0 -> mu in ``stages`` steps, each from the previous solution."""
    full_mu = batch.mu
    q = q0.copy()
    alive = np.ones(len(q), dtype=bool)
    for fraction in np.linspace(0.0, 1.0, stages + 1):
        batch.mu = fraction * full_mu
        q_next, state, converged = _newton(q, batch)
        alive &= converged
        q = np.where(alive[:, None], q_next, q)
    batch.mu = full_mu
    return q, state, alive


def _predict(track: _Track, target: float) -> FloatArray:
    """Linear extrapolation to ``target`` along a smooth stretch, never further than the last
    step's length (a sub-step of a failed step near a fold must not be predicted past the
    fold that failed it); the last state after a hard step."""
    if len(track.history) < 2 or not track.smooth:
        return track.q.copy()
    fraction = _fraction(track, target)
    if fraction >= 1.0 - 1e-9:
        return 2.0 * track.history[-1] - track.history[-2]
    return track.history[-1] + fraction * (track.history[-1] - track.history[-2])


def _fraction(track: _Track, target: float) -> float:
    """The step to ``target`` as a fraction of the last step (1 without two states to tell),
    at most 1."""
    if len(track.history_x) < 2:
        return 1.0
    x_before, x_last = track.history_x[-2:]
    return min(1.0, (x_last - target) / (x_before - x_last)) if x_before > x_last else 1.0


def _predict_alternating(track: _Track) -> FloatArray:
    """Extrapolation of every other state (period-2 stick-slip), NaN without enough history."""
    if len(track.history) < 4 or track.smooth:
        return np.full(Q_WIDTH, np.nan)
    return 2.0 * track.history[-2] - track.history[-4]


FAR_STEPS = 2.0
FAR_GROWTH = 4.0
"""A slide is far when it moves the contact further than both ``FAR_STEPS`` steps (a step: the
furthest any point of the straight rod moves) and ``FAR_GROWTH`` times the last step's move. A
far slide is taken only where no later stage finds the contact held (inside the cone) or, a
tip, slipping a little from where it holds: the return mapping of frictional contact, whose
state goes on from the last one. Far slides are jumps to another branch: a tip on a ball (mu
0.3) stepped 0.12-0.28 L every other sample at one step per sample, where 4 sub-steps per
sample stick and creep at most 0.003 L (tests/core/test_tip_jump.py). Continuous slides move the
contact up to about 1.5 steps (the paper's trail near a detachment: 2-3, each step's move
growing by less than 2x)."""


def _far(track: _Track, chord: float, target: float, step: float) -> bool:
    """Whether a slide moving the contact by ``chord`` in the step of ``step`` to ``target``
    is far (``FAR_STEPS`` of the rod's travel in it); not when it repeats the move two steps
    back (within 2x): in stick-slip, jumps alternate with creeps where each creep's branch
    folds, and checking every jump cost the paper's trail at mu 0.4 3x the time for the same
    states."""
    return (chord > FAR_GROWTH * track.chord
            and chord > FAR_STEPS * track.trail.travel(target + step, target)
            and not 0.5 * track.chord_before <= chord <= 2.0 * track.chord_before)


RESOLVED_CHORD_L = 1e-5
"""The shortest chord eq. 7's friction direction is taken along where the plain stages found
no state, units of L: a slide whose last step moved the contact less then takes it from further
back along its track (`_chord_origin`, the ``secant`` stage). The tip's slip just after a
touch is about 1.2 d dx (deflection d, step dx), 1e-6 L per step at 10 samples per 0.1 mm of a
35 mm rod, and Newton's basin for a direction along so short a chord is narrower than any
predictor: refining the step only shortens the chord further."""
_TRACE_POINTS = 64


def _chord_origin(track: _Track, target: float) -> FloatArray:
    """Where the friction direction of a slide from ``track`` to ``target`` points back to
    (3,), L: the last contact point, or the newest one of the slide's track at least
    ``RESOLVED_CHORD_L`` from where it is going when the step would move it less at the last
    step's pace (the secant of the last steps: the direction of the slip over a resolvable
    length; a sub-step of a step that failed moves it less than the step did)."""
    expected = track.chord * _fraction(track, target)
    if expected >= RESOLVED_CHORD_L or len(track.trace) < 2:
        return track.p1
    for p in reversed(track.trace[:-1]):
        if _chord(track.p1, p) + expected >= RESOLVED_CHORD_L:
            return p
    return track.trace[0]


def _chord(p1: FloatArray, previous: FloatArray) -> float:
    moved = p1 - previous
    return math.sqrt(moved.dot(moved))  # np.linalg.norm's arithmetic, without its calls


_TURN_L = 1e-6
"""Slides shorter than this (units of L) have no direction to turn back from: a nearly stuck
tip slips by 1e-8 to 1e-7, and round-off sets where."""


def _turns_back(track: _Track, p1: FloatArray) -> bool:
    """Whether moving the contact to ``p1`` turns back against its last slide."""
    if track.slid is None:
        return False
    moved = p1 - track.p1
    return (float(moved @ track.slid) < 0.0 and math.sqrt(moved.dot(moved)) > _TURN_L
            and math.sqrt(track.slid.dot(track.slid)) > _TURN_L)  # np.linalg.norm's arithmetic


def _accept(track: _Track, x0: float, q: FloatArray, state: _State, k: int, mode: int) -> None:
    if mode not in _STUCK:
        track.slid = state.p1[k] - track.p1
    track.q = q.copy()
    track.history = [*track.history[-3:], track.q]
    track.history_x = [*track.history_x[-3:], x0]
    track.x0 = x0
    phase_before = _phase_of(track.mode)
    track.mode = mode
    if track.rows and _phase_of(mode) != phase_before:
        track.phase_changes.append((x0, phase_before.label, _phase_of(mode).label))
    track.p1 = state.p1[k].copy()
    if mode not in _STUCK:
        track.anchor = track.p1
        track.trace = [*track.trace[1 - _TRACE_POINTS:], track.p1]
    else:
        track.trace = [track.p1]
    track.pending = (state.p1[k].copy(), state.normal[k].copy(), state.force[k].copy(), float(state.s1[k]))


def _phase_of(mode: int) -> ContactPhase:
    return ContactPhase.TANGENTIAL if _sliding(mode) == _MODE_TANGENTIAL else ContactPhase.TIP


def _sliding(mode: int) -> int:
    """The sliding mode of a mode's phase (a held tip: the tip's)."""
    return _MODE_TIP if mode == _MODE_STICK else _MODE_TANGENTIAL if mode == _MODE_HELD else mode


def _record(track: _Track, refined: bool) -> None:
    p1, normal, force, s1 = track.pending
    if track.rows:
        x_b, f_b = track.rows[-1][0], track.rows[-1][6]
        track.pace = _force_change(force, f_b) / max(x_b - track.x0, 1e-300)
    track.rows.append((track.x0, track.mode, refined, track.q.copy(), p1, normal, force, s1,
                       track.jumped))
    track.jumped = False


def _clamp_reactions(q: FloatArray, force_W: FloatArray, R_WC: FloatArray, shape: RodShape
                     ) -> tuple[FloatArray, FloatArray]:
    """f0, m0 (n, 3) in the clamp frames C of states ``q`` (n, ``Q_WIDTH``) of a rod of
    ``shape`` with contact forces ``force_W`` (n, 3) in W and clamp rotations ``R_WC``
    (n, 3, 3).

    From the rod's own internal loads at s = 0 (not from r x F, so that the statics
    m0 + r x F = 0 stays a check of the rod): f0 = -F, m0 = -kappa0 e_w of the elastica, the
    unknown m0 of the Kirchhoff rod.
    """
    f0 = -np.matmul(force_W[:, None, :], R_WC)[:, 0, :]
    if not shape.uniform:
        return f0, q[:, 4:7].copy()
    e_w_C = bending_plane(q[:, 0])[1]
    return f0, -q[:, 3:4] * e_w_C


def _finish(track: _Track) -> Sweep:
    rows = track.rows
    n = len(rows)
    q = np.array([r[3] for r in rows]).reshape(n, Q_WIDTH)
    x0 = np.array([r[0] for r in rows], dtype=float)
    modes = np.array([r[1] for r in rows], dtype=np.int64)
    refined = np.array([r[2] for r in rows], dtype=bool)
    jumped = np.array([r[8] for r in rows], dtype=bool)
    contact = np.array([r[4] for r in rows]).reshape(n, 3)
    normal = np.array([r[5] for r in rows]).reshape(n, 3)
    force = np.array([r[6] for r in rows]).reshape(n, 3)
    f0, m0 = _clamp_reactions(q, force, track.trail.clamp_pose(x0)[1], track.shape)
    psi = -np.arctan2(m0[:, 0], m0[:, 1])
    fn = np.einsum("ni,ni->n", force, normal)
    ft = np.linalg.norm(force - fn[:, None] * normal, axis=1)
    s1 = np.minimum(np.array([r[7] for r in rows], dtype=float), 1.0)
    end = track.end or SweepEnd.MAX_STEPS
    return Sweep(
        trail=track.trail,
        step=track.step,
        x0=x0,
        phase=np.array([_phase_of(m) for m in modes], dtype=np.int64),
        state=np.where(_stuck(modes), STICK, SLIDE).astype(np.int64),
        s1=s1,
        psi=psi,
        f0=f0,
        m0=m0,
        contact=contact,
        normal=normal,
        force=force,
        fn=fn,
        ft=ft,
        refined=refined,
        jumped=jumped,
        end=end,
        x0_end=float(track.x0_end),
        phase_changes=track.phase_changes,
        x_touch=float(track.x_touch),
        s_touch=float(track.s_touch),
        _q=q,
        shape=track.shape,
    )
