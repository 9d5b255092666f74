"""The reconstructor node's side (socket-free): batches drained from the input queue, its
parameters; a single whisker's wrench is a tick of one row."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.streaming.test_live_tick import recorder
from vibrissa.msgs import EndOfStream, WhiskerWrenchArray
from vibrissa.nodes.reconstructor import BatchCollector, ReconstructorParams, collect_batch
from vibrissa.streaming import reconstruct_messages
from vibrissa.units import RodScale
from vibrissa.wire.transport import Header, Received


def _wrenches(n: int = 5) -> list[WhiskerWrenchArray]:
    """One whisker's samples, each a tick of one row."""
    rng = np.random.default_rng(3)
    arrays = []
    for i in range(n):
        position = rng.uniform(-1, 1, (1, 3))
        f0, m0 = recorder().single_contact(rng.normal(0, 1, (1, 3)), rng.normal(0, 1, (1, 3)))
        arrays.append(WhiskerWrenchArray(
            stamp=float(i), seq=i, whisker_ids=["w"], frame_ids=["w/clamp"], pose_frame_id="world",
            clamp_position=position, clamp_orientation=[[0.0, 0.0, 0.0, 1.0]], f0=f0, m0=m0))
    return arrays


def _tick(wrenches: list[WhiskerWrenchArray], seq: int) -> WhiskerWrenchArray:
    """The samples as the rows of one tick, whisker ``w<seq>`` for each."""
    return WhiskerWrenchArray(
        stamp=2.5, seq=seq, pose_frame_id="world",
        frame_ids=[f"w{w.seq}/clamp" for w in wrenches], whisker_ids=[f"w{w.seq}" for w in wrenches],
        clamp_position=np.concatenate([w.clamp_position for w in wrenches]),
        clamp_orientation=np.concatenate([w.clamp_orientation for w in wrenches]),
        f0=np.concatenate([w.f0 for w in wrenches]), m0=np.concatenate([w.m0 for w in wrenches]))


def _rx(msg: Any) -> Received:
    return Received("/w", msg, b"", Header(1, 0), 0.0)


def test_collect_batch_drains_up_to_max_and_stops_at_end_of_stream() -> None:
    queue: list[Any] = [*_wrenches(5), EndOfStream(stamp=0.0, source="/s", count=5),
                        *_wrenches(2)]
    timeouts: list[float] = []

    def receive(timeout_s: float) -> Received | None:
        timeouts.append(timeout_s)
        return _rx(queue.pop(0)) if queue else None

    batch, eos, backlog = collect_batch(receive, 0.1, max_batch=3)
    assert [w.seq for w in batch] == [0, 1, 2] and eos is None and backlog
    assert timeouts == [0.1, 0.0, 0.0]  # waits only for the first, then drains
    batch, eos, backlog = collect_batch(receive, 0.1, max_batch=3)
    assert [w.seq for w in batch] == [3, 4] and eos is not None and eos.count == 5
    batch, eos, backlog = collect_batch(receive, 0.1, max_batch=100)
    assert len(batch) == 2 and eos is None and not backlog
    assert collect_batch(receive, 0.1, max_batch=3) == ([], None, False)


def test_ticks_of_any_size_are_drained_in_arrival_order() -> None:
    wrenches = _wrenches(3)
    queue: list[Any] = [wrenches[0], _tick(wrenches[1:], seq=1), _tick(wrenches[1:], seq=2),
                        wrenches[2]]

    def receive(timeout_s: float) -> Received | None:
        return _rx(queue.pop(0)) if queue else None

    batch, eos, _ = collect_batch(receive, 0.1, max_batch=3)
    assert [len(m.whisker_ids) for m in batch] == [1, 2, 2]
    assert [m.seq for m in batch] == [0, 1, 2] and eos is None
    assert collect_batch(receive, 0.1, max_batch=100)[0] == [wrenches[2]]


def test_batches_stay_small_until_a_backlog_then_drain_it_in_one() -> None:
    queue: list[Any] = []

    def receive(timeout_s: float) -> Received | None:
        return _rx(queue.pop(0)) if queue else None

    batches = BatchCollector(receive, drain_limit=4, max_batch=100)
    queue += _wrenches(3)
    assert len(batches.collect(0.1)[0]) == 3  # below the limit: the queue was empty
    queue += _wrenches(30)
    sizes = [len(batches.collect(0.1)[0]) for _ in range(3)]
    assert sizes == [4, 26, 0]  # limit hit: a backlog, drained in one batch
    queue += _wrenches(30)
    assert len(batches.collect(0.1)[0]) == 4  # back to the limit after the backlog
    batches.collect(0.1)
    queue += [*_wrenches(2), EndOfStream(stamp=0.0, source="/s", count=2), *_wrenches(9)]
    batch, eos = batches.collect(0.1)
    assert len(batch) == 2 and eos is not None
    assert len(batches.collect(0.1)[0]) == 4


def test_a_bad_robot_description_is_a_parameter_error_naming_it(tmp_path: Path) -> None:
    for body, words in (
        ("whiskers:\n  - {name: w0, length_m: 0.05, ei_nm2: 1.0e-4}\n", "missing 'mount'"),
        ("whiskers:\n  - {name: w0, length_m: -0.05, ei_nm2: 1.0e-4, mount: {}}\n", "length_m"),
        ("objects: []\n", "missing 'whiskers'"),
    ):
        robot = tmp_path / "robot.yaml"
        robot.write_text(body)
        with pytest.raises(ValueError, match="parameter 'robot'") as info:
            ReconstructorParams(robot=str(robot))
        assert words in str(info.value) and "robot.yaml" in str(info.value)


def test_a_tick_of_one_row_gives_the_bytes_of_the_same_row_of_a_larger_tick() -> None:
    """A single whisker is a batch of one: the same point, force, s1 and status, bit for bit."""
    wrenches = _wrenches(12)
    singles = [o.contacts for o in reconstruct_messages(wrenches, RodScale())]
    whole = reconstruct_messages([_tick(wrenches, seq=0)], RodScale())[0].contacts
    for i, contact in enumerate(singles):
        row = [k for k, w in enumerate(whole.whisker_ids) if w == f"w{i}"]
        assert len(contact.whisker_ids) == len(row)
        if not row:
            continue
        assert (contact.seq, contact.whisker_ids, contact.frame_id) == (i, ["w"], "world")
        assert contact.point.tobytes() == whole.point[row].tobytes()
        assert contact.force.tobytes() == whole.force[row].tobytes()
        assert contact.s1.tobytes() == whole.s1[row].tobytes()
        assert contact.status.tobytes() == whole.status[row].tobytes()
    assert sum(bool(c.whisker_ids) for c in singles) >= 2
