"""The wait for a robot pose and the poses' frame buffer (socket-free): ticks in clamp frames
placed through the robot's poses, held poses, timeouts, refused poses, warnings."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from vibrissa.frames import Transform
from vibrissa.msgs import ContactPointArray, RobotPose, WhiskerWrenchArray
from vibrissa.nodes.reconstructor import BatchCollector
from vibrissa.reconstruct import reconstruct_si
from vibrissa.scene import Whisker
from vibrissa.streaming import (
    BACKLOG_TIMEOUTS,
    PoseWait,
    Warnings,
    pose_handler,
    reconstruct_messages,
    robot_frames,
)
from vibrissa.wire.transport import Header, Received


def _rx(msg: Any) -> Received:
    return Received("/w", msg, b"", Header(1, 0), 0.0)


# -- wrenches in clamp frames, placed through the robot's poses ----------------------------------


def _robot_wrench(stamp: float, seq: int, whiskers: tuple[str, ...] = ("a", "b")) -> WhiskerWrenchArray:
    n = len(whiskers)
    return WhiskerWrenchArray(stamp=stamp, seq=seq, whisker_ids=list(whiskers),
                              frame_ids=[f"{w}/clamp" for w in whiskers],
                              f0=np.tile([2e-3, 0.0, 0.0], (n, 1)), m0=np.tile([0.0, 5e-5, 0.0], (n, 1)))


def test_a_pose_stream_that_stops_makes_wrenches_no_pose_after_the_timeout() -> None:

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
    assert wait.wait_s() == pytest.approx(0.5 * BACKLOG_TIMEOUTS)  # unless a wrench comes
    now[0] += 0.49
    wait.add([_robot_wrench(0.03, 3)])  # the wrenches go on
    assert wait.take() == [] and wait.wait_s() == pytest.approx(0.5 * BACKLOG_TIMEOUTS - 0.49)
    now[0] += 0.02  # the pose stream has stopped: after pose_timeout_s, on without a pose,
    assert wait.take() == []  # once a wrench came that long after them
    wait.add([_robot_wrench(0.04, 4)])
    assert wait.wait_s() == 0.0
    late = wait.take()
    assert [m.seq for m in late] == [1, 2] and len(wait) == 2
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


def test_a_sensor_that_stalls_between_a_wrench_and_its_pose_loses_no_pose() -> None:
    """The sensor's process sent a wrench, then was not scheduled for 2 s (a loaded machine)
    before the pose that covers it: the node saw its queue empty all along, but no wrench came
    after it, so it waits for the pose and gets it. A sensor silent for good ends the wait
    after ``BACKLOG_TIMEOUTS`` x ``pose_timeout_s``; the wrenches' end after ``pose_timeout_s``."""
    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0]))]
    frames = robot_frames(whiskers)
    now = [100.0]
    wait = PoseWait(frames, "world", timeout_s=0.5, clock=lambda: now[0])
    frames.add("world", "base_link", 0.0, Transform())
    wait.add([_robot_wrench(0.005, 1, ("a",))])
    for _ in range(20):  # 2 s, the queue seen empty every 0.1 s
        now[0] += 0.1
        assert wait.take(drained_at=now[0]) == []
    frames.add("world", "base_link", 0.01, Transform())  # the pose, at last
    (ready,) = wait.take(drained_at=now[0])
    (out,) = reconstruct_messages([ready], {w.name: w.scale for w in whiskers}, frames, "world")
    assert ready.seq == 1 and out.no_pose == 0
    # silent for good: no pose, no wrench
    wait.add([_robot_wrench(0.02, 2, ("a",))])
    now[0] += 0.5 * BACKLOG_TIMEOUTS - 0.01
    assert wait.take(drained_at=now[0]) == [] and wait.wait_s() == pytest.approx(0.01)
    now[0] += 0.02
    assert [m.seq for m in wait.take(drained_at=now[0])] == [2]
    # the wrenches' EndOfStream: no wrench will come, pose_timeout_s is the wait
    wait.add([_robot_wrench(0.03, 3, ("a",))])
    wait.end()
    assert wait.wait_s() == pytest.approx(0.5)
    now[0] += 0.49
    assert wait.take(drained_at=now[0]) == []
    now[0] += 0.02
    assert [m.seq for m in wait.take(drained_at=now[0])] == [3]


def test_a_pose_queued_behind_a_backlog_is_waited_for_not_counted_missing() -> None:
    """The node reads its input 0.3 s per message (slow next to pose_timeout_s 0.5 s): the
    pose that covers the first wrenches is 8 messages behind them in the queue. Every wrench
    gets its pose; only once the queue is empty and the timeout has passed are the wrenches
    past the last pose no_pose, and a backlog that never drains ends the wait at 10 timeouts."""
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
    on_pose = pose_handler(frames, counters, Warnings("/robot/reconstructor"))
    rods = {w.name: w.scale for w in whiskers}
    batches = BatchCollector(receive, drain_limit=2, max_batch=3, on_pose=on_pose,
                             clock=lambda: now[0])
    taken: list[tuple[int, int]] = []  # (seq, no_pose rows) as each wrench is let through
    while queue:
        batch, _ = batches.collect(0.0)
        wait.add(batch)
        ready = wait.take(batches.drained_at)
        if ready:
            taken += [(m.seq, out.no_pose) for m, out in
                      zip(ready, reconstruct_messages(ready, rods, frames, "world"), strict=True)]
    # each waited up to 2.4 s for its pose, and it came: none is no_pose
    assert taken == [(seq, 0) for seq in range(1, 9)]
    wait.end()  # the wrenches' EndOfStream: no wrench comes after seq 9
    batches.collect(0.0)
    assert batches.drained_at == now[0] and len(wait) == 1  # seq 9 (0.2 s) is past the last pose
    now[0] += 0.5
    assert wait.take(batches.drained_at) == []  # not seen empty since it waited 0.5 s
    batches.collect(0.0)
    (late,) = wait.take(batches.drained_at)
    assert late.seq == 9 and reconstruct_messages([late], rods, frames, "world")[0].no_pose == 2
    # a backlog that never drains: wait BACKLOG_TIMEOUTS x timeout_s, not forever
    wait.add([_robot_wrench(0.3, 10)])
    now[0] += 0.5 * BACKLOG_TIMEOUTS - 0.01
    assert wait.take(drained_at=-math.inf) == []
    now[0] += 0.02
    assert [m.seq for m in wait.take(drained_at=-math.inf)] == [10]


def test_a_pose_that_came_while_the_node_was_not_scheduled_is_not_missing() -> None:
    """The node saw its queue empty with a wrench waiting, then was not scheduled for 2 s (a
    loaded machine) while the wrench's pose arrived: the wrench has waited past
    ``pose_timeout_s``, but the queue has not been seen empty since, so it waits for the pose
    the next read brings, and gets it."""
    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0]))]
    frames = robot_frames(whiskers)
    now = [100.0]
    queue: list[Any] = [_robot_wrench(0.005, 1, ("a",))]

    def pose(stamp: float) -> RobotPose:
        return RobotPose(stamp=stamp, frame_id="world", child_frame_id="base_link",
                         position=[stamp, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0])

    def receive(timeout_s: float) -> Received | None:
        return _rx(queue.pop(0)) if queue else None

    counters = {"robot_poses": 0, "bad_robot_pose": 0}
    batches = BatchCollector(receive, drain_limit=15, max_batch=100, clock=lambda: now[0],
                             on_pose=pose_handler(frames, counters, Warnings("/robot/x")))
    wait = PoseWait(frames, "world", timeout_s=0.5, clock=lambda: now[0])
    frames.add("world", "base_link", 0.0, Transform())  # a pose before the wrench's stamp
    wait.add(batches.collect(0.0)[0])
    assert wait.take(batches.drained_at) == [] and batches.drained_at == now[0]
    now[0] += 2.0  # not scheduled; meanwhile the pose arrives
    queue.append(pose(0.01))
    assert wait.take(batches.drained_at) == []
    wait.add(batches.collect(0.0)[0])
    (ready,) = wait.take(batches.drained_at)
    (out,) = reconstruct_messages([ready], {w.name: w.scale for w in whiskers}, frames, "world")
    assert ready.seq == 1 and out.no_pose == 0 and counters["robot_poses"] == 1


def test_held_poses_wait_until_a_wrench_needs_them_and_give_the_same_points() -> None:
    """A tick that comes with the next pose (a pose stream ahead of the wrenches) goes out
    before that pose is handled; a tick that needs a held pose gets it at once, also past its
    timeout (a held pose is not a missing one); the points equal those of poses applied as
    they came, bit for bit."""
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
                    on_pose=pose_handler(frames, counters, Warnings("/robot/reconstructor")))
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
    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0])),
                Whisker("b", 0.03, 9e-5, Transform.from_xyz_rpy([0, -0.02, 0.01], [1.5, 0, 0]))]
    frames = robot_frames(whiskers, history_s=10.0)
    counters = {"robot_poses": 0, "bad_robot_pose": 0}
    now = [0.0]
    wait = PoseWait(frames, "world", timeout_s=0.5, lead_s=lead_s, clock=lambda: now[0],
                    on_pose=pose_handler(frames, counters, Warnings("/robot/reconstructor")))
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
    now[0] += 0.01  # held for the timeout with no wrench coming: they go in, but only once
    wait.apply_poses(drained_at=-math.inf)  # no input waits behind (queued wrenches may need the
    assert counters["robot_poses"] == 302  # history they would push out)
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
                             on_pose=pose_handler(frames, counters, Warnings("/robot/reconstructor")))
    wait = PoseWait(frames, "world", timeout_s=0.5)
    rods = {w.name: w.scale for w in whiskers}
    no_pose = placed_ticks = 0
    while queue or len(wait):
        batch, _ = batches.collect(0.0)
        wait.add(batch)
        ready = wait.take(batches.drained_at)
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

    warn = Warnings("/robot/reconstructor")
    with caplog.at_level("WARNING", logger="vibrissa.streaming.stream"):
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

    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0]))]
    frames = robot_frames(whiskers)
    counters = dict.fromkeys(("robot_poses", "bad_robot_pose", "pose_time_jumps",
                              "pose_reparents"), 0)
    on_pose = pose_handler(frames, counters, Warnings("/robot/reconstructor"))
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
    whiskers = [Whisker("a", 0.05, 2e-4, Transform.from_xyz_rpy([0, -0.02, 0], [1.2, 0, 0]))]
    frames = robot_frames(whiskers, max_gap_s=1.0)
    counters = dict.fromkeys(("robot_poses", "bad_robot_pose", "pose_time_jumps",
                              "pose_reparents"), 0)
    on_pose = pose_handler(frames, counters, Warnings("/robot/reconstructor"))

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
