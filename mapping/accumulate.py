"""Contact points gathered per frame, within bounds, repeats merged (`Accumulator`), from plain
arrays."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import compress

import numpy as np
import numpy.typing as npt

from vibrissa.status import ContactStatus

FloatArray = npt.NDArray[np.float64]

MAX_POINTS = 10_000_000
"""Default bound of the points kept (all frames): a point takes about 200 bytes."""
MAX_FRAMES = 64
"""Default bound of the frames kept."""
MERGE_RESOLUTION_M = 1e-5
"""Default edge of the cells in which a repeated point is merged, m (`Accumulator`): far below
what a contact point's position is known to on the demos (its noise, 0.1 mm and up) and a mesh
cell of the map (about 1 mm), so that a merged point adds nothing the map can show."""
MAX_POSITION_M = 1e7
"""The largest coordinate of a contact point the map takes, m: a scene file's positions
(``vibrissa.formats.scene_file.LIMITS``; tests/mapping checks that the two agree)."""
MAX_FORCE_N = 1e12
"""The largest contact force component the map takes, N: a normal from its direction."""
COVARIANCE_RTOL = 1e-9
"""How far from symmetric positive semidefinite a covariance may be, relative to its largest
entry (asymmetry) and |eigenvalue| (a negative eigenvalue): the reconstructor's J S J^T is off
by rounding only, a rank-deficient one has eigenvalues of about -1e-16 x the largest."""


@dataclass(frozen=True)
class ContactBatch:
    """Contact points that arrived together (one message, one tick of an array), SI.

    Attributes
    ----------
    frame_id
        The frame the points and forces are expressed in.
    points_m : ndarray, shape (N, 3)
        Contact points, m.
    forces_n : ndarray, shape (N, 3)
        Contact force on the rod at each point, N (its direction gives the contact normal).
    whisker_ids
        The whisker of each point (N names).
    seq
        The batch's place in its source's stream: a whisker's points are ordered by it (and
        in the order given within a batch), which is the order along its contact lines.
    covariances_m2 : ndarray, shape (N, 3, 3), optional
        Each point's position covariance, m^2; None: none (the points get
        ``MapSettings.point_std_m``).
    stamp
        When the points were measured, s (the message's stamp).
    status : ndarray of int, shape (N,), optional
        Step 2's `vibrissa.status.ContactStatus` of each point; None: all 0. A point whose
        place was chosen among several that fit its wrench (AMBIGUOUS_CONTACT: a tapered or
        pre-curved rod) is not mapped (counted, ``ambiguous_contact``).
    """

    frame_id: str
    points_m: FloatArray
    forces_n: FloatArray
    whisker_ids: Sequence[str]
    seq: int = 0
    covariances_m2: FloatArray | None = None
    stamp: float = 0.0
    status: npt.NDArray[np.integer] | None = None

    def __post_init__(self) -> None:
        n = len(self.whisker_ids)
        for name, shape in (("points_m", (n, 3)), ("forces_n", (n, 3)),
                            ("covariances_m2", (n, 3, 3))):
            value = getattr(self, name)
            if value is not None and np.shape(value) != shape:
                raise ValueError(f"{name} must have shape {shape} (one row per whisker id), "
                                 f"got {np.shape(value)}")


@dataclass
class FrameCloud:
    """Contact points of one frame, in arrival order, one block of arrays per batch, and the
    newest ``stamp`` of the batches it took (s; -inf before the first)."""

    stamp: float = -math.inf
    whisker_ids: list[str] = field(default_factory=list)
    seqs: list[int] = field(default_factory=list)
    points: list[FloatArray] = field(default_factory=list)  # (k, 3) per batch
    forces: list[FloatArray] = field(default_factory=list)
    covariances: list[FloatArray] = field(default_factory=list)  # (k, 3, 3); NaN: none

    def add(self, batch: ContactBatch, keep: npt.NDArray[np.bool_] | None,
            covariances: FloatArray) -> None:
        """Append every row of ``batch``, or those ``keep`` says, each with its whisker, the
        batch's ``seq`` and its covariance from ``covariances`` (k, 3, 3) of the rows appended
        (NaN: none)."""
        rows = slice(None) if keep is None else keep
        whisker_ids = (list(batch.whisker_ids) if keep is None
                       else list(compress(batch.whisker_ids, keep.tolist())))
        self.whisker_ids += whisker_ids
        self.seqs += [batch.seq] * len(whisker_ids)
        self.points.append(np.reshape(batch.points_m, (-1, 3))[rows])
        self.forces.append(np.reshape(batch.forces_n, (-1, 3))[rows])
        self.covariances.append(covariances)
        self.stamp = max(self.stamp, batch.stamp)

    def ordered(self) -> tuple[FloatArray, FloatArray, list[str], FloatArray]:
        """Points (N, 3), forces (N, 3), whisker ids and covariances (N, 3, 3; NaN where
        none came), sorted by (whisker, seq): line order."""
        order = sorted(range(len(self.seqs)), key=lambda i: (self.whisker_ids[i], self.seqs[i]))
        return (np.concatenate([np.empty((0, 3)), *self.points])[order],
                np.concatenate([np.empty((0, 3)), *self.forces])[order],
                [self.whisker_ids[i] for i in order],
                np.concatenate([np.empty((0, 3, 3)), *self.covariances])[order])


Cell = tuple[int, int, int, int]
"""A merge cell: its grid's level (edge ``merge_resolution_m`` x 2**level) and its index."""


def _coarser(cell: Cell, level: int) -> Cell:
    """The cell of grid ``level`` that holds ``cell`` of the finest grid (level 0): grids of
    power-of-two edges aligned at the origin nest, floor(floor(x / r) / 2**k) being
    floor(x / (r 2**k))."""
    return (level, cell[1] >> level, cell[2] >> level, cell[3] >> level)


def _rows(batch: ContactBatch, rows: npt.NDArray[np.bool_]) -> ContactBatch:
    """The batch of the ``rows`` of ``batch``."""
    return ContactBatch(
        batch.frame_id, np.reshape(batch.points_m, (-1, 3))[rows],
        np.reshape(batch.forces_n, (-1, 3))[rows],
        list(compress(batch.whisker_ids, rows.tolist())), batch.seq,
        None if batch.covariances_m2 is None
        else np.reshape(batch.covariances_m2, (-1, 3, 3))[rows], batch.stamp,
        None if batch.status is None else np.asarray(batch.status)[rows])


def is_covariance(covariances: FloatArray) -> npt.NDArray[np.bool_]:
    """Whether each of ``covariances`` (k, 3, 3) is a covariance: finite, symmetric and
    positive semidefinite, to `COVARIANCE_RTOL`."""
    c = np.asarray(covariances, dtype=np.float64).reshape(-1, 3, 3)
    finite = np.isfinite(c).all(axis=(1, 2))
    c = np.where(np.isfinite(c), c, 0.0)  # refused by `finite`; zeros keep the rest finite
    # each matrix over its largest entry: eigvalsh neither overflows nor loses subnormals
    scale = np.abs(c).max(axis=(1, 2))
    unit = c / np.where(scale > 0, scale, 1.0)[:, None, None]
    symmetric = np.abs(unit - unit.transpose(0, 2, 1)).max(axis=(1, 2)) <= COVARIANCE_RTOL
    eigenvalues = np.linalg.eigvalsh(unit)  # of its lower triangle: symmetric checked above
    semidefinite = eigenvalues[:, 0] >= -COVARIANCE_RTOL * np.abs(eigenvalues).max(axis=1)
    return np.asarray(finite & symmetric & semidefinite)


class Accumulator:
    """Points per frame and the sources that ended, within bounds.

    It keeps at most ``max_points`` points in at most ``max_frames`` frames, so that a long run
    or a flood cannot exhaust the memory: a batch beyond either bound is dropped whole and
    its rows are counted in ``dropped`` (by reason). A row the map cannot use is dropped and
    counted too: a point with a coordinate beyond `MAX_POSITION_M` (``out_of_range``), a
    contact force of zero or beyond `MAX_FORCE_N` (``no_force_direction``: no normal). A row
    whose covariance is not one (`is_covariance`) is kept as a point without a covariance and
    counted in ``bad_covariance``. ``expected`` is how many sources (or which) must
    ``end`` before ``done``.

    A point that repeats one kept before is merged into it: counted in ``merged``, not kept,
    neither lost nor dropped, and not held against the bounds, so that a robot driving the
    same path again and again keeps its memory bounded and the bounds bite only on new data.
    A point repeats when a point of the same whisker and frame from an earlier contact line
    lies in the same cell of a grid of edge ``merge_resolution_m`` (cells aligned with the
    frame's origin; so within sqrt(3) x that distance), or, for a point whose position std
    (the square root of its covariance's trace) exceeds that edge, of a grid whose
    edge is the next power-of-two multiple of it at or above the std (a noisy repeat adds
    nothing its first measurement within its own noise did not; memory is then bounded by the
    cells within a few stds of the lines). A whisker's contact line is a run of
    its points in consecutive batches (``seq`` n, n + 1, ...; a batch without a point of it
    ends the run). Points of one line are never merged: a single pass of a path (a stick
    phase, whose contact point stays put, included) is mapped as it came; a whisker that rests
    in contact is bounded by ``max_points`` only. Driving the same path again, memory is
    bounded by the cells its lines cross, whatever the number of passes. 0: nothing is merged.
    """

    def __init__(self, expected: int | Sequence[str] = 1, max_points: int = MAX_POINTS,
                 max_frames: int = MAX_FRAMES,
                 merge_resolution_m: float = MERGE_RESOLUTION_M) -> None:
        if not (math.isfinite(merge_resolution_m) and merge_resolution_m >= 0):
            raise ValueError(f"merge_resolution_m must be finite and >= 0, got "
                             f"{merge_resolution_m}")
        self.expected = expected
        self.max_points = max_points
        self.max_frames = max_frames
        self.merge_resolution_m = merge_resolution_m
        self.merged = 0
        # per (frame, whisker): its current line (number, last seq) and, per grid cell (level,
        # index), the
        self._lines: dict[tuple[str, str], tuple[int, int]] = {}
        # first line that left a point there; and which grid levels it uses
        self._cells: dict[tuple[str, str], dict[Cell, int]] = {}
        self._grids: dict[tuple[str, str], set[int]] = {}
        self.frames: dict[str, FrameCloud] = {}
        self.ended: set[str] = set()
        self.n_points = 0
        self.dropped: Counter[str] = Counter()
        self.bad_covariance = 0

    def add(self, batch: ContactBatch) -> None:
        """Take a batch of contact points (one without points changes nothing)."""
        if not len(batch.whisker_ids):
            return
        cells: list[tuple[tuple[str, str], Cell, int] | None] = []
        if self.merge_resolution_m:
            new, cells = self._lines_and_cells(batch)
            if not new.all():
                self.merged += int(np.count_nonzero(~new))
                batch = _rows(batch, new)
                cells = list(compress(cells, new.tolist()))
        rows = len(batch.whisker_ids)
        if not rows:
            return
        if batch.frame_id not in self.frames and len(self.frames) >= self.max_frames:
            self.dropped["max_frames"] += rows
        elif self.n_points + rows > self.max_points:
            self.dropped["max_points"] += rows
        else:
            keep = self._usable(batch)
            kept = rows if keep is None else int(np.count_nonzero(keep))
            if kept:
                self.frames.setdefault(batch.frame_id, FrameCloud()).add(
                    batch, keep, self._covariances(batch, keep, kept))
                self.n_points += kept
            for r, cell in enumerate(cells):  # a later line's repeat of a kept point merges
                if cell is not None and (keep is None or keep[r]):
                    key, where, line = cell
                    held = self._cells.setdefault(key, {})
                    for level in self._grids.get(key, {0}):
                        held.setdefault(_coarser(where, level), line)

    def _levels(self, batch: ContactBatch) -> npt.NDArray[np.int64]:
        """Each row's merge grid: its edge is ``merge_resolution_m`` x 2**level, the smallest
        at or above the row's position std, taken as the square root of its covariance's
        trace (at least its largest eigenvalue's; level 0 without a covariance, or with a
        trace that is not a finite number > 0)."""
        if batch.covariances_m2 is None:
            return np.zeros(len(batch.whisker_ids), dtype=np.int64)
        c = np.reshape(batch.covariances_m2, (-1, 3, 3))
        trace = c[:, 0, 0] + c[:, 1, 1] + c[:, 2, 2]
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            level = np.ceil(0.5 * np.log2(trace / self.merge_resolution_m**2))
        return np.where(np.isfinite(level) & (level > 0), np.minimum(level, 1000), 0).astype(
            np.int64)

    def _lines_and_cells(self, batch: ContactBatch) -> tuple[
            npt.NDArray[np.bool_], list[tuple[tuple[str, str], Cell, int] | None]]:
        """Which rows of ``batch`` are not repeats, and each row's (frame and whisker, cell of
        the finest grid, line) (None: a point off the grid, left to `_usable`); moves each
        whisker's line on."""
        points = np.reshape(batch.points_m, (-1, 3))
        with np.errstate(invalid="ignore", over="ignore"):
            scaled = np.floor(points / self.merge_resolution_m)
        grid = np.asarray(np.isfinite(scaled).all(axis=1) & (np.abs(scaled) < 2.0**62).all(axis=1))
        on_grid = [bool(b) for b in grid]
        where: list[list[int]] = np.where(grid[:, None], scaled, 0.0).astype(np.int64).tolist()
        levels: list[int] = self._levels(batch).tolist()
        new = np.ones(len(where), dtype=bool)
        cells: list[tuple[tuple[str, str], Cell, int] | None] = []
        for r, whisker in enumerate(batch.whisker_ids):
            key = (batch.frame_id, whisker)
            line, last = self._lines.get(key, (-1, batch.seq - 2))
            if batch.seq not in (last, last + 1):
                line += 1  # a new contact line
            self._lines[key] = (line, batch.seq)
            if not on_grid[r]:
                cells.append(None)
                continue
            cell = (0, where[r][0], where[r][1], where[r][2])
            level = levels[r]
            self._use_level(key, level)
            new[r] = self._cells.get(key, {}).get(_coarser(cell, level), line) == line
            cells.append((key, cell, line))
        return new, cells

    def _use_level(self, key: tuple[str, str], level: int) -> None:
        """Make the grid ``level`` hold every point of ``key`` kept so far (from its cells of
        the finest grid, each with its earliest line), once."""
        used = self._grids.setdefault(key, {0})
        if level in used:
            return
        used.add(level)
        cells = self._cells.setdefault(key, {})
        for cell, line in list(cells.items()):
            if cell[0] == 0:
                cells.setdefault(_coarser(cell, level), line)

    def end(self, source: str) -> None:
        """Note that ``source`` has ended its stream."""
        self.ended.add(source)

    def _usable(self, batch: ContactBatch) -> npt.NDArray[np.bool_] | None:
        """The rows the map can use (None: all), counting the others in ``dropped``."""
        point = np.abs(np.reshape(batch.points_m, (-1, 3))).max(axis=1)
        force = np.abs(np.reshape(batch.forces_n, (-1, 3))).max(axis=1)
        far, no_force = point > MAX_POSITION_M, ~((force > 0) & (force <= MAX_FORCE_N))
        ambiguous = (np.zeros(len(point), dtype=bool) if batch.status is None
                     else (np.asarray(batch.status) & int(ContactStatus.AMBIGUOUS_CONTACT)) != 0)
        if not (far.any() or no_force.any() or ambiguous.any()):
            return None
        for reason, rows in (("out_of_range", far), ("no_force_direction", no_force & ~far),
                             ("ambiguous_contact", ambiguous & ~far & ~no_force)):
            if rows.any():
                self.dropped[reason] += int(np.count_nonzero(rows))
        return ~(far | no_force | ambiguous)

    def _covariances(self, batch: ContactBatch, keep: npt.NDArray[np.bool_] | None,
                     kept: int) -> FloatArray:
        """The covariances (kept, 3, 3) of the rows kept, NaN where none came or where one is
        not a covariance (counted in ``bad_covariance``)."""
        if batch.covariances_m2 is None:
            return np.full((kept, 3, 3), np.nan)
        covariances = np.reshape(batch.covariances_m2, (-1, 3, 3))[
            slice(None) if keep is None else keep]
        bad = ~is_covariance(covariances)
        self.bad_covariance += int(np.count_nonzero(bad))
        return np.where(bad[:, None, None], np.nan, covariances)

    @property
    def done(self) -> bool:
        """Whether every expected source has ended."""
        if isinstance(self.expected, int):
            return len(self.ended) >= self.expected
        return set(self.expected) <= self.ended
