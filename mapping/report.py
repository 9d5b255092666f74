"""The map's report as typed results: per object (`ObjectResult`), per frame (`FrameResult`) and
for the whole map (`MapReport`), with the dict of ``report.json`` (``as_dict``) and the text of
``report.txt`` (``MapReport.text``). Distances in m; None where the truth is not known."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from vibrissa.mapping.accumulate import MAX_FORCE_N, MAX_POSITION_M

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class WhiskerCount:
    """How many of a group's points came from a whisker."""

    whisker_id: str
    n_points: int


def whisker_counts(whisker_ids: Sequence[str]) -> tuple[WhiskerCount, ...]:
    """The points per whisker of ``whisker_ids``, sorted by whisker id."""
    return tuple(WhiskerCount(w, n) for w, n in sorted(Counter(whisker_ids).items()))


@dataclass(frozen=True)
class NextSweep:
    """A proposed next sweep of an object (`vibrissa.mapping.next_sweep.Proposal`), in the
    report: the section plane's offset along its normal ``axis`` (3,), the points of its line,
    the largest std on it, and the object's largest std before and after, m."""

    offset_m: float
    axis: list[float]
    line_points: int
    std_on_line_m: float
    std_max_before_m: float
    std_max_after_m: float


@dataclass(frozen=True)
class Clustering:
    """How a frame's points were separated into objects: ``method`` ``dbscan`` (then every
    other attribute is set: `vibrissa.mapping.objects.Clusters`, the clusters joined as patches
    of one convex object, the line spacing or None with one line) or ``none: ...`` (why not)."""

    method: str
    eps_m: float | None = None
    eps_rule: str | None = None
    min_points: int | None = None
    dbscan_clusters: int | None = None
    joined_convex: list[list[int]] = field(default_factory=list)
    line_spacing_m: float | None = None
    line_extent_m: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """``{"method"}``, and the rest with DBSCAN."""
        if self.method != "dbscan":
            return {"method": self.method}
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class ObjectResult:
    """One object of a frame: its points, the whiskers that touched it, its surface estimate
    and errors. The mesh counts and distances are those of the known part (position std <=
    ``max_std_m``); ``unknown_triangles`` were meshed but are not on the map.
    ``points_nearer_other`` counts its points nearer another true object than its own, by that
    object (two objects in one); ``files`` are what the caller wrote of it. ``uncertainty``
    is False for a mesh without a position std (Open3D's Poisson or ball pivoting,
    ``MapSettings.method``): then every triangle is known, the std and ``max_std_m`` are None
    and there are no next sweeps."""

    name: str
    n_points: int
    whiskers: tuple[WhiskerCount, ...]
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
    next_sweeps: tuple[NextSweep, ...] = ()
    files: dict[str, str] = field(default_factory=dict)
    points_nearer_other: dict[str, int] = field(default_factory=dict)
    uncertainty: bool = True

    def as_dict(self) -> dict[str, Any]:
        """The object as ``report.json`` holds it."""
        d = asdict(self)
        d.update(whiskers=[asdict(w) for w in self.whiskers],
                 next_sweeps=[asdict(s) for s in self.next_sweeps])
        return d


@dataclass(frozen=True)
class FrameResult:
    """Fit and errors of one frame, over all its objects; ``noise_*`` are the points in no
    object; ``files`` what the caller wrote of it."""

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
    clustering: Clustering = Clustering("none")
    noise_points: int = 0
    noise_whiskers: tuple[WhiskerCount, ...] = ()
    noise_to_surface_max: float | None = None
    objects: tuple[ObjectResult, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """The frame as ``report.json`` holds it."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d.update(files=dict(self.files), clustering=self.clustering.as_dict(),
                 noise_whiskers=[asdict(w) for w in self.noise_whiskers],
                 objects=[obj.as_dict() for obj in self.objects])
        return d


@dataclass(frozen=True)
class InputStream:
    """One input stream (a publisher on a topic) that ended: what it said was sent, what
    arrived, what was lost, what arrived and did not decode (rejected)."""

    topic: str
    pub: int
    source: str
    sent: int
    received: int
    lost: int
    rejected: int = 0


@dataclass(frozen=True)
class UpstreamNode:
    """A node whose messages reach the map, as the graph's statuses tell: what it received,
    lost and refused of its own input over all its starts, and what its producers sent it
    (``sent_to_it``; None where their messages also went elsewhere)."""

    node: str
    received: int
    lost: int
    rejected: int
    sent_to_it: int | None

    @property
    def short(self) -> int:
        """Messages that never reached it: sent but not received by any of its starts (a
        start killed, input sent before it listened, lost, refused); where what was sent is
        not known, those it counted as lost or refused."""
        if self.sent_to_it is None:
            return self.lost + self.rejected
        return max(0, self.sent_to_it - self.received)


@dataclass(frozen=True)
class Exploration:
    """How much of the true objects an exploration's map covers (`vibrissa.mapping.coverage`):
    the ``planner`` that drove the robot, the path length of its base so far, m, and
    ``coverage``: (path length at the map, m; the share of the true surface's samples covered)
    of each map of the run in order (every update, and the final map when it is not the last
    update's)."""

    planner: str
    path_length_m: float
    coverage: tuple[tuple[float, float], ...] = ()
    base_path: tuple[FloatArray, FloatArray] | None = field(default=None, compare=False,
                                                            repr=False)
    """The base's poses driven so far, for the pictures (not in report.json): positions
    (N, 3) m and quaternions (N, 4) (x, y, z, w), about one a
    `vibrissa.mapping.coverage.PATH_STEP_M` of travel."""

    @property
    def coverage_final(self) -> float | None:
        """The last map's coverage (None before the first)."""
        return self.coverage[-1][1] if self.coverage else None

    def as_dict(self) -> dict[str, Any]:
        """``report.json``'s ``exploration``."""
        return {"planner": self.planner, "path_length_m": self.path_length_m,
                "coverage_final": self.coverage_final,
                "coverage": [[length, share] for length, share in self.coverage]}


@dataclass(frozen=True)
class Localization:
    """The localizer's correction (`vibrissa.mapping.localize`) as the map saw it: how many
    ``map -> odom`` estimates came, the last one (a translation x, y, m) and the stamp it is
    given for (s: the last estimate's, or with the truth known the run's end, where the last
    estimate still holds); with the truth (``true_map_to_odom``: x, y in m and yaw in rad at
    that stamp), the estimate's error and the true drift there, m (the translations' distance
    and length: the end pose's position error with and without the correction)."""

    corrections: int
    stamp: float | None = None
    map_to_odom_m: tuple[float, float] | None = None
    true_map_to_odom: tuple[float, float, float] | None = None

    def as_dict(self) -> dict[str, Any]:
        """``report.json``'s ``localization``."""
        est, true = self.map_to_odom_m, self.true_map_to_odom
        error = drift = None
        if true is not None:
            drift = math.hypot(true[0], true[1])
            if est is not None:
                error = math.hypot(est[0] - true[0], est[1] - true[1])
        return {"corrections": self.corrections, "stamp": self.stamp,
                "map_to_odom_m": None if est is None else list(est),
                "true_map_to_odom": None if true is None else list(true),
                "error_m": error, "true_drift_m": drift}


@dataclass(frozen=True)
class MapReport:
    """The whole map: its frames, the truth it was measured against, and what was lost or
    dropped on the way (``dropped_points`` by reason, `vibrissa.mapping.Accumulator`), and the
    points merged into ones kept before (``merged_points``: repeats, neither lost nor dropped).

    ``true_surface`` (a surface spec in units of ``rod_length_m``) or ``scene`` (a scene file
    with ``scene_objects``) name the truth; ``lost`` counts input messages lost, ``streams``
    the input streams; ``upstream`` what the nodes before the map lost on the way;
    ``files`` the report files written. ``final``: the last map of the run (else a periodic
    one, written while the streams go on); ``ended_by`` (final only) what ended the run:
    ``streams`` (every source ended), ``stop`` (SIGINT or SIGTERM) or ``timeout`` (silence);
    ``updates`` the map updates (fits) so far and ``update_fits`` what they did
    (`vibrissa.mapping.LiveMap.fits`: objects fitted in ``full``, ``conditioned`` on new points
    or ``kept``; frames ``clustered``, ``joined`` or ``unchanged``). ``exploration``: the
    coverage of an exploration along its path (`Exploration`), or None (``null``) when the run
    is not one; ``localization`` the correction of a drifting odometry (`Localization`), or
    None when the map took none.
    """

    n_points: int
    sources_ended: tuple[str, ...]
    frames: tuple[FrameResult, ...]
    true_surface: str | None = None
    scene: str | None = None
    scene_objects: tuple[str, ...] | None = None
    rod_length_m: float = 1.0
    lost: int = 0
    dropped_points: dict[str, int] = field(default_factory=dict)
    bad_covariance: int = 0
    merged_points: int = 0
    streams: tuple[InputStream, ...] = ()
    upstream: tuple[UpstreamNode, ...] = ()
    files: dict[str, str] = field(default_factory=dict)
    final: bool = True
    ended_by: str | None = "streams"
    updates: int = 1
    update_fits: dict[str, int] = field(default_factory=dict)
    exploration: Exploration | None = None
    localization: Localization | None = None

    @property
    def upstream_lost(self) -> int:
        """Messages the nodes before the map lost, refused or never counted."""
        return sum(u.short for u in self.upstream)

    @property
    def max_reconstruction_error_m(self) -> float | None:
        """The largest cloud -> true surface distance over the frames, m."""
        return max((f.cloud_to_surface_max for f in self.frames
                    if f.cloud_to_surface_max is not None), default=None)

    def as_dict(self) -> dict[str, Any]:
        """What ``report.json`` holds."""
        return {
            "n_points": self.n_points,
            "sources_ended": list(self.sources_ended),
            "true_surface": self.true_surface,
            "scene": self.scene,
            "scene_objects": None if self.scene_objects is None else list(self.scene_objects),
            "rod_length_m": self.rod_length_m,
            "max_reconstruction_error_m": self.max_reconstruction_error_m,
            "frames": [frame.as_dict() for frame in self.frames],
            "lost": self.lost,
            "dropped_points": dict(self.dropped_points),
            "bad_covariance": self.bad_covariance,
            "merged_points": self.merged_points,
            "streams": [asdict(stream) for stream in self.streams],
            "upstream": [{**asdict(node), "short": node.short} for node in self.upstream],
            "upstream_lost": self.upstream_lost,
            "files": dict(self.files),
            "final": self.final,
            "ended_by": self.ended_by,
            "updates": self.updates,
            "update_fits": dict(sorted(self.update_fits.items())),
            "exploration": None if self.exploration is None else self.exploration.as_dict(),
            "localization": None if self.localization is None else self.localization.as_dict(),
        }

    def text(self) -> str:
        """The human-readable report (lengths in mm)."""
        return _format_report(self.as_dict())


def _mm(value: float | None) -> str:
    return "n/a" if value is None else f"{value * 1e3:.4g} mm"


def _counts(whiskers: list[dict[str, Any]]) -> str:
    return ", ".join(f"{w['whisker_id']} ({w['n_points']})" for w in whiskers)


_DROPPED = {"out_of_range": f"with a coordinate beyond {MAX_POSITION_M:g} m",
            "no_force_direction": f"with a contact force of zero or over {MAX_FORCE_N:g} N (no "
                                  "normal)"}


def _format_report(report: dict[str, Any]) -> str:
    """The human-readable report (lengths in mm)."""
    empty = " - THE MAP IS EMPTY" if report["n_points"] == 0 else ""
    truth = (f"scene {report['scene']} ({', '.join(report['scene_objects']) or 'no objects'})"
             if report.get("scene") else
             f"{report['true_surface'] or 'not given'} (L = {report['rod_length_m']} m)")
    state = (f"final map (ended by {report['ended_by']})" if report["final"]
             else "map so far (the streams go on)")
    fits = ", ".join(f"{n} {what}" for what, n in report.get("update_fits", {}).items())
    lines = [f"{state}, {report['updates']} update(s)" + (f" ({fits})" if fits else ""),
             f"contact points: {report['n_points']}{empty} (sources: "
             f"{', '.join(report['sources_ended']) or 'none ended'})",
             f"true surface: {truth}",
             f"max reconstruction error (cloud -> true surface): "
             f"{_mm(report['max_reconstruction_error_m'])}"]
    localization = report.get("localization")
    if localization is not None and localization["map_to_odom_m"] is not None:
        x, y = localization["map_to_odom_m"]
        line = (f"localization: {localization['corrections']} correction(s), map -> odom at the "
                f"end ({_mm(x)}, {_mm(y)})")
        if localization["error_m"] is not None:
            line += (f", {_mm(localization['error_m'])} from the true one (the odometry "
                     f"drifted {_mm(localization['true_drift_m'])})")
        lines.append(line)
    exploration = report.get("exploration")
    if exploration is not None:
        final = exploration["coverage_final"]
        lines.append(f"exploration ({exploration['planner']}): path {_mm(exploration['path_length_m'])}"
                     f", coverage {'n/a' if final is None else f'{final:.1%}'} of the true "
                     f"surface in reach ({len(exploration['coverage'])} map(s))")
    if report["lost"]:
        lines.append(f"LOST: {report['lost']} contact message(s) never arrived")
    for bound, n in report.get("dropped_points", {}).items():
        lines.append(f"DROPPED: {n} contact point(s) {_DROPPED.get(bound, 'beyond ' + bound)}")
    if report.get("merged_points"):
        lines.append(f"merged: {report['merged_points']} contact point(s) repeating one kept "
                     "before (the same whisker, an earlier contact line), not kept again")
    if report["bad_covariance"]:
        lines.append(f"BAD COVARIANCE: {report['bad_covariance']} contact point(s) with a "
                     "covariance that is not symmetric positive semidefinite, mapped as points "
                     "without one (point_std_m)")
    for stream in report["streams"]:
        lines.append(f"input {stream['topic']} from {stream['source']}: {stream['sent']} sent, "
                     f"{stream['received']} received, {stream['lost']} lost"
                     + (f", {stream['rejected']} rejected" if stream.get("rejected") else ""))
    if report.get("upstream_lost") and report.get("ended_by") == "stop":
        lines.append(f"UPSTREAM AT THE STOP: {report['upstream_lost']} message(s) had not "
                     "reached the nodes before the map when the graph stopped (on their way, "
                     "or lost):")
    elif report.get("upstream_lost"):
        lines.append(f"LOST UPSTREAM: {report['upstream_lost']} message(s) did not reach the "
                     "nodes before the map, so the map may miss what they carried:")
    for node in report.get("upstream", []):
        if node["short"]:
            sent = "" if node["sent_to_it"] is None else f" of the {node['sent_to_it']} sent to it"
            lines.append(f"  {node['node']}: received {node['received']}{sent} (lost "
                         f"{node['lost']}, refused {node['rejected']}; a start killed or input "
                         "sent before it listened is short too)")
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
            ]
            if obj.get("uncertainty", True):
                lines += [
                    f"    mesh: {obj['n_vertices']} vertices, {obj['n_triangles']} triangles "
                    f"known, {obj['unknown_triangles']} unknown (std above "
                    f"{_mm(obj['max_std_m'])})",
                    f"    std of the known surface: median {_mm(obj['std_median_m'])}, "
                    f"max {_mm(obj['std_max_m'])}"]
            else:
                lines += [
                    f"    mesh: {obj['n_vertices']} vertices, {obj['n_triangles']} triangles, "
                    "NO UNCERTAINTY: no std, nothing marked unknown, no next sweeps (they "
                    "need the GP's std; method gp)"]
            lines += [
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
