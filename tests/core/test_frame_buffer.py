"""Frames over time (tf2's semantics): lookups interpolate exactly as scipy's Slerp and a
straight line do, compose static mounts, and never extrapolate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from vibrissa.frame_buffer import (
    MAX_DEPTH,
    MAX_FRAMES,
    MAX_POSES,
    TIME_JUMP_POSES,
    ConnectivityError,
    ExtrapolationError,
    FrameBuffer,
)
from vibrissa.frames import Transform

RNG = np.random.default_rng(7)
T = np.cumsum(RNG.uniform(0.005, 0.02, 200))  # robot poses at an uneven rate
P = np.cumsum(RNG.normal(size=(200, 3)) * 0.01, axis=0)
R = Rotation.from_rotvec(np.cumsum(RNG.normal(size=(200, 3)) * 0.05, axis=0))
MOUNT = Transform(Rotation.from_euler("xyz", [0.3, -0.2, 1.1]), [0.05, -0.02, 0.01])


def robot_buffer(history_s: float = 100.0) -> FrameBuffer:
    buffer = FrameBuffer(history_s)
    buffer.set_static("base_link", "w0/clamp", MOUNT)
    for k in RNG.permutation(len(T)):  # out of order, as several streams may interleave
        buffer.add("world", "base_link", float(T[k]), Transform(R[k], P[k]))
    return buffer


def test_lookup_interpolates_as_slerp_and_a_straight_line_and_composes_the_mount() -> None:
    buffer = robot_buffer()
    stamps = RNG.uniform(T[0], T[-1], 500)
    R_ref = Slerp(T, R)(stamps) * MOUNT.rotation
    k = np.searchsorted(T, stamps) - 1
    frac = (stamps - T[k]) / (T[k + 1] - T[k])
    p_WR = P[k] + frac[:, None] * (P[k + 1] - P[k])
    p_ref = p_WR + Slerp(T, R)(stamps).apply(np.array(MOUNT.translation))
    for i, stamp in enumerate(stamps):
        X_WC = buffer.lookup("world", "w0/clamp", float(stamp))
        assert np.allclose(X_WC.translation, p_ref[i], rtol=0, atol=1e-14)
        assert (X_WC.rotation * R_ref[i].inv()).magnitude() < 1e-12
        # and the other way round: the world in the clamp frame
        X_CW = buffer.lookup("w0/clamp", "world", float(stamp))
        assert np.allclose((X_CW @ X_WC).matrix, np.eye(4), rtol=0, atol=1e-13)
    # at a sample: that pose (to rounding)
    X = buffer.lookup("world", "base_link", float(T[17]))
    assert np.allclose(X.matrix[:3], np.column_stack([R[17].as_matrix(), P[17]]), rtol=0,
                       atol=1e-15)
    # many stamps at once: the same as one by one
    p_many, R_many = buffer.lookup_many("world", "w0/clamp", stamps[:50])
    for i in range(50):
        X_WC = buffer.lookup("world", "w0/clamp", float(stamps[i]))
        assert np.allclose(p_many[i], X_WC.translation, rtol=0, atol=1e-15)
        assert (R_many[i] * X_WC.rotation.inv()).magnitude() < 1e-14


def test_a_lookup_does_not_depend_on_when_it_is_made() -> None:
    """At each pose's stamp, looked up as soon as that pose is the newest and again once all
    have arrived: the same pose bit for bit (a live node and a replay see the poses at
    different moments and must place a wrench identically)."""
    live, later = FrameBuffer(100.0), robot_buffer()
    live.set_static("base_link", "w0/clamp", MOUNT)
    first: list[tuple[np.ndarray, np.ndarray]] = []
    for k in range(len(T)):
        live.add("world", "base_link", float(T[k]), Transform(R[k], P[k]))
        rows = live.lookup_rows("world", ["w0/clamp"], [T[k]])
        assert rows.ok.all()
        first.append((rows.p[0], rows.q_xyzw[0]))
    rows = later.lookup_rows("world", ["w0/clamp"] * len(T), T)
    assert all(np.array_equal(rows.p[k], first[k][0]) and np.array_equal(rows.q_xyzw[k], first[k][1])
               for k in range(len(T)))


def test_a_straight_line_robot_moves_linearly_in_time() -> None:
    buffer = FrameBuffer()
    buffer.add("odom", "base_link", 1.0, Transform(translation=[0.0, 0.0, 0.0]))
    buffer.add("odom", "base_link", 3.0, Transform(translation=[2.0, -4.0, 0.0]))
    X = buffer.lookup("odom", "base_link", 2.5)
    assert X.translation.tolist() == [1.5, -3.0, 0.0]
    assert np.array_equal(X.R, np.eye(3))


def test_never_extrapolates_and_names_frames_and_times() -> None:
    buffer = robot_buffer()
    with pytest.raises(ExtrapolationError, match=r"cannot look up w0/clamp in world at "
                       r"t=.*base_link in world is known from t=.* s newer than the last pose"):
        buffer.lookup("world", "w0/clamp", float(T[-1]) + 0.05)
    with pytest.raises(ExtrapolationError, match="older than the kept history"):
        buffer.lookup("world", "w0/clamp", float(T[0]) - 1e-6)


def test_history_is_bounded() -> None:
    buffer = FrameBuffer(history_s=1.0)
    for k in range(300):  # 3 s at 100 Hz
        buffer.add("world", "base_link", 0.01 * k, Transform(translation=[0.01 * k, 0, 0]))
    buffer.lookup("world", "base_link", 2.5)
    with pytest.raises(ExtrapolationError, match="older than the kept history"):
        buffer.lookup("world", "base_link", 1.5)
    with pytest.raises(ValueError, match=r"at t=0.5: older than the kept history \(the newest "
                       r"pose is at t=2.99, 1 s are kept\); 2 more such"):
        buffer.add("world", "base_link", 0.5, Transform())
    assert buffer.newest("world", "base_link") == pytest.approx(2.99)


def test_a_stray_future_stamp_costs_a_few_poses_not_the_stream() -> None:
    """One pose stamped far ahead pushes the history past the stream; the stream's next poses
    are refused until TIME_JUMP_POSES of them in a row, each newer, start it again."""
    buffer = FrameBuffer(history_s=1.0)
    for k in range(10):
        assert buffer.add("world", "base_link", 0.01 * k, Transform(translation=[k, 0, 0])) is None
    assert buffer.add("world", "base_link", 1e300, Transform()) is None
    for k in range(10, 10 + TIME_JUMP_POSES - 1):
        with pytest.raises(ValueError, match="older than the kept history"):
            buffer.add("world", "base_link", 0.01 * k, Transform(translation=[k, 0, 0]))
    k = 10 + TIME_JUMP_POSES - 1
    assert buffer.add("world", "base_link", 0.01 * k, Transform(translation=[k, 0, 0])) == 1e300
    assert buffer.newest("world", "base_link") == 0.01 * k
    buffer.add("world", "base_link", 0.01 * (k + 1), Transform(translation=[k + 1, 0, 0]))
    p, _q = buffer.lookup_many("world", "base_link", [0.01 * k + 0.005])
    assert p[0] == pytest.approx([k + 0.5, 0.0, 0.0], abs=1e-9)
    with pytest.raises(ExtrapolationError):  # the poses before the jump are gone
        buffer.lookup_many("world", "base_link", [0.05])


def test_a_timeline_restarts_only_on_poses_in_a_row_each_newer() -> None:
    buffer = FrameBuffer(history_s=1.0)
    buffer.add("world", "base_link", 100.0, Transform())
    for stamp in (5.0, 4.0, 5.0, 3.0):  # old, but not moving forward: never a timeline
        with pytest.raises(ValueError, match="older than the kept history"):
            buffer.add("world", "base_link", stamp, Transform())
    buffer.add("world", "base_link", 100.5, Transform())  # a pose in the history breaks a run
    for stamp in (6.0, 7.0):
        with pytest.raises(ValueError, match="older than the kept history"):
            buffer.add("world", "base_link", stamp, Transform())
    assert buffer.add("world", "base_link", 8.0, Transform()) == 100.5
    assert buffer.newest("world", "base_link") == 8.0


def test_unknown_frames_and_a_second_tree_are_named() -> None:
    buffer = robot_buffer()
    with pytest.raises(ConnectivityError, match="unknown frame 'w9/clamp'"):
        buffer.lookup("world", "w9/clamp", float(T[5]))
    buffer.set_static("map", "landmark", Transform())
    with pytest.raises(ConnectivityError, match="landmark is under map, world under world"):
        buffer.lookup("world", "landmark", float(T[5]))


@pytest.mark.parametrize(("call", "message"), [
    (lambda b: b.set_static("odom", "w0/clamp", Transform()), "already has the parent base_link"),
    (lambda b: b.set_static("world", "base_link", Transform()), "is stamped already"),
    (lambda b: b.add("base_link", "w0/clamp", 0.0, Transform()), "is static already"),
    (lambda b: b.set_static("w0/clamp", "world", Transform()), "would close a loop"),
    (lambda b: b.add("world", "base_link", float("nan"), Transform()), "must be finite"),
])
def test_an_inconsistent_tree_is_refused(call, message) -> None:
    with pytest.raises(ValueError, match=message):
        call(robot_buffer())


def test_lookup_rows_equals_lookup_per_row_and_flags_rows_it_cannot_place() -> None:
    buffer = robot_buffer()
    mount_1 = Transform(Rotation.from_euler("y", -0.7), [0.0, 0.03, -0.01])
    buffer.set_static("base_link", "w1/clamp", mount_1)
    buffer.set_static("w1/clamp", "w1/sensor", Transform(Rotation.from_euler("z", 0.4), [0, 0, 0.002]))
    stamps = np.repeat(RNG.uniform(T[0], T[-1], 20), 3)  # ticks: rows share a stamp
    sources = ["w0/clamp", "w1/clamp", "w1/sensor"] * 20
    stamps[4] = T[-1] + 0.01  # newer than the last pose
    sources[7] = "w9/clamp"  # unknown
    rows = buffer.lookup_rows("world", sources, stamps)
    assert rows.ok.tolist() == [i not in (4, 7) for i in range(60)]
    for i in np.flatnonzero(rows.ok):
        X = buffer.lookup("world", sources[i], float(stamps[i]))
        assert np.allclose(rows.p[i], X.translation, rtol=0, atol=1e-15)
        assert (Rotation.from_quat(rows.q_xyzw[i]) * X.rotation.inv()).magnitude() < 1e-14
    assert np.isnan(rows.p[[4, 7]]).all()
    assert len(rows.errors) == 2
    assert "newer than the last pose" in rows.errors[1] or "newer than the last pose" in rows.errors[0]
    assert any("unknown frame 'w9/clamp'" in e for e in rows.errors)
    # what can be looked up, up to when
    assert buffer.newest("world", "w1/sensor") == T[-1]
    assert buffer.newest("base_link", "w1/sensor") == np.inf
    assert buffer.newest("world", "w9/clamp") is None


def test_a_tick_is_one_pose_composed_with_each_mount_bit_for_bit() -> None:
    """The tick's fast path (`mounted_poses`) gives the bits of the row-by-row kernels."""
    from vibrissa.frames import mounted_poses, quaternion_products, quaternion_rotate

    q_TA = Rotation.random(random_state=3).as_quat()
    p_TA = RNG.normal(size=3)
    q_AC, p_AC = Rotation.random(32, random_state=4).as_quat(), RNG.normal(size=(32, 3))
    p, q = mounted_poses(p_TA, q_TA, p_AC, q_AC)
    q_rows = np.tile(q_TA, (32, 1))
    assert np.array_equal(p, p_TA + quaternion_rotate(q_rows, p_AC))
    assert np.array_equal(q, quaternion_products(q_rows, q_AC))


def test_a_tick_under_a_pose_in_the_map_frame_has_the_bits_of_the_general_lookup() -> None:
    """A robot's clamps in the frame of its poses (one stamped edge) take one compiled call
    (`_Edge.mounted_at`); the bits are those of the chain composed edge by edge, between two
    poses, at a kept stamp and at the newest one."""
    buffer = robot_buffer()
    mounts = [f"w{j}/clamp" for j in range(1, 33)]
    for j, name in enumerate(mounts):
        buffer.set_static("base_link", name, Transform(Rotation.random(random_state=j),
                                                       RNG.normal(scale=0.05, size=3)))
    for stamp in (*RNG.uniform(T[0], T[-1], 20), T[0], T[57], T[-1]):
        rows = buffer.lookup_rows("world", mounts, float(stamp))
        assert rows.ok.all() and not rows.errors
        for i, name in enumerate(mounts):
            p, q = buffer._lookup("world", name, np.array([stamp]))  # edge by edge
            assert np.array_equal(rows.p[i], p[0]) and np.array_equal(rows.q_xyzw[i], q[0])


@pytest.mark.parametrize("sources", [
    ["w0/clamp", "w1/clamp", "w1/sensor"],  # one moving frame: the tick's one interpolation
    ["w0/clamp", "w9/clamp", "w1/sensor"],  # an unknown frame: row by row
    ["w0/clamp", "base_link", "landmark"],  # two anchors, one in another tree: row by row
])
def test_one_stamp_for_every_row_is_that_stamp_on_each_row(sources: list[str]) -> None:
    """A tick's stamp given once (a float) gives the bits of the same stamp on every row."""
    buffer = robot_buffer()
    buffer.set_static("base_link", "w1/clamp", Transform(Rotation.from_euler("y", -0.7),
                                                         [0.0, 0.03, -0.01]))
    buffer.set_static("w1/clamp", "w1/sensor", Transform(Rotation.from_euler("z", 0.4),
                                                         [0, 0, 0.002]))
    buffer.add("map", "landmark", 0.0, Transform())
    for stamp in (float(RNG.uniform(T[0], T[-1])), float(T[3]), float(T[-1]) + 0.01):
        one, each = (buffer.lookup_rows("world", sources, s) for s in (stamp, [stamp] * 3))
        assert one.ok.tolist() == each.ok.tolist() and one.errors == each.errors
        assert np.array_equal(one.p, each.p, equal_nan=True) and np.array_equal(one.q_xyzw,
                                                                                each.q_xyzw)
        one.ok[:] = False  # a row's ok is the caller's to change, not the next lookup's
        assert buffer.lookup_rows("world", sources, stamp).ok.tolist() == each.ok.tolist()
    assert buffer.lookup_rows("world", sources, float(T[3])).ok.tolist() == [
        s in ("w0/clamp", "w1/clamp", "w1/sensor", "base_link") for s in sources]


def test_newest_rows_is_the_oldest_of_the_known_frames() -> None:
    buffer = robot_buffer()
    buffer.set_static("base_link", "w1/clamp", MOUNT)
    assert buffer.newest_rows("world", ["w0/clamp", "w1/clamp"]) == T[-1]
    # a frame it does not know holds nothing back: waiting for poses will not make it known
    assert buffer.newest_rows("world", ["w0/clamp", "ghost/clamp"]) == T[-1]
    buffer.add("odom", "other", 1.0, Transform())
    assert buffer.newest_rows("world", ["w0/clamp", "other"]) is None  # not joined to world


@pytest.mark.slow
def test_a_flood_of_poses_or_of_frame_names_keeps_the_buffer_bounded() -> None:
    buffer = FrameBuffer(history_s=1e9)
    stamps = np.arange(MAX_POSES + 500) * 1e-6
    for t in stamps:
        buffer.add_pose("world", "base_link", float(t), [t, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    # the oldest beyond MAX_POSES are forgotten: the newest still look up, the oldest do not
    assert buffer.lookup("world", "base_link", float(stamps[-2])).translation[0] == stamps[-2]
    with pytest.raises(ExtrapolationError):
        buffer.lookup("world", "base_link", float(stamps[499]))
    buffer.lookup("world", "base_link", float(stamps[500]))
    names = FrameBuffer()
    for k in range(MAX_FRAMES - 1):  # world + 1023 children
        names.add_pose("world", f"f{k}", 0.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match=f"holds {MAX_FRAMES} frames already"):
        names.add_pose("world", "one_more", 0.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    names.add_pose("world", "f3", 1.0, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])  # known: fine


def test_a_stray_pose_in_another_parent_moves_the_frame_and_the_stream_takes_it_back() -> None:
    buffer = FrameBuffer()
    buffer.set_static("base_link", "w0/clamp", Transform(translation=[0.0, 0.0, 0.1]))
    identity = [0.0, 0.0, 0.0, 1.0]
    buffer.add_pose("odom", "base_link", 0.0, [5.0, 0.0, 0.0], identity)  # a stray one, first
    assert buffer.parent("base_link") == "odom"
    for k in range(1, 4):  # the robot's stream: base_link moves to world, odom is forgotten
        buffer.add_pose("world", "base_link", 0.1 * k, [0.1 * k, 0.0, 0.0], identity)
    assert buffer.parent("base_link") == "world" and "odom" not in buffer.frames
    X = buffer.lookup("world", "w0/clamp", 0.25)
    assert np.allclose(X.translation, [0.25, 0.0, 0.1], rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="would close a loop"):  # moved, but not into a loop
        buffer.add_pose("w0/clamp", "base_link", 0.4, [0.0, 0.0, 0.0], identity)
    with pytest.raises(ValueError, match="a static frame keeps it"):
        buffer.set_static("odom", "w0/clamp", Transform())


def test_a_flood_of_invented_parents_does_not_fill_the_buffer() -> None:
    buffer = FrameBuffer()
    identity = [0.0, 0.0, 0.0, 1.0]
    for k in range(3 * MAX_FRAMES):  # each moves base_link on; the one it left is dropped
        buffer.add_pose(f"junk{k}", "base_link", float(k), [0.0, 0.0, 0.0], identity)
    assert len(buffer.frames) == 2
    buffer.add_pose("world", "base_link", 0.0, [1.0, 0.0, 0.0], identity)
    assert buffer.frames == {"world", "base_link"}


def test_a_second_pose_at_a_kept_stamp_is_refused_and_the_first_kept() -> None:
    buffer = FrameBuffer()
    buffer.add_pose("world", "base_link", 1.0, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    buffer.add_pose("world", "base_link", 1.0, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])  # the same
    with pytest.raises(ValueError, match="another pose has this stamp already"):
        buffer.add_pose("world", "base_link", 1.0, [6.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    assert buffer.lookup("world", "base_link", 1.0).translation[0] == 1.0


def test_a_quaternion_of_any_finite_size_is_normalised() -> None:
    buffer = FrameBuffer()
    half = np.sqrt(0.5)
    for k, scale in enumerate((1e300, 1e-200, 3.0)):
        buffer.add_pose("world", f"f{k}", 0.0, [0.0, 0.0, 0.0], [0.0, 0.0, scale, scale])
        q = buffer.lookup("world", f"f{k}", 0.0).quaternion_xyzw
        assert np.allclose(np.abs(q), [0.0, 0.0, half, half], rtol=0, atol=1e-15), (scale, q)


def test_an_unknown_frame_error_stays_short_whatever_the_names() -> None:
    buffer = FrameBuffer()
    for k in range(200):
        buffer.add_pose("world", f"{k:04d}" + "x" * 50_000, 0.0, [0.0, 0.0, 0.0],
                        [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(ConnectivityError) as caught:
        buffer.lookup("world", "y" * 50_000, 0.0)
    assert len(str(caught.value)) < 1000 and "(201 in all)" in str(caught.value)
    rows = buffer.lookup_rows("world", ["z" * 50_000], [0.0])
    assert not rows.ok[0] and len(rows.errors[0]) < 1000


def test_poses_further_apart_than_max_gap_are_not_interpolated_between() -> None:
    buffer = FrameBuffer(max_gap_s=0.5)
    buffer.set_static("base_link", "w0/clamp", MOUNT)
    identity = [0.0, 0.0, 0.0, 1.0]
    for stamp in (0.0, 0.1, 0.2, 5.0):  # a stream, then one pose 4.8 s after it
        buffer.add_pose("world", "base_link", stamp, [stamp, 0.0, 0.0], identity)
    assert buffer.lookup("world", "base_link", 0.15).translation[0] == pytest.approx(0.15)
    assert buffer.lookup("world", "base_link", 5.0).translation[0] == 5.0  # on a pose: fine
    with pytest.raises(ExtrapolationError, match=r"at t=0.2 and t=5.0, are 4.8 s apart, more "
                                                 r"than max_gap_s \(0.5 s\)"):
        buffer.lookup("world", "w0/clamp", 1.0)
    rows = buffer.lookup_rows("world", ["w0/clamp"] * 2, [0.15, 1.0])
    assert rows.ok.tolist() == [True, False] and "more than max_gap_s" in rows.errors[0]
    assert not buffer.has_gap_rows("world", ["w0/clamp"], 0.15)
    assert buffer.has_gap_rows("world", ["w0/clamp"], 1.0)
    for stamp in np.arange(0.3, 5.0, 0.1):  # the stream fills the gap
        buffer.add_pose("world", "base_link", float(stamp), [float(stamp), 0.0, 0.0], identity)
    assert not buffer.has_gap_rows("world", ["w0/clamp"], 1.0)
    assert buffer.lookup("world", "base_link", 1.05).translation[0] == pytest.approx(1.05)
    unlimited = robot_buffer()  # the default: tf2's, any two poses are interpolated between
    assert unlimited.max_gap_s == np.inf and not unlimited.has_gap_rows("world", ["w0/clamp"], 1.0)


def test_a_chain_of_invented_parents_stops_at_max_depth() -> None:
    buffer = FrameBuffer()
    buffer.set_static("base_link", "w0/clamp", Transform())
    identity = [0.0, 0.0, 0.0, 1.0]
    buffer.add_pose("a1", "base_link", 0.0, [0.0, 0.0, 0.0], identity)
    for k in range(2, MAX_DEPTH):  # a_k above a_(k-1): MAX_DEPTH edges from w0/clamp up
        buffer.add_pose(f"a{k}", f"a{k - 1}", 0.0, [0.0, 0.0, 0.0], identity)
    with pytest.raises(ValueError, match=f"deeper than {MAX_DEPTH}"):
        buffer.add_pose(f"a{MAX_DEPTH}", f"a{MAX_DEPTH - 1}", 0.0, [0.0, 0.0, 0.0], identity)
    assert buffer.lookup(f"a{MAX_DEPTH - 1}", "w0/clamp", 0.0).translation.tolist() == [0, 0, 0]
