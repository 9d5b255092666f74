"""``line_spacing``: exactly the value of its definition (one KD-tree of the other lines per line,
kept here as the reference) on clouds of few and many lines, duplicates, lines of one point and
identical points; and the sizes that made the definition quadratic, on grids whose answer is
known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from vibrissa.mapping import line_spacing


def spacing_by_definition(points: np.ndarray, lines: np.ndarray) -> float:
    """Median over the points of the distance to the nearest point of another line: a KD-tree
    of all the other lines' points per line (the mapper's former implementation)."""
    labels = np.unique(lines)
    if len(labels) < 2:
        return float("inf")
    nearest = np.full(len(points), np.inf)
    for label in labels:
        inside = lines == label
        nearest[inside] = cKDTree(points[~inside]).query(points[inside])[0]
    return float(np.median(nearest))


def cloud(kind: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) and line labels (N,) of a random cloud of ``kind``."""
    n = int(rng.integers(1, 400))
    if kind == "two lines":
        return rng.normal(size=(n, 3)), (np.arange(n) >= rng.integers(0, n + 1)).astype(np.int64)
    if kind == "one-point lines":
        return rng.normal(size=(n, 3)), rng.permutation(n).astype(np.int64) * 7 - 50
    if kind == "all identical":
        return np.tile(rng.normal(size=3), (n, 1)), np.sort(rng.integers(0, 8, n))
    if kind == "duplicates":  # few places, shared by points of one line and of several
        points = rng.integers(0, 3, size=(n, 3)) * 0.25
    elif kind == "signed zeros":
        points = np.asarray(rng.choice([-0.0, 0.0, 1.0], size=(n, 3)), dtype=np.float64)
    elif kind == "rows":  # contact lines: dense along x, apart in y
        points = np.column_stack([rng.uniform(size=n), rng.integers(0, 5, n) * 0.2, np.zeros(n)])
    elif kind == "extreme scales":  # distances that overflow to inf, subnormal ones
        points = rng.normal(size=(n, 3)) * 10.0 ** float(rng.choice([-310, -160, 150, 300]))
        points[rng.integers(0, n, n // 3)] = points[0]
    else:
        points = rng.normal(size=(n, 3))
    many = int(rng.choice([2, 3, 8, 40, n + 1]))
    return points, np.sort(rng.integers(0, many, n)) * 3 - 1  # labels need not be 0, 1, ...


KINDS = ["random", "two lines", "one-point lines", "all identical", "duplicates", "signed zeros",
         "rows", "extreme scales"]


@pytest.mark.parametrize("kind", KINDS)
def test_line_spacing_is_exactly_its_definition(kind: str) -> None:
    rng = np.random.default_rng(KINDS.index(kind))
    for _ in range(60):
        points, lines = cloud(kind, rng)
        assert line_spacing(points, lines) == spacing_by_definition(points, lines)


def test_one_line_or_identical_points_of_several_lines() -> None:
    points = np.tile([0.01, 0.0, 0.04], (200_000, 1))
    assert line_spacing(points, np.zeros(200_000, dtype=np.int64)) == float("inf")
    # 8 whiskers all at one place: the definition's KD-trees scanned every point per query
    assert line_spacing(points, np.arange(200_000) // 25_000) == 0.0


def test_a_line_per_point_on_a_grid_is_the_grid_step() -> None:
    # 20 000 whisker ids of one point each: the definition built 20 000 KD-trees (2 minutes)
    step = 2.0**-10  # a power of two: the differences of the grid's coordinates are exact
    grid = np.stack(np.meshgrid(*[np.arange(k) * step for k in (20, 25, 40)]), axis=-1)
    points = grid.reshape(-1, 3)
    assert line_spacing(points, np.arange(len(points))) == step
    # whiskers along x, one per (y, z) row: the rows are one step apart
    rows = np.unique(points[:, 1:], axis=0, return_inverse=True)[1].ravel()
    assert line_spacing(points, rows) == step
