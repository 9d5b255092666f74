"""The surface of one object: a Gaussian-process implicit surface on its contacts and their
normals (`vibrissa.mapping.gp_surface`), meshed over the object's box, or Open3D's Poisson or
ball-pivoting mesh of them without an uncertainty (`vibrissa.mapping.open3d_surface`), as
``MapSettings.method`` chooses."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from vibrissa.mapping import gp_surface
from vibrissa.mapping.gp_surface import GPParams, GPSurface, SurfaceMeshStd
from vibrissa.mapping.open3d_surface import open3d_mesh
from vibrissa.mapping.settings import MapSettings

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

MIN_EXTENT_M = 1e-9
"""The smallest spread of an object's points a surface is fitted to, m: below a nanometre the
contacts of a whisker are one place (and the fit's scales underflow)."""


def too_little_for_a_surface(points: FloatArray) -> str | None:
    """Why ``points`` (N, 3) cannot carry a surface (fewer than 4, all at one point or within
    `MIN_EXTENT_M` of it, all on one straight line), or ``None`` when they can."""
    if len(points) < 4:
        return f"{len(points)} point(s), a surface needs 4 or more"
    singular = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if not singular[0] > max(1e-9 * float(np.abs(points).max()), MIN_EXTENT_M):
        return f"all {len(points)} points at one place"
    if singular[1] <= 1e-9 * singular[0]:
        return f"all {len(points)} points on one straight line"
    return None


@dataclass(frozen=True)
class ObjectSurface:
    """The surface estimate of one object (:func:`estimate_surface`).

    ``method`` names the method and its fitted parameters, or says why there is no surface
    (``none: ...``; then ``gp`` and ``mesh`` are None). Without ``gp`` (Open3D's methods) the
    mesh has no uncertainty: every triangle is known and every std NaN.
    """

    method: str
    gp: GPSurface | None = None
    mesh: SurfaceMeshStd | None = None

    def part(self, known: bool = True) -> tuple[FloatArray, IntArray, FloatArray]:
        """(vertices (V, 3) m, triangles (T, 3), position std (V,) m) of the known (or
        unknown) triangles; empty without a mesh."""
        if self.mesh is None:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0)
        return self.mesh.part(known)

    @property
    def uncertainty(self) -> bool:
        """False for a mesh without a position std (Open3D's): no known part, std or next
        sweeps, which need the GP's."""
        return self.mesh is None or self.gp is not None


def estimate_surface(points: FloatArray, normals: FloatArray,
                     settings: MapSettings | None = None,
                     point_var_m2: FloatArray | None = None, cells: int = 0,
                     single: bool = False) -> ObjectSurface:
    """The surface of one object's contacts by ``settings.method``: the Gaussian-process
    implicit surface (`vibrissa.mapping.gp_surface`) meshed over its box, or Open3D's Poisson or
    ball-pivoting mesh (`vibrissa.mapping.open3d_surface`), or why there is none
    (``too_little_for_a_surface``).

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
        Contact points (m) in line order and outward unit normals (:func:`contact_normals`).
    settings
        The method, meshing and noise settings (``method``, ``cells``, ``margin``,
        ``max_std_m``, ``point_std_m``).
    point_var_m2 : ndarray, shape (N,), optional
        Each point's position variance along its normal, m^2 (from its covariance): the GP
        weights the points by it (``gp_surface.fit``); Open3D's methods do not use it.
    cells
        The GP surface's marching-cubes grid along the box's longest side (0:
        ``settings.cells``; `meshed_surface`).
    single
        Its vertex stds solved in single precision (`gp_surface.mesh`).
    """
    settings = settings or MapSettings()
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    too_little = too_little_for_a_surface(points)
    if too_little is not None:
        return ObjectSurface(f"none: {too_little}")
    if settings.method != "gp":
        mesh, method = open3d_mesh(points, np.asarray(normals, dtype=np.float64).reshape(-1, 3),
                                   settings)
        return ObjectSurface(method, None, mesh)
    gp = gp_surface.fit(points, normals, GPParams(point_std_m=settings.point_std_m), point_var_m2)
    return meshed_surface(gp, points, settings, cells, single)


def meshed_surface(gp: GPSurface, points: FloatArray, settings: MapSettings,
                   cells: int = 0, single: bool = False) -> ObjectSurface:
    """The surface ``gp`` of an object's contact ``points`` (N, 3), m, meshed over its box:
    the points' box grown by ``settings.margin``, on a grid of ``cells`` along its longest side
    (0: ``settings.cells``), its vertex stds solved in single precision with ``single``."""
    pad = settings.margin * float(np.linalg.norm(np.ptp(points, axis=0)))
    mesh = gp_surface.mesh(gp, points.min(axis=0) - pad, points.max(axis=0) + pad,
                           cells or settings.cells, settings.max_std_m, single)
    method = (f"gp implicit surface (quadric trend + SE: ell {gp.length_scale * gp.scale:.3g} m, "
              f"sigma {gp.sigma * gp.scale:.3g} m; normal std {gp.normal_std:.3g} rad; "
              f"{len(gp.active)} of {len(points)} points; known where std <= "
              f"{mesh.max_std:.3g} m)")
    return ObjectSurface(method, gp, mesh)
