"""Mapper node: accumulates contact points and maps them with `vibrissa.mapping` (objects, a
surface per object, next sweeps) while they arrive, then writes the final map.

Subscribes
----------
``topics`` (default ``[contact]``) : ContactPointArray
    Points in SI (m, N), each in its ``frame_id``; each row is a point of its whisker;
    ``EndOfStream`` from every expected source ends the accumulation.
``pose_topic`` (default none) : RobotPose
    With ``explore_planner``: the pose of ``base_link`` in ``world``, for the path length of
    the exploration (poses of other frames are ignored, counted in ``ignored_poses`` and
    logged once); its ``EndOfStream`` ends nothing.

Publishes
---------
Each message of an update is stamped with the newest stamp of the contact points it holds
(its data's time, as tf2 stamps a transform).

``cloud_topic`` (default ``contact_cloud``) : ContactCloud
    Every point with its contact normal, one message per ``frame_id`` and update, then
    ``EndOfStream``.
``proposal_topic`` (default ``next_sweep``) : SweepProposal
    Where to sweep next: ``proposals`` sections per object, best first
    (`vibrissa.mapping.next_sweep`), then ``EndOfStream``; also in the report.
``mesh_topic`` (default ``surface_mesh``) : SurfaceMesh
    The known part of the meshes of a ``frame_id``, all objects in one mesh (``method`` names
    the method and its fitted parameters, per object when there are several; the distance
    fields are filled when the truth is known: ``true_surface`` or ``scene``), one message
    per ``frame_id`` and update (possibly without a triangle), then ``EndOfStream``.
``unknown_mesh_topic`` (default ``surface_mesh_unknown``) : SurfaceMesh
    The unknown part of the same meshes (the triangles whose std exceeds ``max_std_m``),
    with each known part, then ``EndOfStream``: a live view draws the two apart.

Files in ``out_dir`` (for frame ``world``; another frame F gets the suffix ``_F``):
``cloud.ply`` (points + normals), ``mesh.ply`` (every object's known mesh, with each vertex's
position std ``std_m``), ``mesh_<object>.ply`` (one per object with a known mesh), ``map.png``
(`vibrissa.figures.map_figure`), ``map.html`` (the same layers as a rotatable self-contained page,
`vibrissa.figures.map_page`), ``report.json`` and ``report.txt``; the files of an earlier map of
the run that the new one does not have are removed (`remove_stale_files`). Then the node exits 0
(the demo launch ends on it with ``on_exit: shutdown``), or ``EXIT_EMPTY_MAP`` (3) when the streams
ended without a single contact point (only the reports are written, and they say so), or
``EXIT_LOST_DATA`` (4) when input messages were lost (the report lists every input stream: sent,
received, lost) or points were dropped beyond ``max_points`` / ``max_frames``, unless
``allow_loss``.

The live map: from the first contact point on, an update (`vibrissa.mapping.LiveMap.update`:
only the objects that received points are fitted again, a grown object's surface conditioned on
its new points) is due at most every ``map_period_s`` and the last update's duration; it waits
until every message queued meanwhile is taken in (``map_period_s`` at most). Each update's cloud
and meshes are published at once; its next sweeps (as long again: ``LiveMap.propose``) when no
update falls due before they would be done, `SWEEPS_DUE` periods after it at the latest; then
its files are rewritten, each whole, at most every ``write_period_s``, with ``"final": false``.
The final map (``"final": true``, ``"ended_by"``: ``streams``, ``timeout`` or ``stop``) holds every point
received. When the streams ended or fell silent it is the one of a single fit (`LiveMap.final`,
bit for bit): the last update when it is that already (then only the reports are rewritten when
its files are written), else the objects that changed fitted again; the points no update held
go out first in one more update (published only). On a stop it is the live
map (`LiveMap.update`: the last update when it holds every point, else one more), so that it is
written within the launcher's grace; Open3D is loaded before the node joins the graph and the
fits' kernels in a thread while it joins (`vibrissa.mapping.fit.warm_up`), not in its first
update. Updates run in the main thread, the receive loop waiting (ZeroMQ queues
the input, ``hwm`` 200 000), not in a worker thread: Open3D holds the interpreter, and a fit in
a thread would only race the final one for the 2 cores. A SIGINT or SIGTERM is therefore seen
when the update under way returns; the node then takes no more input and writes the final map
of every point received (stopped before a single one, it writes nothing), and exits 0. Its
handlers (`vibrissa.runtime.signals.SignalHandlers` with ``once``) give a signal its default
action after its first time: the same signal again (a second Ctrl-C) ends the process at once,
even inside the fit, while the launcher's SIGTERM after its grace for a SIGINT leaves the final
map the launcher's second grace before its SIGKILL. Nothing of the fit is skipped to be faster.

Exploration: with ``explore_planner``, ``scene`` must have an ``explore`` key
(`vibrissa.formats.scene_file.load_explore`); the true objects' surfaces are sampled uniformly by
area within the longest whisker's length of its workspace box, once at start
(`vibrissa.mapping.coverage.coverage_samples`, a sample per mm^2), and every map (each update,
and the final map when it is not the last update's) records its coverage of them (a sample is
covered when a vertex of frame ``world``'s known mesh lies within ``coverage_tol_m``) with the
path length of the base so far (`vibrissa.mapping.ExplorationLog`: the distances between its
successive poses on ``pose_topic`` summed). The report's ``exploration`` holds them (``null``
without ``explore_planner``), ``report.txt`` a line, and ``map.png`` a plot of coverage against
path length. A pose that moved the base counts as input for ``timeout_s`` (a robot travelling
between contacts is not silence); one that did not move it does not (a driver publishing an
idle robot's pose keeps no dead map alive).

Points dropped are counted by reason (`vibrissa.mapping.Accumulator`; the report's ``dropped_points``): beyond
the bounds (``max_points``, ``max_frames``) or not usable (``out_of_range``,
``no_force_direction``, ``ambiguous_contact``: a tapered or pre-curved rod's point chosen among
several that fit its wrench); a point whose covariance is not symmetric positive semidefinite is
mapped as one without a covariance and counted in ``bad_covariance`` (the report's too). Counters in this node's
``NodeStatus`` (besides the runtime's received, published, rejected, lost): ``bad_covariance``
and each of the dropped counts once it is not 0.

Objects: with ``true_surface`` a frame is that one object; otherwise DBSCAN separates the points
of a frame into objects (`vibrissa.mapping.objects.cluster_points`; clusters that are patches of
one convex object are joined, ``join_convex``), named after the nearest
object of ``scene`` (frame ``world``) or ``object0``, ``object1``, ... in the order of their
first point. Surfaces: a Gaussian-process implicit surface per object (`vibrissa.mapping.gp_surface`)
on the points and their contact normals (the contact force with its component along the contact
line removed, `vibrissa.mapping.objects.contact_normals`), meshed by marching cubes; a
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
import threading
import time
from collections import Counter
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np

from vibrissa.exploration import Explore
from vibrissa.figures.map_figure import map_layers, plot_map
from vibrissa.figures.map_page import write_page
from vibrissa.formats.errors import SceneError
from vibrissa.formats.files import whole_file
from vibrissa.formats.ply import write_ply
from vibrissa.formats.scene_file import load_explore, load_scene
from vibrissa.formats.truth_poses import read_truth
from vibrissa.frames import ROBOT_FRAME
from vibrissa.mapping import (
    Accumulator,
    ContactBatch,
    Exploration,
    ExplorationLog,
    FrameMap,
    FrameResult,
    InputStream,
    LiveMap,
    Localization,
    MapReport,
    MapSettings,
    TrueObject,
    UpstreamNode,
    fit_frame,
    true_map_to_odom,
)
from vibrissa.mapping.accumulate import MAX_FRAMES, MAX_POINTS
from vibrissa.mapping.coverage import COVERAGE_TOL_M, coverage_samples
from vibrissa.mapping.fit import joined_part, warm_up
from vibrissa.msgs import (
    ContactCloud,
    ContactPointArray,
    EndOfStream,
    NodeStatus,
    RobotPose,
    SurfaceMesh,
    SweepProposal,
)
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.node import EXIT_LOST_DATA
from vibrissa.runtime.params import require, require_non_negative, require_parsed, require_positive
from vibrissa.runtime.signals import SignalHandlers
from vibrissa.runtime.traffic import Traffic, Upstream
from vibrissa.scene import Scene, robot_path
from vibrissa.surfaces import parse_surface
from vibrissa.units import RodScale
from vibrissa.wire.topics import STATUS_TOPIC, resolve_topic, validate_name
from vibrissa.wire.transport import StreamEnd

log = logging.getLogger(__name__)

EXIT_EMPTY_MAP = 3
"""Exit status of a mapper whose streams ended without a single contact point."""

SCENE_FRAME = "world"
"""The frame of a scene file's objects, path and mounts (W), by default (``scene_frame``)."""


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
        half the typical extent of a contact line; see `vibrissa.mapping.objects`).
    cluster_min_points
        DBSCAN ``min_points``; smaller groups are noise (counted and reported, not fitted).
    join_convex, join_normal_tol_rad
        Join clusters that are patches of one convex object (an object touched by whiskers
        far apart), within this error of the contact normals, rad
        (`vibrissa.mapping.objects.join_convex`).
    rod_length_m
        L, m (scales ``true_surface``); the mapper converts lengths only, so it needs no EI.
    cells, margin, max_std_m, point_std_m
        The surface estimate and its mesh: grid cells along an object's box, the box's margin
        (a fraction of the points' box diagonal), the largest std of a known triangle (m; 0:
        a fifth of the prior std), the std of a contact point (m); see
        `vibrissa.mapping.MapSettings`.
    method
        The surface method: ``gp`` (the uncertainty), ``poisson`` or ``ball_pivoting``
        (Open3D's, no uncertainty, no next sweeps); `vibrissa.mapping.MapSettings`.
    timeout_s
        Write the final map of what has arrived after this long without a message, s (0 =
        wait for the ends); the time of a map update is not counted (its input waits).
    map_period_s, write_period_s
        While the streams go on, map (and publish the map) at most every ``map_period_s``
        and rewrite the files at most every ``write_period_s``, s.
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
        `vibrissa.mapping.next_sweep`.
    cloud_topic, mesh_topic, unknown_mesh_topic, proposal_topic
        Output topics.
    wait_for
        Nodes that must subscribe to the outputs before they go out (default: nobody).
    explore_planner
        The planner of the exploration the map follows (a name for the report, e.g.
        ``uncertainty``); needs ``scene`` with an ``explore`` key; empty: no exploration (the
        report's ``exploration`` is null).
    pose_topic
        RobotPose topic of ``base_link`` in ``world`` for the exploration's path length (needs
        ``explore_planner``); empty: none (the path length stays 0).
    coverage_tol_m
        A true surface's sample is covered when a known mesh vertex lies within this, m.
    scene_frame
        The frame of ``scene``'s objects: the frame they are the truth of, whose files carry
        no suffix (``map`` for a robot whose contacts a localizer places there).
    correction_topic
        RobotPose topic of the localizer's ``map -> odom`` (`vibrissa.nodes.localizer`): the
        report's ``localization`` gives the last one; empty: none (``localization`` null).
    truth_poses
        The wrench source's ``truth_file`` (`vibrissa.formats.truth_poses`), read when the
        final report is written: the true ``map -> odom`` at the end, against the estimate;
        for evaluation only. Empty: none.
    rod
        L as ``vibrissa.units.RodScale`` (derived, not a parameter).
    world
        The scene read from ``scene``, or None (derived, not a parameter).
    explore
        The ``explore`` key of ``scene`` with ``explore_planner``, or None (derived, not a
        parameter).
    settings
        The map's settings (`vibrissa.mapping.MapSettings`) from these (derived, not a
        parameter); ``true_surface`` makes the frame one object.
    """

    topics: tuple[str, ...] = ("contact",)
    expected_sources: int | tuple[str, ...] = 1
    out_dir: str = "out/mapper"
    true_surface: str = ""
    scene: str = ""
    cluster_eps_m: float = 0.0
    cluster_min_points: int = MapSettings.cluster_min_points
    join_convex: bool = MapSettings.join_convex
    join_normal_tol_rad: float = MapSettings.join_normal_tol_rad
    rod_length_m: float = 1.0
    cells: int = MapSettings.cells
    margin: float = MapSettings.margin
    max_std_m: float = MapSettings.max_std_m
    point_std_m: float = MapSettings.point_std_m
    method: str = MapSettings.method
    timeout_s: float = 0.0
    map_period_s: float = 1.0
    write_period_s: float = 5.0
    max_points: int = MAX_POINTS
    max_frames: int = MAX_FRAMES
    plot: bool = True
    allow_loss: bool = False
    proposals: int = MapSettings.proposals
    proposal_axis: tuple[float, float, float] = MapSettings.proposal_axis
    cloud_topic: str = "contact_cloud"
    mesh_topic: str = "surface_mesh"
    unknown_mesh_topic: str = "surface_mesh_unknown"
    proposal_topic: str = "next_sweep"
    wait_for: tuple[str, ...] = ()
    explore_planner: str = ""
    pose_topic: str = ""
    coverage_tol_m: float = COVERAGE_TOL_M
    scene_frame: str = SCENE_FRAME
    correction_topic: str = ""
    truth_poses: str = ""
    rod: RodScale = field(init=False, repr=False, compare=False)
    world: Scene | None = field(init=False, repr=False, compare=False)
    explore: Explore | None = field(init=False, repr=False, compare=False)
    settings: MapSettings = field(init=False, repr=False, compare=False)
    _truths: dict[str, tuple[TrueObject, ...]] = field(
        init=False, repr=False, compare=False, default_factory=dict)

    def __post_init__(self) -> None:
        require_positive("rod_length_m", self.rod_length_m)
        object.__setattr__(self, "rod", RodScale(self.rod_length_m))
        require(len(self.topics) > 0, "topics", self.topics, "one or more topic names")
        for topic in self.topics:
            require_parsed("topics", topic, validate_name)
        for name in (self.cloud_topic, self.mesh_topic, self.unknown_mesh_topic,
                     self.proposal_topic):
            require_parsed("cloud_topic/mesh_topic/unknown_mesh_topic/proposal_topic", name,
                           validate_name)
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
        explore = None
        if self.explore_planner:
            require(bool(self.scene), "explore_planner", self.explore_planner,
                    "empty without a scene (its explore key and objects are the coverage's)")
            explore = load_explore(self.scene)
            require(explore is not None, "explore_planner", self.explore_planner,
                    f"empty: scene {self.scene} has no explore key")
        object.__setattr__(self, "explore", explore)
        if self.pose_topic:
            require_parsed("pose_topic", self.pose_topic, validate_name)
            require(bool(self.explore_planner), "pose_topic", self.pose_topic,
                    "empty without explore_planner (the path length is the exploration's)")
            require(self.pose_topic not in self.topics, "pose_topic", self.pose_topic,
                    "a topic other than the contact topics")
        if self.correction_topic:
            require_parsed("correction_topic", self.correction_topic, validate_name)
            require(self.correction_topic not in self.topics, "correction_topic",
                    self.correction_topic, "a topic other than the contact topics")
        require_positive("coverage_tol_m", self.coverage_tol_m)
        try:  # the map's settings check their own ranges
            settings = MapSettings(
                one_object=bool(self.true_surface), cluster_eps_m=self.cluster_eps_m,
                cluster_min_points=self.cluster_min_points, join_convex=self.join_convex,
                join_normal_tol_rad=self.join_normal_tol_rad, cells=self.cells,
                margin=self.margin, max_std_m=self.max_std_m, point_std_m=self.point_std_m,
                proposals=self.proposals, proposal_axis=self.proposal_axis,
                method=self.method)
        except ValueError as exc:
            raise ValueError(f"parameter {exc}") from None
        object.__setattr__(self, "settings", settings)
        require_non_negative("timeout_s", self.timeout_s)
        require_positive("map_period_s", self.map_period_s)
        require_positive("write_period_s", self.write_period_s)
        require(self.max_points >= 1, "max_points", self.max_points, "a count >= 1")
        require(self.max_frames >= 1, "max_frames", self.max_frames, "a count >= 1")


    def truth(self, frame_id: str) -> tuple[TrueObject, ...]:
        """The known objects of frame ``frame_id``: ``true_surface`` (any frame), the objects of
        ``scene`` (frame ``world``), or none; the same objects at every call (a live map keeps
        an object's fit only while its truth is the same)."""
        if frame_id not in self._truths:
            truth: tuple[TrueObject, ...] = ()
            if self.true_surface:
                truth = (TrueObject(self.true_surface, parse_surface(self.true_surface),
                                    self.rod_length_m),)
            elif self.world is not None and frame_id == self.scene_frame:
                truth = tuple(TrueObject(obj.name, obj.surface(1.0)) for obj in self.world.objects)
            self._truths[frame_id] = truth
        return self._truths[frame_id]


PARAMS = MapperParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


def contact_batch(msg: ContactPointArray) -> ContactBatch:
    """An incoming contact message as the map's arrays."""
    return ContactBatch(
        msg.frame_id, np.reshape(msg.point, (-1, 3)), np.reshape(msg.force, (-1, 3)),
        msg.whisker_ids, msg.seq,
        None if msg.covariance is None else np.reshape(msg.covariance, (-1, 3, 3)), msg.stamp,
        msg.status)


def _file_part(text: str) -> str:
    """``text`` as part of a file name: itself when it is short and only letters, digits,
    ``-`` and ``_``, else a cut-down form with a hash of the whole text, so that any two texts
    give distinct names and every name fits the file system."""
    safe = "".join(c if c.isascii() and (c.isalnum() or c in "-_") else "_" for c in text)
    if safe == text and len(text) <= 64:
        return text
    return f"{safe[:40]}-{hashlib.sha1(text.encode()).hexdigest()[:10]}"


def _suffix(frame_id: str, scene_frame: str = SCENE_FRAME) -> str:
    """File name suffix of a frame: ``""`` for the scene's frame, else ``_`` and its file name
    part."""
    return "" if frame_id == scene_frame else f"_{_file_part(frame_id)}"


def receive(acc: Accumulator, msg: ContactPointArray | EndOfStream) -> None:
    """Hand an incoming message to the accumulator: an end of stream, or its contacts."""
    if isinstance(msg, EndOfStream):
        acc.end(msg.source)
    else:
        acc.add(contact_batch(msg))


def fit_frames(acc: Accumulator, params: MapperParams, live: LiveMap | None = None,
               final: bool = True, propose: bool = True) -> list[FrameMap]:
    """Map every frame of ``acc`` in frame order: the full fit (`vibrissa.mapping.fit_frame`)
    on all its points, or with ``live`` its update (`vibrissa.mapping.LiveMap.update`: only
    what changed is fitted again; ``propose=False``: the next sweeps of what was fitted in full
    are left to `LiveMap.propose`) or, ``final``, its final map (`LiveMap.final`: the full
    fit's)."""
    frames = []
    for frame_id, cloud in sorted(acc.frames.items()):
        t0 = time.monotonic()
        truth = params.truth(frame_id)
        if live is None:
            frame = fit_frame(frame_id, cloud, params.settings, truth)
        elif final:
            frame = live.final(frame_id, cloud, params.settings, truth)
        else:
            frame = live.update(frame_id, cloud, params.settings, truth, propose)
        result = frame.result
        log.info("mapped %s: %d points -> %s (%d noise points), %d triangles in %.1f s",
                 frame_id, result.n_points,
                 ", ".join(f"{o.name} ({o.n_points})" for o in result.objects) or "no object",
                 result.noise_points, result.n_triangles, time.monotonic() - t0)
        frames.append(frame)
    return frames


class MapMessages(NamedTuple):
    """The messages of one frame's map update."""

    cloud: ContactCloud
    mesh: SurfaceMesh
    unknown_mesh: SurfaceMesh
    proposals: list[SweepProposal]


def map_messages(frame: FrameMap, stamp: float) -> MapMessages:
    """The messages of a mapped frame: its cloud, the known and the unknown part of its meshes
    and its next sweeps, each stamped ``stamp`` (the newest stamp of the points it holds)."""
    result = frame.result
    unknown_vertices, unknown_triangles, _ = joined_part(frame.surfaces, known=False)
    errors = {"cloud_to_surface_max": result.cloud_to_surface_max,
              "cloud_to_surface_mean": result.cloud_to_surface_mean}
    return MapMessages(
        ContactCloud(stamp=stamp, frame_id=result.frame_id, points=frame.points,
                     normals=frame.normals, whisker_ids=frame.whisker_ids),
        SurfaceMesh(stamp=stamp, frame_id=result.frame_id, vertices=frame.vertices,
                    triangles=frame.triangles.astype(np.int32), method=result.method,
                    n_points=result.n_points, **errors,
                    mesh_to_surface_max=result.mesh_to_surface_max,
                    mesh_to_surface_mean=result.mesh_to_surface_mean),
        SurfaceMesh(stamp=stamp, frame_id=result.frame_id, vertices=unknown_vertices,
                    triangles=unknown_triangles.astype(np.int32), method=result.method,
                    n_points=result.n_points, **errors),
        proposal_messages(frame, stamp),
    )


def proposal_messages(frame: FrameMap, stamp: float) -> list[SweepProposal]:
    """The next sweeps of a mapped frame, best first per object, each stamped ``stamp``."""
    return [SweepProposal(stamp=stamp, frame_id=frame.result.frame_id, object=obj.name,
                          rank=rank, axis=p.axis, offset=p.offset_m, line=p.line,
                          std_on_line=p.std_on_line_m, std_max_before=p.std_max_before_m,
                          std_max_after=p.std_max_after_m)
            for obj, proposals in zip(frame.result.objects, frame.proposals, strict=True)
            for rank, p in enumerate(proposals, start=1)]


def write_frame_files(frame: FrameMap, params: MapperParams, out_dir: Path,
                      final: bool = True, status: str = "",
                      exploration: Exploration | None = None) -> FrameResult:
    """Write a mapped frame's PLYs and pictures (PNG, HTML page, with the line ``status``; the
    PNG of frame ``world`` with the coverage of ``exploration`` when given), each file whole
    (`vibrissa.formats.files.whole_file`); its result with the files and each object's mesh
    file. A frame or object without a surface is logged in the ``final`` map only."""
    frame_id, result = frame.result.frame_id, frame.result
    sfx = _suffix(frame_id, params.scene_frame)
    files = {"cloud": out_dir / f"cloud{sfx}.ply"}
    with whole_file(files["cloud"]) as partial:
        write_ply(str(partial), frame.points, normals=frame.normals)
    if len(frame.vertices):
        files["mesh"] = out_dir / f"mesh{sfx}.ply"
        with whole_file(files["mesh"]) as partial:
            write_ply(str(partial), frame.vertices, frame.triangles,
                      scalars={"std_m": frame.std})
    elif final:
        log.warning("no surface for frame %r: %s (the cloud is written)", frame_id,
                    result.method.removeprefix("none: "))
    objects = list(result.objects)
    for k, (obj, surface) in enumerate(zip(result.objects, frame.surfaces, strict=True)):
        vertices, triangles, std = surface.part(known=True)
        if not len(triangles):
            if len(result.objects) > 1 and final:
                log.warning("no surface for object %r of frame %r: %s", obj.name, frame_id,
                            obj.method.removeprefix("none: ") if surface.mesh is None
                            else "nowhere known")
            continue
        target = out_dir / f"mesh_{_file_part(obj.name)}{sfx}.ply"
        with whole_file(target) as partial:
            write_ply(str(partial), vertices, triangles, scalars={"std_m": std})
        files[f"mesh_{obj.name}"] = target
        objects[k] = replace(obj, files={"mesh": str(target)})
    if params.plot:
        files.update(write_pictures(frame, params, out_dir, status, exploration))
    return replace(result, objects=tuple(objects), files={k: str(v) for k, v in files.items()})


def write_pictures(frame: FrameMap, params: MapperParams, out_dir: Path, status: str,
                   exploration: Exploration | None = None) -> dict[str, Path]:
    """A mapped frame's map.png and map.html with the line ``status`` (`write_frame_files`)."""
    frame_id = frame.result.frame_id
    world = frame_id == params.scene_frame
    scene = params.world if world else None
    if scene is not None and exploration is not None and exploration.base_path is not None \
            and len(exploration.base_path[0]) >= 2:  # the path driven, not the scene file's
        positions, quaternions = exploration.base_path
        scene = replace(scene, path=robot_path(np.arange(len(positions), dtype=float),
                                               positions, quaternions))
    layers = map_layers(frame, scene, status,
                        exploration.coverage if world and exploration is not None else None)
    files = {"png": out_dir / f"map{_suffix(frame_id, params.scene_frame)}.png",
             "html": out_dir / f"map{_suffix(frame_id, params.scene_frame)}.html"}
    with whole_file(files["png"]) as partial:
        plot_map(partial, layers)
    with whole_file(files["html"]) as partial:
        write_page(partial, layers)
    return files


def remove_stale_files(before: set[str], report: MapReport) -> set[str]:
    """Remove the files of an earlier map of this run that ``report``'s map no longer has (an
    object merged into another, a frame or object that has no known mesh now), so that the
    folder holds one map; the files of ``report``."""
    now = {path for frame in report.frames for path in frame.files.values()}
    now.update(report.files.values())
    for path in before - now:
        Path(path).unlink(missing_ok=True)
    return now


def map_status(final: bool, ended_by: str | None, updates: int, n_points: int) -> str:
    """The pictures' line saying which map they show: the final one and what ended it, or a
    map so far with the time it was written (UTC)."""
    if final:
        return f"final map (ended by {ended_by}): {n_points} contact points, {updates} update(s)"
    return (f"map so far (the streams go on): update {updates}, {n_points} contact points, "
            f"written {time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime())} UTC")


@dataclass(frozen=True)
class AccumulatorCounts:
    """What the reports say of an `Accumulator`, taken at one moment (`write_outputs` from
    another thread while points go on arriving)."""

    n_points: int
    ended: frozenset[str]
    dropped: Counter[str]
    bad_covariance: int
    merged: int

    @classmethod
    def of(cls, acc: Accumulator) -> AccumulatorCounts:
        return cls(acc.n_points, frozenset(acc.ended), Counter(acc.dropped), acc.bad_covariance,
                   acc.merged)


def write_outputs(acc: Accumulator | AccumulatorCounts, params: MapperParams, out_dir: Path,
                  streams: Sequence[StreamEnd] = (), lost: int = 0,
                  upstream: Sequence[Upstream] = (), frames: Sequence[FrameMap] | None = None,
                  *, written: Sequence[FrameResult] | None = None, final: bool = True,
                  ended_by: str | None = "streams", updates: int = 1,
                  update_fits: dict[str, int] | None = None,
                  exploration: Exploration | None = None,
                  localization: Localization | None = None,
                  ) -> tuple[MapReport, list[MapMessages]]:
    """Write the map of ``acc``: its frames' files (`write_frame_files`) and the reports, each
    file whole; returns (report, messages).

    ``acc`` may be its counts only (`AccumulatorCounts`), with ``frames`` given; no messages are
    returned then. ``frames`` are its frames mapped (default: `fit_frames` now); ``written`` their results
    when their files are written already (then only the reports are, and in the ``final`` map
    the pictures again, after the reports, with the final map's line). ``streams`` are the input
    streams that ended (what each said was sent, what arrived, what was lost), ``lost`` the
    input messages lost in all and ``upstream`` what the nodes before the map moved
    (`vibrissa.runtime.traffic`), for the report; ``final``, ``ended_by`` and ``updates`` go
    into it as they are, and ``update_fits``, ``exploration`` and ``localization``
    (`vibrissa.mapping.MapReport`; the exploration's coverage is plotted in the scene frame's
    map.png).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    if frames is None:
        assert isinstance(acc, Accumulator), "the frames of counts are given"
        frames = fit_frames(acc, params)
    t0 = time.monotonic()
    results = (list(written) if written is not None else
               [write_frame_files(frame, params, out_dir, final,
                                  map_status(final, ended_by, updates, acc.n_points),
                                  exploration)
                for frame in frames])
    report_json = out_dir / "report.json"
    report_txt = out_dir / "report.txt"
    report = MapReport(
        n_points=acc.n_points, sources_ended=tuple(sorted(acc.ended)), frames=tuple(results),
        true_surface=params.true_surface or None, scene=params.scene or None,
        scene_objects=(tuple(obj.name for obj in params.world.objects)
                       if params.world is not None else None),
        rod_length_m=params.rod_length_m, lost=lost, dropped_points=dict(acc.dropped),
        bad_covariance=acc.bad_covariance, merged_points=acc.merged,
        streams=tuple(InputStream(**asdict(stream)) for stream in streams),
        upstream=tuple(UpstreamNode(u.node, u.received, u.lost, u.rejected, u.sent_to_it)
                       for u in upstream),
        files={"report_json": str(report_json), "report_txt": str(report_txt)},
        final=final, ended_by=ended_by, updates=updates, update_fits=dict(update_fits or {}),
        exploration=exploration, localization=localization)
    with whole_file(report_json) as partial:
        partial.write_text(json.dumps(report.as_dict(), indent=2) + "\n")
    with whole_file(report_txt) as partial:
        partial.write_text(report.text())
    if written is not None and final and params.plot:  # the pictures say "map so far"
        for frame in frames:
            write_pictures(frame, params, out_dir,
                           map_status(final, ended_by, updates, acc.n_points), exploration)
    log.info("wrote the %s map (%s) in %.1f s", "final" if final else "periodic",
             "files and reports" if written is None
             else "reports and pictures" if final and params.plot else "reports",
             time.monotonic() - t0)
    if not isinstance(acc, Accumulator):
        return report, []
    return report, [map_messages(frame, acc.frames[frame.result.frame_id].stamp)
                    for frame in frames]


SWEEPS_DUE = 10
"""The next sweeps of an update go out at the latest this many ``map_period_s`` after it (before
the next update; until then, only when no update falls due before they would be done)."""


def _warm_up(settings: MapSettings) -> None:
    """`warm_up`, or why it failed (the first map fails then too, and says why)."""
    try:
        warm_up(settings)
    except Exception as exc:
        log.warning("the mapper's warm-up failed: %r", exc)


def run(node: Node, params: MapperParams, warming: threading.Thread | None = None,
        ) -> MapReport | None:
    """Accumulate and map while the streams go on (an update at most every ``map_period_s``,
    its files at most every ``write_period_s``), then write the final map when every source
    ended, after ``timeout_s`` of silence or on a stop; the final report (``None`` when stopped
    before a single contact point: nothing is written). ``warming``: the thread of `warm_up`,
    which the final map waits for (it is computed with nothing else at work in the process:
    the single fit's bits)."""
    expected: int | list[str] = (
        params.expected_sources if isinstance(params.expected_sources, int)
        else [resolve_topic(n, node.namespace) for n in params.expected_sources])
    acc = Accumulator(expected, params.max_points, params.max_frames)
    track = exploration_log(params)
    poses = {params.pose_topic: RobotPose} if params.pose_topic else {}
    pose_topic = node.resolve(params.pose_topic) if params.pose_topic else None
    corrections = Corrections(params) if params.correction_topic else None
    if corrections is not None:
        poses[params.correction_topic] = RobotPose
    correction_topic = node.resolve(params.correction_topic) if corrections is not None else None
    subscriber = node.create_subscriber(
        {**{t: ContactPointArray for t in params.topics}, **poses, STATUS_TOPIC: NodeStatus},
        hwm=200_000)
    traffic = Traffic()  # what the nodes before the map moved, for the report
    cloud_pub = node.create_publisher(params.cloud_topic, ContactCloud, wait_for=params.wait_for)
    mesh_pub = node.create_publisher(params.mesh_topic, SurfaceMesh, wait_for=params.wait_for)
    proposal_pub = node.create_publisher(params.proposal_topic, SweepProposal,
                                         wait_for=params.wait_for)

    unknown_pub = node.create_publisher(params.unknown_mesh_topic, SurfaceMesh,
                                        wait_for=params.wait_for)
    publishers = (cloud_pub, mesh_pub, unknown_pub, proposal_pub)
    live = LiveMap()

    def publish(messages: list[MapMessages]) -> None:
        for cloud, mesh, unknown_mesh, proposals in messages:
            cloud_pub.publish(cloud)
            mesh_pub.publish(mesh)
            unknown_pub.publish(unknown_mesh)
            for proposal in proposals:
                proposal_pub.publish(proposal)

    def publish_maps(frames: list[FrameMap]) -> list[float]:
        """Publish an update's maps (``fit_frames`` with ``propose=False``) without their
        next sweeps: the stamps they went out with, for their sweeps."""
        stamps = [acc.frames[frame.result.frame_id].stamp for frame in frames]
        publish([map_messages(frame, stamp)._replace(proposals=[])
                 for frame, stamp in zip(frames, stamps, strict=True)])
        return stamps

    def publish_proposals(frames: list[FrameMap], stamps: list[float]) -> list[FrameMap]:
        """Propose the next sweeps the update of ``frames`` (its maps published with
        ``stamps``) left out and publish them all: the frames with them."""
        frames = [live.propose(frame.result.frame_id) for frame in frames]
        for frame, stamp in zip(frames, stamps, strict=True):
            for proposal in proposal_messages(frame, stamp):
                proposal_pub.publish(proposal)
        return frames

    on_disk: set[str] = set()  # the files of the map written last

    def write(written: Sequence[FrameResult] | None, final: bool, ended_by: str | None,
              ) -> tuple[MapReport, list[MapMessages]]:
        nonlocal on_disk
        report, messages = write_outputs(
            acc, params, Path(params.out_dir), list(subscriber.ended_streams),
            subscriber.totals()["lost"], traffic.upstream_of(node.fqn), frames, written=written,
            final=final, ended_by=ended_by, updates=updates, update_fits=live.fits,
            exploration=track.result() if track is not None else None,
            localization=corrections.result(final) if corrections is not None else None)
        on_disk = remove_stale_files(on_disk, report)
        return report, messages

    def record_coverage(frames: Sequence[FrameMap]) -> None:
        if track is not None:  # the coverage of frame world's known mesh (none: no vertex)
            world = [f.vertices for f in frames if f.result.frame_id == params.scene_frame]
            track.record(world[0] if world else np.zeros((0, 3)))

    node.counters["bad_covariance"] = 0
    node.set_state("running", f"waiting for {expected} source(s) to end")
    last = time.monotonic()
    ended_by = "streams"
    frames: list[FrameMap] = []  # the last update's map
    fitted = 0  # the points it holds
    written: list[FrameResult] | None = None  # its frames' results once its files are written
    updates = 0
    fit_start = files_time = -np.inf  # monotonic times of the last update and files
    update_s = 0.0  # how long the last update's maps took (not its next sweeps)
    due_since = np.inf  # monotonic time since when an update is due
    unproposed: float | None = None  # since when the last update's next sweeps are left out
    stamps: list[float] = []  # the stamps its maps went out with
    propose_s = 0.0  # how long the last next sweeps took
    # the periodic files are written in a thread of their own (seconds of plotting): the map
    # goes on meanwhile; one write at a time, the final one here once it is done
    files = ThreadPoolExecutor(1, thread_name_prefix="map-files")
    pending: tuple[Future[MapReport], list[FrameMap]] | None = None  # a write, of which map

    def write_periodic(of: list[FrameMap]) -> None:
        nonlocal pending
        args = (AccumulatorCounts.of(acc), params, Path(params.out_dir),
                list(subscriber.ended_streams), subscriber.totals()["lost"],
                traffic.upstream_of(node.fqn), of)
        job = partial(write_outputs, *args, written=None, final=False, ended_by=None,
                      updates=updates, update_fits=dict(live.fits),
                      exploration=track.result() if track is not None else None,  # as of now
                      localization=corrections.result(False) if corrections is not None else None)
        pending = (files.submit(lambda: job()[0]), of)

    def collect(wait: bool) -> None:
        """Take a periodic write that ended (``wait``: wait for it): its files are the map's
        on disk, and the last update's when it wrote that."""
        nonlocal pending, on_disk, written
        if pending is None or not (wait or pending[0].done()):
            return
        (future, of), pending = pending, None
        try:
            report = future.result()
        except Exception:  # the final write tries again, and says why if it fails too
            log.exception("%s: writing the periodic map files failed", node.fqn)
            return
        on_disk = remove_stale_files(on_disk, report)
        if of is frames:
            written = list(report.frames)

    # a stop during an update is seen when it returns: a signal asks to stop, the same signal
    # again ends the process at once (Open3D holds the interpreter while it works)
    with SignalHandlers(lambda signum: node.request_stop(), once=True):
        while not node.stop_requested and not acc.done:
            collect(wait=False)
            # an update is due once map_period_s passed since the last one began, and its
            # time; it waits until the input queued meanwhile is taken in (no message waiting,
            # statuses included: input may wait behind them), map_period_s at most
            due = (acc.n_points > fitted and time.monotonic() - fit_start
                   >= max(params.map_period_s, update_s))
            if not due:
                due_since = np.inf
            elif due_since == np.inf:
                due_since = time.monotonic()
            rx = subscriber.receive(0.0 if due else 0.1)
            took = rx is not None and not isinstance(rx.msg, NodeStatus)
            if rx is not None and isinstance(rx.msg, NodeStatus):
                traffic.add(rx.msg)  # not input: the timeout of silence runs on
            elif rx is not None and rx.topic == correction_topic:
                if corrections is not None and isinstance(rx.msg, RobotPose):
                    corrections.take(rx.msg)
            elif rx is not None and rx.topic == pose_topic:
                if track is not None and isinstance(rx.msg, RobotPose) and take_pose(
                        node, track, rx.msg) > 0:
                    last = time.monotonic()  # the base moved: not silence
            elif rx is not None:
                dropped, bad = acc.dropped.total(), acc.bad_covariance
                receive(acc, rx.msg)
                node.counters.update(acc.dropped, bad_covariance=acc.bad_covariance)
                if acc.dropped.total() > dropped and _power_of_ten(acc.dropped.total(), dropped):
                    log.warning("%s: %d contact point(s) dropped so far, beyond the map's "
                                "bounds (max_points %d, max_frames %d) or not usable: %s",
                                node.fqn, acc.dropped.total(), params.max_points,
                                params.max_frames, dict(acc.dropped))
                if acc.bad_covariance > bad and _power_of_ten(acc.bad_covariance, bad):
                    log.warning("%s: %d contact point(s) so far with a covariance that is not "
                                "symmetric positive semidefinite, mapped without it", node.fqn,
                                acc.bad_covariance)
                last = time.monotonic()
            now = time.monotonic()
            if not took and params.timeout_s > 0 and now - last > params.timeout_s:
                log.warning("%s: nothing for %.1f s; mapping what arrived (ended: %s)",
                            node.fqn, params.timeout_s, sorted(acc.ended))
                ended_by = "timeout"
                break
            # the next sweeps of an update go out SWEEPS_DUE periods after it at the latest
            overdue = (unproposed is not None
                       and now - unproposed >= SWEEPS_DUE * params.map_period_s)
            if (due and (rx is None or now - due_since >= params.map_period_s) and not overdue
                    and not acc.done):
                fit_start = now
                node.set_state("running", f"mapping {acc.n_points} points (update "
                                          f"{updates + 1})")
                frames = fit_frames(acc, params, live, final=False, propose=False)
                fitted = acc.n_points
                updates += 1
                record_coverage(frames)
                # the maps go out at once; their next sweeps (as long again) when the map has
                # time for them, their files (seconds of plotting) after those
                stamps = publish_maps(frames)
                update_s = time.monotonic() - fit_start
                written = None
                if unproposed is None:  # since when next sweeps are left out
                    unproposed = time.monotonic()
                # the time of an update is not silence: what arrived meanwhile waits in the
                # queue, behind the statuses that came with it
                last += update_s
                node.set_state("running", f"map of {fitted} points (update {updates}) in "
                                          f"{update_s:.1f} s; waiting for {expected} "
                                          "source(s) to end")
            elif unproposed is not None and (overdue or rx is None and (
                    acc.n_points == fitted
                    or fit_start + max(params.map_period_s, update_s) - now >= propose_s)):
                # the next sweeps of the last update: when no update is due before they would
                # be done (as long as the last ones took), or overdue
                frames = publish_proposals(frames, stamps)
                done = time.monotonic()
                propose_s, unproposed = done - now, None
                if (pending is None and done - files_time >= params.write_period_s
                        and not node.stop_requested):
                    # (a stop meanwhile: the final files follow at once)
                    files_time = done
                    write_periodic(frames)
                last += propose_s
        if node.stop_requested:
            ended_by = "stop"
            if acc.n_points == 0:
                log.warning("%s: stopped before a single contact point: no map written "
                            "(sources ended: %s)", node.fqn, ", ".join(sorted(acc.ended))
                            or "none")
                return None
            log.warning("%s: stopped before the end of the streams: writing the final map of "
                        "the %d contact points received (sources ended: %s)", node.fqn,
                        acc.n_points, ", ".join(sorted(acc.ended)) or "none")
        else:
            if updates and acc.n_points > fitted:
                # what came since the last update goes out at once, in an update (the grown
                # objects conditioned on their new points: a fraction of the final fit's time)
                frames = fit_frames(acc, params, live, final=False, propose=False)
                fitted, written = acc.n_points, None
                updates += 1
                record_coverage(frames)
                frames = publish_proposals(frames, publish_maps(frames))
            # every node's status after the ends
            settle = time.monotonic() + 2 * node.heartbeat_s
            while time.monotonic() < settle and not node.stop_requested:
                rx = subscriber.receive(0.05)
                if rx is not None and isinstance(rx.msg, NodeStatus):
                    traffic.add(rx.msg)
        # the final map: the single fit's, or at a stop the live map of every point (an update:
        # the launcher's grace is short); the last update when it is that already (only the
        # reports are written again when its files are); a stop now changes nothing, the same
        # signal again ends the process at once
        collect(wait=True)
        files.shutdown()
        node.set_state("running", f"final map of {acc.n_points} points")
        if warming is not None:
            warming.join()
        final = fit_frames(acc, params, live, final=ended_by != "stop")
        if not updates or len(final) != len(frames) or any(
                a is not b for a, b in zip(final, frames, strict=False)):
            frames, written = final, None
            updates += 1
            record_coverage(frames)
        report, messages = write(written, True, ended_by)
    if report.lost:
        log.error("%s: %d input message(s) were lost on the way to the map%s", node.fqn,
                  report.lost, " (allowed: allow_loss)" if params.allow_loss else "")
    if report.upstream_lost:  # at a stop, every node stops with messages on their way
        log.log(logging.WARNING if ended_by == "stop" else logging.ERROR,
                "%s: %d message(s) did not reach the nodes before the map%s (%s)", node.fqn,
                report.upstream_lost, " by the stop" if ended_by == "stop" else "",
                ", ".join(u.node for u in report.upstream if u.short))
    if report.dropped_points:
        log.error("%s: %d contact point(s) were dropped beyond the map's bounds: %s%s",
                  node.fqn, sum(report.dropped_points.values()), report.dropped_points,
                  " (allowed: allow_loss)" if params.allow_loss else "")
    publish(messages)
    for publisher in publishers:
        publisher.publish_end_of_stream(node.fqn)
    if report.n_points == 0 and params.explore is not None:
        log.error("%s: the map is empty: the exploration touched nothing (sources ended: %s); "
                  "a larger path budget reaches further", node.fqn,
                  ", ".join(sorted(acc.ended)) or "none")
    elif report.n_points == 0:
        log.error("%s: the map is empty: no contact point arrived (sources ended: %s); the "
                  "wrench source's log says how its sweeps ended (no-contact: the straight rod "
                  "clears the object all along; no-equilibrium: none after the first touch)",
                  node.fqn, ", ".join(sorted(acc.ended)) or "none")
    print(f"map of {report.n_points} contact points written to {params.out_dir}:",
          flush=True)
    for frame in report.frames:
        for path in frame.files.values():
            print(f"  {path}", flush=True)
    for path in report.files.values():
        print(f"  {path}", flush=True)
    print(report.text(), end="", flush=True)
    return report


class Corrections:
    """The localizer's ``map -> odom`` estimates as they come, for the report's
    ``localization`` (against the truth of ``truth_poses`` in the final report)."""

    def __init__(self, params: MapperParams) -> None:
        self.params = params
        self.count = 0
        self.last: RobotPose | None = None

    def take(self, msg: RobotPose) -> None:
        """An estimate of ``scene_frame`` -> odom (others, and ones not finite, are left out)."""
        if msg.frame_id == self.params.scene_frame and np.isfinite(msg.position).all():
            self.count += 1
            self.last = msg

    def result(self, final: bool) -> Localization | None:
        """The report's ``localization``: None before the first estimate."""
        last = self.last
        if last is None:
            return None
        truth, stamp = None, last.stamp
        if final and self.params.truth_poses and Path(self.params.truth_poses).is_file():
            try:
                poses = read_truth(Path(self.params.truth_poses))
            except SceneError as exc:
                log.warning("the truth of the poses is not read: %s", exc)
            else:
                if len(poses.stamp_s):  # the run's end: the estimate holds until the next
                    stamp = max(stamp, float(poses.stamp_s[-1]))
                truth = true_map_to_odom(poses.stamp_s, poses.p_map_m, poses.q_map,
                                         poses.p_odom_m, poses.q_odom, stamp)
        return Localization(self.count, stamp,
                            (float(last.position[0]), float(last.position[1])), truth)


def exploration_log(params: MapperParams) -> ExplorationLog | None:
    """The exploration's log with the samples of its true surfaces (`coverage_samples`: within
    the longest whisker's length of the workspace box), or None without ``explore_planner``."""
    if params.explore is None or params.world is None:
        return None
    explore = params.explore
    samples = coverage_samples(params.truth(params.scene_frame), explore.workspace_min_m,
                               explore.workspace_max_m,
                               max(w.length_m for w in params.world.whiskers))
    log.info("coverage: %d samples of the true surfaces within reach of the workspace",
             len(samples))
    return ExplorationLog(params.explore_planner, samples, params.coverage_tol_m)


def take_pose(node: Node, track: ExplorationLog, msg: RobotPose) -> float:
    """Move the exploration's base to a pose of ``base_link`` in ``world``; the step, m (0 for
    a pose of other frames: counted in ``ignored_poses``, logged the first time)."""
    if msg.frame_id != SCENE_FRAME or msg.child_frame_id != ROBOT_FRAME:
        ignored = node.counters.get("ignored_poses", 0)
        if not ignored:
            log.warning("%s: a pose of %r in %r ignored: the path length is that of %r in %r",
                        node.fqn, msg.child_frame_id, msg.frame_id, ROBOT_FRAME, SCENE_FRAME)
        node.counters["ignored_poses"] = ignored + 1
        return 0.0
    return track.move(msg.position, msg.orientation)


def _power_of_ten(now: int, before: int) -> bool:
    """Whether a count went from ``before`` past 1, 10, 100, ... (when to log it again)."""
    return before == 0 or len(str(now)) > len(str(before))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the mapper node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.mapper")
    configure_logging()
    params = load_params(MapperParams, args.params_file, args.params)
    Path(params.out_dir).mkdir(parents=True, exist_ok=True)  # fail now, not after the sweeps
    # seconds to load, before the first map: Open3D before the graph starts, then the fits'
    # kernels in a thread of their own (the node starts and maps meanwhile)
    import open3d  # noqa: F401
    warming = threading.Thread(target=_warm_up, args=(params.settings,), name="map-warm-up",
                               daemon=True)
    warming.start()
    with Node.from_args(args) as node:
        report = run(node, params, warming)
    if report is not None and report.n_points == 0:
        return EXIT_EMPTY_MAP
    if (report is not None and (report.lost or report.dropped_points)
            and not params.allow_loss):
        return EXIT_LOST_DATA
    return 0


if __name__ == "__main__":
    run_main(main)
