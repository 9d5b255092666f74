"""A map that grows with its stream (`LiveMap`): each update refits only what new points changed.

An update first finds the frame's objects: when every point new since the last update lies
within the DBSCAN radius of one object and of nothing else, no point is gone and the frame has
grown by less than ``LiveSettings.refit_growth`` since its last clustering, the new points join
that object; otherwise the whole cloud is clustered again (contact normals, DBSCAN,
``join_convex``), the only way a merge or a split is seen as the data decide it. Then each
object is matched to the object of the previous update that holds its points:

* **unchanged** (the same points, normals and variances in the same order): its surface, mesh
  and next sweeps are kept;
* **grown** (all of one previous object's points and new ones): its Gaussian-process surface is
  conditioned on the new points, its hyperparameters kept (`gp_surface.extended`: the Cholesky
  factor extended by a block, exact for the active points it holds), and meshed again on a grid
  of ``LiveSettings.cells``; its next sweeps are those of its last full fit (or proposed on
  it, when that fit's were never);
* anything else (a new object, objects that **merged**, an object that **split**, one grown
  by ``LiveSettings.refit_growth`` of its points since its last full fit: the cadence of the
  hyperparameters): a full fit as `fit_frame` does it, meshed on the grid of
  ``LiveSettings.cells`` too.

An update proposes the next sweeps of the objects it fitted in full, or with
``propose=False`` leaves them to `LiveMap.propose` (the mapper publishes the meshes first: the
sweeps take as long as the surfaces); until then those objects have none.

`LiveMap.final` fits every object whose surface is not already the full fit on exactly its
points, meshed on the settings' grid: the final map is then the single fit's (`fit_frame` on
the same cloud), bit for bit, which a grown object's conditioned surface is not (its active
points are those of each update, not a selection along the whole cloud, and its normals are
those of the points' first update).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import cast

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from vibrissa.mapping import gp_surface
from vibrissa.mapping.accumulate import FrameCloud
from vibrissa.mapping.fit import (
    FrameMap,
    FrameObjects,
    contact_objects,
    frame_contacts,
    frame_map,
    object_proposals,
    with_proposals,
)
from vibrissa.mapping.gp_surface import GPParams
from vibrissa.mapping.next_sweep import Proposal
from vibrissa.mapping.settings import MAX_CELLS, MapSettings
from vibrissa.mapping.surface import ObjectSurface, estimate_surface, meshed_surface
from vibrissa.mapping.truth import TrueObject, name_objects

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class LiveSettings:
    """How a `LiveMap` spends its updates.

    Attributes
    ----------
    refit_growth
        A grown object is fitted in full (its hyperparameters re-estimated, its next sweeps
        proposed again) once its points have grown by this fraction since its last full fit;
        below it, its surface is conditioned on the new points.
    cells
        Marching-cubes grid cells along the longest side of an object's box in an update (8 to
        ``MAX_CELLS``; the final map uses the settings' own): the std at the mesh's vertices
        is most of an update's cost, and it scales with their number, the square of the
        cells.
    single
        An update solves the std at the mesh's vertices in single precision
        (`gp_surface.GPSurface.std`: half its time; on the robot demo's objects within 2e-3
        of the prior std, the same known part); the final map in double.
    """

    refit_growth: float = 0.5
    cells: int = 32
    single: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.refit_growth) and self.refit_growth > 0):
            raise ValueError(f"'refit_growth' must be a finite number > 0, got "
                             f"{self.refit_growth!r}")
        if not 8 <= self.cells <= MAX_CELLS:
            raise ValueError(f"'cells' must be a grid size in [8, {MAX_CELLS}], got "
                             f"{self.cells!r}")


@dataclass(frozen=True)
class _Object:
    """An object of the last update: its points (n, 3), normals (n, 3) and variances (n,) in
    line order, its surface and next sweeps (None: not proposed yet), the points of its last
    full fit, and whether its surface and sweeps are that full fit on exactly these points."""

    points: FloatArray
    normals: FloatArray
    normal_var: FloatArray
    surface: ObjectSurface
    proposals: list[Proposal] | None
    fitted: int
    exact: bool

    def same(self, points: FloatArray, normals: FloatArray, normal_var: FloatArray) -> bool:
        """Whether these are its points, normals and variances."""
        return (np.array_equal(points, self.points) and np.array_equal(normals, self.normals)
                and np.array_equal(normal_var, self.normal_var, equal_nan=True))


def _keys(points: FloatArray) -> list[bytes]:
    """Each point's (N, 3) bytes: a point is the same point when its coordinates are."""
    rows = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    return cast(list[bytes], rows.view(np.dtype((np.void, rows.itemsize * 3))).ravel().tolist())


@dataclass(frozen=True)
class _Frame:
    """A frame's last update: its settings, truth, cloud and how many points it held, the map,
    its objects and their fits, the points of its last full clustering, and whether the map is
    the single fit's (clustered on these points, every object's surface a full fit)."""

    settings: MapSettings
    truth: tuple[TrueObject, ...]
    cloud: FrameCloud
    n_points: int
    map: FrameMap
    objects: FrameObjects
    tracked: list[_Object]
    clustered: int
    exact: bool


def _grown_objects(last: FrameObjects, contacts: tuple[FloatArray, FloatArray, list[str],
                                                       IntArray, FloatArray],
                   keys: list[bytes], truth: tuple[TrueObject, ...]) -> FrameObjects | None:
    """The objects of ``contacts`` (`frame_contacts`; ``keys`` of their points) when the points
    new since ``last`` all lie within its DBSCAN radius of one object and of no other object
    or noise point: they join it, and the rest keeps its objects (DBSCAN on the whole would put
    them there too, but for points that only chain together); None otherwise (a merge, a
    split, a new object or noise, or points of ``last`` gone: cluster again). The line
    spacings are the last ones."""
    points = contacts[0]
    label_of = dict(zip(_keys(last.points), last.labels.tolist(), strict=True))
    labels = np.array([label_of.get(key, NEW) for key in keys], dtype=np.int64)
    new = np.flatnonzero(labels == NEW)
    if len(keys) - len(new) != len(last.points):  # some of the last points are gone
        return None
    if len(new) and last.clustering.eps_m is None:  # one object: theirs
        labels[new] = 0
    elif len(new):
        eps = np.nextafter(last.clustering.eps_m, np.inf)
        near = {int(g): np.isfinite(cKDTree(last.points[last.labels == g]).query(
            points[new], distance_upper_bound=eps)[0]) for g in np.unique(last.labels)}
        hit = [g for g, close in near.items() if close.any()]
        if len(hit) != 1 or hit[0] < 0 or not near[hit[0]].all():
            return None
        labels[new] = hit[0]
    named = (last.named if last.clustering.eps_m is None
             else name_objects(points, labels, truth))
    return FrameObjects(*contacts, labels, named, last.spacing, last.clustering, last.spacings)


NEW = -2
"""The label of a point new since the last update (noise is -1)."""


class LiveMap:
    """The maps of a stream's frames, updated as points arrive (see module).

    ``fits`` counts what the updates did: objects fitted in ``"full"``, ``"conditioned"`` on
    new points and ``"kept"``; frames ``"clustered"`` again, whose new points were ``"joined"``
    to an object, and ``"unchanged"`` (no point since the last update, which is returned as it
    was: a frame's cloud only grows, as `Accumulator` keeps it).
    """

    def __init__(self, live: LiveSettings | None = None) -> None:
        self.live = live or LiveSettings()
        self.fits: Counter[str] = Counter()
        self._frames: dict[str, _Frame] = {}

    def update(self, frame_id: str, cloud: FrameCloud, settings: MapSettings | None = None,
               truth: Sequence[TrueObject] = (), propose: bool = True) -> FrameMap:
        """The map of ``frame_id`` with all of its points so far (``cloud``, as for
        `fit_frame`), refitting only the objects that changed since its last update;
        ``propose=False``: the next sweeps of objects fitted in full are left to `propose`."""
        return self._map(frame_id, cloud, settings or MapSettings(), tuple(truth), final=False,
                         propose=propose)

    def propose(self, frame_id: str) -> FrameMap:
        """The last map of ``frame_id`` with the next sweeps its update left out (the same map
        when it left none)."""
        last = self._frames[frame_id]
        if all(obj.proposals is not None for obj in last.tracked):
            return last.map
        tracked = [self._proposed(obj, last.settings) for obj in last.tracked]
        mapped = with_proposals(last.map, [cast(list[Proposal], obj.proposals)
                                           for obj in tracked])
        self._frames[frame_id] = replace(last, map=mapped, tracked=tracked)
        return mapped

    def final(self, frame_id: str, cloud: FrameCloud, settings: MapSettings | None = None,
              truth: Sequence[TrueObject] = ()) -> FrameMap:
        """The map of ``frame_id`` equal to ``fit_frame(frame_id, cloud, settings, truth)``:
        as `update`, with the objects clustered again and a full fit of every object whose
        surface is not one already."""
        return self._map(frame_id, cloud, settings or MapSettings(), tuple(truth), final=True,
                         propose=True)

    def _map(self, frame_id: str, cloud: FrameCloud, settings: MapSettings,
             truth: tuple[TrueObject, ...], final: bool, propose: bool) -> FrameMap:
        last = self._frames.get(frame_id)
        if last is not None and (last.settings != settings or last.truth != truth):
            last = None
        if (last is not None and last.cloud is cloud and last.n_points == len(cloud.seqs)
                and (last.exact or not final)):
            self.fits["unchanged"] += 1
            return self.propose(frame_id) if propose else last.map
        contacts = frame_contacts(cloud)
        keys = _keys(contacts[0])
        objects = None
        if (last is not None and not final
                and len(keys) < (1 + self.live.refit_growth) * last.clustered):
            objects = _grown_objects(last.objects, contacts, keys, truth)
        if objects is None:
            self.fits["clustered"] += 1
            objects, clustered = contact_objects(contacts, settings, truth), len(keys)
            exact = True
        else:
            exact = False
            self.fits["joined"] += 1
            clustered = last.clustered if last is not None else len(keys)
        before = last.tracked if last is not None else []
        owner = {key: j for j, obj in enumerate(before) for key in _keys(obj.points)}
        tracked = [self._object(objects, k, [keys[i] for i in objects.inside(k)], before, owner,
                                settings, final) for k in range(len(objects.named))]
        if propose:
            tracked = [self._proposed(obj, settings) for obj in tracked]
        mapped = frame_map(frame_id, objects, [obj.surface for obj in tracked],
                           [obj.proposals or [] for obj in tracked], truth)
        self._frames[frame_id] = _Frame(settings, truth, cloud, len(cloud.seqs), mapped,
                                        objects, tracked, clustered,
                                        exact and all(obj.exact for obj in tracked))
        return mapped

    def _object(self, objects: FrameObjects, k: int, keys: list[bytes], last: list[_Object],
                owner: dict[bytes, int], settings: MapSettings, final: bool) -> _Object:
        """Object ``k`` of this update (its points' ``keys``), from the object of the last
        update that holds its points when there is one (``owner``: which holds each key)."""
        inside = objects.inside(k)
        points, normals = objects.points[inside], objects.normals[inside]
        normal_var = objects.normal_var[inside]
        before = {owner[key] for key in keys if key in owner}
        if len(before) == 1:
            previous = last[before.pop()]
            held = set(_keys(previous.points))
            new = np.array([i for i, key in enumerate(keys) if key not in held], dtype=np.int64)
            whole = len(held) == len(keys) - len(new)  # all of its points are in this object
            if whole and previous.same(points, normals, normal_var) and (
                    previous.exact or not final):
                self.fits["kept"] += 1
                return previous
            gp = previous.surface.gp
            if (whole and len(new) and not final and gp is not None
                    and len(keys) < (1 + self.live.refit_growth) * previous.fitted):
                self.fits["conditioned"] += 1
                count = math.ceil(GPParams.max_active * len(new) / len(keys))
                gp = gp_surface.extended(gp, points[new], normals[new], count, normal_var[new])
                return _Object(points, normals, normal_var,
                               meshed_surface(gp, points, settings, self.live.cells,
                                              self.live.single),
                               previous.proposals, previous.fitted, exact=False)
        self.fits["full"] += 1
        # while the stream goes on, meshed on the live grid as a conditioned surface is (the
        # final map meshes it on the settings' grid again)
        surface = estimate_surface(points, normals, settings, normal_var,
                                   0 if final else self.live.cells,
                                   not final and self.live.single)
        exact = final or (self.live.cells == settings.cells and not self.live.single)
        return _Object(points, normals, normal_var, surface, None, len(points), exact=exact)

    @staticmethod
    def _proposed(obj: _Object, settings: MapSettings) -> _Object:
        """``obj`` with its next sweeps proposed when they are not yet."""
        if obj.proposals is not None:
            return obj
        return replace(obj, proposals=object_proposals(obj.surface, obj.points, settings))
