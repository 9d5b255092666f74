"""Coverage of the true objects by a map, defined once: the true surfaces are sampled uniformly
by area (`coverage_samples`), the samples kept within a reach of the workspace box (what the
whiskers can touch from a base inside it), and a sample is covered when a vertex of the known
mesh lies within a tolerance of it (`coverage`).

The samples are exact, not a mesh's: a point uniform on the parameter domain of a surface is
kept with probability proportional to the surface's area element there (rejection sampling),
which leaves points uniform by area on the surface itself. An ellipsoid x = D u (D =
diag(a, b, c)) over the unit sphere u has the area element dA = abc |D^-1 u| dA_u; a paraboloid
z = a x^2 + b y^2 + h over its (x, y) plane has dA = sqrt(1 + 4 a^2 x^2 + 4 b^2 y^2) dx dy,
sampled over the body-frame (x, y) rectangle that holds the reach box's shadow (the box grown
by the reach on every side) and lies below the box's top, where every point it can keep lies.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from vibrissa.mapping.report import Exploration
from vibrissa.mapping.truth import TrueObject
from vibrissa.surfaces import Ellipsoid, Paraboloid

FloatArray = npt.NDArray[np.float64]

COVERAGE_SPACING_M = 1e-3
"""Default sample spacing: one sample per (1 mm)^2 of true surface, in expectation."""

COVERAGE_TOL_M = 1e-3
"""Default tolerance: a sample is covered when a known mesh vertex lies within 1 mm of it."""

MAX_CANDIDATES = 5_000_000
"""The most candidate points drawn for one object (about 120 MB of floats at once): an object
(or a reach box) far larger than the spacing is refused, not sampled without end."""


def box_distance(points_m: FloatArray, box_min_m: npt.ArrayLike, box_max_m: npt.ArrayLike
                 ) -> FloatArray:
    """Euclidean distance (N,) of points (N, 3) to the box [box_min_m, box_max_m], 0 inside, m."""
    points_m = np.asarray(points_m, dtype=float).reshape(-1, 3)
    low, high = np.asarray(box_min_m, dtype=float), np.asarray(box_max_m, dtype=float)
    excess = np.maximum(np.maximum(low - points_m, points_m - high), 0.0)
    return np.asarray(np.linalg.norm(excess, axis=1))


def coverage_samples(true_objects: Sequence[TrueObject], workspace_min_m: npt.ArrayLike,
                     workspace_max_m: npt.ArrayLike, reach_m: float,
                     spacing_m: float = COVERAGE_SPACING_M, seed: int = 0) -> FloatArray:
    """Points (N, 3), m, uniform by area on the true objects' surfaces, kept where they lie
    within ``reach_m`` of the workspace box (distance to the box, 0 inside).

    The density is one sample per ``spacing_m``^2 of surface in expectation (the count is
    random, binomial around it), the same on every object, so that a share of the samples is
    a share of the area. Deterministic for a ``seed``: the objects are drawn in order from one
    generator. ValueError naming the argument for a box with min >= max, a reach below 0, a
    spacing <= 0, a shape other than an ellipsoid (sphere) or a paraboloid, or an object that
    needs more than `MAX_CANDIDATES` candidates.
    """
    low = np.asarray(workspace_min_m, dtype=float).reshape(-1)
    high = np.asarray(workspace_max_m, dtype=float).reshape(-1)
    if low.shape != (3,) or high.shape != (3,) or not np.all(low < high):
        raise ValueError(f"workspace_min_m, workspace_max_m: expected (3,) each with min < max, "
                         f"got {low.tolist()} and {high.tolist()}")
    if not (np.isfinite(reach_m) and reach_m >= 0):
        raise ValueError(f"reach_m: expected a number >= 0, got {reach_m!r}")
    if not (np.isfinite(spacing_m) and spacing_m > 0):
        raise ValueError(f"spacing_m: expected a number > 0, got {spacing_m!r}")
    rng = np.random.default_rng(seed)
    density = 1.0 / spacing_m**2  # samples per m^2
    parts = [np.zeros((0, 3))]
    for true in true_objects:
        points = _area_samples(true, density, low - reach_m, high + reach_m, rng)
        parts.append(points[box_distance(points, low, high) <= reach_m])
    return np.concatenate(parts)


def _area_samples(true: TrueObject, density: float, box_min_m: FloatArray,
                  box_max_m: FloatArray, rng: np.random.Generator) -> FloatArray:
    """Points (N, 3) in W, m, uniform by area at ``density`` per m^2 on the surface of ``true``:
    all of an ellipsoid, or a paraboloid's part over the body-frame (x, y) shadow of the box."""
    surface, unit = true.surface, true.unit_m
    if isinstance(surface, Ellipsoid):
        radii = surface.radii * unit
        # candidates on the unit sphere: density * max(dA / dA_u) * 4 pi = density * 4 pi abc / min r
        n = _candidates(density * 4.0 * np.pi * np.prod(radii) / radii.min(), true.name)
        u = rng.standard_normal((n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        keep = rng.random(n) * (1.0 / radii.min()) < np.linalg.norm(u / radii, axis=1)
        p_B = u[keep] * radii
    elif isinstance(surface, Paraboloid):
        a, b, h = surface.a / unit, surface.b / unit, surface.h * unit  # 1/m, 1/m, m
        corners = np.array([[x, y, z] for x in (box_min_m[0], box_max_m[0])
                            for y in (box_min_m[1], box_max_m[1])
                            for z in (box_min_m[2], box_max_m[2])])
        corners_B = surface.pose.apply_inverse(corners / unit) * unit
        # the box's shadow, cut to where the cup is not above the box's top in B
        rim = max(float(corners_B[:, 2].max()) - h, 0.0)
        reach_xy = np.sqrt(rim / np.array([a, b]))
        lo = np.maximum(corners_B[:, :2].min(axis=0), -reach_xy)
        hi = np.maximum(np.minimum(corners_B[:, :2].max(axis=0), reach_xy), lo)
        x_far, y_far = np.maximum(np.abs(lo), np.abs(hi))
        weight_max = np.sqrt(1.0 + 4.0 * a**2 * x_far**2 + 4.0 * b**2 * y_far**2)
        n = _candidates(density * float(np.prod(hi - lo)) * weight_max, true.name)
        xy = lo + (hi - lo) * rng.random((n, 2))
        weight = np.sqrt(1.0 + 4.0 * a**2 * xy[:, 0] ** 2 + 4.0 * b**2 * xy[:, 1] ** 2)
        xy = xy[rng.random(n) * weight_max < weight]
        p_B = np.column_stack([xy, a * xy[:, 0] ** 2 + b * xy[:, 1] ** 2 + h])
    else:
        raise ValueError(f"true_objects: {true.name!r} is a {type(surface).__name__}: expected "
                         "an ellipsoid, a sphere or a paraboloid")
    return np.asarray(surface.pose.apply(p_B / unit) * unit)


def _candidates(expected: float, name: str) -> int:
    """The candidate count for an expected ``expected``, refused beyond `MAX_CANDIDATES`."""
    if not expected <= MAX_CANDIDATES:
        raise ValueError(f"true_objects: {name!r} needs {expected:.3g} candidate samples "
                         f"(at most {MAX_CANDIDATES}): a larger spacing_m or a smaller reach")
    return int(np.ceil(expected))


def coverage(samples_m: FloatArray, mesh_vertices_m: FloatArray, tol_m: float = COVERAGE_TOL_M
             ) -> float:
    """The share of ``samples_m`` (N, 3) with a vertex of ``mesh_vertices_m`` (V, 3) within
    ``tol_m``, all in one frame, m: 0 without vertices, and 0 without samples (nothing to
    cover is not covered)."""
    samples_m = np.asarray(samples_m, dtype=float).reshape(-1, 3)
    vertices = np.asarray(mesh_vertices_m, dtype=float).reshape(-1, 3)
    if not (np.isfinite(tol_m) and tol_m >= 0):
        raise ValueError(f"tol_m: expected a number >= 0, got {tol_m!r}")
    if len(samples_m) == 0 or len(vertices) == 0:
        return 0.0
    distance, _ = cKDTree(vertices).query(samples_m, distance_upper_bound=tol_m)
    return float(np.mean(distance <= tol_m))


PATH_STEP_M = 0.001
"""How far the base moves between the poses `ExplorationLog` keeps for the pictures, m: a path
of 1 m is about 1 000 poses."""

PATH_TURN_RAD = 0.05
"""... or how far it turns in place, rad."""
_TURN_GAP = 1.0 - math.cos(PATH_TURN_RAD / 2)  # 1 - |q1 . q2| at that turn


class ExplorationLog:
    """An exploration as the map sees it: the path length of the robot base, and the coverage
    of each map along it (`coverage` of ``samples_m`` (N, 3), m, within ``tol_m``).

    The path length is the sum of the distances between the base's successive positions
    (`move`), m: the chords of the poses as they arrive.
    """

    def __init__(self, planner: str, samples_m: FloatArray, tol_m: float = COVERAGE_TOL_M
                 ) -> None:
        self.planner = planner
        self.samples_m = np.asarray(samples_m, dtype=float).reshape(-1, 3)
        self.tol_m = tol_m
        self.path_length_m = 0.0
        self.history: list[tuple[float, float]] = []
        self._last: FloatArray | None = None
        self._path: list[tuple[FloatArray, FloatArray]] = []  # for the pictures

    def move(self, p_W_m: npt.ArrayLike, q_W_xyzw: npt.ArrayLike | None = None) -> float:
        """Take the base's next position (3,), m, and its orientation (4,) (x, y, z, w) when
        given (kept for the pictures once the base moved `PATH_STEP_M` or turned
        `PATH_TURN_RAD`); the step from the last position, m (0 for the first)."""
        p = np.asarray(p_W_m, dtype=float).reshape(3)
        step = 0.0 if self._last is None else float(np.linalg.norm(p - self._last))
        self._last = p
        self.path_length_m += step
        q = None if q_W_xyzw is None else np.asarray(q_W_xyzw, dtype=float).reshape(4)
        if q is not None and np.all(np.isfinite(p)) and np.linalg.norm(q) > 0:
            q = q / np.linalg.norm(q)
            if not self._path or (np.linalg.norm(p - self._path[-1][0]) >= PATH_STEP_M
                                  or 1.0 - abs(float(q @ self._path[-1][1])) >= _TURN_GAP):
                self._path.append((p, q))
        return step

    def record(self, mesh_vertices_m: FloatArray) -> float:
        """The coverage of a map's known mesh (its vertices (V, 3), m), kept with the path
        length now."""
        share = coverage(self.samples_m, mesh_vertices_m, self.tol_m)
        self.history.append((self.path_length_m, share))
        return share

    def result(self) -> Exploration:
        """The exploration so far, for the report."""
        path = (np.array([p for p, _ in self._path]).reshape(-1, 3),
                np.array([q for _, q in self._path]).reshape(-1, 4))
        return Exploration(self.planner, self.path_length_m, tuple(self.history), path)
