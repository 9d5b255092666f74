"""The accumulator merges points that repeat an earlier contact line of the same whisker
(`vibrissa.mapping.Accumulator`, ``merge_resolution_m``): counted in ``merged``, never lost or
dropped, memory bounded over endless passes, the bounds biting only on new data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vibrissa.mapping import Accumulator, ContactBatch
from vibrissa.mapping.accumulate import MERGE_RESOLUTION_M
from vibrissa.mapping.report import MapReport

RES = MERGE_RESOLUTION_M


def _line(n: int, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    """A contact line of n points 20 resolutions apart along x, each in the middle of its
    merge cell (m)."""
    return np.column_stack([np.arange(n) * 20 * RES, np.full(n, y), np.full(n, z)]) + 0.5 * RES


def _pass(acc: Accumulator, seq: int, lines: dict[str, np.ndarray],
          jitter: float = 0.0, rng: np.random.Generator | None = None) -> int:
    """One pass of the path: a batch per sample with a row per whisker in contact there,
    ``seq`` running on; a free sample between passes ends every line. Returns the next seq."""
    n = max(len(p) for p in lines.values())
    for k in range(n):
        rows = {w: p[k] for w, p in lines.items() if k < len(p)}
        points = np.array(list(rows.values()))
        if jitter and rng is not None:
            points = points + rng.uniform(-jitter, jitter, points.shape)
        acc.add(ContactBatch("world", points, np.tile([0.0, 0.0, 1.0], (len(rows), 1)),
                             list(rows), seq=seq + k))
    acc.add(ContactBatch("world", np.zeros((0, 3)), np.zeros((0, 3)), [], seq=seq + n))
    return seq + n + 1


def test_repeats_of_an_earlier_line_are_merged_counted_and_never_lost() -> None:
    lines = {"w0": _line(200), "w1": _line(150, y=0.01)}
    acc = Accumulator(1)
    seq = _pass(acc, 0, lines)
    assert (acc.n_points, acc.merged) == (350, 0)
    rng = np.random.default_rng(1)
    for _ in range(20):  # the same path again, each point moved by less than a cell
        seq = _pass(acc, seq, lines, jitter=0.2 * RES, rng=rng)
    assert (acc.n_points, acc.merged) == (350, 20 * 350)
    assert not acc.dropped
    points, _, ids, _ = acc.frames["world"].ordered()
    assert len(points) == acc.n_points and ids.count("w0") >= 200


def test_memory_stays_bounded_over_an_endless_stream_of_the_same_passes() -> None:
    """Forth and back again and again (the return line differs: 3 resolutions to the side):
    after the first cycle nothing is kept, however long it runs."""
    forth, back = {"w0": _line(300)}, {"w0": _line(300, y=3 * RES)[::-1]}
    acc = Accumulator(1)
    seq = _pass(acc, 0, forth)
    seq = _pass(acc, seq, back)
    first_cycle = acc.n_points
    cells_after_first = sum(len(c) for c in acc._cells.values())
    assert first_cycle == 600
    for _ in range(50):
        seq = _pass(acc, seq, forth)
        seq = _pass(acc, seq, back)
    assert acc.n_points == first_cycle and acc.merged == 50 * 600
    assert sum(len(c) for c in acc._cells.values()) == cells_after_first
    assert len(acc._lines) == 1  # one entry per whisker and frame, not per line


def test_one_line_is_never_merged_with_itself() -> None:
    """A stick phase repeats its contact point sample after sample within one line: mapped as
    it came, as before merging existed."""
    acc = Accumulator(1)
    stuck = np.vstack([_line(10), np.tile(_line(10)[-1], (40, 1)), _line(10) + [0.0, 0.0, 1e-3]])
    _pass(acc, 0, {"w0": stuck})
    assert (acc.n_points, acc.merged) == (60, 0)


def test_another_whisker_or_frame_or_a_coarse_difference_is_new_data() -> None:
    acc = Accumulator(1)
    seq = _pass(acc, 0, {"w0": _line(50)})
    seq = _pass(acc, seq, {"w1": _line(50)})  # another whisker at the same places
    seq = _pass(acc, seq, {"w0": _line(50) + [0.0, 2 * RES, 0.0]})  # two cells aside
    acc.add(ContactBatch("arm", _line(1), np.array([[0.0, 0, 1]]), ["w0"], seq=seq))
    assert (acc.n_points, acc.merged) == (151, 0)


def test_no_merging_with_a_resolution_of_zero() -> None:
    acc = Accumulator(1, merge_resolution_m=0.0)
    seq = _pass(acc, 0, {"w0": _line(50)})
    _pass(acc, seq, {"w0": _line(50)})
    assert (acc.n_points, acc.merged) == (100, 0)
    for bad in (-1e-6, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="merge_resolution_m must be finite and >= 0"):
            Accumulator(1, merge_resolution_m=bad)


def test_max_points_bites_only_on_new_data() -> None:
    lines = {"w0": _line(100)}
    acc = Accumulator(1, max_points=150)
    seq = _pass(acc, 0, lines)
    for _ in range(10):  # repeats: merged, never dropped, however far beyond the bound
        seq = _pass(acc, seq, lines)
    assert (acc.n_points, acc.merged, dict(acc.dropped)) == (100, 1000, {})
    _pass(acc, seq, {"w0": _line(100, z=0.01)})  # new data: the bound bites after 50 points
    assert (acc.n_points, dict(acc.dropped)) == (150, {"max_points": 50})


def test_a_dropped_point_is_not_one_to_merge_with() -> None:
    """Points beyond the bound were not kept: their repeats are dropped again, not merged."""
    acc = Accumulator(1, max_points=10)
    seq = _pass(acc, 0, {"w0": _line(30)})
    _pass(acc, seq, {"w0": _line(30)})
    assert (acc.n_points, acc.merged, dict(acc.dropped)) == (10, 10, {"max_points": 40})


def test_a_repeat_with_a_covariance_merges_with_a_point_kept_without_one() -> None:
    """A grid coarser than the finest, first used by a noisy point, holds the points kept
    before on the finest one."""
    acc = Accumulator(1)
    seq = _pass(acc, 0, {"w0": _line(5)})
    near = _line(5)[2] + 3 * RES  # 3 cells away on the finest grid, within its std of 10 cells
    acc.add(ContactBatch("world", near[None], np.array([[0.0, 0, 1]]), ["w0"], seq=seq + 5,
                         covariances_m2=(10 * RES) ** 2 * np.eye(3)[None]))
    assert (acc.n_points, acc.merged) == (5, 1)
    acc.add(ContactBatch("world", near[None] + 40 * RES, np.array([[0.0, 0, 1]]), ["w0"],
                         seq=seq + 7, covariances_m2=(10 * RES) ** 2 * np.eye(3)[None]))
    assert (acc.n_points, acc.merged) == (6, 1)  # beyond its cell: kept


def test_a_mixed_batch_keeps_its_new_rows() -> None:
    acc = Accumulator(1)
    seq = _pass(acc, 0, {"w0": _line(5)})
    acc.add(ContactBatch("world", np.vstack([_line(5)[2], _line(1, y=0.5)[0]]),
                         np.array([[0.0, 0, 1], [0.0, 0, 2]]), ["w0", "w1"], seq=seq + 5,
                         covariances_m2=np.stack([np.eye(3), 2 * np.eye(3)]) * 1e-8))
    assert (acc.n_points, acc.merged) == (6, 1)
    points, forces, ids, cov = acc.frames["world"].ordered()
    assert ids[-1] == "w1" and forces[-1].tolist() == [0.0, 0.0, 2.0]
    assert cov[-1, 0, 0] == 2e-8


def test_the_report_counts_merged_points(tmp_path: Path) -> None:
    report = MapReport(n_points=3, sources_ended=(), frames=(), merged_points=7)
    assert report.as_dict()["merged_points"] == 7
    assert json.loads(json.dumps(report.as_dict()))["merged_points"] == 7
    assert "merged: 7 contact point(s)" in report.text()
    assert MapReport(n_points=3, sources_ended=(), frames=()).as_dict()["merged_points"] == 0


def test_noisy_repeats_merge_within_their_std_and_memory_stays_bounded() -> None:
    """The same line again and again, each point measured anew with noise of std 0.2 mm, which
    its covariance states: repeats within their std merge and the points kept stop growing;
    without the covariance (cells of 10 um) nearly every repeat would be kept."""
    std = 20 * RES
    line = np.column_stack([np.arange(200) * 2 * std, np.zeros(200), np.zeros(200)])
    rng = np.random.default_rng(7)

    def run(passes: int, with_covariance: bool) -> list[int]:
        acc, kept = Accumulator(1), []
        for p in range(passes):
            points = line + rng.normal(0.0, std, line.shape)
            for k, point in enumerate(points):
                acc.add(ContactBatch("world", point[None], np.array([[0.0, 0.0, 1.0]]), ["w0"],
                                     seq=p * 1000 + k, covariances_m2=(
                                         std**2 * np.eye(3)[None] if with_covariance else None)))
            kept.append(acc.n_points)
        assert acc.n_points + acc.merged == 200 * passes and not acc.dropped
        return kept

    noisy = run(90, with_covariance=True)
    assert noisy[0] == 200  # one line is never merged with itself
    # the points kept grow as the noise's tails are reached, ever more slowly (the log of the
    # passes): the last 30 passes keep less than a tenth of their points
    assert noisy[-1] - noisy[59] < 0.1 * 30 * 200
    assert noisy[-1] - noisy[59] < noisy[29] - noisy[0]
    plain = run(10, with_covariance=False)
    assert plain[-1] > 0.9 * 10 * 200
