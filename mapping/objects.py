"""Contact lines, contact normals and the objects of a whisker contact cloud (Open3D DBSCAN).

Why this method
---------------
A whisker's contact cloud is a handful of dense *lines* on the object (one per sweep, points
~step apart along a line, lines ~0.2 L apart), not an area sample. Two things follow:

* **Normals come from the contact mechanics, not from the cloud.** Open3D's PCA normals
  (``estimate_normals``) are undefined on a line: its neighbourhood is one-dimensional
  unless the radius spans the gap to the next line, which blurs the estimate across it. The
  contact force F on the rod is known at every point, and Coulomb's law puts it in the plane
  of the outward normal n and the sliding direction t: F = f_n (n + mu t), with t along the
  contact line (eq. 7: towards the previous contact point). Removing from F its component
  along the line's local tangent therefore gives n exactly while sliding (for any mu), and
  F itself is n for mu = 0 or at an isolated point. The orientation is free: the object
  pushes the rod, so F . n > 0 and n points out of the object.
* **The surface** is a Gaussian-process implicit surface on the points and these normals
  (`vibrissa.mapping.surface`): docs/MAPPING.md measures it against screened Poisson and an
  RBF implicit surface.

Separating objects
------------------
Several whiskers passing several objects give one cloud per frame; ``cluster_points`` splits it
into objects with Open3D's DBSCAN (``PointCloud.cluster_dbscan``). A contact line never spans
two objects (a whisker touches one at a time, and leaving one for another is a jump that
``split_lines`` breaks at), so what decides is which lines join: the lines of neighbouring
whiskers on one object lie about one *line spacing* apart, the objects farther. The radius
``eps`` is a length of the geometry, not of the sampling (a faster sampling rate must not
split an object): ``EPS_LINE_SPACINGS`` line spacings, but at most ``EPS_LINE_EXTENT`` of the
typical extent of a contact line, because with only one or two lines per object the spacing
measures the gap between objects instead (docs/NODES.md has the measurements behind both
numbers); an object touched by whiskers farther apart than ``eps`` is then several clusters, which
``join_convex`` joins when they are patches of one convex object (by the contact normals).
DBSCAN runs on one representative point per cubic cell of ``eps / DBSCAN_CELLS``, and
each point takes its cell's label: Open3D keeps the neighbour list of every point, which grows
with the sampling rate; the cells bound it by the geometry. Open3D's labels are deterministic
for the same input (its labelling pass is sequential) and numbered by their seed points; they
are renumbered here by their first point, so the order of the objects is the order of the
points, whatever Open3D's numbering.

Open3D (2 s and ~180 MB to import) is imported by ``cluster_points`` only,
so that a node that is stopped before its fit, or a launcher checking the mapper's parameters,
never loads it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

EPS_LINE_SPACINGS = 15.0
"""DBSCAN radius in line spacings: the simulated scenes of docs/NODES.md need 3.6 to 11 to give
one cluster per object."""

EPS_LINE_EXTENT = 0.5
"""Largest DBSCAN radius, as a fraction of the typical extent of a contact line."""

DBSCAN_CELLS = 8
"""DBSCAN sees one point per cubic cell of ``eps / DBSCAN_CELLS``."""

MIN_POINTS = 4
"""Default DBSCAN ``min_points``: the fewest points a surface needs
(``too_little_for_a_surface``), so that every cluster could carry one."""


def split_lines(points: FloatArray, line_break: float = 20.0) -> IntArray:
    """Line label (N,) of ordered points: a jump > ``line_break`` x median step starts a line.

    ``points`` (N, 3) must be in acquisition order (per whisker, by ``seq``).
    """
    if len(points) < 2:
        return np.zeros(len(points), dtype=np.int64)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    typical = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    breaks = steps > line_break * typical if typical > 0 else steps > 0
    return np.concatenate([[0], np.cumsum(breaks)]).astype(np.int64)


def whisker_lines(points: FloatArray, whisker_ids: list[str],
                  line_break: float = 20.0) -> IntArray:
    """Line label (N,) of points ordered by (whisker, seq): :func:`split_lines`, and a new line
    wherever the whisker changes."""
    lines = split_lines(points, line_break)
    if len(points) < 2:
        return lines
    ids = np.asarray(whisker_ids, dtype=object)
    breaks = (np.diff(lines) > 0) | (ids[1:] != ids[:-1])
    return np.concatenate([[0], np.cumsum(breaks)]).astype(np.int64)


def contact_normals(points: FloatArray, forces: FloatArray, lines: IntArray) -> FloatArray:
    """Outward surface normals (N, 3) at contact points from the contact forces.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Contact points, in acquisition order.
    forces : ndarray, shape (N, 3)
        Contact force on the rod at each point (same frame); F . n > 0.
    lines : ndarray of int, shape (N,)
        Line label of each point (:func:`split_lines`).

    Returns
    -------
    ndarray, shape (N, 3)
        Unit normals: F minus its component along the line's local tangent (central
        differences within a line), or F's direction where there is no tangent.
    """
    n = len(points)
    prev_idx = np.arange(n) - 1
    next_idx = np.arange(n) + 1
    prev_idx[0], next_idx[-1] = 0, n - 1
    same_prev = np.r_[False, lines[1:] == lines[:-1]]
    same_next = np.r_[lines[:-1] == lines[1:], False]
    a = np.where(same_prev[:, None], points[prev_idx], points)
    b = np.where(same_next[:, None], points[next_idx], points)
    tangent = b - a
    t_norm = np.linalg.norm(tangent, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        tangent = np.where(t_norm > 0, tangent / t_norm, 0.0)
    normal = forces - np.einsum("ni,ni->n", forces, tangent)[:, None] * tangent
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    f_length = np.linalg.norm(forces, axis=1, keepdims=True)
    # A tangent nearly along F (or none) leaves too little: use F's direction there.
    weak = (length <= 1e-3 * f_length).ravel()
    normal[weak] = forces[weak]
    length[weak] = f_length[weak]
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(length > 0, normal / length, 0.0)
    return np.asarray(out, dtype=np.float64)


def line_spacing(points: FloatArray, lines: IntArray) -> float:
    """Median over the points (N, 3) of the distance to the nearest point of another line
    (``lines`` (N,)); inf with one line.

    Exact, in O(N log N log L) for L lines: two lines differ in a bit of their index, so for
    each bit the points whose line has it 0 query a KD-tree of those with it 1 and the other
    way round, and the least distance over the bits is the nearest point of another line.
    Identical points are one place first: a KD-tree cannot split them (a query would scan them
    all), and a place with points of two or more lines is 0 from another line and is in every
    KD-tree (it has a line other than any point's).
    """
    labels, line_of = np.unique(lines, return_inverse=True)
    if len(labels) < 2:
        return float("inf")
    places, place_of = np.unique(np.asarray(points, dtype=np.float64).reshape(-1, 3), axis=0,
                                 return_inverse=True)
    place_of = place_of.ravel()
    pairs = np.unique(place_of * len(labels) + line_of.ravel())  # each (place, line) once
    pair_place, pair_line = np.divmod(pairs, len(labels))
    shared = np.bincount(pair_place, minlength=len(places)) > 1
    line_at = np.zeros(len(places), dtype=np.int64)
    line_at[pair_place] = pair_line  # the one line of a place not shared
    nearest = np.where(shared, 0.0, np.inf)
    alone, together = np.flatnonzero(~shared), np.flatnonzero(shared)
    for bit in range((len(labels) - 1).bit_length()):
        side = (line_at[alone] >> bit) & 1
        for s in (0, 1):
            query = alone[side == s]
            others = np.concatenate([alone[side != s], together])
            if len(query) and len(others):
                distance = cKDTree(places[others]).query(places[query])[0]
                nearest[query] = np.minimum(nearest[query], distance)
    return float(np.median(nearest[place_of]))


def line_extent(points: FloatArray, lines: IntArray) -> float:
    """Typical extent of a line: the median over points of the diagonal of their line's
    bounding box (weighted by points, so that stray one-point lines do not pull it down)."""
    if len(points) == 0:
        return 0.0
    order = np.argsort(lines, kind="stable")
    _, start, count = np.unique(lines[order], return_index=True, return_counts=True)
    lo = np.minimum.reduceat(points[order], start, axis=0)
    hi = np.maximum.reduceat(points[order], start, axis=0)
    return float(np.median(np.repeat(np.linalg.norm(hi - lo, axis=1), count)))


@dataclass(frozen=True)
class Clusters:
    """Objects of a cloud (:func:`cluster_points`).

    Attributes
    ----------
    labels : ndarray of int, shape (N,)
        Object of each point, numbered 0, 1, ... in the order of their first point; -1 for a
        noise point (DBSCAN: in no ``eps``-neighbourhood of ``min_points`` or more).
    eps : float
        The DBSCAN radius used, cloud units.
    min_points : int
        The DBSCAN ``min_points`` used.
    eps_rule : str
        Where ``eps`` came from: ``given``, ``line spacing``, ``line extent`` or ``one place``.
    line_spacing, line_extent : float
        :func:`line_spacing` (inf with one line) and :func:`line_extent` of the cloud.
    """

    labels: IntArray
    eps: float
    min_points: int
    eps_rule: str
    line_spacing: float
    line_extent: float

    @property
    def n_clusters(self) -> int:
        """Number of objects."""
        return int(self.labels.max()) + 1 if len(self.labels) else 0


def cluster_points(points: FloatArray, lines: IntArray, eps: float = 0.0,
                   min_points: int = MIN_POINTS) -> Clusters:
    """Objects of a contact cloud by DBSCAN (Open3D), labels deterministic (see module).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Contact points, in acquisition order (per whisker, by ``seq``).
    lines : ndarray of int, shape (N,)
        Line label of each point (:func:`whisker_lines`).
    eps : float
        DBSCAN radius, cloud units; 0 = ``EPS_LINE_SPACINGS`` x :func:`line_spacing`, at most
        ``EPS_LINE_EXTENT`` x :func:`line_extent`.
    min_points : int
        DBSCAN ``min_points`` (>= 1), counted in cells of ``eps / DBSCAN_CELLS``.
    """
    if min_points < 1:
        raise ValueError(f"min_points must be >= 1, got {min_points}")
    if not (np.isfinite(eps) and eps >= 0):
        raise ValueError(f"eps must be a finite number >= 0, got {eps}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    spacing = line_spacing(points, lines) if len(points) else float("inf")
    extent = line_extent(points, lines)
    rule = "given"
    if eps == 0:
        candidates = [(EPS_LINE_SPACINGS * spacing, "line spacing"),
                      (EPS_LINE_EXTENT * extent, "line extent")]
        eps, rule = min((c for c in candidates if 0 < c[0] < np.inf), default=(0.0, "one place"))
        if eps == 0:  # one line, all at one place: no length to go by, any radius will do
            eps = 1.0
    labels = np.full(len(points), -1, dtype=np.int64)
    if len(points):
        import open3d as o3d

        cells = np.floor((points - points.min(axis=0)) / (eps / DBSCAN_CELLS))
        _, first, cell_of = np.unique(cells, axis=0, return_index=True, return_inverse=True)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[first]))
        raw = np.asarray(cloud.cluster_dbscan(eps, min_points))[cell_of.ravel()]
        found, first_point = np.unique(raw, return_index=True)
        keep = found >= 0
        rank = np.empty(len(found), dtype=np.int64)
        rank[keep] = np.argsort(np.argsort(first_point[keep]))
        rank[~keep] = -1
        labels = rank[np.searchsorted(found, raw)]
    return Clusters(labels, float(eps), int(min_points), rule, spacing, extent)


JOIN_NORMAL_TOL_RAD = 0.05
"""How far a contact normal may be off, rad, when :func:`join_convex` tests two clusters for
one convex object: on 9 simulated clouds (mu 0-0.9; docs/NODES.md) the 10 pairs of clusters on
one object passed with a margin of 0.05 or more (as a sine), the 23 on two objects failed by
0.16 or more."""

JOIN_SIGMAS = 3.0
"""Std of the points along their normals allowed in :func:`join_convex`'s test."""

JOIN_MAX_CLUSTERS = 64
"""The most clusters :func:`join_convex` tests (beyond, a cloud is not a few objects)."""

_JOIN_POINTS = 6400  # points of a pair's test, at most 400 of a cluster (evenly spread over it)


def join_convex(points: FloatArray, normals: FloatArray, labels: IntArray,
                normal_var: FloatArray | None = None,
                tol_rad: float = JOIN_NORMAL_TOL_RAD) -> tuple[IntArray, list[list[int]]]:
    """Clusters that are patches of one convex object, joined into it.

    A convex object lies behind each of its tangent planes: for contacts a, b on it,
    n_a . (p_b - p_a) <= 0, with n_a the outward normal at a. Two clusters pass when every point
    of each lies behind every tangent plane of the other, within ``sin(tol_rad) |p_b - p_a|``
    (the normals' error) and `JOIN_SIGMAS` std of the two points along their normals
    (``normal_var``, m^2; NaN: none). Patches of one object that DBSCAN split (whiskers that
    touched it far apart) pass; two objects side by side do not, as one lies in front of a
    tangent plane of the other. Groups are joined closest first, and only where every pair of
    their clusters passes (complete linkage).

    ``labels`` are those of :func:`cluster_points`: 0 ... k-1, each with points, -1 for noise.
    Returns them renumbered by their first point (noise stays -1) and the groups of input
    labels joined (each of two or more, in label order); more than `JOIN_MAX_CLUSTERS`
    clusters are returned as they are.
    """
    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1 if len(labels) else 0
    if len(np.unique(labels[labels >= 0])) != k:
        raise ValueError(f"labels must be 0 ... {k - 1}, each with points (and -1)")
    if not 2 <= k <= JOIN_MAX_CLUSTERS:
        return labels, []
    sample = min(400, _JOIN_POINTS // k)
    var = (np.zeros(len(points)) if normal_var is None
           else np.nan_to_num(np.asarray(normal_var, dtype=np.float64), nan=0.0, posinf=np.inf))
    sigma = np.sqrt(np.maximum(var, 0.0))  # a variance below 0 by rounding: 0
    members = []
    for label in range(k):
        inside = np.flatnonzero(labels == label)
        members.append(inside[np.linspace(0, len(inside) - 1, min(len(inside), sample))
                              .round().astype(np.int64)])
    slack = math.sin(tol_rad)
    excess = np.full((k, k), -np.inf)  # the worst point pair's excess over the tolerance
    for a in range(k):
        for b in range(a + 1, k):
            ia, ib = members[a], members[b]
            d = points[ib][None, :, :] - points[ia][:, None, :]  # p_b - p_a
            distance = np.linalg.norm(d, axis=2)
            std = np.hypot(sigma[ia][:, None], sigma[ib][None, :])
            allowed = slack * distance + JOIN_SIGMAS * std
            front = np.maximum(np.einsum("ai,abi->ab", normals[ia], d),
                               -np.einsum("bi,abi->ab", normals[ib], d))
            worst = float(np.max(front - allowed))  # -inf where every pair's std is inf
            excess[a, b] = excess[b, a] = np.inf if math.isnan(worst) else worst
    groups = [[label] for label in range(k)]
    while True:
        pairs = [(max(excess[a, b] for a in g for b in h), i, j)
                 for i, g in enumerate(groups) for j, h in enumerate(groups) if i < j]
        best = min(pairs, default=None)
        if best is None or not best[0] <= 0:
            break
        _, i, j = best
        groups[i] = sorted(groups[i] + groups.pop(j))
    group_of = np.empty(k, dtype=np.int64)
    first = np.empty(len(groups), dtype=np.int64)
    for g, group in enumerate(groups):
        group_of[group] = g
        first[g] = min(int(np.flatnonzero(labels == label)[0]) for label in group)
    rank = np.argsort(np.argsort(first))
    out = np.where(labels >= 0, rank[group_of[np.maximum(labels, 0)]], -1)
    return out.astype(np.int64), [group for group in groups if len(group) > 1]
