"""Node logic without sockets: SI scaling, batching, clamp poses, normals, fit, accumulation."""

from __future__ import annotations

import math
import resource
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from vibrissa.frames import quaternion_matrices
from vibrissa.msgs import (
    ContactPhase,
    ContactPointArray,
    ContactStatus,
    EndOfStream,
    WhiskerWrenchArray,
)
from vibrissa.msgs.codec import decode, encode
from vibrissa.nodes.mapper import Accumulator, MapperParams, write_outputs
from vibrissa.nodes.reconstructor import (
    BatchCollector,
    Reconstructed,
    ReconstructorParams,
    collect_batch,
    reconstruct_messages,
)
from vibrissa.nodes.surface_fit import contact_normals, split_lines
from vibrissa.nodes.wrench_source import WrenchSourceParams, tick_messages
from vibrissa.reconstruct import reconstruct, reconstruct_si
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import SweepRun, Trail, first_contact, simulate_sweeps
from vibrissa.ticks import array_ticks, sequential_ticks
from vibrissa.units import RodScale
from vibrissa.wire.bag import BagReader
from vibrissa.wire.transport import Header, Received

UNIT_ROD = RodScale()


@dataclass
class WrenchesResult:
    """The points of a batch of wrenches, and its counts."""

    contacts: list[ContactPointArray]  # those of one row
    no_contact: int
    bad_pose: int


def one_row(*, stamp: float, seq: int, whisker_id: str, frame_id: str,
            pose_frame_id: str | None = None, clamp_position: Any = None,
            clamp_orientation: Any = None, f0: Any, m0: Any) -> WhiskerWrenchArray:
    """One whisker's sample: a WhiskerWrenchArray of one row."""
    def row(value: Any) -> Any:
        return None if value is None else np.reshape(value, (1, -1))
    return WhiskerWrenchArray(stamp=stamp, seq=seq, whisker_ids=[whisker_id], frame_ids=[frame_id],
                              pose_frame_id=pose_frame_id, clamp_position=row(clamp_position),
                              clamp_orientation=row(clamp_orientation), f0=row(f0), m0=row(m0))


def reconstruct_wrenches(wrenches: list[WhiskerWrenchArray], rod: RodScale = UNIT_ROD
                         ) -> WrenchesResult:
    """The node's one path on a batch of one-row wrenches, its outcomes summed; the contacts
    of the rows that have one."""
    outcomes = reconstruct_messages(wrenches, rod)
    return WrenchesResult([o.contacts for o in outcomes
                           if o.contacts is not None and o.contacts.whisker_ids],
                          sum(o.no_contact for o in outcomes), sum(o.bad_pose for o in outcomes))


def reconstruct_arrays(ticks: list[WhiskerWrenchArray], rod: RodScale = UNIT_ROD) -> list[Reconstructed]:
    """The node's one path on a batch of ticks."""
    return reconstruct_messages(ticks, rod)


def reconstruct_array(tick: WhiskerWrenchArray, rod: RodScale = UNIT_ROD) -> Reconstructed:
    """The node's one path on one tick."""
    return reconstruct_messages([tick], rod)[0]


def sweep_wrenches(run: SweepRun, whisker_id: str, frame_id: str, rod: RodScale
                   ) -> Iterator[WhiskerWrenchArray]:
    """The wrench source's one path, one whisker sweeping one sweep after the other."""
    return tick_messages(sequential_ticks(run, rod), [whisker_id] * len(run.trails), frame_id)


def sweep_arrays(run: SweepRun, whisker_ids: list[str], frame_id: str, rod: RodScale
                 ) -> Iterator[WhiskerWrenchArray]:
    """The wrench source's one path, the sweeps as one rigid array."""
    return tick_messages(array_ticks(run, rod), whisker_ids, frame_id, array=True)


def _wrenches(n: int = 64, seed: int = 3, **kwargs: Any) -> list[WhiskerWrenchArray]:
    """Wrenches of a rod touched at random points of a bent plane (some without contact)."""
    rng = np.random.default_rng(seed)
    p0 = rng.uniform(-1, 1, (n, 3))
    f0 = rng.normal(0, 1, (n, 3))
    m0 = rng.normal(0, 1, (n, 3))
    f0[0] = 0.0  # no force: no contact
    m0[0] = 0.0
    return [one_row(stamp=float(i), seq=i, whisker_id="w", frame_id="w/clamp", pose_frame_id="world",
                          clamp_position=p0[i], clamp_orientation=[0.0, 0.0, 0.0, 1.0],
                          f0=f0[i], m0=m0[i], **kwargs) for i in range(n)]


def _to_si(wrenches: list[WhiskerWrenchArray], length: float, ei: float,
           quaternion: Any = None) -> list[WhiskerWrenchArray]:
    """The wrenches of a rod of length ``length`` and stiffness ``ei`` (written out, not RodScale)."""
    return [one_row(stamp=w.stamp, seq=w.seq, whisker_id="w", frame_id="w/clamp", pose_frame_id="world",
                          clamp_position=w.clamp_position * length,
                          clamp_orientation=w.clamp_orientation if quaternion is None else quaternion,
                          f0=w.f0 * ei / length**2, m0=w.m0 * ei / length) for w in wrenches]


def test_sweep_wrenches_are_si_with_running_seq() -> None:
    surface = parse_surface("paraboloid:a=0.5,b=1,h=0.4")
    trails = [Trail(0.0, 0.1), Trail(0.3, 0.0)]
    sweeps = simulate_sweeps(surface, trails, 0.02)
    length, ei = 0.05, 2e-4
    msgs = list(sweep_wrenches(SweepRun(surface, trails, 0.02), "w7", "world",
                               RodScale(length, ei)))
    n0, n1 = sweeps[0].n_steps, sweeps[1].n_steps
    assert n0 > 3 and n1 > 3
    assert [m.seq for m in msgs] == list(range(n0 + n1))
    assert all(m.whisker_ids == ["w7"] for m in msgs)  # a batch of one row each
    last = msgs[n0 + 2]  # the third equilibrium of the second sweep
    np.testing.assert_array_equal(last.clamp_orientation, [[0, 0, 0, 1]])
    np.testing.assert_allclose(last.clamp_position[0], sweeps[1].p0[2] * length, rtol=1e-15)
    np.testing.assert_allclose(last.f0[0], sweeps[1].f0[2] * ei / length**2, rtol=1e-15)
    np.testing.assert_allclose(last.m0[0], sweeps[1].m0[2] * ei / length, rtol=1e-15)


def test_batch_equals_library_and_counts_no_contact() -> None:
    wrenches = _wrenches()
    result = reconstruct_wrenches(wrenches)
    rec = reconstruct(np.vstack([w.clamp_position for w in wrenches]),
                      np.vstack([w.f0 for w in wrenches]), np.vstack([w.m0 for w in wrenches]))
    assert result.no_contact == int(np.count_nonzero(~rec.valid)) >= 1
    assert [c.seq for c in result.contacts] == np.flatnonzero(rec.valid).tolist()
    for contact in result.contacts:
        np.testing.assert_allclose(contact.point[0], rec.point[contact.seq], rtol=0, atol=1e-12)
        np.testing.assert_allclose(contact.force[0], rec.force[contact.seq], rtol=0, atol=1e-12)
        assert contact.s1[0] == pytest.approx(rec.s1[contact.seq], abs=1e-12)
        assert int(contact.status[0]) == int(rec.status[contact.seq])
        assert int(contact.phase[0]) == int(rec.phase[contact.seq])


@pytest.mark.parametrize("quaternion", [[0.0, 0.0, 0.0, 1.0], [0.3, -0.2, 0.5, 2.0]])
def test_a_wrench_gives_the_same_point_bit_for_bit_in_any_batch(quaternion) -> None:
    # Batches follow arrival timing; a bag replay must still give the live run's points.
    length, ei = 0.04, 3e-3
    wrenches = _to_si(_wrenches(48), length, ei, quaternion)
    wrenches[5] = one_row(stamp=0.0, seq=5, whisker_id="w", frame_id="w/clamp", pose_frame_id="world",
                                clamp_position=[0, 0, 0], clamp_orientation=[0, 0, 0, 0],
                                f0=[1.0, 0, 0], m0=[0, 1.0, 0])
    whole = reconstruct_wrenches(wrenches, RodScale(length, ei))
    parts = [reconstruct_wrenches(wrenches[i:i + 3], RodScale(length, ei))
             for i in range(0, len(wrenches), 3)]
    assert whole.bad_pose == sum(p.bad_pose for p in parts) == 1
    assert whole.no_contact == sum(p.no_contact for p in parts) >= 1
    assert [c for p in parts for c in p.contacts] == whole.contacts


def test_si_scaling_round_trip() -> None:
    """Scaling the wrench to a rod of length L and stiffness EI scales the point by L."""
    length, ei = 0.04, 3e-3
    unit = _wrenches()
    a, b = reconstruct_wrenches(unit), reconstruct_wrenches(_to_si(unit, length, ei),
                                                            RodScale(length, ei))
    assert len(a.contacts) == len(b.contacts)
    for ca, cb in zip(a.contacts, b.contacts, strict=True):
        np.testing.assert_allclose(cb.point, ca.point * length, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(cb.force, ca.force * ei / length**2, rtol=1e-12, atol=1e-15)
        assert cb.s1[0] == pytest.approx(ca.s1[0] * length, rel=1e-12)


@pytest.mark.parametrize("cls", [WrenchSourceParams, ReconstructorParams, MapperParams])
def test_params_give_the_rod_scale_and_refuse_a_rod_without_length(cls: Any) -> None:
    assert cls(rod_length_m=0.05).rod == RodScale(0.05, getattr(cls(), "rod_ei_nm2", 1.0))
    with pytest.raises(ValueError, match="length_m"):
        cls(rod_length_m=0.0)


def test_array_names_default_per_whisker_and_must_match_the_trails() -> None:
    params = WrenchSourceParams(y0=(0.1, 0.2, 0.3), array=True)
    assert params.array_whisker_ids == ["whisker0", "whisker1", "whisker2"]
    assert WrenchSourceParams(y0=(0.1,), whisker_ids=("left",)).array_whisker_ids == ["left"]
    with pytest.raises(ValueError, match=r"parameter 'whisker_ids' must be one name per y0 \(2\)"):
        WrenchSourceParams(y0=(0.1, 0.2), whisker_ids=("left",))


def test_clamp_orientation_rotates_the_contact() -> None:
    angle = 0.7
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    q = np.r_[axis * np.sin(angle / 2), np.cos(angle / 2)]
    rotations, norm2 = quaternion_matrices(np.array([q, 2.0 * q]))
    R = rotations[0]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    np.testing.assert_array_equal(rotations[1], R)  # normalised first: 2 q is the same rotation
    np.testing.assert_allclose(norm2, [1.0, 4.0], rtol=1e-15)
    # Rodrigues' formula as the reference
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    np.testing.assert_allclose(R, np.eye(3) + np.sin(angle) * K
                               + (1 - np.cos(angle)) * K @ K, atol=1e-15)
    straight = _wrenches()
    turned = [one_row(stamp=w.stamp, seq=w.seq, whisker_id="w", frame_id="w/clamp", pose_frame_id="world",
                            clamp_position=w.clamp_position, clamp_orientation=q * 2.0,
                            f0=w.f0, m0=w.m0) for w in straight]  # not unit: normalised
    a, b = reconstruct_wrenches(straight), reconstruct_wrenches(turned)
    assert [c.seq for c in a.contacts] == [c.seq for c in b.contacts]
    for ca, cb in zip(a.contacts, b.contacts, strict=True):
        p0 = straight[ca.seq].clamp_position[0]  # type: ignore[index]
        np.testing.assert_allclose(cb.point[0] - p0, R @ (ca.point[0] - p0), atol=1e-12)
        np.testing.assert_allclose(cb.force[0], R @ ca.force[0], atol=1e-12)


def test_zero_quaternion_is_counted_as_bad_pose() -> None:
    w = _wrenches(3)
    bad = one_row(stamp=0.0, seq=9, whisker_id="w", frame_id="w/clamp", pose_frame_id="world",
                        clamp_position=w[1].clamp_position, clamp_orientation=[0, 0, 0, 0],
                        f0=w[1].f0, m0=w[1].m0)
    result = reconstruct_wrenches([w[1], bad])
    assert result.bad_pose == 1
    assert 9 not in [c.seq for c in result.contacts]


def _tick(wrenches: list[WhiskerWrenchArray], seq: int = 4) -> WhiskerWrenchArray:
    """The wrenches as the rows of one array message."""
    return WhiskerWrenchArray(
        stamp=2.5, seq=seq, pose_frame_id="world",
        frame_ids=[f"w{w.seq}/clamp" for w in wrenches], whisker_ids=[f"w{w.seq}" for w in wrenches],
        clamp_position=np.vstack([w.clamp_position for w in wrenches]),
        clamp_orientation=np.vstack([w.clamp_orientation for w in wrenches]),
        f0=np.vstack([w.f0 for w in wrenches]), m0=np.vstack([w.m0 for w in wrenches]))


def test_an_array_of_whiskers_moves_as_one_and_reconstructs_its_sweeps() -> None:
    # Three whiskers of one rigid array (one misses the object), L = 0.04 m, EI = 3e-3 N m^2.
    surface = parse_surface("paraboloid:a=0.5,b=1,h=0.4")
    length, ei, step = 0.04, 3e-3, 0.01
    rod = RodScale(length, ei)
    y0 = (-0.3, 0.1, 0.9)
    x_grid = max(t[0] for t in (first_contact(surface, y) for y in y0) if t is not None)
    sweeps = simulate_sweeps(surface, [Trail(y, 0.2) for y in y0], step, x_grid=x_grid)
    assert sweeps[2].end == "no-contact" and all(s.end == "detachment" for s in sweeps[:2])
    arrays = list(sweep_arrays(SweepRun(surface, [Trail(y, 0.2) for y in y0], step,
                                        x_grid=x_grid), ["a", "b", "c"], "world", rod))
    assert [m.seq for m in arrays] == list(range(len(arrays)))
    assert len(arrays) - 1 == max(round((x_grid - s.x0[-1]) / step) for s in sweeps[:2])
    loaded = 0
    for k, msg in enumerate(arrays):
        assert msg.whisker_ids == ["a", "b", "c"]  # no longer steps, no snap-off: all rows
        np.testing.assert_allclose(msg.clamp_position / length,
                                   [[x_grid - k * step, y, 0.0] for y in y0], atol=1e-12)
        free = ~np.any(msg.f0 != 0.0, axis=1) & ~np.any(msg.m0 != 0.0, axis=1)
        loaded += int(np.count_nonzero(~free))
        # a zero wrench only where the straight rod is clear of the object
        t_in, t_out = surface.line_interval(msg.clamp_position[free] / length, [0.0, 0.0, 1.0])
        assert np.all(~(t_in < 1.0) | ~(t_out > 0.0) | np.isclose(t_in, t_out))
    assert loaded == sum(s.n_steps for s in sweeps)
    # Step 2 on the arrays: every simulated contact, at its step, in SI
    results = reconstruct_arrays(arrays, rod)
    for whisker, sweep in zip("ab", sweeps, strict=False):
        for x0, contact in zip(sweep.x0, sweep.contact, strict=True):
            points = results[round((x_grid - x0) / step)].contacts
            row = points.whisker_ids.index(whisker)
            np.testing.assert_allclose(points.point[row], contact * length, rtol=0, atol=1e-13)
    assert sum(r.no_contact for r in results) == 3 * len(arrays) - loaded


def test_array_equals_library_and_per_wrench_path_and_counts_rows() -> None:
    length, ei = 0.04, 3e-3
    rod = RodScale(length, ei)
    unit = _wrenches(32)
    q = np.random.default_rng(5).normal(size=(32, 4))
    q[7] = 0.0  # bad pose
    wrenches = [one_row(stamp=w.stamp, seq=w.seq, whisker_id=f"w{w.seq}",
                              frame_id=f"w{w.seq}/clamp", pose_frame_id="world",
                              clamp_position=w.clamp_position * length, clamp_orientation=q[i],
                              f0=w.f0 * ei / length**2, m0=w.m0 * ei / length)
                for i, w in enumerate(unit)]
    result = reconstruct_array(_tick(wrenches), rod)
    per_wrench = reconstruct_wrenches(wrenches, rod)
    got = result.contacts
    assert (got.stamp, got.seq, got.frame_id) == (2.5, 4, "world")
    assert got.whisker_ids == [c.whisker_ids[0] for c in per_wrench.contacts]
    assert (result.no_contact, result.bad_pose) == (per_wrench.no_contact, per_wrench.bad_pose)
    assert result.bad_pose == 1 and result.no_contact >= 1 and "w7" not in got.whisker_ids
    # the library on the dimensionless rows, one array call
    rows = [int(w[1:]) for w in got.whisker_ids]
    good = [i for i in range(32) if i != 7]
    R = Rotation.from_quat(q[good]).as_matrix()  # scipy's (x, y, z, w), normalised first
    np.testing.assert_allclose(quaternion_matrices(q[good])[0], R, rtol=0, atol=2e-15)
    rec = reconstruct(np.vstack([unit[i].clamp_position for i in good]),
                      np.vstack([unit[i].f0 for i in good]), np.vstack([unit[i].m0 for i in good]), R)
    keep = [good.index(i) for i in rows]
    assert rec.valid.sum() == len(rows)
    np.testing.assert_allclose(got.point, rec.point[keep] * length, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got.s1, rec.s1[keep] * length, rtol=1e-12)
    np.testing.assert_allclose(got.force, rec.force[keep] * ei / length**2, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(got.phase, rec.phase[keep])
    np.testing.assert_array_equal(got.status, rec.status[keep])
    # one wrench at a time: the same rows, the same bits
    np.testing.assert_array_equal(got.point, np.vstack([c.point for c in per_wrench.contacts]))
    np.testing.assert_array_equal(got.force, np.vstack([c.force for c in per_wrench.contacts]))
    assert got.s1.tolist() == [c.s1[0] for c in per_wrench.contacts]
    assert got.phase.tolist() == [c.phase[0] for c in per_wrench.contacts]


def test_an_array_gives_the_same_points_bit_for_bit_after_the_wire() -> None:
    # A bag replay decodes the recorded bytes: the points must be the live run's exactly.
    tick = _tick(_to_si(_wrenches(32), 0.04, 3e-3, [0.3, -0.2, 0.5, 2.0]))
    rod = RodScale(0.04, 3e-3)
    live = reconstruct_array(tick, rod).contacts
    replayed = decode(encode(tick))
    assert isinstance(replayed, WhiskerWrenchArray)
    assert reconstruct_array(replayed, rod).contacts == live and len(live.whisker_ids) > 0


def test_an_array_without_contact_gives_an_empty_array() -> None:
    result = reconstruct_array(_tick(_wrenches(1)))
    assert result.no_contact == 1 and result.contacts.whisker_ids == []
    assert result.contacts.point.shape == (0, 3)
    assert decode(encode(result.contacts)) == result.contacts


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


def test_arrays_are_drained_like_wrenches_in_arrival_order() -> None:
    wrenches = _wrenches(3)
    queue: list[Any] = [wrenches[0], _tick(wrenches[1:], seq=1), _tick(wrenches[1:], seq=2),
                        wrenches[2]]

    def receive(timeout_s: float) -> Received | None:
        return _rx(queue.pop(0)) if queue else None

    batch, eos, _ = collect_batch(receive, 0.1, max_batch=3)
    assert [len(m.whisker_ids) for m in batch] == [1, 2, 2]
    assert [m.seq for m in batch] == [0, 1, 2] and eos is None
    assert collect_batch(receive, 0.1, max_batch=100)[0] == [wrenches[2]]


def test_a_backlog_of_arrays_gives_each_tick_its_own_points_bit_for_bit() -> None:
    # One Step 2 call for several ticks: each tick's points must be those it gets alone
    # (batches follow arrival timing; a replay must give the live run's points exactly).
    rod = RodScale(0.04, 3e-3)
    rng = np.random.default_rng(11)
    ticks = []
    for seq, n in enumerate((32, 5, 0, 17, 32, 1)):
        rows = _to_si(_wrenches(max(n, 1), seed=seq), 0.04, 3e-3)[:n]
        q = rng.normal(size=(n, 4))
        if n > 3:
            q[2] = 0.0  # bad pose in the middle of the batch
        # (forces 10x those of _wrenches: most rows then have a contact)
        ticks.append(WhiskerWrenchArray(
            stamp=2.5, seq=seq, pose_frame_id="world",
            frame_ids=[f"w{i}/clamp" for i in range(n)], whisker_ids=[f"w{i}" for i in range(n)],
            clamp_position=np.reshape([w.clamp_position for w in rows], (n, 3)),
            clamp_orientation=q, f0=10.0 * np.reshape([w.f0 for w in rows], (n, 3)),
            m0=np.reshape([w.m0 for w in rows], (n, 3))))
    together = reconstruct_arrays(ticks, rod)
    alone = [reconstruct_array(tick, rod) for tick in ticks]
    assert [r.contacts for r in together] == [r.contacts for r in alone]
    assert [(r.no_contact, r.bad_pose) for r in together] == [
        (r.no_contact, r.bad_pose) for r in alone]
    assert [r.contacts.seq for r in together] == list(range(6))
    assert sum(r.bad_pose for r in together) == 4
    assert sum(len(r.contacts.whisker_ids) for r in together) > 40
    # and each tick's rows are those of its wrenches one by one, bit for bit
    for tick, result in zip(ticks, together, strict=True):
        rows = [one_row(stamp=0.0, seq=i, whisker_id=tick.whisker_ids[i],
                              frame_id=f"{tick.whisker_ids[i]}/clamp", pose_frame_id="world",
                              clamp_position=tick.clamp_position[i],
                              clamp_orientation=tick.clamp_orientation[i], f0=tick.f0[i],
                              m0=tick.m0[i]) for i in range(len(tick.whisker_ids))]
        one_by_one = [reconstruct_wrenches([row], rod) for row in rows]
        contacts = [c for r in one_by_one for c in r.contacts]
        assert result.contacts.whisker_ids == [c.whisker_ids[0] for c in contacts]
        assert (result.no_contact, result.bad_pose) == (
            sum(r.no_contact for r in one_by_one), sum(r.bad_pose for r in one_by_one))
        np.testing.assert_array_equal(result.contacts.point.reshape(-1, 3),
                                      np.reshape([c.point for c in contacts], (-1, 3)))


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


def _paraboloid_lines(mu: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Five contact lines on the demo paraboloid, sliding forces F = fn (n + mu t)."""
    surface = parse_surface("paraboloid:a=0.5,b=1,h=0.4")
    lines = []
    for y in (-0.4, -0.2, 0.0, 0.2, 0.4):
        x = np.linspace(0.8, -0.8, 400)  # the trail runs along -x
        lines.append(np.column_stack([x, np.full_like(x, y), 0.5 * x**2 + y**2 + 0.4]))
    points = np.vstack(lines)
    normal = surface.normal(points)
    # eq. 7: friction along the line towards the previous contact point (+x here)
    tangent = np.column_stack([np.ones(len(points)), np.zeros(len(points)), points[:, 0]])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    forces = 2.0 * (normal + mu * tangent)
    return points, forces, normal


def test_contact_normals_recover_the_surface_normal_with_friction() -> None:
    points, forces, normal = _paraboloid_lines(mu=0.3)
    lines = split_lines(points)
    assert np.unique(lines).tolist() == [0, 1, 2, 3, 4]
    estimate = contact_normals(points, forces, lines)
    cos = np.einsum("ni,ni->n", estimate, normal)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.5  # F itself is 16.7 deg off


def test_accumulator_ends_on_count_or_names() -> None:
    point = ContactPointArray(stamp=0.0, seq=0, whisker_ids=["w"], frame_id="world",
                              point=[[0, 0, 1]], s1=[0.5], phase=[1], force=[[0, 0, 1]], status=[0])
    acc = Accumulator(2)
    acc.add(point)
    acc.add(EndOfStream(stamp=0.0, source="/a", count=1))
    acc.add(EndOfStream(stamp=0.0, source="/a", count=1))  # the same source twice
    assert not acc.done and acc.n_points == 1
    acc.add(EndOfStream(stamp=0.0, source="/b", count=0))
    assert acc.done
    acc.add(ContactPointArray(stamp=0.0, seq=3, frame_id="arm", whisker_ids=[],
                              point=np.zeros((0, 3)), s1=[], phase=[], force=np.zeros((0, 3)),
                              status=[]))
    assert "arm" not in acc.frames  # a tick without contact adds no frame
    acc.add(ContactPointArray(stamp=0.0, seq=3, frame_id="world", whisker_ids=["u", "v"],
                              point=[[0, 0, 2], [0, 0, 3]], s1=[0.5, 0.6], phase=[1, 2],
                              force=[[0, 0, 1], [0, 1, 0]], status=[0, 0]))
    assert acc.n_points == 3
    points, forces, ids, _ = acc.frames["world"].ordered()
    assert ids == ["u", "v", "w"] and points[:, 2].tolist() == [2, 3, 1]
    np.testing.assert_array_equal(forces[1], [0, 1, 0])
    named = Accumulator(["/b"])
    named.add(EndOfStream(stamp=0.0, source="/a", count=1))
    assert not named.done
    named.add(EndOfStream(stamp=0.0, source="/b", count=1))
    assert named.done


def test_a_result_that_overflows_is_counted_as_no_contact_not_published() -> None:
    """Finite inputs near the float limit, rotated, once gave a valid row with an infinite
    force: encoding it raised inside the node's publish and the node exited."""
    q = np.array([0.79623251, 0.10475497, -0.46211826, -0.37614744])
    p0 = np.array([-1.30861562e308, 1.49614536e308, 1.16312171e308])
    f0 = np.array([1.15378996e308, -9.47832554e307, 1.11655258e308])
    m0 = np.array([4.86599216e153, 9.48589037e153, 5.07180288e153])
    wrench = one_row(stamp=1.0, seq=3, whisker_id="w", frame_id="w/clamp", pose_frame_id="world",
                           clamp_position=p0,
                           clamp_orientation=q, f0=f0, m0=m0)
    decode(encode(wrench))  # the codec takes it: every value is finite
    single = reconstruct_messages([wrench])[0]
    array = reconstruct_messages([WhiskerWrenchArray(
        stamp=1.0, seq=3, pose_frame_id="world",
        frame_ids=["w/clamp", "v/clamp"], whisker_ids=["w", "v"], clamp_position=[p0, p0],
        clamp_orientation=[q, q], f0=[f0, f0], m0=[m0, np.zeros(3)])])[0]
    assert single.contacts is not None and single.contacts.whisker_ids == []
    assert (single.no_contact, single.bad_pose) == (1, 0)
    assert array.contacts is not None and array.contacts.whisker_ids == []
    assert (array.no_contact, array.bad_pose) == (2, 0)
    encode(array.contacts)  # what is published can be encoded


def _contact(i: int, point: list[float], frame_id: str = "world") -> ContactPointArray:
    return ContactPointArray(stamp=0.0, seq=i, whisker_ids=["w0"], frame_id=frame_id,
                             point=[point], s1=[0.5], phase=[ContactPhase.TIP],
                             force=[[0.0, 0.0, 1.0]], status=[ContactStatus.OK])


@pytest.mark.parametrize(("points", "why"), [
    ([[0.0, 0.0, 0.5]], "1 point(s), a surface needs 4 or more"),
    ([[0.1 * i, 0.0, 0.5] for i in range(3)], "3 point(s), a surface needs 4 or more"),
    ([[0.01 * i, 0.02 * i, 0.5 - 0.01 * i] for i in range(100)],
     "all 100 points on one straight line"),
    ([[0.1, 0.1, 0.5]] * 50, "all 50 points at one place"),
])
def test_too_little_for_a_surface_is_a_report_line_and_the_cloud_is_written(
    tmp_path: Path, points: list[list[float]], why: str
) -> None:
    acc = Accumulator(1)
    for i, point in enumerate(points):
        acc.add(_contact(i, point))
    report, messages = write_outputs(acc, MapperParams(out_dir=str(tmp_path)), tmp_path)
    frame = report["frames"][0]
    assert frame["method"] == f"none: {why}"
    assert (frame["n_vertices"], frame["n_triangles"]) == (0, 0)
    assert sorted(frame["files"]) == ["cloud", "html", "png"]
    assert not (tmp_path / "mesh.ply").exists()
    assert (tmp_path / "cloud.ply").stat().st_size > 0
    assert f"method: none: {why}" in (tmp_path / "report.txt").read_text()
    cloud, mesh, _ = messages[0]
    assert len(cloud.points) == len(points) and len(mesh.vertices) == 0


def test_frame_ids_that_collide_or_are_long_get_files_of_their_own(tmp_path: Path) -> None:
    frames = ["a/b", "a_b", "f" * 300, "ω"]
    acc = Accumulator(1)
    for frame in frames:
        for i in range(12):
            acc.add(_contact(i, [0.01 * i, 0.02 * (i % 3), 0.5 + 0.001 * i * i], frame))
    report, _ = write_outputs(acc, MapperParams(out_dir=str(tmp_path), plot=False), tmp_path)
    clouds = [frame["files"]["cloud"] for frame in report["frames"]]
    assert len(set(clouds)) == len(frames)
    assert all(len(Path(c).name) < 80 and Path(c).exists() for c in clouds)


def run_with_file_size_limit(script: str, limit_bytes: int) -> subprocess.CompletedProcess[str]:
    """``script`` in a Python whose files cannot grow past ``limit_bytes``: writes beyond it
    fail as on a full disk (EFBIG instead of ENOSPC; SIGXFSZ is ignored)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, preexec_fn=limit)  # noqa: PLW1509 - the test's own child


def test_a_full_disk_leaves_no_half_written_map_file(tmp_path: Path) -> None:
    script = f"""
import numpy as np
from pathlib import Path
from vibrissa.msgs import ContactPhase, ContactPointArray
from vibrissa.nodes.mapper import Accumulator, MapperParams, write_outputs
acc = Accumulator(1)
for i in range(3000):
    acc.add(ContactPointArray(stamp=0.0, seq=i, whisker_ids=["w"], frame_id="world",
                              point=[[0.001 * (i % 60), 0.001 * (i // 60), 0.5 + 1e-4 * (i % 7)]],
                              s1=[0.5], phase=[ContactPhase.TIP], force=[[0.0, 0.0, 1.0]],
                              status=[0]))
out = Path({str(tmp_path)!r})
try:
    write_outputs(acc, MapperParams(out_dir=str(out), plot=False), out)
except OSError as exc:
    print("error:", exc)
"""
    result = run_with_file_size_limit(script, 20_000)  # the cloud alone is ~100 kB
    assert "error:" in result.stdout, result.stdout + result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no file at all, half or whole


def test_a_full_disk_stops_the_recorder_with_one_error_and_a_readable_bag(
    tmp_path: Path,
) -> None:
    bag = tmp_path / "rec.mcap"
    script = f"""
import numpy as np
from vibrissa.msgs import WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.nodes.recorder import RecorderParams, record
from vibrissa.wire.bag import BagReader
from vibrissa.wire.transport import Header, Received

class Endless:
    seq = 0
    def receive(self, timeout_s):
        self.seq += 1
        msg = WhiskerWrenchArray(stamp=0.0, seq=self.seq, whisker_ids=["w"], frame_ids=["w/clamp"],
                                 pose_frame_id="world", clamp_position=np.random.rand(1, 3),
                                 clamp_orientation=[[0, 0, 0, 1]], f0=np.random.rand(1, 3),
                                 m0=np.random.rand(1, 3))
        return Received("/w/wrench", msg, encode(msg), Header(1, self.seq), 0.0)
    def totals(self):
        return {{"lost": 0, "rejected": 0}}

try:
    record(RecorderParams(output={str(bag)!r}, chunk_size=4096), Endless())
except OSError as exc:
    print("error:", exc.errno, "chained:", exc.__context__ is not None)
"""
    result = run_with_file_size_limit(script, 200_000)
    # the write's own error, not a second one from closing the bag on the same full disk
    assert result.stdout.strip() == "error: 27 chained: False", result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    got = list(BagReader(bag))
    assert len(got) > 100 and all(r.topic == "/w/wrench" for r in got)


# -- wrenches in clamp frames, placed through the robot's poses ----------------------------------


def _robot_wrench(stamp: float, seq: int, whiskers: tuple[str, ...] = ("a", "b")) -> WhiskerWrenchArray:
    n = len(whiskers)
    return WhiskerWrenchArray(stamp=stamp, seq=seq, whisker_ids=list(whiskers),
                              frame_ids=[f"{w}/clamp" for w in whiskers],
                              f0=np.tile([2e-3, 0.0, 0.0], (n, 1)), m0=np.tile([0.0, 5e-5, 0.0], (n, 1)))


def test_a_pose_stream_that_stops_makes_wrenches_no_pose_after_the_timeout() -> None:
    from vibrissa.frames import Transform
    from vibrissa.nodes.reconstructor import PoseWait, robot_frames
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0])),
                Whisker("b", 0.03, 9e-5, Transform.from_xyz_rpy([0, -0.02, 0.01], [1.5, 0, 0]))]
    frames = robot_frames(whiskers)
    now = [100.0]
    wait = PoseWait(frames, "world", timeout_s=0.5, clock=lambda: now[0])
    for stamp in (0.0, 0.01):
        frames.add("world", "base_link", stamp, Transform.from_xyz_rpy([stamp, 0, 0]))
    wait.add([_robot_wrench(0.005, 0), _robot_wrench(0.02, 1), _robot_wrench(0.008, 2)])
    ready = wait.take()
    assert [m.seq for m in ready] == [0]  # seq 1 is newer than the last pose: it waits (and 2 behind it)
    assert wait.wait_s() == pytest.approx(0.5)
    now[0] += 0.49
    assert wait.take() == []
    now[0] += 0.02  # the pose stream has stopped: after pose_timeout_s, on without a pose
    late = wait.take()
    assert [m.seq for m in late] == [1, 2] and len(wait) == 0
    rods = {w.name: w.scale for w in whiskers}
    out = reconstruct_messages(ready + late, rods, frames, "world")
    assert [(o.no_pose, o.unknown_whisker) for o in out] == [(0, 0), (2, 0), (0, 0)]
    assert "newer than the last pose" in out[1].errors[0]
    # placed rows are those of the pose interpolated at their stamp, mount composed
    X = frames.lookup("world", "b/clamp", 0.005)
    assert out[0].contacts is not None and out[0].contacts.frame_id == "world"
    expected = reconstruct_si(X.quaternion_xyzw[None], X.translation[None], [[2e-3, 0, 0]],
                              [[0, 5e-5, 0]], rods["b"])
    rows = out[0].contacts.whisker_ids
    assert "b" in rows
    np.testing.assert_allclose(out[0].contacts.point[rows.index("b")], expected.point_m[0],
                               rtol=0, atol=1e-15)


def test_a_pose_queued_behind_a_backlog_is_waited_for_not_counted_missing() -> None:
    """The node reads its input 0.3 s per message (slow next to pose_timeout_s 0.5 s): the
    pose that covers the first wrenches is 8 messages behind them in the queue. Every wrench
    gets its pose; only once the queue is empty and the timeout has passed are the wrenches
    past the last pose no_pose, and a backlog that never drains ends the wait at 10 timeouts."""
    from vibrissa.frames import Transform
    from vibrissa.msgs import RobotPose
    from vibrissa.nodes.reconstructor import (
        BACKLOG_TIMEOUTS,
        PoseWait,
        Warnings,
        _on_pose,
        robot_frames,
    )
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0])),
                Whisker("b", 0.03, 9e-5, Transform.from_xyz_rpy([0, -0.02, 0.01], [1.5, 0, 0]))]
    frames = robot_frames(whiskers)
    now = [100.0]

    def pose(stamp: float) -> RobotPose:
        return RobotPose(stamp=stamp, frame_id="world", child_frame_id="base_link",
                         position=[stamp, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0])

    queue: list[Any] = [pose(0.0), *(_robot_wrench(0.001 * k, k) for k in range(1, 9)),
                            pose(0.1), _robot_wrench(0.2, 9)]

    def receive(timeout_s: float) -> Received | None:
        if not queue:
            now[0] += timeout_s
            return None
        now[0] += 0.3
        return Received("/robot/x", queue.pop(0), b"", Header(1, 0), 0.0)

    wait = PoseWait(frames, "world", timeout_s=0.5, clock=lambda: now[0])

    counters = {"robot_poses": 0, "bad_robot_pose": 0}
    on_pose = _on_pose(frames, counters, Warnings("/robot/reconstructor"))
    rods = {w.name: w.scale for w in whiskers}
    batches = BatchCollector(receive, drain_limit=2, max_batch=3, on_pose=on_pose)
    taken: list[tuple[int, int]] = []  # (seq, no_pose rows) as each wrench is let through
    while queue:
        batch, _ = batches.collect(0.0)
        wait.add(batch)
        ready = wait.take(batches.drained)
        if ready:
            taken += [(m.seq, out.no_pose) for m, out in
                      zip(ready, reconstruct_messages(ready, rods, frames, "world"), strict=True)]
    # each waited up to 2.4 s for its pose, and it came: none is no_pose
    assert taken == [(seq, 0) for seq in range(1, 9)]
    batches.collect(0.0)
    assert batches.drained and len(wait) == 1  # seq 9 (stamp 0.2) is past the last pose
    now[0] += 0.5
    (late,) = wait.take(batches.drained)
    assert late.seq == 9 and reconstruct_messages([late], rods, frames, "world")[0].no_pose == 2
    # a backlog that never drains: wait BACKLOG_TIMEOUTS x timeout_s, not forever
    wait.add([_robot_wrench(0.3, 10)])
    now[0] += 0.5 * BACKLOG_TIMEOUTS - 0.01
    assert wait.take(drained=False) == []
    now[0] += 0.02
    assert [m.seq for m in wait.take(drained=False)] == [10]


def test_held_poses_wait_until_a_wrench_needs_them_and_give_the_same_points() -> None:
    """A tick that comes with the next pose (a pose stream ahead of the wrenches) goes out
    before that pose is handled; a tick that needs a held pose gets it at once, also past its
    timeout (a held pose is not a missing one); the points equal those of poses applied as
    they came, bit for bit."""
    from vibrissa.frames import Transform
    from vibrissa.msgs import RobotPose
    from vibrissa.nodes.reconstructor import PoseWait, Warnings, _on_pose, robot_frames
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0])),
                Whisker("b", 0.03, 9e-5, Transform.from_xyz_rpy([0, -0.02, 0.01], [1.5, 0, 0]))]
    rods = {w.name: w.scale for w in whiskers}

    def pose(stamp: float) -> RobotPose:
        return RobotPose(stamp=stamp, frame_id="world", child_frame_id="base_link",
                         position=[stamp, 0.3 * stamp, 0.0],
                         orientation=[0.0, 0.0, math.sin(2 * stamp), math.cos(2 * stamp)])

    frames = robot_frames(whiskers)
    counters = {"robot_poses": 0, "bad_robot_pose": 0}
    now = [0.0]
    wait = PoseWait(frames, "world", timeout_s=0.5, clock=lambda: now[0],
                    on_pose=_on_pose(frames, counters, Warnings("/robot/reconstructor")))
    for stamp in (0.0, 0.01):
        wait.hold(pose(stamp))
    wait.apply_poses()
    assert counters["robot_poses"] == 2
    wait.hold(pose(0.02))
    wait.add([_robot_wrench(0.005, 1)])
    taken = wait.take()
    assert [m.seq for m in taken] == [1]
    assert counters["robot_poses"] == 2 and frames.newest("world", "a/clamp") == 0.01  # held
    wait.add([_robot_wrench(0.015, 2)])
    taken += wait.take()  # needs the held pose: applied now
    assert [m.seq for m in taken] == [1, 2] and counters["robot_poses"] == 3
    wait.hold(pose(0.03))
    wait.add([_robot_wrench(0.025, 3)])
    now[0] += 0.6  # past its timeout, with its pose held
    taken += wait.take()
    wait.apply_poses()
    assert [m.seq for m in taken] == [1, 2, 3] and counters["robot_poses"] == 4
    outcomes = reconstruct_messages(taken, rods, frames, "world")
    assert [out.no_pose for out in outcomes] == [0, 0, 0]

    eager = robot_frames(whiskers)  # every pose applied as it came
    for stamp in (0.0, 0.01, 0.02, 0.03):
        kept = pose(stamp)
        eager.add_pose("world", "base_link", stamp, kept.position, kept.orientation)
    for out, ref in zip(outcomes, reconstruct_messages(taken, rods, eager, "world"), strict=True):
        assert isinstance(out.contacts, ContactPointArray) and isinstance(ref.contacts, ContactPointArray)
        assert len(out.contacts.whisker_ids) == 2
        assert out.contacts.point.tobytes() == ref.contacts.point.tobytes()


@pytest.mark.parametrize("lead_s, placed", [(5.0, True), (math.inf, False)])
def test_poses_far_ahead_of_the_wrenches_are_held_not_pushed_out_of_the_history(
        lead_s: float, placed: bool) -> None:
    """A path sampled every 2 s played as fast as possible: its 300 poses (600 s) reach the node
    before its wrenches (they come on their own socket), then a tick per pose. Held while they
    are more than 5 s past the newest wrench, every tick is placed; applied as they came, the
    10-s history keeps only the last six poses and the ticks before them have none. A pose held
    for the timeout with no wrench coming goes in."""
    from vibrissa.frames import Transform
    from vibrissa.msgs import RobotPose
    from vibrissa.nodes.reconstructor import PoseWait, Warnings, _on_pose, robot_frames
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0])),
                Whisker("b", 0.03, 9e-5, Transform.from_xyz_rpy([0, -0.02, 0.01], [1.5, 0, 0]))]
    frames = robot_frames(whiskers, history_s=10.0)
    counters = {"robot_poses": 0, "bad_robot_pose": 0}
    now = [0.0]
    wait = PoseWait(frames, "world", timeout_s=0.5, lead_s=lead_s, clock=lambda: now[0],
                    on_pose=_on_pose(frames, counters, Warnings("/robot/reconstructor")))
    rods = {w.name: w.scale for w in whiskers}

    def pose(stamp: float) -> RobotPose:
        return RobotPose(stamp=stamp, frame_id="world", child_frame_id="base_link",
                         position=[0.01 * stamp, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0])

    for k in range(300):
        wait.hold(pose(2.0 * k))
    wait.apply_poses()  # the node's loop after a batch of poses alone
    no_pose = 0
    for k in range(300):
        now[0] += 0.001
        wait.add([_robot_wrench(2.0 * k, k)])
        ready = wait.take()
        assert [m.seq for m in ready] == [k]
        no_pose += sum(out.no_pose for out in reconstruct_messages(ready, rods, frames, "world"))
        wait.apply_poses()
    assert counters["robot_poses"] == 300
    if not placed:
        assert no_pose == 2 * 294  # all but the ticks of the poses of the last 10 s
        return
    assert no_pose == 0
    for k in range(300, 310):  # the wrenches have stopped; the poses go on
        wait.hold(pose(2.0 * k))
    wait.apply_poses()
    assert counters["robot_poses"] == 302  # up to 5 s past the last wrench (598 s)
    now[0] += 0.49
    wait.apply_poses()
    assert counters["robot_poses"] == 302
    now[0] += 0.01  # held for the timeout with no wrench coming: they go in
    wait.apply_poses()
    assert counters["robot_poses"] == 310
    wait.hold(pose(620.0))  # a wrench meanwhile keeps a far pose held for the timeout again
    now[0] += 0.3
    wait.add([_robot_wrench(599.0, 300)])
    now[0] += 0.3
    wait.apply_poses()
    assert counters["robot_poses"] == 310
    now[0] += 0.2
    wait.apply_poses()
    assert counters["robot_poses"] == 311


@pytest.mark.parametrize("max_span_s, placed", [(5.0, True), (math.inf, False)])
def test_a_stream_played_faster_than_real_time_keeps_the_poses_its_wrenches_need(
        max_span_s: float, placed: bool) -> None:
    """A robot's 30 s at 100 Hz (a pose, then a tick of two whiskers, every 10 ms) queued at once,
    as a bag played as fast as possible reaches the node, with poses kept 10 s. Batches that end
    once their stamps span 5 s place every tick; batches of up to 4 096 messages (2 048 ticks,
    20 s of stream) would first apply poses far past the history of their first ticks."""
    from vibrissa.frames import Transform
    from vibrissa.msgs import RobotPose
    from vibrissa.nodes.reconstructor import PoseWait, Warnings, _on_pose, robot_frames
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0])),
                Whisker("b", 0.03, 9e-5, Transform.from_xyz_rpy([0, -0.02, 0.01], [1.5, 0, 0]))]
    frames = robot_frames(whiskers, history_s=10.0)
    queue: list[Any] = []
    for k in range(3000):
        stamp = round(0.01 * k, 9)
        queue += [RobotPose(stamp=stamp, frame_id="world", child_frame_id="base_link",
                            position=[0.1 * stamp, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0]),
                  _robot_wrench(stamp, k)]

    def receive(timeout_s: float) -> Received | None:
        return _rx(queue.pop(0)) if queue else None

    counters = {"robot_poses": 0, "bad_robot_pose": 0}
    batches = BatchCollector(receive, drain_limit=15, max_batch=4096, max_span_s=max_span_s,
                             on_pose=_on_pose(frames, counters, Warnings("/robot/reconstructor")))
    wait = PoseWait(frames, "world", timeout_s=0.5)
    rods = {w.name: w.scale for w in whiskers}
    no_pose = placed_ticks = 0
    while queue or len(wait):
        batch, _ = batches.collect(0.0)
        wait.add(batch)
        ready = wait.take(batches.drained)
        for outcome in reconstruct_messages(ready, rods, frames, "world") if ready else ():
            no_pose += outcome.no_pose
            placed_ticks += outcome.no_pose == 0
    assert counters["robot_poses"] == 3000
    if placed:
        assert no_pose == 0 and placed_ticks == 3000
    else:  # the batching this replaces: ticks lost their poses
        assert no_pose > 1000


def test_warnings_are_logged_once_per_kind_then_every_thousandth(
        caplog: pytest.LogCaptureFixture) -> None:
    from vibrissa.nodes.reconstructor import Warnings

    warn = Warnings("/robot/reconstructor")
    with caplog.at_level("WARNING", logger="vibrissa.nodes.reconstructor"):
        for k in range(1000):  # a stamp in each: one kind
            warn(f"cannot look up w00/clamp in world at t={k * 0.001!r}: 0.2 s newer than the "
                 "last pose; no extrapolation")
        warn("whisker 'ghost' is not in the robot description (w00)")  # another kind: logged
        warn("robot pose refused: " + "x" * 70_000)  # off the wire: logged, shortened
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 4, lines
    assert "t=0.0:" in lines[0] and lines[1].endswith("(1000 of this kind so far)")
    assert "'ghost' is not in the robot description" in lines[2]
    assert len(lines[3]) < 600 and lines[3].endswith("...")


def test_a_stray_pose_in_another_frame_is_counted_and_the_stream_goes_on() -> None:
    from vibrissa.frames import Transform
    from vibrissa.msgs import RobotPose
    from vibrissa.nodes.reconstructor import Warnings, _on_pose, robot_frames
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0]))]
    frames = robot_frames(whiskers)
    counters = dict.fromkeys(("robot_poses", "bad_robot_pose", "pose_time_jumps",
                              "pose_reparents"), 0)
    on_pose = _on_pose(frames, counters, Warnings("/robot/reconstructor"))
    on_pose(RobotPose(stamp=0.0, frame_id="odom", child_frame_id="base_link",
                      position=[5.0, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0]))
    for k in range(3):
        on_pose(RobotPose(stamp=0.1 * k, frame_id="world", child_frame_id="base_link",
                          position=[0.1 * k, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0]))
    assert counters == {"robot_poses": 4, "bad_robot_pose": 0, "pose_time_jumps": 0,
                        "pose_reparents": 1}
    for k in range(2000):  # invented frames that no clamp hangs under: refused, not kept
        on_pose(RobotPose(stamp=0.3, frame_id="odom", child_frame_id=f"junk{k}",
                          position=[0.0, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0]))
    assert counters["bad_robot_pose"] == 2000 and frames.frames == {"world", "base_link", "a/clamp"}
    on_pose(RobotPose(stamp=0.3, frame_id="world", child_frame_id="base_link",
                      position=[0.3, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0]))
    assert counters["robot_poses"] == 5
    rows = frames.lookup_rows("world", ["a/clamp"], [0.15])
    assert rows.ok[0] and np.allclose(rows.p[0] - whiskers[0].X_RC.translation,
                                      [0.15, 0.0, 0.0], rtol=0, atol=1e-15)


def test_a_wrench_waits_for_the_poses_across_a_gap_not_for_a_stray_pose_ahead() -> None:
    """The pose stream lags; one pose stamped 5 s ahead of it (1 m off) would end the wait of
    every wrench before it and place it between the last real pose and the stray one. With
    max_pose_gap_s the wrench waits until the stream passes its stamp, and its point is the
    stream's."""
    from vibrissa.frames import Transform
    from vibrissa.msgs import RobotPose
    from vibrissa.nodes.reconstructor import PoseWait, Warnings, _on_pose, robot_frames
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0]))]
    frames = robot_frames(whiskers, max_gap_s=1.0)
    counters = dict.fromkeys(("robot_poses", "bad_robot_pose", "pose_time_jumps",
                              "pose_reparents"), 0)
    on_pose = _on_pose(frames, counters, Warnings("/robot/reconstructor"))

    def pose(stamp: float, x: float) -> RobotPose:
        return RobotPose(stamp=stamp, frame_id="world", child_frame_id="base_link",
                         position=[x, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0])

    now = [0.0]
    wait = PoseWait(frames, "world", timeout_s=0.5, clock=lambda: now[0])
    on_pose(pose(0.0, 0.0))
    on_pose(pose(5.0, 1.0))  # the stray one
    wait.add([_robot_wrench(0.025, 1, ("a",))])
    assert wait.take() == []  # not placed between t=0 and the stray pose
    gap = frames.lookup_rows("world", ["a/clamp"], [0.025])
    assert not gap.ok[0] and "more than max_pose_gap_s (1 s)" in gap.errors[0]  # the parameter
    for k in (1, 2, 3):
        on_pose(pose(0.01 * k, 0.01 * k))
    (ready,) = wait.take()
    rods = {w.name: w.scale for w in whiskers}
    out = reconstruct_messages([ready], rods, frames, "world")[0]
    rows = frames.lookup_rows("world", ["a/clamp"], [0.025])
    assert out.no_pose == 0 and rows.ok[0]
    assert np.allclose(rows.p[0] - whiskers[0].X_RC.translation, [0.025, 0.0, 0.0], rtol=0,
                       atol=1e-15)


def test_rows_of_a_whisker_the_robot_does_not_have_are_counted_and_named() -> None:
    from vibrissa.frames import Transform
    from vibrissa.nodes.reconstructor import robot_frames
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0]))]
    frames = robot_frames(whiskers)
    for stamp in (0.0, 1.0):
        frames.add("world", "base_link", stamp, Transform())
    (out,) = reconstruct_messages([_robot_wrench(0.5, 0, ("a", "ghost"))],
                                  {w.name: w.scale for w in whiskers}, frames)
    assert (out.unknown_whisker, out.no_pose) == (1, 0)
    assert any("'ghost' is not in the robot description (a)" in e for e in out.errors)
    assert out.contacts is not None and "ghost" not in out.contacts.whisker_ids


def test_a_row_measured_in_another_whiskers_frame_is_counted_not_placed() -> None:
    from vibrissa.frames import Transform
    from vibrissa.nodes.reconstructor import robot_frames
    from vibrissa.scene import Whisker

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0])),
                Whisker("b", 0.03, 9e-5, Transform.from_xyz_rpy([0, 0.02, 0], [-1.2, 0, 0]))]
    frames = robot_frames(whiskers)
    for stamp in (0.0, 1.0):
        frames.add("world", "base_link", stamp, Transform())
    tick = _robot_wrench(0.5, 0)
    swapped = WhiskerWrenchArray(stamp=0.5, seq=1, whisker_ids=["a", "b"],
                                 frame_ids=["b/clamp", "b/clamp"], f0=tick.f0, m0=tick.m0)
    rods = {w.name: w.scale for w in whiskers}
    good, bad = reconstruct_messages([tick, swapped], rods, frames)
    assert (good.wrong_frame, good.contacts.whisker_ids) == (0, ["a", "b"])  # type: ignore[union-attr]
    # row a of the second tick at b's mount would be a's rod at b's place: a point nowhere
    assert (bad.wrong_frame, bad.no_pose, bad.unknown_whisker) == (1, 0, 0)
    assert bad.contacts is not None and bad.contacts.whisker_ids == ["b"]
    assert np.array_equal(bad.contacts.point, good.contacts.point[1:])  # type: ignore[union-attr]
    assert any("whisker 'a' measured in frame 'b/clamp', not in its clamp frame 'a/clamp'" in e
               for e in bad.errors)


def test_a_bad_robot_description_is_a_parameter_error_naming_it(tmp_path: Path) -> None:
    from vibrissa.nodes.reconstructor import ReconstructorParams

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


def test_with_a_noise_model_free_rows_are_counted_and_points_carry_covariances() -> None:
    from vibrissa.contact_detection import ContactDetector, wrench_covariance
    from vibrissa.units import RodScale

    rod = RodScale(0.05, 2e-5)
    sigma_f, sigma_m = 1e-6, 1e-8
    detector = ContactDetector(wrench_covariance(sigma_f, sigma_m))
    rng = np.random.default_rng(2)
    loaded_f0 = np.array([0.1, 0.0, 0.0]) * rod.force_n
    loaded_m0 = np.array([0.0, 0.05, 0.0]) * rod.moment_nm
    axial_f0 = np.array([0.0, 0.0, 0.1]) * rod.force_n  # the tip pushed home: no covariance

    def tick(seq: int, f0: np.ndarray, m0: np.ndarray) -> WhiskerWrenchArray:
        return WhiskerWrenchArray(
            stamp=float(seq), seq=seq, whisker_ids=["a", "b"], frame_ids=["a/clamp", "b/clamp"],
            f0=f0, m0=m0, pose_frame_id="world", clamp_position=np.zeros((2, 3)),
            clamp_orientation=np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)))

    noise = [rng.normal(size=(2, 6)) * np.r_[[sigma_f] * 3, [sigma_m] * 3] for _ in range(3)]
    ticks = [tick(0, noise[0][:, :3], noise[0][:, 3:]),  # both free
             tick(1, np.vstack([loaded_f0, axial_f0]) + noise[1][:, :3] * [[1], [0]],
                  np.vstack([loaded_m0, np.zeros(3)]) + noise[1][:, 3:] * [[1], [0]]),
             tick(2, noise[2][:, :3], noise[2][:, 3:])]  # both free again
    out = reconstruct_messages(ticks, rod, detector=detector)
    assert [o.free for o in out] == [2, 0, 2]
    contacts = out[1].contacts
    assert isinstance(contacts, ContactPointArray) and contacts.whisker_ids == ["a", "b"]
    assert out[0].contacts.whisker_ids == [] and out[2].contacts.whisker_ids == []
    cov = contacts.covariance
    assert cov is not None and cov.shape == (2, 3, 3)
    assert np.all(np.linalg.eigvalsh(cov[0]) >= 0) and np.trace(cov[0]) < 1e-6 * rod.length_m**2
    # the axial load has no derivative: it carries the rod's reach, and is counted
    np.testing.assert_array_equal(cov[1], np.eye(3) * rod.length_m**2)
    assert out[1].no_covariance == 1
    # without a noise model: no covariance, no free rows, noise rows are contacts
    plain = reconstruct_messages(ticks[:1], rod)
    assert plain[0].free == 0 and plain[0].contacts.covariance is None


_FINITE = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(["a", "b", "c"]),
                          st.lists(_FINITE, min_size=6, max_size=6),
                          st.lists(_FINITE, min_size=4, max_size=4),
                          st.lists(_FINITE, min_size=3, max_size=3)), min_size=1, max_size=8))
def test_the_noise_path_takes_any_finite_wrench_and_publishes_only_encodable_points(rows) -> None:
    # any finite wrench, quaternion and position a sender can put on the wire (the codec
    # refuses NaN and inf): no exception, every row accounted for once, every message the
    # node would publish encodes (finite points and covariances)
    from vibrissa.contact_detection import ContactDetector, wrench_covariance
    from vibrissa.units import RodScale

    detector = ContactDetector(wrench_covariance(1e-4, 1e-6))
    tick = WhiskerWrenchArray(
        stamp=0.0, seq=0, whisker_ids=[r[0] for r in rows], frame_ids=[f"{r[0]}/clamp" for r in rows],
        f0=[r[1][:3] for r in rows], m0=[r[1][3:] for r in rows], pose_frame_id="world",
        clamp_position=[r[3] for r in rows], clamp_orientation=[r[2] for r in rows])
    [out] = reconstruct_messages([tick], RodScale(0.05, 2e-5), detector=detector)
    contacts = out.contacts
    assert isinstance(contacts, ContactPointArray)
    assert (len(contacts.whisker_ids) + out.free + out.no_contact + out.bad_pose == len(rows))
    assert decode(encode(contacts)) is not None
    if len(contacts.whisker_ids):
        assert contacts.covariance is not None and np.isfinite(contacts.covariance).all()
