"""The true objects of a map, when known: distances to them and the names of the objects found."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from vibrissa.surfaces import Surface

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class TrueObject:
    """A known object: ``surface`` in units of ``unit_m`` metres, in the cloud's frame."""

    name: str
    surface: Surface
    unit_m: float = 1.0

    def distance(self, points_m: FloatArray) -> FloatArray:
        """|signed distance| (N,) of points (N, 3), m, to the surface, m."""
        points_m = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
        if len(points_m) == 0:
            return np.zeros(0)
        return np.abs(self.surface.signed_distance(points_m / self.unit_m)) * self.unit_m


def name_objects(points: FloatArray, labels: IntArray, truth: Sequence[TrueObject]
                 ) -> list[tuple[str, TrueObject | None, float | None]]:
    """(name, true object, median |signed distance| to it in m) of each object of ``labels``.

    With ``truth`` an object is named after the true object nearest to its points (median
    |signed distance|); a second object on the same true object is ``<name>-2``, and so on.
    Without, ``object0``, ``object1``, ... in the order of the labels.
    """
    named: list[tuple[str, TrueObject | None, float | None]] = []
    taken: set[str] = set()
    for k in range(int(labels.max()) + 1 if len(labels) else 0):
        if not truth:
            named.append((f"object{k}", None, None))
            continue
        inside = points[labels == k]
        medians = [float(np.median(true.distance(inside))) for true in truth]
        best = int(np.argmin(medians))
        name, n = truth[best].name, 1
        while name in taken:
            n += 1
            name = f"{truth[best].name}-{n}"
        taken.add(name)
        named.append((name, truth[best], medians[best]))
    return named
