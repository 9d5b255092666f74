"""Mapper node: accumulates contact points, separates objects and fits a surface per object at
end of stream, writes the map.

Subscribes
----------
``topics`` (default ``[contact]``) : ContactPointArray
    Points in SI (m, N), each in its ``frame_id``; each row of an array is a point of its
    whisker; ``EndOfStream`` from every expected source ends the accumulation.

Publishes
---------
``cloud_topic`` (default ``contact_cloud``) : ContactCloud
    Every point with its contact normal, one message per ``frame_id``, then ``EndOfStream``.
``proposal_topic`` (default ``next_sweep``) : SweepProposal
    Where to sweep next: ``proposals`` sections per object, best first
    (``vibrissa.next_sweep``), then ``EndOfStream``; also in the report.
``mesh_topic`` (default ``surface_mesh``) : SurfaceMesh
    The known part of the meshes of a ``frame_id``, all objects in one mesh (``method`` names
    the method and its fitted parameters, per object when there are several; the distance
    fields are filled when the truth is known: ``true_surface`` or ``scene``), then
    ``EndOfStream``.

Files in ``out_dir`` (for frame ``world``; another frame F gets the suffix ``_F``):
``cloud.ply`` (points + normals), ``mesh.ply`` (every object's known mesh, with each vertex's
position std ``std_m``), ``mesh_<object>.ply`` (one per object with a known mesh), ``map.png``
(`vibrissa.nodes.map_figure`), ``map.html`` (the same layers as a rotatable self-contained page,
`vibrissa.nodes.map_page`), ``report.json`` and ``report.txt``. Then the node exits 0 (the
demo launch ends on it with ``on_exit: shutdown``), or ``EXIT_EMPTY_MAP`` (3) when the streams
ended without a single contact point (only the reports are written, and they say so), or
``EXIT_LOST_DATA`` (4) when input messages were lost (the report lists every input stream: sent,
received, lost) or points were dropped beyond ``max_points`` / ``max_frames``, unless
``allow_loss``. Stopped (SIGINT, SIGTERM) before the streams end, it
writes nothing and exits 0; a stop during the fit ends the process at once (Open3D and LAPACK do
not return to Python until they are done).

Points dropped are counted by reason (``Accumulator``; the report's ``dropped_points``): beyond
the bounds (``max_points``, ``max_frames``) or not usable (``out_of_range``,
``no_force_direction``); a point whose covariance is not symmetric positive semidefinite is
mapped as one without a covariance and counted in ``bad_covariance`` (the report's too). Counters in this node's
``NodeStatus`` (besides the runtime's received, published, rejected, lost): ``bad_covariance``
and each of the dropped counts once it is not 0.

Objects: with ``true_surface`` a frame is that one object; otherwise DBSCAN separates the points
of a frame into objects (``vibrissa.nodes.surface_fit.cluster_points``; clusters that are patches of
one convex object are joined, ``join_convex``), named after the nearest
object of ``scene`` (frame ``world``) or ``object0``, ``object1``, ... in the order of their
first point. Surfaces: a Gaussian-process implicit surface per object (``vibrissa.gp_surface``)
on the points and their contact normals (the contact force with its component along the contact
line removed, ``vibrissa.nodes.surface_fit.contact_normals``), meshed by marching cubes; a
triangle is *known* where the surface's predicted position std is at most ``max_std_m``, and
only the known part is on the map (files, message, errors); the figure shows the rest as
unknown. docs/MAPPING.md has the choice of the method. Errors against the truth
(``true_surface``, a ``parse_surface`` spec in units of L placed in the points' frame, or the
object of ``scene`` an object was matched to): cloud -> surface = max/mean |signed distance| of
the points to the nearest true object (the reconstruction error, whatever the clustering made
of them; a point nearer another true object than its object's is counted in
``points_nearer_other``), mesh -> surface = max/mean over the known mesh's vertices to the
object's true object.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from itertools import compress
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vibrissa.formats.files import whole_file
from vibrissa.formats.scene_file import LIMITS, load_scene
from vibrissa.msgs import (
    ContactCloud,
    ContactPointArray,
    EndOfStream,
    SurfaceMesh,
    SweepProposal,
)
from vibrissa.next_sweep import Proposal, propose_sections
from vibrissa.nodes.map_figure import MapLayers, MeshLayer, plot_map, short_name, thousands
from vibrissa.nodes.map_page import write_page
from vibrissa.nodes.surface_fit import (
    JOIN_NORMAL_TOL_RAD,
    MIN_POINTS,
    MapParams,
    ObjectSurface,
    TrueObject,
    cluster_points,
    contact_normals,
    estimate_surface,
    join_convex,
    line_spacing,
    too_little_for_a_surface,
    whisker_lines,
    write_ply,
)
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.node import EXIT_LOST_DATA
from vibrissa.runtime.params import require, require_non_negative, require_parsed, require_positive
from vibrissa.runtime.signals import default_actions
from vibrissa.scene import Scene
from vibrissa.surfaces import parse_surface
from vibrissa.units import RodScale
from vibrissa.wire.topics import resolve_topic, validate_name
from vibrissa.wire.transport import StreamEnd

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

EXIT_EMPTY_MAP = 3
"""Exit status of a mapper whose streams ended without a single contact point."""

MAX_CELLS = 512
"""Finest marching-cubes grid: 512 cells along an object's box."""

SCENE_FRAME = "world"
"""The frame of a scene file's objects, path and mounts (W)."""


@dataclass(frozen=True)
class MapperParams:
    """Parameters of the mapper node.

    Attributes
    ----------
    topics
        ContactPointArray topics, relative to the namespace unless absolute.
    expected_sources
        How many distinct ``EndOfStream`` sources end the accumulation, or their node names
        (relative names resolve in the namespace).
    out_dir
        Folder of the output files (created).
    true_surface
        Surface spec of the one object, units of L, in the points' frame: the frame is that
        object (no clustering); empty: see ``scene``.
    scene
        Scene file (``vibrissa.formats.scene_file``): its objects, robot path and whisker
        mounts in frame ``world``, for the names of the objects, their errors and the figure;
        empty: the truth is not known. One of ``true_surface`` and ``scene`` at most.
    cluster_eps_m
        DBSCAN radius separating the objects, m; 0 = from the data (15 line spacings, at most
        half the typical extent of a contact line; see ``vibrissa.nodes.surface_fit``).
    cluster_min_points
        DBSCAN ``min_points``; smaller groups are noise (counted and reported, not fitted).
    join_convex, join_normal_tol_rad
        Join clusters that are patches of one convex object (an object touched by whiskers
        far apart), within this error of the contact normals, rad
        (``vibrissa.nodes.surface_fit.join_convex``).
    rod_length_m
        L, m (scales ``true_surface``); the mapper converts lengths only, so it needs no EI.
    cells, margin, max_std_m, point_std_m
        The surface estimate and its mesh: grid cells along an object's box, the box's margin
        (a fraction of the points' box diagonal), the largest std of a known triangle (m; 0:
        a fifth of the prior std), the std of a contact point (m); see
        ``vibrissa.nodes.surface_fit.MapParams``.
    timeout_s
        Fit what has arrived after this long without a message, s (0 = wait for the ends).
    max_points, max_frames
        The most points (all frames) and frames kept: the memory's bound (a point takes about
        200 bytes). A message beyond either is dropped, counted in the report and logged, and
        the map is then lossy (``allow_loss``).
    plot
        Write ``map.png``.
    allow_loss
        Exit 0 even when input messages were lost (the report says so either way); by
        default a lossy map exits ``EXIT_LOST_DATA`` (4).
    proposals, proposal_axis
        How many next sweeps to propose per object (0: none) and the normal of their section
        planes in the points' frame (the paper's trails: y, the lateral offset); see
        ``vibrissa.next_sweep``.
    cloud_topic, mesh_topic, proposal_topic
        Output topics.
    wait_for
        Nodes that must subscribe to the outputs before they go out (default: nobody).
    rod
        L as ``vibrissa.units.RodScale`` (derived, not a parameter).
    world
        The scene read from ``scene``, or None (derived, not a parameter).
    """

    topics: tuple[str, ...] = ("contact",)
    expected_sources: int | tuple[str, ...] = 1
    out_dir: str = "out/mapper"
    true_surface: str = ""
    scene: str = ""
    cluster_eps_m: float = 0.0
    cluster_min_points: int = MIN_POINTS
    join_convex: bool = True
    join_normal_tol_rad: float = JOIN_NORMAL_TOL_RAD
    rod_length_m: float = 1.0
    cells: int = MapParams.cells
    margin: float = MapParams.margin
    max_std_m: float = MapParams.max_std_m
    point_std_m: float = MapParams.point_std_m
    timeout_s: float = 0.0
    max_points: int = 10_000_000
    max_frames: int = 64
    plot: bool = True
    allow_loss: bool = False
    proposals: int = 3
    proposal_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    cloud_topic: str = "contact_cloud"
    mesh_topic: str = "surface_mesh"
    proposal_topic: str = "next_sweep"
    wait_for: tuple[str, ...] = ()
    rod: RodScale = field(init=False, repr=False, compare=False)
    world: Scene | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        require_positive("rod_length_m", self.rod_length_m)
        object.__setattr__(self, "rod", RodScale(self.rod_length_m))
        require(len(self.topics) > 0, "topics", self.topics, "one or more topic names")
        for topic in self.topics:
            require_parsed("topics", topic, validate_name)
        for name in (self.cloud_topic, self.mesh_topic, self.proposal_topic):
            require_parsed("cloud_topic/mesh_topic/proposal_topic", name, validate_name)
        require(self.proposals >= 0, "proposals", self.proposals, "a count >= 0")
        require(len(self.proposal_axis) == 3 and all(map(math.isfinite, self.proposal_axis))
                and any(self.proposal_axis), "proposal_axis", self.proposal_axis,
                "a nonzero vector [x, y, z]")
        for name in self.wait_for:
            require_parsed("wait_for", name, validate_name)
        if isinstance(self.expected_sources, int):
            require(self.expected_sources >= 1, "expected_sources", self.expected_sources,
                    "a count >= 1 or a list of node names")
        else:
            for name in self.expected_sources:
                require_parsed("expected_sources", name, validate_name)
        require(bool(self.out_dir), "out_dir", self.out_dir, "a folder")
        if self.true_surface:
            require_parsed("true_surface", self.true_surface, parse_surface)
        require(not (self.scene and self.true_surface), "scene", self.scene,
                "empty when true_surface is given (one or the other)")
        world = None
        if self.scene:
            try:  # read now: a missing or bad file is a parameter error at start
                world = load_scene(self.scene)
            except ValueError as exc:
                raise ValueError(f"parameter 'scene': {exc}") from None
        object.__setattr__(self, "world", world)
        require_non_negative("cluster_eps_m", self.cluster_eps_m)
        require(self.cluster_min_points >= 1, "cluster_min_points", self.cluster_min_points,
                "a count >= 1")
        require(0 <= self.join_normal_tol_rad < math.pi / 2, "join_normal_tol_rad",
                self.join_normal_tol_rad, "an angle in [0, pi/2), rad")
        require(8 <= self.cells <= MAX_CELLS, "cells", self.cells,
                f"a grid size in [8, {MAX_CELLS}]")
        require_non_negative("margin", self.margin)
        require_non_negative("max_std_m", self.max_std_m)
        require_positive("point_std_m", self.point_std_m)
        require_non_negative("timeout_s", self.timeout_s)
        require(self.max_points >= 1, "max_points", self.max_points, "a count >= 1")
        require(self.max_frames >= 1, "max_frames", self.max_frames, "a count >= 1")

    @property
    def map_params(self) -> MapParams:
        """The surface estimate's parameters."""
        return MapParams(self.cells, self.margin, self.max_std_m, self.point_std_m)

    def truth(self, frame_id: str) -> list[TrueObject]:
        """The known objects of frame ``frame_id``: ``true_surface`` (any frame), the objects of
        ``scene`` (frame ``world``), or none."""
        if self.true_surface:
            return [TrueObject(self.true_surface, parse_surface(self.true_surface),
                               self.rod_length_m)]
        if self.world is not None and frame_id == SCENE_FRAME:
            return [TrueObject(obj.name, obj.surface(1.0)) for obj in self.world.objects]
        return []


PARAMS = MapperParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


@dataclass
class FrameCloud:
    """Contact points of one frame, in arrival order, one block of arrays per message."""

    whisker_ids: list[str] = field(default_factory=list)
    seqs: list[int] = field(default_factory=list)
    points: list[FloatArray] = field(default_factory=list)  # (k, 3) per message
    forces: list[FloatArray] = field(default_factory=list)
    covariances: list[FloatArray] = field(default_factory=list)  # (k, 3, 3); NaN: none

    def add(self, msg: ContactPointArray, keep: npt.NDArray[np.bool_] | None,
            covariances: FloatArray) -> None:
        """Append every row of a message, or those ``keep`` says,
        each with its whisker, the message's ``seq`` and its covariance from ``covariances``
        (k, 3, 3) of the rows appended (NaN: none)."""
        whisker_ids = msg.whisker_ids
        rows = slice(None) if keep is None else keep
        whisker_ids = whisker_ids if keep is None else list(compress(whisker_ids, keep.tolist()))
        self.whisker_ids += whisker_ids
        self.seqs += [msg.seq] * len(whisker_ids)
        self.points.append(np.reshape(msg.point, (-1, 3))[rows])
        self.forces.append(np.reshape(msg.force, (-1, 3))[rows])
        self.covariances.append(covariances)

    def ordered(self) -> tuple[FloatArray, FloatArray, list[str], FloatArray]:
        """Points (N, 3), forces (N, 3), whisker ids and covariances (N, 3, 3; NaN where
        none came), sorted by (whisker, seq): line order."""
        order = sorted(range(len(self.seqs)), key=lambda i: (self.whisker_ids[i], self.seqs[i]))
        return (np.concatenate([np.empty((0, 3)), *self.points])[order],
                np.concatenate([np.empty((0, 3)), *self.forces])[order],
                [self.whisker_ids[i] for i in order],
                np.concatenate([np.empty((0, 3, 3)), *self.covariances])[order])


MAX_POSITION_M = LIMITS["position_m"][1]
"""The largest coordinate of a contact point the map takes, m (a scene's positions: `LIMITS`)."""
MAX_FORCE_N = 1e12
"""The largest contact force component the map takes, N: a normal from its direction."""
COVARIANCE_RTOL = 1e-9
"""How far from symmetric positive semidefinite a covariance may be, relative to its largest
entry (asymmetry) and |eigenvalue| (a negative eigenvalue): the reconstructor's J S J^T is off
by rounding only, a rank-deficient one has eigenvalues of about -1e-16 x the largest."""


def is_covariance(covariances: FloatArray) -> npt.NDArray[np.bool_]:
    """Whether each of ``covariances`` (k, 3, 3) is a covariance: finite, symmetric and
    positive semidefinite, to `COVARIANCE_RTOL`."""
    c = np.asarray(covariances, dtype=np.float64).reshape(-1, 3, 3)
    finite = np.isfinite(c).all(axis=(1, 2))
    c = np.where(np.isfinite(c), c, 0.0)  # refused by `finite`; zeros keep the rest finite
    # each matrix over its largest entry: eigvalsh neither overflows nor loses subnormals
    scale = np.abs(c).max(axis=(1, 2))
    unit = c / np.where(scale > 0, scale, 1.0)[:, None, None]
    symmetric = np.abs(unit - unit.transpose(0, 2, 1)).max(axis=(1, 2)) <= COVARIANCE_RTOL
    eigenvalues = np.linalg.eigvalsh(unit)  # of its lower triangle: symmetric checked above
    semidefinite = eigenvalues[:, 0] >= -COVARIANCE_RTOL * np.abs(eigenvalues).max(axis=1)
    return np.asarray(finite & symmetric & semidefinite)


class Accumulator:
    """The mapper's state without sockets: points per frame and ended sources.

    It keeps at most ``max_points`` points in at most ``max_frames`` frames, so that a long run
    or a flood cannot exhaust the memory: a message beyond either bound is dropped whole and
    its rows are counted in ``dropped`` (by reason). A row the map cannot use is dropped and
    counted too: a point with a coordinate beyond `MAX_POSITION_M` (``out_of_range``), a
    contact force of zero or beyond `MAX_FORCE_N` (``no_force_direction``: no normal). A row
    whose covariance is not one (`is_covariance`) is kept as a point without a covariance and
    counted in ``bad_covariance``.
    """

    def __init__(self, expected: int | Sequence[str], max_points: int = MapperParams.max_points,
                 max_frames: int = MapperParams.max_frames) -> None:
        self.expected = expected
        self.max_points = max_points
        self.max_frames = max_frames
        self.frames: dict[str, FrameCloud] = {}
        self.ended: set[str] = set()
        self.n_points = 0
        self.dropped: Counter[str] = Counter()
        self.bad_covariance = 0

    def add(self, msg: object) -> None:
        """Take a ContactPointArray or an EndOfStream."""
        if isinstance(msg, ContactPointArray) and msg.whisker_ids:  # not a tick without contact
            rows = len(msg.whisker_ids)
            if msg.frame_id not in self.frames and len(self.frames) >= self.max_frames:
                self.dropped["max_frames"] += rows
            elif self.n_points + rows > self.max_points:
                self.dropped["max_points"] += rows
            else:
                keep = self._usable(msg)
                kept = rows if keep is None else int(np.count_nonzero(keep))
                if kept:
                    self.frames.setdefault(msg.frame_id, FrameCloud()).add(
                        msg, keep, self._covariances(msg, keep, kept))
                    self.n_points += kept
        elif isinstance(msg, EndOfStream):
            self.ended.add(msg.source)

    def _usable(self, msg: ContactPointArray) -> npt.NDArray[np.bool_] | None:
        """The rows the map can use (None: all), counting the others in ``dropped``."""
        point = np.abs(np.reshape(msg.point, (-1, 3))).max(axis=1)
        force = np.abs(np.reshape(msg.force, (-1, 3))).max(axis=1)
        far, no_force = point > MAX_POSITION_M, ~((force > 0) & (force <= MAX_FORCE_N))
        if not (far.any() or no_force.any()):
            return None
        for reason, rows in (("out_of_range", far), ("no_force_direction", no_force & ~far)):
            if rows.any():
                self.dropped[reason] += int(np.count_nonzero(rows))
        return ~(far | no_force)

    def _covariances(self, msg: ContactPointArray,
                     keep: npt.NDArray[np.bool_] | None, kept: int) -> FloatArray:
        """The covariances (kept, 3, 3) of the rows kept, NaN where none came or where one is
        not a covariance (counted in ``bad_covariance``)."""
        if msg.covariance is None:
            return np.full((kept, 3, 3), np.nan)
        covariances = np.reshape(msg.covariance, (-1, 3, 3))[slice(None) if keep is None else keep]
        bad = ~is_covariance(covariances)
        self.bad_covariance += int(np.count_nonzero(bad))
        return np.where(bad[:, None, None], np.nan, covariances)

    @property
    def done(self) -> bool:
        """Whether every expected source has ended."""
        if isinstance(self.expected, int):
            return len(self.ended) >= self.expected
        return set(self.expected) <= self.ended


@dataclass
class ObjectResult:
    """One object of a frame: its points, the whiskers that touched it, its surface estimate
    and errors (distances in m; None without the truth). The mesh counts and distances are
    those of the known part (position std <= ``max_std_m``); ``unknown_triangles`` were
    meshed but are not on the map."""

    name: str
    n_points: int
    whiskers: list[dict[str, Any]]
    method: str
    n_vertices: int
    n_triangles: int
    line_spacing_m: float | None
    unknown_triangles: int = 0
    max_std_m: float | None = None
    std_median_m: float | None = None
    std_max_m: float | None = None
    true_object: str | None = None
    true_object_median_m: float | None = None
    cloud_to_surface_max: float | None = None
    cloud_to_surface_mean: float | None = None
    mesh_to_surface_max: float | None = None
    mesh_to_surface_mean: float | None = None
    next_sweeps: list[dict[str, Any]] = field(default_factory=list)
    files: dict[str, str] = field(default_factory=dict)
    points_nearer_other: dict[str, int] = field(default_factory=dict)  # by true object: two in one


@dataclass
class FrameResult:
    """Fit and errors of one frame (distances in m), over all its objects."""

    frame_id: str
    n_points: int
    method: str
    n_vertices: int
    n_triangles: int
    line_spacing_m: float | None
    cloud_to_surface_max: float | None = None
    cloud_to_surface_mean: float | None = None
    mesh_to_surface_max: float | None = None
    mesh_to_surface_mean: float | None = None
    files: dict[str, str] = field(default_factory=dict)
    clustering: dict[str, Any] = field(default_factory=dict)
    noise_points: int = 0
    noise_whiskers: list[dict[str, Any]] = field(default_factory=list)
    noise_to_surface_max: float | None = None
    objects: list[ObjectResult] = field(default_factory=list)


@dataclass
class FrameMap:
    """A frame mapped: its result and what goes into the files, messages and figure.

    ``points``, ``normals`` (N, 3) and ``whisker_ids`` (N,) in line order; ``labels`` (N,)
    the object of each point (index into ``result.objects`` and ``surfaces``, -1: noise);
    ``surfaces`` the estimate of each object and ``proposals`` its next sweeps; ``vertices``
    (V, 3), ``triangles`` (T, 3) and ``std`` (V,) the known part of every object's mesh in one.
    """

    result: FrameResult
    points: FloatArray
    normals: FloatArray
    whisker_ids: list[str]
    labels: IntArray
    surfaces: list[ObjectSurface]
    vertices: FloatArray
    triangles: IntArray
    std: FloatArray
    proposals: list[list[Proposal]]


def _stats(distance: FloatArray) -> tuple[float | None, float | None]:
    """Max and mean of distances (None, None when there are none)."""
    if len(distance) == 0:
        return None, None
    return float(distance.max()), float(distance.mean())


def _whisker_counts(whisker_ids: Sequence[str]) -> list[dict[str, Any]]:
    """``[{"whisker_id", "n_points"}]`` sorted by whisker id."""
    return [{"whisker_id": w, "n_points": n} for w, n in sorted(Counter(whisker_ids).items())]


def name_objects(points: FloatArray, labels: IntArray, truth: Sequence[TrueObject]
                 ) -> list[tuple[str, TrueObject | None, float | None]]:
    """(name, true object, median |signed distance| to it in m) of each object of ``labels``.

    With ``truth`` an object is named after the true object nearest to its points (median
    |signed distance|); a second object on the same true object is ``<name>-2``, and so on.
    Without, ``object0``, ``object1``, ... in the order of the labels.
    """
    named: list[tuple[str, TrueObject | None, float | None]] = []
    taken: set[str] = set()
    for k in range(int(labels.max()) + 1 if len(labels) else 0):
        if not truth:
            named.append((f"object{k}", None, None))
            continue
        inside = points[labels == k]
        medians = [float(np.median(true.distance(inside))) for true in truth]
        best = int(np.argmin(medians))
        name, n = truth[best].name, 1
        while name in taken:
            n += 1
            name = f"{truth[best].name}-{n}"
        taken.add(name)
        named.append((name, truth[best], medians[best]))
    return named


def fit_frame(frame_id: str, cloud: FrameCloud, params: MapperParams) -> FrameMap:
    """Objects, normals, surface estimates and errors of one frame."""
    points, forces, whisker_ids, covariances = cloud.ordered()
    lines = whisker_lines(points, whisker_ids)
    normals = contact_normals(points, forces, lines)
    # each point's variance along its normal (NaN without a covariance, or with one that is not
    # a covariance: the floor point_std_m; one too large for floats: the ceiling)
    given = np.isfinite(covariances).all(axis=(1, 2))
    with np.errstate(over="ignore", invalid="ignore"):
        normal_var = np.einsum("ni,nij,nj->n", normals, covariances, normals)
    normal_var[given & ~np.isfinite(normal_var)] = np.inf
    truth = params.truth(frame_id)
    spacing = line_spacing(points, lines) if len(points) else float("inf")
    if params.true_surface:  # the single-object map: the frame is the true surface
        labels = np.zeros(len(points), dtype=np.int64)
        named: list[tuple[str, TrueObject | None, float | None]] = [("object0", truth[0], None)]
        clustering: dict[str, Any] = {"method": "none: true_surface is the one object"}
    else:
        clusters = cluster_points(points, lines, params.cluster_eps_m, params.cluster_min_points)
        labels, joined = (join_convex(points, normals, clusters.labels, normal_var,
                                      params.join_normal_tol_rad) if params.join_convex
                          else (clusters.labels, []))
        named = name_objects(points, labels, truth)
        clustering = {"method": "dbscan", "eps_m": clusters.eps, "eps_rule": clusters.eps_rule,
                      "min_points": clusters.min_points, "dbscan_clusters": clusters.n_clusters,
                      "joined_convex": joined,
                      "line_spacing_m": spacing if np.isfinite(spacing) else None,
                      "line_extent_m": clusters.line_extent}
    objects: list[ObjectResult] = []
    surfaces: list[ObjectSurface] = []
    proposals: list[list[Proposal]] = []
    cloud_distance: list[FloatArray] = []
    mesh_distance: list[FloatArray] = []
    for k, (name, true, median) in enumerate(named):
        inside = np.flatnonzero(labels == k)
        surface = estimate_surface(points[inside], normals[inside], params.map_params,
                                   normal_var[inside])
        vertices, triangles, std = surface.part(known=True)
        own_spacing = line_spacing(points[inside], lines[inside])
        obj = ObjectResult(
            name, len(inside), _whisker_counts([whisker_ids[i] for i in inside]),
            surface.method, len(vertices), len(triangles),
            own_spacing if np.isfinite(own_spacing) else None,
            unknown_triangles=len(surface.part(known=False)[1]),
            max_std_m=surface.mesh.max_std if surface.mesh is not None else None,
            std_median_m=float(np.median(std)) if len(std) else None,
            std_max_m=float(std.max()) if len(std) else None,
            true_object=true.name if true is not None else None, true_object_median_m=median)
        if true is not None:
            to_each = np.array([other.distance(points[inside]) for other in truth])
            cloud_distance.append(to_each.min(axis=0))
            mesh_distance.append(true.distance(vertices))
            nearer = cloud_distance[-1] < to_each[list(truth).index(true)]  # than to its own
            obj.points_nearer_other = dict(sorted(Counter(
                truth[j].name for j in np.argmin(to_each, axis=0)[nearer]).items()))
            obj.cloud_to_surface_max, obj.cloud_to_surface_mean = _stats(cloud_distance[-1])
            obj.mesh_to_surface_max, obj.mesh_to_surface_mean = _stats(mesh_distance[-1])
        proposals.append([] if surface.gp is None or surface.mesh is None or not params.proposals
                         else propose_sections(surface.gp, surface.mesh.vertices,
                                               points[inside], np.array(params.proposal_axis),
                                               params.proposals))
        obj.next_sweeps = [
            {"offset_m": p.offset_m, "axis": p.axis.tolist(), "line_points": len(p.line),
             "std_on_line_m": p.std_on_line_m, "std_max_before_m": p.std_max_before_m,
             "std_max_after_m": p.std_max_after_m} for p in proposals[-1]]
        objects.append(obj)
        surfaces.append(surface)
    noise = np.flatnonzero(labels < 0)
    if len(objects) == 1:
        method = objects[0].method
    elif objects:
        method = "; ".join(f"{obj.name}: {obj.method}" for obj in objects)
    else:
        method = "none: " + (too_little_for_a_surface(points) or (
            f"no object: all {len(points)} points are noise (DBSCAN eps "
            f"{clustering['eps_m']:.4g} m, min_points {clustering['min_points']})"))
    parts = [surface.part(known=True) for surface in surfaces]
    offsets = np.cumsum([0] + [len(v) for v, _, _ in parts])[:-1]
    vertices = np.concatenate([v for v, _, _ in parts] or [np.zeros((0, 3))])
    triangles = np.concatenate(
        [t + offset for (_, t, _), offset in zip(parts, offsets, strict=True)]
        or [np.zeros((0, 3), dtype=np.int64)])
    result = FrameResult(
        frame_id, len(points), method, len(vertices), len(triangles),
        spacing if np.isfinite(spacing) else None,
        clustering=clustering, noise_points=len(noise),
        noise_whiskers=_whisker_counts([whisker_ids[i] for i in noise]), objects=objects)
    if truth:
        result.cloud_to_surface_max, result.cloud_to_surface_mean = _stats(
            np.concatenate(cloud_distance or [np.zeros(0)]))
        result.mesh_to_surface_max, result.mesh_to_surface_mean = _stats(
            np.concatenate(mesh_distance or [np.zeros(0)]))
        if len(noise):
            result.noise_to_surface_max = float(np.max(np.min(
                [true.distance(points[noise]) for true in truth], axis=0)))
    std = np.concatenate([s for _, _, s in parts] or [np.zeros(0)])
    return FrameMap(result, points, normals, whisker_ids, labels, surfaces, vertices, triangles,
                    std, proposals)


def _plural(n: int, word: str) -> str:
    """``1 object``, ``2 objects``, ``5 214 contacts``."""
    return f"{thousands(n)} {word}{'' if n == 1 else 's'}"


def map_layers(frame: FrameMap, params: MapperParams) -> MapLayers:
    """What the figure of a frame shows: the contacts, the meshes (coloured by their distance
    to the true surface when it is known, else by their std), and the truth when known."""
    result = frame.result
    whiskers = sorted(set(frame.whisker_ids))
    title = (f"{short_name(result.frame_id)} map: {_plural(len(result.objects), 'object')}, "
             f"{_plural(result.n_points, 'contact')} from {_plural(len(whiskers), 'whisker')}")
    truth = params.truth(result.frame_id)
    notes = []
    for obj in result.objects[:6]:
        note = f"{short_name(obj.name)}: {_plural(obj.n_points, 'point')}, "
        note += (f"surface known over {_plural(obj.n_triangles, 'triangle')}"
                 f" ({obj.n_triangles / (obj.n_triangles + obj.unknown_triangles):.0%})"
                 if obj.n_triangles else obj.method.removeprefix("none: "))
        if obj.mesh_to_surface_mean is not None and obj.mesh_to_surface_max is not None:
            note += (f", {obj.mesh_to_surface_mean * 1e3:.2g} mm from the true surface on "
                     f"average, {obj.mesh_to_surface_max * 1e3:.2g} mm at most")
        elif obj.std_max_m is not None:
            note += f", std at most {obj.std_max_m * 1e3:.2g} mm"
        notes.append(note)
    if len(result.objects) > 6:
        notes.append(f"... and {len(result.objects) - 6} more objects (report.txt)")
    if result.noise_points:
        notes.append(f"noise: {_plural(result.noise_points, 'point')} in no object")
    meshes = []
    true_of = {t.name: t for t in truth}
    for obj, surface in zip(result.objects, frame.surfaces, strict=True):
        vertices, triangles, std = surface.part(known=True)
        true = true_of.get(obj.true_object or "") if truth else None
        meshes.append(MeshLayer(
            obj.name, vertices, triangles,
            true.distance(vertices) if true is not None else std,
            *surface.part(known=False)[:2],
            max_std_m=surface.mesh.max_std if surface.mesh is not None else 0.0))
    scene = params.world if result.frame_id == SCENE_FRAME else None
    return MapLayers(
        title=title, subtitle="\n".join(notes), points=frame.points,
        whisker_ids=frame.whisker_ids, labels=frame.labels, meshes=meshes,
        colour_by="distance to the true surface" if truth else "predicted std of the surface",
        true_objects=truth, path=scene.path if scene is not None else None,
        whiskers=scene.whiskers if scene is not None else ())


def _file_part(text: str) -> str:
    """``text`` as part of a file name: itself when it is short and only letters, digits,
    ``-`` and ``_``, else a cut-down form with a hash of the whole text, so that any two texts
    give distinct names and every name fits the file system."""
    safe = "".join(c if c.isascii() and (c.isalnum() or c in "-_") else "_" for c in text)
    if safe == text and len(text) <= 64:
        return text
    return f"{safe[:40]}-{hashlib.sha1(text.encode()).hexdigest()[:10]}"


def _suffix(frame_id: str) -> str:
    """File name suffix of a frame: ``""`` for ``world``, else ``_`` and its file name part."""
    return "" if frame_id == "world" else f"_{_file_part(frame_id)}"


def write_outputs(acc: Accumulator, params: MapperParams, out_dir: Path,
                  streams: Sequence[StreamEnd] = (), lost: int = 0,
                  ) -> tuple[dict[str, Any],
                             list[tuple[ContactCloud, SurfaceMesh, list[SweepProposal]]]]:
    """Map every frame, write PLYs, the pictures (PNG, HTML page) and the reports; returns
    (report, messages).

    ``streams`` are the input streams that ended (what each said was sent, what arrived,
    what was lost) and ``lost`` the input messages lost in all, for the report.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    results: list[FrameResult] = []
    messages: list[tuple[ContactCloud, SurfaceMesh, list[SweepProposal]]] = []
    for frame_id, cloud in sorted(acc.frames.items()):
        t0 = time.monotonic()
        frame = fit_frame(frame_id, cloud, params)
        result = frame.result
        sfx = _suffix(frame_id)
        files = {"cloud": out_dir / f"cloud{sfx}.ply"}
        with whole_file(files["cloud"]) as partial:
            write_ply(str(partial), frame.points, normals=frame.normals)
        if len(frame.vertices):
            files["mesh"] = out_dir / f"mesh{sfx}.ply"
            with whole_file(files["mesh"]) as partial:
                write_ply(str(partial), frame.vertices, frame.triangles,
                          scalars={"std_m": frame.std})
        else:
            log.warning("no surface for frame %r: %s (the cloud is written)", frame_id,
                        result.method.removeprefix("none: "))
        for obj, surface in zip(result.objects, frame.surfaces, strict=True):
            vertices, triangles, std = surface.part(known=True)
            if not len(triangles):
                if len(result.objects) > 1:
                    log.warning("no surface for object %r of frame %r: %s", obj.name, frame_id,
                                obj.method.removeprefix("none: ") if surface.mesh is None
                                else "nowhere known")
                continue
            target = out_dir / f"mesh_{_file_part(obj.name)}{sfx}.ply"
            with whole_file(target) as partial:
                write_ply(str(partial), vertices, triangles, scalars={"std_m": std})
            files[f"mesh_{obj.name}"] = target
            obj.files = {"mesh": str(target)}
        if params.plot:
            layers = map_layers(frame, params)  # one source for both pictures
            files["png"] = out_dir / f"map{sfx}.png"
            with whole_file(files["png"]) as partial:
                plot_map(partial, layers)
            files["html"] = out_dir / f"map{sfx}.html"
            with whole_file(files["html"]) as partial:
                write_page(partial, layers)
        result.files = {k: str(v) for k, v in files.items()}
        results.append(result)
        stamp = time.time()
        messages.append((
            ContactCloud(stamp=stamp, frame_id=frame_id, points=frame.points,
                         normals=frame.normals, whisker_ids=frame.whisker_ids),
            SurfaceMesh(stamp=stamp, frame_id=frame_id, vertices=frame.vertices,
                        triangles=frame.triangles.astype(np.int32), method=result.method,
                        n_points=result.n_points,
                        cloud_to_surface_max=result.cloud_to_surface_max,
                        cloud_to_surface_mean=result.cloud_to_surface_mean,
                        mesh_to_surface_max=result.mesh_to_surface_max,
                        mesh_to_surface_mean=result.mesh_to_surface_mean),
            [SweepProposal(stamp=stamp, frame_id=frame_id, object=obj.name, rank=rank,
                           axis=p.axis, offset=p.offset_m, line=p.line,
                           std_on_line=p.std_on_line_m, std_max_before=p.std_max_before_m,
                           std_max_after=p.std_max_after_m)
             for obj, proposals in zip(result.objects, frame.proposals, strict=True)
             for rank, p in enumerate(proposals, start=1)],
        ))
        log.info("mapped %s: %d points -> %s (%d noise points), %d triangles in %.1f s",
                 frame_id, result.n_points,
                 ", ".join(f"{o.name} ({o.n_points})" for o in result.objects) or "no object",
                 result.noise_points, result.n_triangles, time.monotonic() - t0)
    report: dict[str, Any] = {
        "n_points": acc.n_points,
        "sources_ended": sorted(acc.ended),
        "true_surface": params.true_surface or None,
        "scene": params.scene or None,
        "scene_objects": ([obj.name for obj in params.world.objects]
                          if params.world is not None else None),
        "rod_length_m": params.rod_length_m,
        "max_reconstruction_error_m": max(
            (r.cloud_to_surface_max for r in results if r.cloud_to_surface_max is not None),
            default=None),
        "frames": [asdict(r) for r in results],
        "lost": lost,
        "dropped_points": dict(acc.dropped),
        "bad_covariance": acc.bad_covariance,
        "streams": [asdict(stream) for stream in streams],
    }
    report_json = out_dir / "report.json"
    report_txt = out_dir / "report.txt"
    report["files"] = {"report_json": str(report_json), "report_txt": str(report_txt)}
    with whole_file(report_json) as partial:
        partial.write_text(json.dumps(report, indent=2) + "\n")
    with whole_file(report_txt) as partial:
        partial.write_text(format_report(report))
    return report, messages


def _mm(value: float | None) -> str:
    return "n/a" if value is None else f"{value * 1e3:.4g} mm"


def _counts(whiskers: list[dict[str, Any]]) -> str:
    return ", ".join(f"{w['whisker_id']} ({w['n_points']})" for w in whiskers)


_DROPPED = {"out_of_range": f"with a coordinate beyond {MAX_POSITION_M:g} m",
            "no_force_direction": f"with a contact force of zero or over {MAX_FORCE_N:g} N (no "
                                  "normal)"}


def format_report(report: dict[str, Any]) -> str:
    """The human-readable report (lengths in mm)."""
    empty = " - THE MAP IS EMPTY" if report["n_points"] == 0 else ""
    truth = (f"scene {report['scene']} ({', '.join(report['scene_objects']) or 'no objects'})"
             if report.get("scene") else
             f"{report['true_surface'] or 'not given'} (L = {report['rod_length_m']} m)")
    lines = [f"contact points: {report['n_points']}{empty} (sources: "
             f"{', '.join(report['sources_ended']) or 'none ended'})",
             f"true surface: {truth}",
             f"max reconstruction error (cloud -> true surface): "
             f"{_mm(report['max_reconstruction_error_m'])}"]
    if report["lost"]:
        lines.append(f"LOST: {report['lost']} contact message(s) never arrived")
    for bound, n in report.get("dropped_points", {}).items():
        lines.append(f"DROPPED: {n} contact point(s) {_DROPPED.get(bound, 'beyond ' + bound)}")
    if report["bad_covariance"]:
        lines.append(f"BAD COVARIANCE: {report['bad_covariance']} contact point(s) with a "
                     "covariance that is not symmetric positive semidefinite, mapped as points "
                     "without one (point_std_m)")
    for stream in report["streams"]:
        lines.append(f"input {stream['topic']} from {stream['source']}: {stream['sent']} sent, "
                     f"{stream['received']} received, {stream['lost']} lost")
    for frame in report["frames"]:
        clustering = frame["clustering"]
        how = clustering["method"]
        if how == "dbscan":
            how = (f"DBSCAN eps {_mm(clustering['eps_m'])} (from the {clustering['eps_rule']}), "
                   f"min_points {clustering['min_points']}")
            for group in clustering.get("joined_convex", []):
                how += f"; {len(group)} of its clusters joined as patches of one convex object"
        lines += [
            f"frame {frame['frame_id']}: {frame['n_points']} points, "
            f"{len(frame['objects'])} object(s), {frame['noise_points']} noise point(s)",
            f"  objects: {how}",
            f"  method: {frame['method']}",
            f"  mesh: {frame['n_vertices']} vertices, {frame['n_triangles']} triangles",
            f"  cloud -> surface: max {_mm(frame['cloud_to_surface_max'])}, "
            f"mean {_mm(frame['cloud_to_surface_mean'])}",
            f"  mesh -> surface:  max {_mm(frame['mesh_to_surface_max'])}, "
            f"mean {_mm(frame['mesh_to_surface_mean'])}",
        ]
        for obj in frame["objects"]:
            matched = ("" if obj["true_object"] is None else
                       f"; true object {obj['true_object']}" + (
                           "" if obj["true_object_median_m"] is None else
                           f" (median {_mm(obj['true_object_median_m'])} off)"))
            others = obj.get("points_nearer_other") or {}
            if others:
                matched += ("; TWO OBJECTS IN ONE: " + ", ".join(
                    f"{n} of its points nearer {name}" for name, n in others.items()))
            lines += [
                f"  object {obj['name']}: {obj['n_points']} points from "
                f"{_counts(obj['whiskers'])}{matched}",
                f"    method: {obj['method']}",
                f"    mesh: {obj['n_vertices']} vertices, {obj['n_triangles']} triangles known, "
                f"{obj['unknown_triangles']} unknown (std above {_mm(obj['max_std_m'])})",
                f"    std of the known surface: median {_mm(obj['std_median_m'])}, "
                f"max {_mm(obj['std_max_m'])}",
                f"    cloud -> surface: max {_mm(obj['cloud_to_surface_max'])}, "
                f"mean {_mm(obj['cloud_to_surface_mean'])}",
                f"    mesh -> surface:  max {_mm(obj['mesh_to_surface_max'])}, "
                f"mean {_mm(obj['mesh_to_surface_mean'])}",
            ]
            lines += [
                f"    next sweep {rank}: section at {_mm(p['offset_m'])} along "
                f"{p['axis']} (std on it {_mm(p['std_on_line_m'])}; largest std "
                f"{_mm(p['std_max_before_m'])} -> {_mm(p['std_max_after_m'])})"
                for rank, p in enumerate(obj["next_sweeps"], start=1)]
            lines += [f"    {name}: {path}" for name, path in obj["files"].items()]
        if frame["noise_points"]:
            far = ("" if frame["noise_to_surface_max"] is None else
                   f", at most {_mm(frame['noise_to_surface_max'])} from a true object")
            lines.append(f"  noise: {frame['noise_points']} point(s) in no object, from "
                         f"{_counts(frame['noise_whiskers'])}{far}")
        lines += [f"  {name}: {path}" for name, path in frame["files"].items()]
    return "\n".join(lines) + "\n"


def run(node: Node, params: MapperParams) -> dict[str, Any] | None:
    """Accumulate until every source ended (or ``timeout_s`` idle), then map; the report
    (``None`` when stopped before the streams ended: nothing is fitted or written)."""
    expected: int | list[str] = (
        params.expected_sources if isinstance(params.expected_sources, int)
        else [resolve_topic(n, node.namespace) for n in params.expected_sources])
    acc = Accumulator(expected, params.max_points, params.max_frames)
    subscriber = node.create_subscriber(
        {t: ContactPointArray for t in params.topics}, hwm=200_000)
    cloud_pub = node.create_publisher(params.cloud_topic, ContactCloud, wait_for=params.wait_for)
    mesh_pub = node.create_publisher(params.mesh_topic, SurfaceMesh, wait_for=params.wait_for)
    proposal_pub = node.create_publisher(params.proposal_topic, SweepProposal,
                                         wait_for=params.wait_for)
    node.counters["bad_covariance"] = 0
    node.set_state("running", f"waiting for {expected} source(s) to end")
    last = time.monotonic()
    while not node.stop_requested and not acc.done:
        rx = subscriber.receive(0.1)
        if rx is not None:
            dropped, bad = acc.dropped.total(), acc.bad_covariance
            acc.add(rx.msg)
            node.counters.update(acc.dropped, bad_covariance=acc.bad_covariance)
            if acc.dropped.total() > dropped and _power_of_ten(acc.dropped.total(), dropped):
                log.warning("%s: %d contact point(s) dropped so far, beyond the map's bounds "
                            "(max_points %d, max_frames %d) or not usable: %s", node.fqn,
                            acc.dropped.total(), params.max_points, params.max_frames,
                            dict(acc.dropped))
            if acc.bad_covariance > bad and _power_of_ten(acc.bad_covariance, bad):
                log.warning("%s: %d contact point(s) so far with a covariance that is not "
                            "symmetric positive semidefinite, mapped without it", node.fqn,
                            acc.bad_covariance)
            last = time.monotonic()
        elif params.timeout_s > 0 and time.monotonic() - last > params.timeout_s:
            log.warning("%s: nothing for %.1f s; mapping what arrived (ended: %s)", node.fqn,
                        params.timeout_s, sorted(acc.ended))
            break
    if node.stop_requested:
        log.warning("%s: stopped before the end of the streams: no map written (%d contact "
                    "points received, sources ended: %s)", node.fqn, acc.n_points,
                    ", ".join(sorted(acc.ended)) or "none")
        return None
    node.set_state("running", f"fitting {acc.n_points} points")
    with default_actions():  # Open3D holds the interpreter while fitting: a stop ends us at once
        report, messages = write_outputs(acc, params, Path(params.out_dir),
                                         list(subscriber.ended_streams),
                                         subscriber.totals()["lost"])
    if report["lost"]:
        log.error("%s: %d contact message(s) were lost on the way to the map%s", node.fqn,
                  report["lost"], " (allowed: allow_loss)" if params.allow_loss else "")
    if report["dropped_points"]:
        log.error("%s: %d contact point(s) were dropped beyond the map's bounds: %s%s",
                  node.fqn, sum(report["dropped_points"].values()), report["dropped_points"],
                  " (allowed: allow_loss)" if params.allow_loss else "")
    for cloud, mesh, proposals in messages:
        cloud_pub.publish(cloud)
        mesh_pub.publish(mesh)
        for proposal in proposals:
            proposal_pub.publish(proposal)
    for publisher in (cloud_pub, mesh_pub, proposal_pub):
        publisher.publish_end_of_stream(node.fqn)
    if report["n_points"] == 0:
        log.error("%s: the map is empty: no contact point arrived (sources ended: %s); the "
                  "wrench source's log says how its sweeps ended (no-contact: the straight rod "
                  "clears the object all along; no-equilibrium: none after the first touch)",
                  node.fqn, ", ".join(sorted(acc.ended)) or "none")
    print(f"map of {report['n_points']} contact points written to {params.out_dir}:",
          flush=True)
    for frame in report["frames"]:
        for path in frame["files"].values():
            print(f"  {path}", flush=True)
    for path in report["files"].values():
        print(f"  {path}", flush=True)
    print(format_report(report), end="", flush=True)
    return report


def _power_of_ten(now: int, before: int) -> bool:
    """Whether a count went from ``before`` past 1, 10, 100, ... (when to log it again)."""
    return before == 0 or len(str(now)) > len(str(before))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the mapper node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.mapper")
    configure_logging()
    params = load_params(MapperParams, args.params_file, args.params)
    Path(params.out_dir).mkdir(parents=True, exist_ok=True)  # fail now, not after the sweeps
    with Node.from_args(args) as node:
        report = run(node, params)
    if report is not None and report["n_points"] == 0:
        return EXIT_EMPTY_MAP
    if (report is not None and (report["lost"] or report["dropped_points"])
            and not params.allow_loss):
        return EXIT_LOST_DATA
    return 0


if __name__ == "__main__":
    run_main(main)
