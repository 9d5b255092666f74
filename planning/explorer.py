"""Where a whiskered robot goes next to map what it has not touched (`Explorer`), planar: the
base drives on the floor of the workspace (x, y and yaw in W; its height and tilt those of its
start).

What it knows is its own: the robot description (whisker mounts and lengths), its body's radius,
the workspace box, its poses, the contacts of each tick and the map's meshes. From the ticks it
keeps a `FreeSpace` grid: a rod without contact sweeps the cells from its clamp to its tip at
its height, a rod in contact from its clamp to the contact point, which is occupied, and so are
the map's known surfaces; a cell the rods of every height swept is free. The body only goes
where every cell within its radius is free (unknown is blocked) and keeps a skirt margin from
the lowest rods' contacts (a wall may lean out below them), by the shortest route through such
cells; where the map marked a surface beside it after it arrived, it first steps out of there,
no closer to that surface.

A plan is a route to a goal, then a look: a full turn in place, which sweeps the rods around the
body. The goal is the standable cell of most *gain* per metre of route (its gain over one plus
its route over ``detour_m``):

* ``uncertainty``: the cells still unknown within the rods' reach of it, plus
  ``surface_weight`` times the unknown-part vertices of the map's meshes (its uncertainty)
  within that reach and at the whiskers' heights, each drawing one look within reach of it;
  no cell is looked from twice;
* ``lawnmower`` (the baseline): parallel lanes across the workspace, ``lane_spacing_m`` apart
  (default: the rods' reach), visited in order, each lane's points one reach apart; the goal is
  the standable cell nearest to the next point not yet reached or given up.

Exploration ends when the base has travelled ``budget_m``, or when no goal gains anything (the
``uncertainty`` planner: nothing unknown within reach of a standable cell; ``lawnmower``: every
lane point visited or given up).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.signal import fftconvolve
from scipy.spatial.transform import Rotation
from skimage.graph import MCP_Geometric

from vibrissa.frames import Transform
from vibrissa.planning.free_space import OCCUPIED, UNKNOWN, FreeSpace
from vibrissa.scene import Whisker

FloatArray = npt.NDArray[np.float64]

PLANNERS = ("uncertainty", "lawnmower")
"""The goal choices of `Explorer`."""


@dataclass(frozen=True)
class ExploreSettings:
    """How an `Explorer` plans.

    Attributes
    ----------
    planner
        One of `PLANNERS`.
    budget_m
        The base's path length at most, m.
    cell_m
        Edge of the free-space grid's cells, m.
    detour_m
        A goal's gain is divided by one plus its route's length over this, m.
    surface_weight
        Gain of an unknown-part mesh vertex within reach, in unknown cells.
    object_weight, object_ring_m
        Extra gain of an unknown cell within ``object_ring_m`` of an occupied one (a touched
        object goes on there), in unknown cells.
    lane_spacing_m
        Distance between the lawnmower's lanes, m; 0: the rods' reach.
    height_tol_m
        A mesh vertex is at a whisker's height within this, m.
    skirt_slope
        How far an object's wall may lean out below the lowest rods, per metre of height (1:
        45 degrees): the body keeps this times the lowest mounts' height above the workspace's
        floor (``skirt_m``) further from where the lowest rods touched something.
    """

    planner: str = "uncertainty"
    budget_m: float = 2.0
    cell_m: float = 0.004
    detour_m: float = 0.1
    surface_weight: float = 4.0
    object_weight: float = 4.0
    object_ring_m: float = 0.01
    lane_spacing_m: float = 0.0
    height_tol_m: float = 0.005
    skirt_slope: float = 1.0

    def __post_init__(self) -> None:
        if self.planner not in PLANNERS:
            raise ValueError(f"'planner' must be one of {', '.join(PLANNERS)}, got "
                             f"{self.planner!r}")
        for name in ("budget_m", "cell_m", "detour_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name!r} must be a finite number > 0, got {value!r}")
        for name in ("surface_weight", "object_weight", "object_ring_m", "lane_spacing_m",
                     "height_tol_m", "skirt_slope"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name!r} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class Plan:
    """Waypoints of the base X_WR: positions (N, 3) m and quaternions (N, 4) (x, y, z, w), and
    what they are for."""

    position: FloatArray
    orientation: FloatArray
    purpose: str


LEVEL_TOL_M = 1e-3
"""Rods whose mounts' heights lie within this of each other sweep the same level of the free
space, m."""


def rod_levels(heights_m: FloatArray) -> npt.NDArray[np.int64]:
    """The level (n,) of rods whose mounts are at ``heights_m`` (n,): heights in ascending
    order, a new level where the next one is more than `LEVEL_TOL_M` above the last."""
    order = np.argsort(heights_m, kind="stable")
    steps = np.diff(np.asarray(heights_m)[order]) > LEVEL_TOL_M
    level = np.empty(len(order), dtype=np.int64)
    level[order] = np.concatenate([[0], np.cumsum(steps)])
    return level


def _yaw(rotation: Rotation) -> float:
    """The heading of ``rotation``: the angle of its x axis in the floor's plane, rad."""
    x = rotation.apply([1.0, 0.0, 0.0])
    return math.atan2(x[1], x[0])


class Explorer:
    """Plans a planar robot's exploration of its workspace (see the module).

    Parameters
    ----------
    whiskers
        The robot description: each rod's mount X_RC on ``base_link`` and length.
    body_radius_m
        The body: a vertical cylinder of this radius around ``base_link``.
    workspace_min_m, workspace_max_m
        The workspace box in W (3,), m: the base stays on its floor.
    start
        X_WR where the robot stands at first.
    settings
        The planner and its numbers.
    """

    def __init__(self, whiskers: Sequence[Whisker], body_radius_m: float,
                 workspace_min_m: Sequence[float], workspace_max_m: Sequence[float],
                 start: Transform, settings: ExploreSettings | None = None) -> None:
        self.settings = settings or ExploreSettings()
        self.whiskers = {w.name: w for w in whiskers}
        self.body_radius_m = body_radius_m
        heights = np.array([w.X_RC.translation[2] for w in whiskers])
        self._level = rod_levels(heights)
        self.space = FreeSpace(np.asarray(workspace_min_m, dtype=np.float64),
                               np.asarray(workspace_max_m, dtype=np.float64), self.settings.cell_m,
                               levels=int(self._level.max()) + 1)
        self.tilt = Rotation.from_euler("z", -_yaw(start.rotation)) * start.rotation
        self.height_m = float(start.translation[2])
        self.reach_m = max(float(np.linalg.norm(w.X_RC.translation[:2])) + w.length_m
                           for w in whiskers)
        self.heights_m = np.array([self.height_m + w.X_RC.translation[2] for w in whiskers])
        self.skirt_m = self.settings.skirt_slope * max(
            float(self.heights_m.min()) - float(workspace_min_m[2]), 0.0)
        self.travelled_m = 0.0
        self.space.mark_disc(start.translation, body_radius_m)
        self._names = [w.name for w in whiskers]
        self._mounts = np.array([w.X_RC.translation for w in whiskers])  # (n, 3) in R
        self._axes = np.array([w.X_RC.R[:, 2] for w in whiskers])  # the rods' axes in R
        self._lengths = np.array([w.length_m for w in whiskers])
        self._segments: list[FloatArray] = []  # pending ticks: rods (n, 4), bodies, contacts
        self._bodies: list[FloatArray] = []
        self._touched: list[FloatArray] = []  # x, y m and 1 for the lowest rods, else 0
        self._last_xy = np.asarray(start.translation[:2], dtype=np.float64)
        self._unknown_surface = np.zeros((0, 3))
        self._lanes = self._lane_points()
        self._lane = 0
        self._look: FloatArray | None = None  # where the last plan looks around
        self._looks: list[FloatArray] = []  # where looks were done
        self.done_because = ""

    def observe(self, X_WR: Transform, contacts_W: Mapping[str, FloatArray],
                free: Collection[str] | None = None) -> None:
        """One tick: the base at X_WR, the contact point in W (3,) m of each whisker in
        contact, and the whiskers found ``free`` (None: every other one). A whisker in neither
        (it touched something that gives no single contact, or its tick could not be placed)
        marks nothing. Marked on the grid in batches (`plan` marks what is pending first)."""
        xy = np.asarray(X_WR.translation[:2], dtype=np.float64)
        self.travelled_m += float(np.linalg.norm(xy - self._last_xy))
        self._last_xy = xy
        self._bodies.append(xy)
        clamps = self._mounts @ X_WR.R.T + X_WR.translation  # (n, 3)
        ends = clamps + self._lengths[:, None] * (self._axes @ X_WR.R.T)
        for k, name in enumerate(self._names):
            point = contacts_W.get(name)
            if point is None:
                if free is not None and name not in free:
                    ends[k] = clamps[k]  # a segment of no length: nothing swept
                continue
            point = np.asarray(point, dtype=np.float64)
            self._touched.append(np.array([point[0], point[1], float(self._level[k] == 0)]))
            # the rod up to a cell short of the contact: its chord may cut the object's edge
            chord = point - clamps[k]
            length = float(np.linalg.norm(chord[:2]))
            cut = max(length - 2 * self.settings.cell_m, 0.0)
            ends[k] = clamps[k] + (chord * cut / length if length > 0 else 0.0 * chord)
        self._segments.append(np.hstack([clamps[:, :2], ends[:, :2]]))
        if len(self._segments) >= 2048:
            self._mark()

    def _mark(self) -> None:
        """Mark the pending ticks on the grid: bodies and rods free, contacts occupied."""
        if self._segments:
            segments = np.vstack(self._segments)
            level = np.tile(self._level, len(self._segments))
            for k in range(self.space.levels):
                self.space.mark_segments(segments[level == k, :2], segments[level == k, 2:], k)
        cells, _ = self.space.cells(np.array(self._bodies).reshape(-1, 2))
        for i in np.unique(cells, axis=0, return_index=True)[1]:
            self.space.mark_disc(self._bodies[i], self.body_radius_m)
        if self._touched:
            touched = np.array(self._touched)
            self.space.mark_occupied(touched[:, :2], lowest=touched[:, 2] > 0)
        self._segments, self._bodies, self._touched = [], [], []

    def observe_surface(self, known_W: FloatArray, unknown_W: FloatArray) -> None:
        """The map's meshes: the known part's vertices (k, 3) m are occupied, the unknown
        part's (k, 3) m what the ``uncertainty`` planner goes to touch."""
        known = np.reshape(known_W, (-1, 3))
        if len(known):
            self.space.mark_occupied(known[:, :2])
        self._unknown_surface = np.reshape(unknown_W, (-1, 3))

    def plan(self, X_WR: Transform) -> Plan | None:
        """The next route and look from X_WR (where the robot stands), or None when the
        exploration is over (`done_because` says why)."""
        self.done_because = ""
        self._mark()
        if self.travelled_m >= self.settings.budget_m:
            self.done_because = f"budget spent ({self.travelled_m:.3f} m)"
            return None
        if self._look is not None:  # the last plan's look is done: what it did not reveal
            self.space.hide_unknown(self._look, self.reach_m)  # no look reveals
            self._looks.append(self._look)
            self._look = None
        here, inside = self.space.cells(X_WR.translation[:2])
        if not inside[0]:
            self.done_because = "the robot is outside its workspace"
            return None
        standable = self.space.standable(self.body_radius_m, here[0], self.skirt_m)
        costs = np.where(standable, 1.0, np.inf)
        mcp = MCP_Geometric(costs)
        route_cells, _ = mcp.find_costs([tuple(here[0])])
        route_m = np.asarray(route_cells) * self.settings.cell_m
        left = self.settings.budget_m - self.travelled_m
        reachable = np.isfinite(route_m) & (route_m <= left)
        goal = self._goal(reachable, route_m, here[0])
        if goal is None:
            self.done_because = (
                f"budget spent ({self.travelled_m:.3f} m; the {left:.3f} m left is less than "
                "a cell)" if left < self.settings.cell_m
                else f"{self.done_because} within the {left:.3f} m of budget left")
            return None
        cells = np.array(mcp.traceback(tuple(goal)), dtype=np.int64)
        return self._route_and_look(X_WR, cells)

    def _goal(self, reachable: npt.NDArray[np.bool_], route_m: FloatArray,
              here: npt.NDArray[np.int64]) -> npt.NDArray[np.int64] | None:
        if not self._looks:  # a look where it stands first: it knows nothing around it
            return here
        if self.settings.planner == "lawnmower":
            return self._lane_goal(reachable, here)
        gain = self._gain()
        score = np.where(reachable, gain / (1.0 + np.where(reachable, route_m, 0.0)
                                            / self.settings.detour_m), 0.0)
        looked, _ = self.space.cells(np.array(self._looks))  # no second look from a place
        score[looked[:, 0], looked[:, 1]] = 0.0
        best = np.unravel_index(int(np.argmax(score)), score.shape)
        if not score[best] > 0.5:
            self.done_because = "nothing unknown within reach of where the body can stand"
            return None
        return np.array(best, dtype=np.int64)

    def _gain(self) -> FloatArray:
        """Per cell: the unknown cells within the rods' reach, and the unknown-surface
        vertices there at the whiskers' heights times ``surface_weight``."""
        radius = int(math.ceil(self.reach_m / self.settings.cell_m))
        di, dj = np.mgrid[-radius:radius + 1, -radius:radius + 1]
        disc = (np.hypot(di, dj) * self.settings.cell_m <= self.reach_m).astype(np.float64)
        unknown = self.space.state == UNKNOWN
        counts = unknown.astype(np.float64)
        if self.settings.object_weight > 0:  # where a touched object goes on
            ring = int(math.ceil(self.settings.object_ring_m / self.settings.cell_m))
            near = ndimage.binary_dilation(self.space.state == OCCUPIED, iterations=ring)
            counts += self.settings.object_weight * (near & unknown)
        surface = self._unknown_surface
        if len(surface) and self.settings.surface_weight > 0:
            level = np.min(np.abs(surface[:, 2, None] - self.heights_m[None]), axis=1)
            wanted = level <= self.settings.height_tol_m
            if self._looks:  # a vertex draws one look within the rods' reach of it
                looked = np.min(np.linalg.norm(surface[:, None, :2] - np.array(self._looks)[None],
                                               axis=2), axis=1)
                wanted &= looked > self.reach_m
            ij, inside = self.space.cells(surface[wanted, :2])
            ij = ij[inside]
            np.add.at(counts, (ij[:, 0], ij[:, 1]), self.settings.surface_weight)
        return np.asarray(fftconvolve(counts, disc, mode="same")).clip(min=0.0)

    def _lane_points(self) -> FloatArray:
        """The lawnmower's points (k, 2) m: lanes along x, ``lane_spacing_m`` apart in y,
        alternating in direction, each one reach apart."""
        lo, hi = self.space.lo_m, self.space.hi_m
        spacing = self.settings.lane_spacing_m or self.reach_m
        margin = self.body_radius_m + 2 * self.settings.cell_m
        ys = np.arange(lo[1] + margin, hi[1] - margin + 1e-12, spacing)
        xs = np.arange(lo[0] + margin, hi[0] - margin + 1e-12, self.reach_m)
        lanes = [np.column_stack([xs if k % 2 == 0 else xs[::-1], np.full(len(xs), y)])
                 for k, y in enumerate(ys)]
        return np.vstack(lanes) if lanes else np.zeros((0, 2))

    def _lane_goal(self, reachable: npt.NDArray[np.bool_],
                   here: npt.NDArray[np.int64]) -> npt.NDArray[np.int64] | None:
        """The reachable cell nearest to the next lane point; the point is passed once the
        body stands within two cells of it, or at the reachable cell nearest to it."""
        candidates = np.argwhere(reachable)
        centres = self.space.centre(candidates)
        while self._lane < len(self._lanes) and len(candidates):
            distance = np.linalg.norm(centres - self._lanes[self._lane], axis=1)
            k = int(np.argmin(distance))
            if distance[k] <= 2 * self.settings.cell_m or np.array_equal(candidates[k], here):
                self._lane += 1
                continue
            return candidates[k]
        self.done_because = "every lane point visited or out of reach"
        return None

    def _route_and_look(self, X_WR: Transform, cells: npt.NDArray[np.int64]) -> Plan:
        """Waypoints from X_WR along ``cells`` (from here), heading along each leg, then a full
        turn in place in quarter turns."""
        xy = self.space.centre(cells)
        xy[0] = X_WR.translation[:2]
        keep = [0]
        for k in range(1, len(xy) - 1):  # corners only
            if not np.allclose(np.sign(xy[k + 1] - xy[k]), np.sign(xy[k] - xy[k - 1])):
                keep.append(k)
        keep.append(len(xy) - 1)
        xy = xy[keep] if len(xy) > 1 else xy
        yaw = _yaw(X_WR.rotation)
        headings = []
        for k in range(1, len(xy)):
            step = xy[k] - xy[k - 1]
            if np.linalg.norm(step) > 0:
                yaw = math.atan2(step[1], step[0])
            headings.append(yaw)
        points = [xy[k] for k in range(1, len(xy))]
        for quarter in range(1, 5):
            points.append(xy[-1])
            headings.append(yaw + quarter * math.pi / 2)
        rotations = Rotation.from_euler("z", np.array(headings)[:, None]) * self.tilt
        position = np.column_stack([np.array(points), np.full(len(points), self.height_m)])
        self._look = np.array(xy[-1])
        # from where it stands (a robot takes a first waypoint only near its pose)
        return Plan(np.vstack([X_WR.translation, position]),
                    np.vstack([X_WR.rotation.as_quat(), rotations.as_quat()]),
                    f"route of {len(xy) - 1} leg(s), then a look")
