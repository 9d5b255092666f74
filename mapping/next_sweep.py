"""Where to sweep next: the sections of an object's estimated surface whose touch would cut its
uncertainty most (`vibrissa.mapping.gp_surface`).

A trail of the paper (the clamp moving along x at a lateral offset y0, the rod along +z) first
touches the object with its tip on the section y = y0 of the surface, and its contact line
runs along and outward of that section. So a trail is proposed as a *section*: a plane normal to
``axis`` at an offset, and the line the plane cuts from the estimated surface (for a robot, the
line to touch, in the map frame). Candidates are offsets over the range the contacts span along
``axis`` (where the rod is known to reach the object).

Greedy uncertainty sampling (active learning with a GP): the proposal is the candidate whose
section has the largest predicted position std; then the surface is conditioned on points along
that section (on its mean, with the mean's normals: the std of a GP depends only on where it
observes, not on what), and the next proposal is chosen on what remains. The std is scored on
the reachable surface: the mesh vertices inside the contacts' box (beyond it the rod is not
known to reach, and chasing the uncertainty there proposes trails that touch nothing); each
proposal reports the largest std there before and after.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from vibrissa.mapping.gp_surface import GPSurface, StdAt

FloatArray = npt.NDArray[np.float64]

CANDIDATES = 41
"""Offsets tried per proposal, evenly over the contacts' range along the axis."""

SECTION_POINTS = 40
"""Points along a section the surface is conditioned on."""

SCORED_POINTS = 2000
"""Points of the reachable surface the std is evaluated at, at most (every k-th vertex)."""


@dataclass(frozen=True)
class Proposal:
    """One proposed section, lengths in m in the cloud's frame.

    Attributes
    ----------
    offset_m
        The plane's offset along ``axis`` (for the paper's trails: y0).
    axis
        Unit normal (3,) of the plane.
    line : ndarray, shape (K, 3)
        Points of the estimated surface on the section, in order along it.
    std_on_line_m
        The largest predicted position std on the section before touching it.
    std_max_before_m, std_max_after_m
        The largest predicted position std over the reachable surface before and after this
        proposal (and the ones before it) would be touched.
    """

    offset_m: float
    axis: FloatArray
    line: FloatArray
    std_on_line_m: float
    std_max_before_m: float
    std_max_after_m: float


def propose_sections(surface: GPSurface, vertices: FloatArray, contacts: FloatArray,
                     axis: FloatArray, count: int = 3) -> list[Proposal]:
    """The next ``count`` sections to touch (see module).

    Parameters
    ----------
    surface
        The object's fit.
    vertices : ndarray, shape (V, 3)
        Points on the estimated surface (its mesh's vertices, known and unknown), m.
    contacts : ndarray, shape (N, 3)
        The contact points, m: their range along ``axis`` is where the rod reaches.
    axis : ndarray, shape (3,)
        Normal of the section planes.
    count
        Number of proposals (>= 1).
    """
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    axis = np.asarray(axis, dtype=np.float64).reshape(3)
    if not np.linalg.norm(axis) > 0:
        raise ValueError(f"axis must be a nonzero vector, got {axis}")
    axis = axis / np.linalg.norm(axis)
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    contacts = np.asarray(contacts, dtype=np.float64).reshape(-1, 3)
    along = contacts @ axis
    lo, hi = float(along.min()), float(along.max())
    inside = np.all((vertices >= contacts.min(axis=0)) & (vertices <= contacts.max(axis=0)),
                    axis=1)
    reach = vertices[inside & (vertices @ axis >= lo) & (vertices @ axis <= hi)]
    reach = reach[::max(1, -(-len(reach) // SCORED_POINTS))]
    if not len(reach) or hi <= lo:
        return []
    offsets = np.linspace(lo, hi, CANDIDATES)
    band = (hi - lo) / (CANDIDATES - 1)
    position = reach @ axis
    proposals: list[Proposal] = []
    # sd_f over the gradient of the fit's own mean: the mean conditioned on its own values
    # stays the same surface, but its gradient's length may drift, and with it sd_f / |grad|
    _, gradient = surface.evaluate(reach)
    slope = np.maximum(np.linalg.norm(gradient, axis=1), 1e-12)
    at = StdAt.of(surface, reach)  # the std there, kept through the conditionings
    std = at.std() / slope
    for _ in range(count):
        scores = np.full(len(offsets), -np.inf)
        for k, offset in enumerate(offsets):
            on = np.abs(position - offset) <= band / 2
            if on.any():
                scores[k] = float(std[on].max())
        best = int(np.argmax(scores))
        if not np.isfinite(scores[best]):
            break
        on = np.flatnonzero(np.abs(position - offsets[best]) <= band / 2)
        line = reach[on[_order_along(reach[on])]]
        taken = line[np.unique(np.linspace(0, len(line) - 1, SECTION_POINTS).astype(int))]
        _, normals = at.surface.evaluate(taken)
        before = float(std.max())
        at = at.conditioned(taken, normals)
        std = at.std() / slope
        proposals.append(Proposal(float(offsets[best]), axis, line, float(scores[best]),
                                  before, float(std.max())))
    return proposals


def _order_along(points: FloatArray) -> npt.NDArray[np.int64]:
    """Indices ordering points (K, 3) along their principal direction."""
    centred = points - points.mean(axis=0)
    direction = np.linalg.svd(centred, full_matrices=False)[2][0] if len(points) > 1 else (
        np.array([1.0, 0.0, 0.0]))
    return np.argsort(centred @ direction, kind="stable").astype(np.int64)
