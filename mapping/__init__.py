"""Contact points -> a map: objects, surfaces with their uncertainty, next sweeps, errors.

A library without processes, messages or files (numpy, scipy, numba, scikit-image, Open3D):
`Accumulator` gathers `ContactBatch` es per frame within bounds, `fit_frame` maps a frame's
cloud with `MapSettings` (or `map_cloud` maps one cloud of arrays), measured against
`TrueObject` s when they are known; the result (`FrameMap`) holds the points, contact
normals, objects, meshes and the typed report (`FrameResult`, `MapReport`); `LiveMap` maps a
growing cloud update by update, refitting only what changed. The steps, each usable alone:
`objects` (contact lines, contact normals, DBSCAN clustering, ``join_convex``),
`surface` (one object's surface), `gp_surface` (the Gaussian-process implicit surface and its
mesh), `next_sweep` (where to sweep next), `truth` (distances to the true objects), `coverage` (how
much of the true objects a map covers, along an exploration: `ExplorationLog`), `localize`
(a drifting odometry corrected from the contacts: `Localizer`).
docs/MAPPING.md has the choice of the method.
"""

from vibrissa.mapping.accumulate import Accumulator, ContactBatch, FrameCloud, is_covariance
from vibrissa.mapping.coverage import ExplorationLog, coverage_samples
from vibrissa.mapping.fit import FrameMap, fit_frame, map_cloud
from vibrissa.mapping.live import LiveMap, LiveSettings
from vibrissa.mapping.localize import Localizer, LocalizeSettings, true_map_to_odom
from vibrissa.mapping.next_sweep import Proposal, propose_sections
from vibrissa.mapping.objects import (
    Clusters,
    cluster_points,
    contact_normals,
    join_convex,
    line_spacing,
    split_lines,
    whisker_lines,
)
from vibrissa.mapping.report import (
    Clustering,
    Exploration,
    FrameResult,
    InputStream,
    Localization,
    MapReport,
    NextSweep,
    ObjectResult,
    UpstreamNode,
    WhiskerCount,
)
from vibrissa.mapping.settings import MapSettings
from vibrissa.mapping.surface import ObjectSurface, estimate_surface, too_little_for_a_surface
from vibrissa.mapping.truth import TrueObject, name_objects

__all__ = [
    "Accumulator", "Clustering", "Clusters", "ContactBatch", "Exploration", "ExplorationLog",
    "FrameCloud", "FrameMap",
    "FrameResult", "InputStream", "LiveMap", "LiveSettings", "Localization", "Localizer",
    "LocalizeSettings", "MapReport", "MapSettings",
    "NextSweep", "ObjectResult", "UpstreamNode",
    "ObjectSurface", "Proposal", "TrueObject", "WhiskerCount", "cluster_points",
    "contact_normals", "coverage_samples", "estimate_surface", "fit_frame", "is_covariance",
    "join_convex",
    "line_spacing", "map_cloud", "name_objects", "propose_sections", "split_lines",
    "too_little_for_a_surface", "true_map_to_odom", "whisker_lines",
]
