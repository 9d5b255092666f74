"""Where the robot body may go: a grid over the workspace's floor (x, y in W) of cells unknown,
free (the rods of every height swept them without touching anything, or the body stood there),
occupied (a contact, or a surface the map knows) or hidden (unknown after a look from near).

A rod proves a cell free only at its own height: a ball's slice at a low rod's height is
narrower than at its equator, and a rod above a low object passes over it. So the grid keeps,
per rod height (``levels``), which cells that height's rods swept, and a cell is free only
when every height swept it.

The body is a vertical cylinder around ``base_link``: it may stand where every cell within its
radius (and a margin of one cell's diagonal) is free. Unknown counts as blocked, so the body
only ever goes where the whiskers have been: safe by construction against objects it has not
found yet, provided the objects reach the whiskers' heights and bulge between two heights by
less than that margin (a rod sweeping above an object low on the floor sees nothing there).
Below the lowest rods no rod sees: a mound's wall leans out there, so the body also keeps a
skirt margin from where the lowest rods touched something.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy import ndimage

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

UNKNOWN, FREE, OCCUPIED, HIDDEN = 0, 1, 2, 3
"""The states of a cell: ``HIDDEN`` is unknown after a look from within the rods' reach (inside
an object or behind one): no look reveals it."""


@dataclass
class FreeSpace:
    """The floor of the workspace box [lo_m, hi_m] (x, y in W, m) in square cells of
    ``cell_m``, for rods at ``levels`` heights: ``state`` (nx, ny) of `UNKNOWN`, `FREE`,
    `OCCUPIED`, `HIDDEN`; ``swept`` (levels, nx, ny) the cells each height's rods swept;
    ``lowest_touched`` (nx, ny) the cells where the lowest rods (level 0) touched something."""

    lo_m: FloatArray
    hi_m: FloatArray
    cell_m: float
    levels: int = 1
    state: npt.NDArray[np.int8] = field(init=False)
    swept: npt.NDArray[np.bool_] = field(init=False)
    lowest_touched: npt.NDArray[np.bool_] = field(init=False)

    def __post_init__(self) -> None:
        self.lo_m = np.asarray(self.lo_m, dtype=np.float64)[:2]
        self.hi_m = np.asarray(self.hi_m, dtype=np.float64)[:2]
        if not (self.cell_m > 0 and np.all(self.hi_m > self.lo_m)):
            raise ValueError(f"a free-space grid needs lo < hi and a cell > 0, got "
                             f"{self.lo_m}, {self.hi_m}, {self.cell_m}")
        if self.levels < 1:
            raise ValueError(f"a free-space grid needs at least one rod height, got "
                             f"{self.levels}")
        shape = tuple(np.ceil((self.hi_m - self.lo_m) / self.cell_m).astype(int))
        self.state = np.zeros(shape, dtype=np.int8)
        self.swept = np.zeros((self.levels, *shape), dtype=np.bool_)
        self.lowest_touched = np.zeros(shape, dtype=np.bool_)

    def cells(self, xy_m: FloatArray) -> tuple[IntArray, npt.NDArray[np.bool_]]:
        """The cell (i, j) of each point (k, 2) m, and whether it lies on the grid."""
        ij = np.floor((np.reshape(xy_m, (-1, 2)) - self.lo_m) / self.cell_m).astype(np.int64)
        inside = np.all((ij >= 0) & (ij < np.array(self.state.shape)), axis=1)
        return ij, inside

    def centre(self, ij: IntArray) -> FloatArray:
        """The centre (k, 2) m of cells (k, 2)."""
        return self.lo_m + (np.reshape(ij, (-1, 2)) + 0.5) * self.cell_m

    def mark_segments(self, start_m: FloatArray, end_m: FloatArray, level: int = 0) -> None:
        """Cells crossed by the segments from ``start_m`` to ``end_m`` (k, 2) m are swept at
        rod height ``level``: a rod swept there without touching anything. A cell every height
        swept becomes free (an occupied cell stays occupied)."""
        start, end = np.reshape(start_m, (-1, 2)), np.reshape(end_m, (-1, 2))
        if not len(start):
            return
        steps = int(np.ceil(np.max(np.linalg.norm(end - start, axis=1)) / (0.5 * self.cell_m)))
        f = np.linspace(0.0, 1.0, max(steps, 1) + 1)
        points = start[:, None, :] + f[None, :, None] * (end - start)[:, None, :]
        ij, inside = self.cells(points.reshape(-1, 2))
        ij = ij[inside]
        self.swept[level, ij[:, 0], ij[:, 1]] = True
        self._free(ij[self.swept[:, ij[:, 0], ij[:, 1]].all(axis=0)])

    def mark_disc(self, centre_m: FloatArray, radius_m: float) -> None:
        """Cells whose centre lies within ``radius_m`` of ``centre_m`` (2,) become free at
        every height: the body stands there."""
        reach = int(np.ceil(radius_m / self.cell_m)) + 1
        ij, _ = self.cells(np.asarray(centre_m)[:2])
        di, dj = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1))
        around = ij[0] + np.column_stack([di.ravel(), dj.ravel()])
        near = np.linalg.norm(self.centre(around) - np.asarray(centre_m)[:2], axis=1) <= radius_m
        ij, inside = self.cells(self.centre(around[near]))
        ij = ij[inside]
        self.swept[:, ij[:, 0], ij[:, 1]] = True
        self._free(ij)

    def mark_occupied(self, xy_m: FloatArray,
                      lowest: npt.NDArray[np.bool_] | None = None) -> None:
        """Cells of the points (k, 2) m become occupied: a contact, a known surface; those of
        the points ``lowest`` (k,) are where the lowest rods touched something."""
        ij, inside = self.cells(xy_m)
        self.state[ij[inside, 0], ij[inside, 1]] = OCCUPIED
        if lowest is not None:
            ij = ij[inside & lowest]
            self.lowest_touched[ij[:, 0], ij[:, 1]] = True

    def _free(self, ij: IntArray) -> None:
        """Cells (k, 2) become free, but an occupied one stays occupied."""
        ij = ij[self.state[ij[:, 0], ij[:, 1]] != OCCUPIED]
        self.state[ij[:, 0], ij[:, 1]] = FREE

    def clearance_m(self) -> FloatArray:
        """Each cell's distance (nx, ny) m from its centre to the nearest cell that is not free
        (unknown, occupied, or beyond the grid's edge)."""
        return _distance_m(self.state == FREE, self.cell_m)

    def standable(self, radius_m: float, here: IntArray | None = None,
                  skirt_m: float = 0.0) -> npt.NDArray[np.bool_]:
        """Cells (nx, ny) where the body of ``radius_m`` may stand: free within its radius and
        a margin of one cell's diagonal (the cells are not points), and ``skirt_m`` further from
        where the lowest rods touched something (the object's wall may lean out below them,
        where no rod sees it). With ``here``, the cell (2,) where the body stands, also that
        cell and its way out of a spot the margins no longer allow (a surface marked near the
        body after it arrived): the free cells within ``radius_m`` of it that are at least as
        clear as it is."""
        clearance = self.clearance_m()
        if skirt_m > 0:
            skirt = _distance_m(~self.lowest_touched, self.cell_m) - skirt_m
            clearance = np.minimum(clearance, skirt)
        standable = clearance > radius_m + math.sqrt(2.0) * self.cell_m
        if here is not None:
            i, j = int(here[0]), int(here[1])
            di, dj = np.indices(standable.shape)
            near = np.hypot(di - i, dj - j) * self.cell_m <= radius_m
            standable |= near & (self.state == FREE) & (clearance >= clearance[i, j])
            standable[i, j] = True
        return standable

    def hide_unknown(self, centre_m: FloatArray, radius_m: float) -> None:
        """Unknown cells whose centre lies within ``radius_m`` of ``centre_m`` (2,) become
        hidden: a look from there swept the rods around and did not reveal them."""
        ij = np.argwhere(self.state == UNKNOWN)
        near = np.linalg.norm(self.centre(ij) - np.asarray(centre_m)[:2], axis=1) <= radius_m
        self.state[ij[near, 0], ij[near, 1]] = HIDDEN

    def frontier(self) -> npt.NDArray[np.bool_]:
        """Free cells (nx, ny) next to an unknown one: where a look reveals something."""
        unknown = ndimage.binary_dilation(self.state == UNKNOWN, structure=np.ones((3, 3)))
        return (self.state == FREE) & unknown


def _distance_m(clear: npt.NDArray[np.bool_], cell_m: float) -> FloatArray:
    """Each cell's distance (nx, ny) m from its centre to the nearest cell not ``clear`` (or
    beyond the grid's edge)."""
    padded = np.pad(clear, 1, constant_values=False)
    return np.asarray(ndimage.distance_transform_edt(padded)[1:-1, 1:-1]) * cell_m
