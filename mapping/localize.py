"""Correcting a drifting odometry from whisker contacts (`Localizer`): the transform ``map ->
odom`` (REP 105) estimated from the contacts, and the contacts placed in ``map`` with it.

The contacts come in *visits*: runs of contacts with less than ``visit_gap_m`` of travel
between them and at most ``max_visit_m`` long (the whiskers sweeping past an object once), or
``max_visit_s`` of stamps (a robot that stands still while it touches).
Over a visit the odometry's error is taken as constant, so a visit is a rigid patch of surface
in ``odom``, and ``map -> odom`` is one translation in the floor's plane per visit (REP 103: z
up). A heading error shows where the robot is as the translation it causes there (the lever
is in the odometry factors below); over a visit's patch, a few centimetres, the rotation it
leaves is a small fraction of that, and the contacts hardly see it (a patch of a ball turned
about the ball's centre fits it as well). When a visit ends, the translations of the last
``window`` visits are estimated together, the earlier ones held where they were (a pose graph,
solved by scipy's ``least_squares``):

* odometry factors: the first visit's translation from zero at the start, each next one from
  the one before, with the drift of the travel between them (the model of
  `vibrissa.odometry`: per metre, position and heading random walks of standard deviation
  ``drift_per_m``; a heading increment shifts the position at the visit by its lever from
  where the base was);
* surface factors: each contact of a visit (up to ``max_points`` of them) against the patch of
  every other visit measured at least ``min_separation_m`` of travel away (a separate drift)
  that has contacts within the radius of it: the residual is its height over a quadric fitted
  to those contacts' positions and normals (`vibrissa.mapping.objects.contact_normals`), over
  ``point_std_m`` and the quadric's own fit, with Huber weights (a wrong match costs
  linearly). A contact matches a quadric only where their normals are within 60 degrees (not
  the far side of a thin object). Matches are made again at each of ``rounds`` rounds, the
  radius halving down to ``match_radius_m``.

An estimate that moves a visit from the one before it by more than the odometry allows
(``ODOMETRY_GATE`` standard deviations of the drift between them) rests on a wrong match (a
patch slid along its surface, or another object's): it is refused, the estimates stay where
they were and the visit is placed by the odometry (`LocalizeCounts.inconsistent`).

The visit that ended is then placed with its estimate (earlier visits are not placed again:
their points have gone out). With no surface factor at all (too few contacts near other
visits') the estimate is the odometry's, and `LocalizeCounts.unregistered` counts it. With
``drift_per_m`` 0 the odometry is taken as exact: the points are placed as they came, at once.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix, csr_matrix
from scipy.spatial import cKDTree

from vibrissa.mapping.objects import contact_normals

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

HUBER_SIGMAS = 2.0
"""A surface factor beyond this many standard deviations costs linearly (Huber)."""
NORMAL_GATE_COS = 0.5
"""A contact is matched to another visit's quadric only where its normal and the quadric's
are within 60 degrees (not the other side of a thin object)."""
ODOMETRY_GATE = 4.3
"""A registration is refused where a visit moved from the one before it by more than this many
standard deviations of the odometry's drift between them (chi-square of 2 degrees of freedom
at 1e-4)."""
HUBER_ROUNDS = 3
"""Solves per matching round, the Huber weights made again after each."""


@dataclass(frozen=True)
class LocalizeSettings:
    """How a `Localizer` corrects (see the module).

    Attributes
    ----------
    drift_per_m
        The odometry's drift model: position (m) and heading (rad) random walk standard
        deviations per metre travelled; 0: the odometry is exact.
    point_std_m
        A contact's height over another visit's surface, its standard deviation, m: the
        contacts' own and what a quadric over a few millimetres misses.
    match_radius_m
        The finest radius in which another visit's contacts give the surface at a contact, m.
    rounds
        Rounds of matching and solving per estimate, the radius halving down to
        ``match_radius_m``.
    min_neighbours
        Contacts of a visit that give a surface.
    min_separation_m
        Visits measured within this much travel of each other are not registered together
        (their drift is the same), m.
    visit_gap_m
        Travel without contact that ends a visit, m.
    max_visit_m, max_visit_s
        Longest visit, m of travel and s of stamps: its contacts wait for it to end.
    max_points
        Contacts of a visit used for its surface factors at most (evenly along the visit).
    window
        The newest visits estimated together; those before stay where they were estimated
        last (still surfaces to register against): the size of a solve is bounded.
    """

    drift_per_m: float = 0.02
    point_std_m: float = 1e-3
    match_radius_m: float = 0.004
    rounds: int = 3
    min_neighbours: int = 8
    min_separation_m: float = 0.03
    visit_gap_m: float = 0.01
    max_visit_m: float = 0.03
    max_visit_s: float = 2.0
    max_points: int = 150
    window: int = 12

    def __post_init__(self) -> None:
        for name in ("drift_per_m", "min_separation_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name!r} must be a finite number >= 0, got {value!r}")
        for name in ("point_std_m", "match_radius_m", "visit_gap_m", "max_visit_m",
                     "max_visit_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name!r} must be a finite number > 0, got {value!r}")
        for name, least in (("rounds", 1), ("min_neighbours", 6), ("max_points", 1),
                            ("window", 1)):
            if getattr(self, name) < least:
                raise ValueError(f"{name!r} must be an integer >= {least}, got "
                                 f"{getattr(self, name)!r}")


@dataclass
class LocalizeCounts:
    """What a `Localizer` did: visits estimated with surface factors (``registered``),
    without (``unregistered``: too few contacts near other visits'), and refused
    (``inconsistent``: the estimate moved a visit further than the odometry allows, and the
    visit went by the odometry), contacts placed."""

    registered: int = 0
    unregistered: int = 0
    inconsistent: int = 0
    placed: int = 0


@dataclass(frozen=True)
class PlacedBatch:
    """A batch of contacts given to `Localizer.add`, placed: its ``token``, the points (n, 3)
    in ``map``, m, and the estimate of ``map -> odom`` it was placed with: a translation
    (x, y), m (the covariances keep their axes: ``map`` and ``odom`` are parallel)."""

    token: Hashable
    points_m: FloatArray
    covariances_m2: FloatArray | None
    map_to_odom_m: tuple[float, float]


@dataclass(frozen=True)
class _Batch:
    """Contacts given to `Localizer.add` together."""

    token: Hashable
    points: FloatArray
    forces: FloatArray
    whisker_ids: list[str]
    covariances: FloatArray | None


@dataclass
class _Visit:
    """A visit's contacts in ``odom`` and where along the travel it was."""

    start_m: float
    end_m: float
    base_odom: FloatArray  # the base's odom position (2,) at its start
    start_s: float  # the stamp of its first contacts
    whiten: FloatArray = field(default_factory=lambda: np.eye(2))  # its odometry factor's L^T
    batches: list[_Batch] = field(default_factory=list)
    points: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))  # used for factors
    point_normals: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))  # theirs
    tree: cKDTree | None = None  # of all its contacts
    anchors: cKDTree | None = None  # of ``points``: where its quadrics are
    quadrics: dict[float, _Quadrics] = field(default_factory=dict)  # by radius

    def close(self, max_points: int) -> None:
        """Its contacts' normals (`contact_normals`, each whisker's contacts a line) and the
        contacts its factors use, evenly along it: they are matched, and its quadrics are
        centred on them."""
        points = np.vstack([b.points for b in self.batches])
        forces = np.vstack([b.forces for b in self.batches])
        names = [name for b in self.batches for name in b.whisker_ids]
        lines = np.unique(names, return_inverse=True)[1].reshape(-1)
        order = np.argsort(lines, kind="stable")  # each line in the order it came
        normals = np.empty_like(points)
        normals[order] = contact_normals(points[order], forces[order], lines[order])
        pick = np.unique(np.linspace(0, len(points) - 1, min(len(points), max_points)).astype(int))
        self.points, self.point_normals = points[pick], normals[pick]
        self.tree, self.anchors = cKDTree(points), cKDTree(self.points)
        self._all, self._normals = points, normals

    def quadrics_at(self, anchors: IntArray, radius_m: float, settings: LocalizeSettings
                    ) -> _Quadrics:
        """The quadrics of radius ``radius_m`` at its contacts ``points[anchors]``, fitted on
        first use (`_quadric`)."""
        q = self.quadrics.get(radius_m)
        if q is None:
            n = len(self.points)
            q = self.quadrics[radius_m] = _Quadrics(
                np.zeros(n, bool), np.zeros(n, bool), np.zeros((n, 3)), np.zeros((n, 3, 3)),
                np.zeros((n, 6)), np.zeros(n))
        assert self.tree is not None
        for i in np.unique(anchors[~q.done[anchors]]).tolist():
            q.done[i] = True
            idx = self.tree.query_ball_point(self.points[i], radius_m)
            if len(idx) >= settings.min_neighbours:
                fitted = _quadric(self._all[idx], self._normals[idx], radius_m)
                q.ok[i] = True
                q.centre[i], q.axes[i], q.coef[i], q.fit_var[i] = fitted
        return q


class _Quadrics(NamedTuple):
    """A visit's quadrics at its factor contacts: fitted yet, fitted with enough neighbours,
    and each one's centre (3,), axes (3, 3) (u, v, normal as rows), coefficients (6,) and
    the variance of its fit to the heights."""

    done: npt.NDArray[np.bool_]
    ok: npt.NDArray[np.bool_]
    centre: FloatArray
    axes: FloatArray
    coef: FloatArray
    fit_var: FloatArray


def _quadric(q: FloatArray, nq: FloatArray, radius_m: float
             ) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """The quadric height field through contacts ``q`` (k, 3) with normals ``nq`` (k, 3), over
    the plane of their mean normal, fitted to their heights and to the slopes their normals
    give (weighted by ``radius_m``): centre, axes (u, v, normal as rows), coefficients of
    (u^2, uv, v^2, u, v, 1), and the variance of the fit to the heights."""
    centre = q.mean(axis=0)
    e_n = nq.mean(axis=0)
    e_n /= math.sqrt(e_n @ e_n)
    # a unit vector across e_n: e_n x (x or y axis, whichever is further from it)
    e_u = (np.array([0.0, e_n[2], -e_n[1]]) if abs(e_n[0]) < 0.9
           else np.array([-e_n[2], 0.0, e_n[0]]))
    e_u /= math.sqrt(e_u @ e_u)
    e_v = np.array([e_n[1] * e_u[2] - e_n[2] * e_u[1], e_n[2] * e_u[0] - e_n[0] * e_u[2],
                    e_n[0] * e_u[1] - e_n[1] * e_u[0]])
    axes = np.array([e_u, e_v, e_n])
    d, m = (q - centre) @ axes.T, nq @ axes.T
    u, v = d[:, 0], d[:, 1]
    k = len(q)
    A = np.zeros((3 * k, 6))
    A[:k] = _quadric_terms(u, v)
    # slopes dh/du = -n_u / n_n, dh/dv = -n_v / n_n, weighted by the radius
    A[k:2 * k, 0], A[k:2 * k, 1], A[k:2 * k, 3] = 2 * radius_m * u, radius_m * v, radius_m
    A[2 * k:, 1], A[2 * k:, 2], A[2 * k:, 4] = radius_m * u, 2 * radius_m * v, radius_m
    y = np.concatenate([d[:, 2], -radius_m * m[:, 0] / m[:, 2], -radius_m * m[:, 1] / m[:, 2]])
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    res = d[:, 2] - A[:k] @ coef
    return centre, axes, coef, float(res @ res) / k


def _quadric_terms(u: FloatArray, v: FloatArray) -> FloatArray:
    return np.column_stack([u * u, u * v, v * v, u, v, np.ones_like(u)])


class Localizer:
    """``map -> odom`` from the contacts of a robot with a drifting odometry (see the module).
    Feed the odometry's poses (`add_pose`) and the contacts (`add`), both in stamp order;
    `take` gives the batches placed in ``map`` once their visit has ended (`finish` ends the
    last one). The same inputs give the same bits."""

    def __init__(self, settings: LocalizeSettings | None = None) -> None:
        self.settings = settings or LocalizeSettings()
        self.counts = LocalizeCounts()
        self.estimate_m = np.zeros(2)  # map -> odom of the newest visit placed
        self._pose_t: list[float] = []
        self._pose_xy: list[FloatArray] = []
        self._pose_s: list[float] = []
        self._visits: list[_Visit] = []  # ended
        self._x = np.zeros((0, 2))  # their translations
        self._open: _Visit | None = None
        self._out: list[PlacedBatch] = []

    def add_pose(self, stamp: float, p_odom_m: FloatArray) -> None:
        """The odometry's pose of the base at ``stamp`` (s): its position in ``odom``, m (a
        stamp not after the last pose's is ignored)."""
        xy = np.asarray(p_odom_m, dtype=np.float64)[:2].copy()
        if self._pose_t and not stamp > self._pose_t[-1]:
            return
        s = self._pose_s[-1] + float(np.hypot(*(xy - self._pose_xy[-1]))) if self._pose_t else 0.0
        self._pose_t.append(float(stamp))
        self._pose_xy.append(xy)
        self._pose_s.append(s)

    def travel(self, stamp: float) -> tuple[float, FloatArray]:
        """The base's travel (m) and odom position (2,) at ``stamp``, interpolated between the
        poses (held before the first and after the last)."""
        if not self._pose_t:
            return 0.0, np.zeros(2)
        k = int(np.searchsorted(self._pose_t, stamp))
        if k == 0:
            return self._pose_s[0], self._pose_xy[0]
        if k >= len(self._pose_t):
            return self._pose_s[-1], self._pose_xy[-1]
        t0, t1 = self._pose_t[k - 1], self._pose_t[k]
        w = (stamp - t0) / (t1 - t0)
        return ((1 - w) * self._pose_s[k - 1] + w * self._pose_s[k],
                (1 - w) * self._pose_xy[k - 1] + w * self._pose_xy[k])

    def add(self, stamp: float, points_odom_m: FloatArray, forces_n: FloatArray,
            whisker_ids: Sequence[str], covariances_m2: FloatArray | None, token: Hashable
            ) -> None:
        """Contacts measured at ``stamp``: points (n, 3) in ``odom``, m, the contact forces on
        the rods (n, 3), N, in ``odom`` too (their normals), the whiskers (n), and the
        covariances (n, 3, 3) m^2 or None; ``token`` comes back with them placed (`take`)."""
        points = np.reshape(np.asarray(points_odom_m, dtype=np.float64), (-1, 3))
        batch = _Batch(token, points, np.reshape(np.asarray(forces_n, dtype=np.float64), (-1, 3)),
                       list(whisker_ids), covariances_m2)
        if self.settings.drift_per_m == 0.0:
            self._place(batch, self.estimate_m)
            return
        s, base = self.travel(stamp)
        visit = self._open
        if visit is not None and (s - visit.end_m > self.settings.visit_gap_m
                                  or s - visit.start_m > self.settings.max_visit_m
                                  or stamp - visit.start_s > self.settings.max_visit_s):
            self._end_visit()
            visit = None
        if not len(points) and visit is None:  # nothing to hold: out at once
            self._place(batch, self.estimate_m)
            return
        if visit is None:
            visit = self._open = _Visit(s, s, base, stamp)
        if len(points):
            visit.end_m = s
        visit.batches.append(batch)

    def finish(self) -> None:
        """End the visit in progress (the stream ended)."""
        if self._open is not None:
            self._end_visit()

    def take(self) -> list[PlacedBatch]:
        """The batches placed since the last call, in the order they came."""
        out, self._out = self._out, []
        return out

    def _place(self, batch: _Batch, x: FloatArray) -> None:
        """``batch`` into ``map`` by the translation x (``map -> odom``), out at `take`."""
        points = batch.points.copy()
        if x.any():
            points[:, :2] += x
        self._out.append(PlacedBatch(batch.token, points, batch.covariances,
                                     (float(x[0]), float(x[1]))))
        self.counts.placed += len(points)

    def _end_visit(self) -> None:
        visit = self._open
        assert visit is not None
        self._open = None
        if not any(len(b.points) for b in visit.batches):
            for batch in visit.batches:
                self._place(batch, self.estimate_m)
            return
        visit.close(self.settings.max_points)
        visit.whiten = self._whitening(self._visits[-1].start_m if self._visits else 0.0,
                                       visit.start_m, visit.base_odom)
        self._visits.append(visit)
        # the next visit's odometry factor needs the poses from this one's start on
        keep = max(0, int(np.searchsorted(self._pose_s, visit.start_m)) - 1)
        del self._pose_t[:keep], self._pose_xy[:keep], self._pose_s[:keep]
        self._x = np.vstack([self._x, self._x[-1] if len(self._x) else np.zeros(2)])
        solved = self._solve()
        if solved is None:
            self.counts.inconsistent += 1
        elif solved:
            self.counts.registered += 1
        else:
            self.counts.unregistered += 1
        self.estimate_m = self._x[-1].copy()
        for batch in visit.batches:
            self._place(batch, self.estimate_m)

    def _whitening(self, from_m: float, to_m: float, base_odom: FloatArray) -> FloatArray:
        """L^T (2, 2), L L^T the inverse covariance of the translation the odometry's error
        grew by over the travel from ``from_m`` to ``to_m``, at the base's place at its end
        ``base_odom``: each stretch ds of the way adds D^2 ds per axis, and a heading
        increment of D^2 ds times its lever from where the base was."""
        s = np.asarray(self._pose_s)
        k = np.flatnonzero((s > from_m) & (s <= to_m))
        k = k[k > 0]
        cov = np.eye(2) * 1e-18  # none: pinned
        if len(k):
            xy = np.asarray(self._pose_xy)
            ds = s[k] - s[k - 1]
            lever = base_odom - 0.5 * (xy[k] + xy[k - 1])
            perp = np.column_stack([-lever[:, 1], lever[:, 0]])
            cov += self.settings.drift_per_m**2 * (np.eye(2) * ds.sum()
                                                    + (perp * ds[:, None]).T @ perp)
        return np.asarray(np.linalg.cholesky(np.linalg.inv(cov)).T)

    def _solve(self) -> bool | None:
        """Estimate every visit's translation (see the module); whether a surface factor was
        made, None when the estimate was refused (`_consistent`)."""
        settings = self.settings
        visits = self._visits
        n = len(visits)
        first = max(0, n - settings.window)
        pairs = [(a, b) for a in range(n) for b in range(n) if a != b and max(a, b) >= first
                 and _apart(visits[a], visits[b], settings.min_separation_m)]
        x = self._x.copy()
        registered = False
        whiten = np.array([visit.whiten for visit in visits])
        for k in range(settings.rounds - 1, -1, -1) if pairs else ():
            matches = self._matches(x, pairs, settings.match_radius_m * 2**k)
            if matches is None:
                continue
            registered = True
            problem = _Problem(whiten, matches, settings.point_std_m, x, first)
            for _ in range(HUBER_ROUNDS):
                fit = least_squares(problem.residuals, x[first:].reshape(-1),
                                    jac=problem.jacobian, x_scale=0.01, max_nfev=100)
                x = problem.full(fit.x)
                problem.reweight(fit.fun)
        if registered and not _consistent(whiten[first:], x, first):
            return None  # every estimate as it was, the new visit's the one before it's
        self._x = x
        return registered

    def _matches(self, x: FloatArray, pairs: list[tuple[int, int]], radius: float
                 ) -> _Matches | None:
        """Each factor contact of a visit a within ``radius`` of another visit b's factor
        contacts, against b's quadric at the nearest of them (see `_Matches`), or None."""
        parts = []
        for a, b in pairs:
            va, vb = self._visits[a], self._visits[b]
            assert vb.anchors is not None
            in_b = va.points.copy()
            in_b[:, :2] += x[a] - x[b]
            dist, nearest = vb.anchors.query(in_b, distance_upper_bound=radius)
            near = np.isfinite(dist)
            q = vb.quadrics_at(nearest[near], radius, self.settings)
            at = nearest[near]
            ok = q.ok[at] & (np.einsum("ki,ki->k", va.point_normals[near], q.axes[at, 2])
                             > NORMAL_GATE_COS)
            at = at[ok]
            if len(at):
                parts.append(_Matches(np.full(len(at), a), np.full(len(at), b),
                                      va.points[near][ok], q.centre[at], q.axes[at], q.coef[at],
                                      q.fit_var[at]))
        if not parts:
            return None
        return _Matches(*(np.concatenate(arrays) for arrays in zip(*parts, strict=True)))


class _Matches(NamedTuple):
    """Contacts of visits ``a`` (m,) at ``point`` (m, 3) in a's odom, each against a quadric
    of visit ``b`` (m,): centres (m, 3), axes (m, 3, 3), coefficients (m, 6), fit variances
    (m,)."""

    a: IntArray
    b: IntArray
    point: FloatArray
    centre: FloatArray
    axes: FloatArray
    coef: FloatArray
    fit_var: FloatArray


class _Problem:
    """The pose graph's residuals and Jacobian over the visits from ``first`` on (those
    before are fixed at ``xs``): odometry factors (2 per free visit) then surface factors
    (one per match, each with a free visit), the latter with Huber weights (`reweight`)."""

    def __init__(self, whiten: FloatArray, matches: _Matches, point_std_m: float,
                 xs: FloatArray, first: int) -> None:
        self.n = len(whiten)
        self.first = first
        self.fixed = xs.copy()
        self.whiten = whiten
        self.m = matches
        self.base_weight = 1.0 / np.sqrt(point_std_m**2 + matches.fit_var)
        self.weight = self.base_weight.copy()

    def full(self, free: FloatArray) -> FloatArray:
        """Every visit's translation (n, 2): the fixed ones, then ``free``."""
        xs = self.fixed.copy()
        xs[self.first:] = free.reshape(-1, 2)
        return xs

    def _surface(self, xs: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Heights (m,) m and the surface's gradient in map (m, 2) (x, y)."""
        m = self.m
        p_b = m.point.copy()
        p_b[:, :2] += xs[m.a] - xs[m.b]
        d = np.einsum("kij,kj->ki", m.axes, p_b - m.centre)
        u, v, c = d[:, 0], d[:, 1], m.coef
        h = d[:, 2] - (c[:, 0] * u * u + c[:, 1] * u * v + c[:, 2] * v * v + c[:, 3] * u
                       + c[:, 4] * v + c[:, 5])
        g = np.column_stack([-(2 * c[:, 0] * u + c[:, 1] * v + c[:, 3]),
                             -(c[:, 1] * u + 2 * c[:, 2] * v + c[:, 4]), np.ones_like(u)])
        return h, np.einsum("kij,ki->kj", m.axes, g)[:, :2]

    def residuals(self, free: FloatArray) -> FloatArray:
        xs = self.full(free)
        step = np.diff(np.vstack([np.zeros(2), xs]), axis=0)[self.first:]
        odometry = np.einsum("vij,vj->vi", self.whiten[self.first:], step)
        return np.concatenate([odometry.reshape(-1), self._surface(xs)[0] * self.weight])

    def jacobian(self, free: FloatArray) -> csr_matrix:
        xs = self.full(free)
        n, m, first = self.n, self.m, self.first
        rows, cols, vals = [], [], []
        v = np.arange(first, n)  # the free visits' odometry factors, rows from 0
        w = self.whiten[first:]
        for i in range(2):
            for k in range(2):  # d (W (x_v - x_{v-1}))_i / d x_v,k and x_{v-1},k
                rows += [2 * (v - first) + i, 2 * (v - first) + i]
                cols += [2 * v + k, 2 * v - 2 + k]
                vals += [w[:, i, k], -w[:, i, k]]
        _, grad = self._surface(xs)
        r = 2 * (n - first) + np.arange(len(m.a))
        for k in range(2):
            rows += [r, r]
            cols += [2 * m.a + k, 2 * m.b + k]
            vals += [grad[:, k] * self.weight, -grad[:, k] * self.weight]
        row, col, val = np.concatenate(rows), np.concatenate(cols) - 2 * first, np.concatenate(vals)
        keep = col >= 0  # a fixed visit is no unknown
        return coo_matrix((val[keep], (row[keep], col[keep])),
                          shape=(2 * (n - first) + len(m.a), 2 * (n - first))).tocsr()

    def reweight(self, fun: FloatArray) -> None:
        """Huber weights from the residuals ``fun`` of the last solve."""
        scaled = np.abs(fun[2 * (self.n - self.first):]) / self.weight * self.base_weight
        self.weight = self.base_weight * np.sqrt(
            np.minimum(1.0, HUBER_SIGMAS / np.maximum(scaled, 1e-300)))


def _consistent(whiten: FloatArray, x: FloatArray, first: int) -> bool:
    """Whether each of the translations ``x[first:]`` moved from the one before it by what the
    odometry's drift allows (its whitened step within ``ODOMETRY_GATE``): a registration that
    needs more is a wrong match (another object's patch, or a patch slid along its surface)."""
    step = np.diff(np.vstack([np.zeros(2), x]), axis=0)[first:]
    whitened = np.einsum("vij,vj->vi", whiten, step)
    return bool(np.all(np.einsum("vi,vi->v", whitened, whitened) <= ODOMETRY_GATE**2))


def _apart(a: _Visit, b: _Visit, separation_m: float) -> bool:
    """Whether visits a and b are at least ``separation_m`` of travel apart."""
    return a.start_m - b.end_m >= separation_m or b.start_m - a.end_m >= separation_m


def true_map_to_odom(stamps_s: FloatArray, p_map_m: FloatArray, q_map: FloatArray,
                     p_odom_m: FloatArray, q_odom: FloatArray, stamp: float
                     ) -> tuple[float, float, float] | None:
    """The true ``map -> odom`` at ``stamp`` from the truth of a simulated run (the base's true
    poses in ``map`` and the odometry's in ``odom``, by stamp; the last pose at or before
    ``stamp``): x, y (m) and yaw (rad), the error the odometry has there; None before the
    first pose."""
    k = int(np.searchsorted(np.asarray(stamps_s), stamp, side="right")) - 1
    if k < 0:
        return None

    def yaw(q: FloatArray) -> float:
        x, y, z, w = np.asarray(q, dtype=np.float64)
        return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))

    e_yaw = yaw(q_map[k]) - yaw(q_odom[k])
    c, s = math.cos(e_yaw), math.sin(e_yaw)
    p, o = p_map_m[k], p_odom_m[k]
    return (float(p[0] - (c * o[0] - s * o[1])), float(p[1] - (s * o[0] + c * o[1])),
            math.remainder(e_yaw, math.tau))
