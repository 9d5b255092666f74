"""Step 2 of a batch of ticks (socket-free): SI scaling, clamp poses, counts, batches that do
not change a row's bits, the noise model."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.streaming.test_live_tick import recorder
from vibrissa.contact_detection import ContactDetector, wrench_covariance
from vibrissa.frames import quaternion_matrices
from vibrissa.msgs import ContactPointArray, WhiskerWrenchArray
from vibrissa.msgs.codec import decode, encode
from vibrissa.nodes.wrench_source import tick_messages
from vibrissa.reconstruct import reconstruct
from vibrissa.streaming import Reconstructed, reconstruct_messages
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import SweepRun, Trail, first_contact, simulate_sweeps
from vibrissa.ticks import array_ticks
from vibrissa.units import RodScale

UNIT_ROD = RodScale()


@dataclass
class Wrench:
    """One whisker's sample, sent as a tick of one row (`Wrench.tick`)."""
    stamp: float
    seq: int
    clamp_position: np.ndarray
    clamp_orientation: np.ndarray
    f0: np.ndarray
    m0: np.ndarray
    whisker_id: str = "w"

    def tick(self) -> WhiskerWrenchArray:
        return WhiskerWrenchArray(
            stamp=self.stamp, seq=self.seq, whisker_ids=[self.whisker_id],
            frame_ids=[f"{self.whisker_id}/clamp"], pose_frame_id="world",
            clamp_position=[self.clamp_position], clamp_orientation=[self.clamp_orientation],
            f0=[self.f0], m0=[self.m0])


@dataclass(frozen=True)
class Point:
    """The one row of a tick's ContactPointArray."""
    seq: int
    whisker_id: str
    point: tuple[float, ...]
    s1: float
    phase: int
    force: tuple[float, ...]
    status: int


@dataclass
class WrenchesResult:
    """The points of a batch of one-row ticks, and its counts."""
    contacts: list[Point]
    no_contact: int
    bad_pose: int


def reconstruct_wrenches(wrenches: list[Wrench], rod: RodScale = UNIT_ROD) -> WrenchesResult:
    """The stream's one path on a batch of one-row ticks, its outcomes summed."""
    outcomes = reconstruct_messages([w.tick() for w in wrenches], rod)
    points = [Point(c.seq, c.whisker_ids[0], tuple(c.point[0]), float(c.s1[0]), int(c.phase[0]),
                    tuple(c.force[0]), int(c.status[0]))
              for c in (o.contacts for o in outcomes) if c.whisker_ids]
    return WrenchesResult(points, sum(o.no_contact for o in outcomes),
                          sum(o.bad_pose for o in outcomes))


def reconstruct_arrays(ticks: list[WhiskerWrenchArray], rod: RodScale = UNIT_ROD) -> list[Reconstructed]:
    """The stream's one path on a batch of ticks."""
    return reconstruct_messages(ticks, rod)


def reconstruct_array(tick: WhiskerWrenchArray, rod: RodScale = UNIT_ROD) -> Reconstructed:
    """The stream's one path on one tick."""
    return reconstruct_messages([tick], rod)[0]


def sweep_arrays(run: SweepRun, whisker_ids: list[str], frame_id: str, rod: RodScale
                 ) -> Iterator[WhiskerWrenchArray]:
    """The wrench source's one path, the sweeps as one rigid array."""
    return tick_messages(array_ticks(run, rod), whisker_ids, frame_id, array=True)  # type: ignore[return-value]


def _wrenches(n: int = 64, seed: int = 3) -> list[Wrench]:
    """Wrenches of a rod touched at random points of a bent plane (some without contact)."""
    rng = np.random.default_rng(seed)
    p0 = rng.uniform(-1, 1, (n, 3))
    f0, m0 = recorder().single_contact(rng.normal(0, 1, (n, 3)), rng.normal(0, 1, (n, 3)))
    f0[0] = 0.0  # no force: no contact
    m0[0] = 0.0
    return [Wrench(float(i), i, p0[i], np.array([0.0, 0.0, 0.0, 1.0]), f0[i], m0[i])
            for i in range(n)]


def _to_si(wrenches: list[Wrench], length: float, ei: float, quaternion: Any = None
           ) -> list[Wrench]:
    """The wrenches of a rod of length ``length`` and stiffness ``ei`` (written out, not RodScale)."""
    return [Wrench(w.stamp, w.seq, w.clamp_position * length,
                   w.clamp_orientation if quaternion is None else np.asarray(quaternion, float),
                   w.f0 * ei / length**2, w.m0 * ei / length) for w in wrenches]


def test_batch_equals_library_and_counts_no_contact() -> None:
    wrenches = _wrenches()
    result = reconstruct_wrenches(wrenches)
    rec = reconstruct(np.stack([w.clamp_position for w in wrenches]),
                      np.stack([w.f0 for w in wrenches]), np.stack([w.m0 for w in wrenches]))
    assert result.no_contact == int(np.count_nonzero(~rec.valid)) >= 1
    assert [c.seq for c in result.contacts] == np.flatnonzero(rec.valid).tolist()
    for contact in result.contacts:
        np.testing.assert_allclose(contact.point, rec.point[contact.seq], rtol=0, atol=1e-12)
        np.testing.assert_allclose(contact.force, rec.force[contact.seq], rtol=0, atol=1e-12)
        assert contact.s1 == pytest.approx(rec.s1[contact.seq], abs=1e-12)
        assert int(contact.status) == int(rec.status[contact.seq])
        assert int(contact.phase) == int(rec.phase[contact.seq])


@pytest.mark.parametrize("quaternion", [[0.0, 0.0, 0.0, 1.0], [0.3, -0.2, 0.5, 2.0]])
def test_a_wrench_gives_the_same_point_bit_for_bit_in_any_batch(quaternion) -> None:
    # Batches follow arrival timing; a bag replay must still give the live run's points.
    length, ei = 0.04, 3e-3
    wrenches = _to_si(_wrenches(48), length, ei, quaternion)
    wrenches[5] = Wrench(0.0, 5, np.zeros(3), np.zeros(4), np.array([1.0, 0, 0]),
                         np.array([0, 1.0, 0]))
    whole = reconstruct_wrenches(wrenches, RodScale(length, ei))
    parts = [reconstruct_wrenches(wrenches[i:i + 3], RodScale(length, ei))
             for i in range(0, len(wrenches), 3)]
    assert whole.bad_pose == sum(p.bad_pose for p in parts) == 1
    assert whole.no_contact == sum(p.no_contact for p in parts) >= 1
    assert [c for p in parts for c in p.contacts] == whole.contacts


def test_a_tick_of_strided_read_only_arrays_gives_the_same_points_and_no_new_compilation(
) -> None:
    """A message may hold read-only views that are not contiguous (f0 and m0 the halves of a
    read-only (N, 6) block): Step 2 takes them as it takes a decoded tick's, the same points,
    and no other compiled variant of its kernel (which would compile in a live node)."""
    from vibrissa.reconstruct_rods import rows_si_tallied

    wrenches = _wrenches(32)
    block = np.hstack([np.stack([w.f0 for w in wrenches]), np.stack([w.m0 for w in wrenches])])
    block.flags.writeable = False
    pose = {"pose_frame_id": "world", "whisker_ids": [f"w{i}" for i in range(32)],
            "frame_ids": [f"w{i}/clamp" for i in range(32)],
            "clamp_position": np.stack([w.clamp_position for w in wrenches]),
            "clamp_orientation": np.stack([w.clamp_orientation for w in wrenches])}
    strided = WhiskerWrenchArray(stamp=0.0, seq=0, f0=block[:, :3], m0=block[:, 3:], **pose)
    assert not strided.f0.flags.c_contiguous  # taken as it is
    decoded = decode(encode(strided))
    expected = reconstruct_array(decoded)
    compiled = len(rows_si_tallied.signatures)
    got = reconstruct_array(strided)
    assert len(rows_si_tallied.signatures) == compiled
    assert encode(got.contacts) == encode(expected.contacts)
    assert got.no_contact == expected.no_contact >= 1


def test_si_scaling_round_trip() -> None:
    """Scaling the wrench to a rod of length L and stiffness EI scales the point by L."""
    length, ei = 0.04, 3e-3
    unit = _wrenches()
    a, b = reconstruct_wrenches(unit), reconstruct_wrenches(_to_si(unit, length, ei),
                                                            RodScale(length, ei))
    assert len(a.contacts) == len(b.contacts)
    for ca, cb in zip(a.contacts, b.contacts, strict=True):
        np.testing.assert_allclose(cb.point, np.multiply(ca.point, length), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(cb.force, np.multiply(ca.force, ei / length**2), rtol=1e-12, atol=1e-15)
        assert cb.s1 == pytest.approx(ca.s1 * length, rel=1e-12)


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
    turned = [Wrench(w.stamp, w.seq, w.clamp_position, q * 2.0, w.f0, w.m0)
              for w in straight]  # not unit: normalised
    a, b = reconstruct_wrenches(straight), reconstruct_wrenches(turned)
    assert [c.seq for c in a.contacts] == [c.seq for c in b.contacts]
    for ca, cb in zip(a.contacts, b.contacts, strict=True):
        p0 = straight[ca.seq].clamp_position
        np.testing.assert_allclose(np.subtract(cb.point, p0), R @ (ca.point - p0), atol=1e-12)
        np.testing.assert_allclose(cb.force, R @ ca.force, atol=1e-12)


def test_zero_quaternion_is_counted_as_bad_pose() -> None:
    w = _wrenches(3)
    bad = Wrench(0.0, 9, w[1].clamp_position, np.zeros(4), w[1].f0, w[1].m0)
    result = reconstruct_wrenches([w[1], bad])
    assert result.bad_pose == 1
    assert 9 not in [c.seq for c in result.contacts]


def _tick(wrenches: list[Wrench], seq: int = 4) -> WhiskerWrenchArray:
    """The wrenches as the rows of one array message."""
    return WhiskerWrenchArray(
        stamp=2.5, seq=seq, pose_frame_id="world",
        frame_ids=[f"w{w.seq}/clamp" for w in wrenches], whisker_ids=[f"w{w.seq}" for w in wrenches],
        clamp_position=np.stack([w.clamp_position for w in wrenches]),
        clamp_orientation=np.stack([w.clamp_orientation for w in wrenches]),
        f0=np.stack([w.f0 for w in wrenches]), m0=np.stack([w.m0 for w in wrenches]))


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
    wrenches = [Wrench(w.stamp, w.seq, w.clamp_position * length, q[i], w.f0 * ei / length**2,
                       w.m0 * ei / length, whisker_id=f"w{w.seq}") for i, w in enumerate(unit)]
    result = reconstruct_array(_tick(wrenches), rod)
    per_wrench = reconstruct_wrenches(wrenches, rod)
    got = result.contacts
    assert (got.stamp, got.seq, got.frame_id) == (2.5, 4, "world")
    assert got.whisker_ids == [c.whisker_id for c in per_wrench.contacts]
    assert (result.no_contact, result.bad_pose) == (per_wrench.no_contact, per_wrench.bad_pose)
    assert result.bad_pose == 1 and result.no_contact >= 1 and "w7" not in got.whisker_ids
    # the library on the dimensionless rows, one array call
    rows = [int(w[1:]) for w in got.whisker_ids]
    good = [i for i in range(32) if i != 7]
    R = Rotation.from_quat(q[good]).as_matrix()  # scipy's (x, y, z, w), normalised first
    np.testing.assert_allclose(quaternion_matrices(q[good])[0], R, rtol=0, atol=2e-15)
    rec = reconstruct(np.stack([unit[i].clamp_position for i in good]),
                      np.stack([unit[i].f0 for i in good]), np.stack([unit[i].m0 for i in good]), R)
    keep = [good.index(i) for i in rows]
    assert rec.valid.sum() == len(rows)
    np.testing.assert_allclose(got.point, rec.point[keep] * length, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got.s1, rec.s1[keep] * length, rtol=1e-12)
    np.testing.assert_allclose(got.force, rec.force[keep] * ei / length**2, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(got.phase, rec.phase[keep])
    np.testing.assert_array_equal(got.status, rec.status[keep])
    # one wrench at a time: the same rows, the same bits
    np.testing.assert_array_equal(got.point, [c.point for c in per_wrench.contacts])
    np.testing.assert_array_equal(got.force, [c.force for c in per_wrench.contacts])
    assert got.s1.tolist() == [c.s1 for c in per_wrench.contacts]
    assert got.phase.tolist() == [int(c.phase) for c in per_wrench.contacts]


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
        rows = [Wrench(0.0, i, tick.clamp_position[i], tick.clamp_orientation[i], tick.f0[i],
                       tick.m0[i], whisker_id=tick.whisker_ids[i])
                for i in range(len(tick.whisker_ids))]
        one_by_one = [reconstruct_wrenches([row], rod) for row in rows]
        contacts = [c for r in one_by_one for c in r.contacts]
        assert result.contacts.whisker_ids == [c.whisker_id for c in contacts]
        assert (result.no_contact, result.bad_pose) == (
            sum(r.no_contact for r in one_by_one), sum(r.bad_pose for r in one_by_one))
        np.testing.assert_array_equal(result.contacts.point.reshape(-1, 3),
                                      np.reshape([c.point for c in contacts], (-1, 3)))


def test_a_result_that_overflows_is_counted_as_no_contact_not_published() -> None:
    """Finite inputs near the float limit, rotated, once gave a valid row with an infinite
    force: encoding it raised inside the node's publish and the node exited."""
    q = np.array([0.79623251, 0.10475497, -0.46211826, -0.37614744])
    p0 = np.array([-1.30861562e308, 1.49614536e308, 1.16312171e308])
    f0 = np.array([1.15378996e308, -9.47832554e307, 1.11655258e308])
    m0 = np.array([4.86599216e153, 9.48589037e153, 5.07180288e153])
    wrench = Wrench(1.0, 3, p0, q, f0, m0).tick()
    decode(encode(wrench))  # the codec takes it: every value is finite
    single = reconstruct_messages([wrench])[0]
    array = reconstruct_messages([WhiskerWrenchArray(
        stamp=1.0, seq=3, pose_frame_id="world",
        frame_ids=["w/clamp", "v/clamp"], whisker_ids=["w", "v"], clamp_position=[p0, p0],
        clamp_orientation=[q, q], f0=[f0, f0], m0=[m0, np.zeros(3)])])[0]
    assert (single.contacts.whisker_ids, single.no_contact, single.bad_pose) == ([], 1, 0)
    assert array.contacts is not None and array.contacts.whisker_ids == []
    assert (array.no_contact, array.bad_pose) == (2, 0)
    encode(array.contacts)  # what is published can be encoded


def test_with_a_noise_model_free_rows_are_counted_and_points_carry_covariances() -> None:

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


def test_step2_builds_its_points_unchecked_as_the_checked_constructor_would() -> None:
    # ContactPointArray.unchecked: the same message and bytes as the constructor's checks make
    # of the same values, for ticks of every row, of some rows, and with covariances
    rod = RodScale(0.05, 2e-5)
    rng = np.random.default_rng(4)
    n = 6
    f0 = np.tile([0.1 * rod.force_n, 0.0, 0.0], (n, 1)) * rng.uniform(0.5, 1.5, (n, 1))
    m0 = np.tile([0.0, 0.05 * rod.moment_nm, 0.0], (n, 1)) * rng.uniform(0.5, 1.5, (n, 1))
    partial_f0 = f0.copy()
    partial_f0[2] = 0.0
    partial_m0 = m0.copy()
    partial_m0[2] = 0.0
    ticks = [WhiskerWrenchArray(
        stamp=0.5 * k, seq=k, whisker_ids=[f"w{j}" for j in range(n)],
        frame_ids=[f"w{j}/clamp" for j in range(n)], f0=f, m0=m, pose_frame_id="world",
        clamp_position=rng.uniform(-0.1, 0.1, (n, 3)),
        clamp_orientation=Rotation.random(n, random_state=k).as_quat())
        for k, (f, m) in enumerate([(f0, m0), (partial_f0, partial_m0)])]
    detector = ContactDetector(wrench_covariance(1e-6, 1e-8))
    outcomes = [*reconstruct_messages(ticks[:1], rod), *reconstruct_messages(ticks, rod),
                *reconstruct_messages(ticks, rod, detector=detector)]
    assert [len(o.contacts.whisker_ids) for o in outcomes] == [n, n, n - 1, n, n - 1]
    for outcome in outcomes:
        contacts = outcome.contacts
        checked = ContactPointArray(**vars(contacts))
        assert checked == contacts and encode(checked) == encode(contacts)
        for name, value in vars(contacts).items():
            if isinstance(value, np.ndarray):
                assert not value.flags.writeable, name
                assert value.dtype == getattr(checked, name).dtype, name


def test_every_row_of_a_mixed_batch_is_counted_once() -> None:
    """Batches of ticks that mix rows with and without a clamp pose, whiskers the robot
    description does not have, rows in another frame than their clamp's, stamps the robot's
    poses do not cover and free rows: every row lands in exactly one count, and every point
    is a known whisker's, finite."""
    from vibrissa.frames import Transform, clamp_frame
    from vibrissa.scene import Whisker
    from vibrissa.streaming import RodTable, robot_frames

    robot = [Whisker(f"w{j}", 0.03 + 0.005 * j, 1e-4 * (1 + j), Transform.from_xyz_rpy(
        [0.0, 0.01 * j, 0.0], [0.0, 0.3 * j, 0.0])) for j in range(4)]
    table = RodTable({w.name: w.scale for w in robot})
    frames = robot_frames(robot, history_s=10.0)
    for stamp in (0.0, 1.0):
        frames.add("world", "base_link", stamp, Transform.from_xyz_rpy([stamp, 0, 0], [0, 0, 0]))
    rng = np.random.default_rng(5)
    for trial in range(200):
        ticks = []
        for _ in range(int(rng.integers(1, 4))):
            n = int(rng.integers(1, 8))
            names = [str(rng.choice(["w0", "w1", "w2", "w3", "ghost"])) for _ in range(n)]
            in_frames = [clamp_frame(w) if rng.random() < 0.8 else clamp_frame("w0")
                         for w in names]
            posed: dict[str, Any] = {}
            if rng.random() < 0.4:
                posed = {"pose_frame_id": "world", "clamp_position": rng.normal(size=(n, 3)),
                         "clamp_orientation": Rotation.random(n, rng).as_quat()}
            ticks.append(WhiskerWrenchArray(
                stamp=float(rng.choice([0.5, 2.0])), seq=len(ticks), whisker_ids=names,
                frame_ids=in_frames, f0=rng.normal(size=(n, 3)) * 1e-3 * (rng.random((n, 1)) < 0.9),
                m0=rng.normal(size=(n, 3)) * 1e-5, **posed))
        detector = ContactDetector(np.eye(6) * 1e-12) if trial % 2 else None
        outcomes = reconstruct_messages(ticks, table, frames, detector=detector)
        for tick, out in zip(ticks, outcomes, strict=True):
            counted = (len(out.contacts.whisker_ids) + out.no_contact + out.bad_pose
                       + out.no_pose + out.unknown_whisker + out.wrong_frame + out.free)
            assert counted == len(tick.whisker_ids)
            for w, point in zip(out.contacts.whisker_ids, out.contacts.point, strict=True):
                assert w in table and np.isfinite(point).all()
