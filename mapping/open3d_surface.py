"""The surface of one object by Open3D's screened Poisson or ball-pivoting reconstruction on its
contact points and outward normals (``MapSettings.method``), without an uncertainty.

* ``poisson``: `TriangleMesh.create_from_point_cloud_poisson` (Kazhdan and Hoppe 2013) at an
  octree depth of ceil(log2(``cells``)) (the GP mesh's grid: 64 cells, depth 6), on one
  thread (more threads sum in another order from run to run), cropped to the object's box (its
  points' box grown by ``margin``, as the GP is meshed) and trimmed of the vertices whose
  density is `POISSON_TRIM_DEPTH` below the densest: a closed surface through the data and
  invented beyond it.
* ``ball_pivoting``: `TriangleMesh.create_from_point_cloud_ball_pivoting` (Bernardini et al.
  1999) on the points voxel-downsampled to the mesh cell (the box's longest side / ``cells``),
  balls of `BALL_RADII` x that cell: triangles only where the points are that dense, holes
  elsewhere, the points' noise kept.

Every triangle is known and every vertex's std is NaN (`vibrissa.mapping.surface.ObjectSurface`
has no ``gp``): no known/unknown split, no std and no next sweeps. Open3D is imported on first
use (2 s, ~180 MB).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from vibrissa.mapping.gp_surface import SurfaceMeshStd
from vibrissa.mapping.settings import MapSettings

FloatArray = npt.NDArray[np.float64]

POISSON_TRIM_DEPTH = 2.0
"""A Poisson vertex whose density is this far below the largest is removed: the surface
Poisson closes far from any point. Open3D's density of a vertex is the octree depth its points
support (PoissonRecon's estimated depth, a log2 scale): 2 is a support cell 4 times wider than
the best supported one's. On an ellipsoid sampled evenly (tests/mapping/test_open3d_surface.py)
every vertex is within 0.5 of the largest and stays; on the demo's five lines past a sphere or
a paraboloid (depth 6) 41-73 % of the vertices stay, within 8.7 and 40 mm of the truth against
158 and 428 mm untrimmed. A quantile would cut the same share off a closed, evenly sampled
object (a 5 % quantile: 8 % of the ellipsoid's area)."""

BALL_RADII = (1.0, 2.0, 4.0)
"""Ball-pivoting radii, in mesh cells (the downsampled points' spacing): a gap wider than
twice the largest stays a hole."""


def _cloud(points: FloatArray, normals: FloatArray) -> Any:
    """An Open3D point cloud of ``points`` (N, 3) m with unit ``normals`` (N, 3)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(
        normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300))
    return cloud


def _box(points: FloatArray, settings: MapSettings) -> tuple[FloatArray, FloatArray, float]:
    """The object's box (lo, hi) (3,) m, as the GP is meshed, and its mesh cell, m."""
    pad = settings.margin * float(np.linalg.norm(np.ptp(points, axis=0)))
    lo, hi = points.min(axis=0) - pad, points.max(axis=0) + pad
    return lo, hi, float(np.max(hi - lo)) / settings.cells


def poisson_depth(cells: int) -> int:
    """The octree depth of a Poisson mesh as fine as a grid of ``cells``: ceil(log2(cells))."""
    return math.ceil(math.log2(cells))


def open3d_mesh(points: FloatArray, normals: FloatArray,
                settings: MapSettings) -> tuple[SurfaceMeshStd, str]:
    """Open3D's mesh of an object's ``points`` (N, 3) m with outward unit ``normals`` (N, 3) by
    ``settings.method`` (``poisson`` or ``ball_pivoting``; see module), every triangle known
    and every std NaN, and the method's description."""
    import open3d as o3d

    lo, hi, cell = _box(points, settings)
    if settings.method == "poisson":
        depth = poisson_depth(settings.cells)
        mesh, support = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            _cloud(points, normals), depth=depth, n_threads=1)
        density = np.asarray(support)
        mesh.remove_vertices_by_mask(density < density.max() - POISSON_TRIM_DEPTH)
        mesh = mesh.crop(o3d.geometry.AxisAlignedBoundingBox(lo, hi))
        method = (f"open3d poisson (depth {depth}, trimmed where the density is "
                  f"{POISSON_TRIM_DEPTH:g} below its largest; no uncertainty)")
    elif settings.method == "ball_pivoting":
        cloud = _cloud(points, normals).voxel_down_sample(cell)
        radii = [r * cell for r in BALL_RADII]
        mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
            cloud, o3d.utility.DoubleVector(radii))
        method = (f"open3d ball pivoting (radii {', '.join(f'{r:.3g}' for r in radii)} m on "
                  f"{len(cloud.points)} points at {cell:.3g} m; no uncertainty)")
    else:
        raise ValueError(f"method must be poisson or ball_pivoting, got {settings.method!r}")
    mesh.remove_degenerate_triangles()
    mesh.remove_unreferenced_vertices()
    vertices = np.asarray(mesh.vertices, dtype=np.float64).copy()
    triangles = np.asarray(mesh.triangles, dtype=np.int64).copy()
    return SurfaceMeshStd(vertices, triangles, np.full(len(vertices), np.nan),
                          np.ones(len(triangles), dtype=bool), math.inf, cell), method
