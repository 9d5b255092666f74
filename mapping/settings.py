"""The settings of a map (`MapSettings`): how objects are separated, how each surface is fitted
and meshed, and how many next sweeps are proposed."""

from __future__ import annotations

import math
from dataclasses import dataclass

from vibrissa.mapping.gp_surface import GPParams
from vibrissa.mapping.objects import JOIN_NORMAL_TOL_RAD, MIN_POINTS

MAX_CELLS = 512
"""Finest marching-cubes grid: 512 cells along an object's box."""

METHODS = ("gp", "poisson", "ball_pivoting")
"""The surface methods (``MapSettings.method``): the Gaussian-process implicit surface with its
uncertainty (`vibrissa.mapping.gp_surface`), or Open3D's screened Poisson or ball-pivoting
reconstruction on the same points and normals, without one (`vibrissa.mapping.open3d_surface`)."""


def _require(ok: bool, name: str, value: object, rule: str) -> None:
    if not ok:
        raise ValueError(f"{name!r} must be {rule}, got {value!r}")


@dataclass(frozen=True)
class MapSettings:
    """How a frame's contacts become a map (`vibrissa.mapping.fit_frame`), lengths in m.

    Attributes
    ----------
    one_object
        The frame is one object: no clustering (a known single object).
    cluster_eps_m
        DBSCAN radius separating the objects, m; 0 = from the data (15 line spacings, at most
        half the typical extent of a contact line; `vibrissa.mapping.objects`).
    cluster_min_points
        DBSCAN ``min_points``; smaller groups are noise (counted and reported, not fitted).
    join_convex, join_normal_tol_rad
        Join clusters that are patches of one convex object, within this error of the contact
        normals, rad (`vibrissa.mapping.objects.join_convex`).
    cells
        Marching-cubes grid cells along the longest side of an object's box (8 to `MAX_CELLS`).
    margin
        The box: the object's points' box grown by this fraction of its diagonal on every side.
    max_std_m
        Largest position std of a known triangle, m; 0: ``gp_surface.KNOWN_FRACTION`` of the
        prior std.
    point_std_m
        Std of a contact point's position without a covariance, m.
    proposals, proposal_axis
        Next sweeps proposed per object (0: none) and the normal (3,) of their section planes
        (`vibrissa.mapping.next_sweep`).
    method
        The surface method, one of `METHODS`: ``gp`` (default; the uncertainty that the known
        part, the std and the next sweeps need), ``poisson`` or ``ball_pivoting`` (Open3D, no
        uncertainty: every triangle known, no std, no next sweeps; docs/MAPPING.md says when
        each is right).

    Raises ``ValueError`` naming the setting when one is out of its range.
    """

    one_object: bool = False
    cluster_eps_m: float = 0.0
    cluster_min_points: int = MIN_POINTS
    join_convex: bool = True
    join_normal_tol_rad: float = JOIN_NORMAL_TOL_RAD
    cells: int = 64
    margin: float = 0.2
    max_std_m: float = 0.0
    point_std_m: float = GPParams.point_std_m
    proposals: int = 3
    proposal_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    method: str = "gp"

    def __post_init__(self) -> None:
        _require(self.method in METHODS, "method", self.method, f"one of {', '.join(METHODS)}")
        _require(math.isfinite(self.cluster_eps_m) and self.cluster_eps_m >= 0, "cluster_eps_m",
                 self.cluster_eps_m, "a finite number >= 0")
        _require(self.cluster_min_points >= 1, "cluster_min_points", self.cluster_min_points,
                 "a count >= 1")
        _require(0 <= self.join_normal_tol_rad < math.pi / 2, "join_normal_tol_rad",
                 self.join_normal_tol_rad, "an angle in [0, pi/2), rad")
        _require(8 <= self.cells <= MAX_CELLS, "cells", self.cells,
                 f"a grid size in [8, {MAX_CELLS}]")
        for name in ("margin", "max_std_m"):
            value = getattr(self, name)
            _require(math.isfinite(value) and value >= 0, name, value, "a finite number >= 0")
        _require(math.isfinite(self.point_std_m) and self.point_std_m > 0, "point_std_m",
                 self.point_std_m, "a finite number > 0")
        _require(self.proposals >= 0, "proposals", self.proposals, "a count >= 0")
        _require(len(self.proposal_axis) == 3 and all(map(math.isfinite, self.proposal_axis))
                 and any(self.proposal_axis), "proposal_axis", self.proposal_axis,
                 "a nonzero vector [x, y, z]")
