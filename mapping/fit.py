"""A frame's map from its contacts: objects, contact normals, a surface and next sweeps per
object, and errors against the true objects when they are known (`fit_frame`)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from vibrissa.mapping.accumulate import ContactBatch, FrameCloud
from vibrissa.mapping.next_sweep import Proposal, propose_sections
from vibrissa.mapping.objects import (
    cluster_points,
    contact_normals,
    join_convex,
    line_spacing,
    whisker_lines,
)
from vibrissa.mapping.report import Clustering, FrameResult, NextSweep, ObjectResult, whisker_counts
from vibrissa.mapping.settings import MapSettings
from vibrissa.mapping.surface import ObjectSurface, estimate_surface, too_little_for_a_surface
from vibrissa.mapping.truth import TrueObject, name_objects

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

ONE_OBJECT = "none: true_surface is the one object"
"""The clustering method of a frame that is one object (``MapSettings.one_object``)."""


@dataclass(frozen=True)
class FrameMap:
    """A frame mapped: its result and what goes into files, messages and figures.

    ``points``, ``normals`` (N, 3) and ``whisker_ids`` (N,) in line order; ``labels`` (N,)
    the object of each point (index into ``result.objects`` and ``surfaces``, -1: noise);
    ``surfaces`` the estimate of each object and ``proposals`` its next sweeps; ``vertices``
    (V, 3), ``triangles`` (T, 3) and ``std`` (V,) the known part of every object's mesh in one;
    ``truth`` the true objects it was measured against.
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
    truth: tuple[TrueObject, ...] = ()


def _stats(distance: FloatArray) -> tuple[float | None, float | None]:
    """Max and mean of distances (None, None when there are none)."""
    if len(distance) == 0:
        return None, None
    return float(distance.max()), float(distance.mean())


@dataclass(frozen=True)
class FrameObjects:
    """A frame's contacts split into objects, before their surfaces (`frame_objects`).

    ``points``, ``normals`` (N, 3), ``whisker_ids`` (N,), ``lines`` (N,) and ``normal_var``
    (N,) (each point's variance along its normal, m^2; NaN: none) in line order; ``labels``
    (N,) the object of each point (-1: noise); ``named`` each object's name, true object and
    median distance to it; ``spacing`` the frame's line spacing and ``spacings`` each object's,
    m (inf: one line).
    """

    points: FloatArray
    normals: FloatArray
    whisker_ids: list[str]
    lines: IntArray
    normal_var: FloatArray
    labels: IntArray
    named: list[tuple[str, TrueObject | None, float | None]]
    spacing: float
    clustering: Clustering
    spacings: list[float]

    def inside(self, k: int) -> IntArray:
        """Indices (n,) of the points of object ``k``, in line order."""
        return np.flatnonzero(self.labels == k)


def frame_contacts(cloud: FrameCloud) -> tuple[FloatArray, FloatArray, list[str], IntArray,
                                                FloatArray]:
    """A frame's contact points (N, 3) m in line order, their outward normals (N, 3), whiskers
    (N,), lines (N,) and variances along the normals (N,) m^2."""
    points, forces, whisker_ids, covariances = cloud.ordered()
    lines = whisker_lines(points, whisker_ids)
    normals = contact_normals(points, forces, lines)
    # each point's variance along its normal (NaN without a covariance, or with one that is not
    # a covariance: the floor point_std_m; one too large for floats: the ceiling)
    given = np.isfinite(covariances).all(axis=(1, 2))
    with np.errstate(over="ignore", invalid="ignore"):
        normal_var = np.einsum("ni,nij,nj->n", normals, covariances, normals)
    normal_var[given & ~np.isfinite(normal_var)] = np.inf
    return points, normals, whisker_ids, lines, normal_var


def frame_objects(cloud: FrameCloud, settings: MapSettings,
                  truth: tuple[TrueObject, ...]) -> FrameObjects:
    """The contacts of a frame in line order, their normals and objects (see `fit_frame`)."""
    return contact_objects(frame_contacts(cloud), settings, truth)


def contact_objects(contacts: tuple[FloatArray, FloatArray, list[str], IntArray, FloatArray],
                    settings: MapSettings, truth: tuple[TrueObject, ...]) -> FrameObjects:
    """`frame_objects` of a frame's `frame_contacts`."""
    points, normals, whisker_ids, lines, normal_var = contacts
    if settings.one_object:  # the frame is one object (its truth, when known)
        spacing = line_spacing(points, lines) if len(points) else float("inf")
        labels = np.zeros(len(points), dtype=np.int64)
        named: list[tuple[str, TrueObject | None, float | None]] = [
            ("object0", truth[0] if truth else None, None)]
        clustering = Clustering(ONE_OBJECT)
    else:
        clusters = cluster_points(points, lines, settings.cluster_eps_m,
                                  settings.cluster_min_points)
        labels, joined = (join_convex(points, normals, clusters.labels, normal_var,
                                      settings.join_normal_tol_rad) if settings.join_convex
                          else (clusters.labels, []))
        named = name_objects(points, labels, truth)
        spacing = clusters.line_spacing
        clustering = Clustering("dbscan", clusters.eps, clusters.eps_rule, clusters.min_points,
                                clusters.n_clusters, joined,
                                spacing if np.isfinite(spacing) else None, clusters.line_extent)
    spacings = []
    for k in range(len(named)):
        inside = np.flatnonzero(labels == k)
        spacings.append(spacing if len(inside) == len(points)  # the frame's, measured once
                        else line_spacing(points[inside], lines[inside]))
    return FrameObjects(points, normals, whisker_ids, lines, normal_var, labels, named, spacing,
                        clustering, spacings)


def object_proposals(surface: ObjectSurface, points: FloatArray,
                     settings: MapSettings) -> list[Proposal]:
    """The next sweeps of an object with ``surface`` and contact ``points`` (n, 3), m."""
    if surface.gp is None or surface.mesh is None or not settings.proposals:
        return []
    return propose_sections(surface.gp, surface.mesh.vertices, points,
                            np.array(settings.proposal_axis), settings.proposals)


def fit_frame(frame_id: str, cloud: FrameCloud, settings: MapSettings | None = None,
              truth: Sequence[TrueObject] = ()) -> FrameMap:
    """Objects, normals, surface estimates, next sweeps and errors of one frame.

    Parameters
    ----------
    frame_id
        The frame of the points.
    cloud
        Its contact points (`vibrissa.mapping.Accumulator.frames`).
    settings
        How to separate objects, fit and mesh them (default `MapSettings()`).
    truth
        The true objects in this frame, m: the objects are named after them and measured
        against them; with ``settings.one_object``, the first is the frame's one object.
    """
    settings = settings or MapSettings()
    objects = frame_objects(cloud, settings, tuple(truth))
    surfaces: list[ObjectSurface] = []
    proposals: list[list[Proposal]] = []
    for k in range(len(objects.named)):
        inside = objects.inside(k)
        surfaces.append(estimate_surface(objects.points[inside], objects.normals[inside],
                                         settings, objects.normal_var[inside]))
        proposals.append(object_proposals(surfaces[-1], objects.points[inside], settings))
    return frame_map(frame_id, objects, surfaces, proposals, tuple(truth))


def frame_map(frame_id: str, objects: FrameObjects, surfaces: Sequence[ObjectSurface],
              proposals: Sequence[list[Proposal]], truth: tuple[TrueObject, ...]) -> FrameMap:
    """The map of a frame's ``objects`` with a surface and proposals per object: its report,
    errors against ``truth`` and the known part of the meshes in one."""
    points, whisker_ids, labels = objects.points, objects.whisker_ids, objects.labels
    spacing, clustering = objects.spacing, objects.clustering
    results: list[ObjectResult] = []
    cloud_distance: list[FloatArray] = []
    mesh_distance: list[FloatArray] = []
    for k, (name, true, median) in enumerate(objects.named):
        inside = objects.inside(k)
        surface = surfaces[k]
        vertices, triangles, std = surface.part(known=True)
        uncertain = surface.uncertainty  # Open3D's meshes: no std
        own_spacing = objects.spacings[k]
        cloud_stats: tuple[float | None, float | None] = (None, None)
        mesh_stats: tuple[float | None, float | None] = (None, None)
        nearer_other: dict[str, int] = {}
        if true is not None:
            to_each = np.array([other.distance(points[inside]) for other in truth])
            cloud_distance.append(to_each.min(axis=0))
            mesh_distance.append(true.distance(vertices))
            nearer = cloud_distance[-1] < to_each[truth.index(true)]  # than to its own
            nearer_other = dict(sorted(Counter(
                truth[j].name for j in np.argmin(to_each, axis=0)[nearer]).items()))
            cloud_stats, mesh_stats = _stats(cloud_distance[-1]), _stats(mesh_distance[-1])
        results.append(ObjectResult(
            name, len(inside), whisker_counts([whisker_ids[i] for i in inside]),
            surface.method, len(vertices), len(triangles),
            own_spacing if np.isfinite(own_spacing) else None,
            unknown_triangles=len(surface.part(known=False)[1]),
            max_std_m=surface.mesh.max_std if surface.mesh is not None and uncertain else None,
            std_median_m=float(np.median(std)) if len(std) and uncertain else None,
            std_max_m=float(std.max()) if len(std) and uncertain else None,
            uncertainty=uncertain,
            true_object=true.name if true is not None else None, true_object_median_m=median,
            next_sweeps=next_sweeps(proposals[k]),
            points_nearer_other=nearer_other, cloud_to_surface_max=cloud_stats[0],
            cloud_to_surface_mean=cloud_stats[1], mesh_to_surface_max=mesh_stats[0],
            mesh_to_surface_mean=mesh_stats[1]))
    noise = np.flatnonzero(labels < 0)
    if len(results) == 1:
        method = results[0].method
    elif results:
        method = "; ".join(f"{obj.name}: {obj.method}" for obj in results)
    else:
        method = "none: " + (too_little_for_a_surface(points) or (
            f"no object: all {len(points)} points are noise (DBSCAN eps "
            f"{clustering.eps_m:.4g} m, min_points {clustering.min_points})"))
    vertices, triangles, std = joined_part(surfaces, known=True)
    cloud_stats, mesh_stats, noise_max = (None, None), (None, None), None
    if truth:
        cloud_stats = _stats(np.concatenate(cloud_distance or [np.zeros(0)]))
        mesh_stats = _stats(np.concatenate(mesh_distance or [np.zeros(0)]))
        if len(noise):
            noise_max = float(np.max(np.min([true.distance(points[noise]) for true in truth],
                                            axis=0)))
    result = FrameResult(
        frame_id, len(points), method, len(vertices), len(triangles),
        spacing if np.isfinite(spacing) else None,
        clustering=clustering, noise_points=len(noise),
        noise_whiskers=whisker_counts([whisker_ids[i] for i in noise]), objects=tuple(results),
        cloud_to_surface_max=cloud_stats[0], cloud_to_surface_mean=cloud_stats[1],
        mesh_to_surface_max=mesh_stats[0], mesh_to_surface_mean=mesh_stats[1],
        noise_to_surface_max=noise_max)
    return FrameMap(result, points, objects.normals, whisker_ids, labels, list(surfaces),
                    vertices, triangles, std, [list(p) for p in proposals], truth)


def next_sweeps(proposals: Sequence[Proposal]) -> tuple[NextSweep, ...]:
    """An object's next sweeps as its report gives them."""
    return tuple(NextSweep(p.offset_m, p.axis.tolist(), len(p.line), p.std_on_line_m,
                           p.std_max_before_m, p.std_max_after_m) for p in proposals)


def with_proposals(frame: FrameMap, proposals: Sequence[list[Proposal]]) -> FrameMap:
    """``frame`` with these next sweeps of its objects (in its report too)."""
    objects = tuple(replace(obj, next_sweeps=next_sweeps(p))
                    for obj, p in zip(frame.result.objects, proposals, strict=True))
    return replace(frame, result=replace(frame.result, objects=objects),
                   proposals=[list(p) for p in proposals])


def joined_part(surfaces: Sequence[ObjectSurface], known: bool = True,
                ) -> tuple[FloatArray, IntArray, FloatArray]:
    """The known (or unknown) part of every surface's mesh in one: vertices (V, 3) m, triangles
    (T, 3) and position std (V,) m."""
    parts = [surface.part(known) for surface in surfaces]
    offsets = np.cumsum([0] + [len(v) for v, _, _ in parts])[:-1]
    vertices = np.concatenate([v for v, _, _ in parts] or [np.zeros((0, 3))])
    triangles = np.concatenate(
        [t + offset for (_, t, _), offset in zip(parts, offsets, strict=True)]
        or [np.zeros((0, 3), dtype=np.int64)])
    return vertices, triangles, np.concatenate([s for _, _, s in parts] or [np.zeros(0)])


def map_cloud(points_m: FloatArray, forces_n: FloatArray, whisker_ids: Sequence[str],
              settings: MapSettings | None = None, truth: Sequence[TrueObject] = (),
              covariances_m2: FloatArray | None = None, frame_id: str = "world") -> FrameMap:
    """The map of one cloud: `fit_frame` on points (N, 3) m, in the order each whisker took
    them, their contact forces on the rod (N, 3) N, their whiskers (N names) and optionally
    their position covariances (N, 3, 3) m^2. No bounds apply (`Accumulator` keeps them for
    a stream)."""
    cloud = FrameCloud()
    batch = ContactBatch(frame_id, np.asarray(points_m, dtype=np.float64),
                         np.asarray(forces_n, dtype=np.float64), list(whisker_ids),
                         covariances_m2=covariances_m2)
    cloud.add(batch, None, np.full((len(batch.whisker_ids), 3, 3), np.nan)
              if covariances_m2 is None else np.asarray(covariances_m2, dtype=np.float64))
    return fit_frame(frame_id, cloud, settings, truth)


def warm_up(settings: MapSettings | None = None) -> None:
    """Map a small made-up object once (`map_cloud`): a process loads the fits' compiled
    kernels and libraries then, not in its first map (a second at start, beside a busy
    stream)."""
    angle = np.linspace(0.2, 1.2, 60)
    lines = [np.column_stack([np.cos(angle) * np.cos(phi), np.cos(angle) * np.sin(phi),
                              np.sin(angle)]) for phi in (0.0, 0.4, 0.8, 1.2)]
    normals = np.vstack(lines)  # points on a ball of 20 mm, pushed along its normals
    coarse = replace(settings or MapSettings(), cells=16)  # the same kernels, a small grid
    map_cloud(0.02 * normals, 0.01 * normals, [f"w{k}" for k in range(4) for _ in angle],
              coarse)
