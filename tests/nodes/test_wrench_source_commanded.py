"""The commanded robot (socket-free): the wrench source in mode ``scene`` with ``path_topic``
drives the segments that arrive, each sample simulated as it comes; a commanded path equal to
the scene's fixed path gives its wrenches (within 1e-12 N: the step comes from the speed
limits) and its poses; two segments appended are one segment of both; bad commands are
counted and logged and the node goes on; the stream ends on the commander's EndOfStream."""

from __future__ import annotations

import dataclasses
import json
import logging
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.nodes.test_scene_results import FakePublisher
from vibrissa.formats.scene_file import load_scene
from vibrissa.formats.scene_results import write_results
from vibrissa.msgs import EndOfStream, Message, PathSegment, RobotPose, WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.nodes.wrench_source import WrenchSourceParams, run_commanded, scene_stream
from vibrissa.scene import SamplePhase, robot_path, simulate

DEMO = Path(__file__).parents[2] / "launch" / "robot" / "scene.yaml"
PATH = "/robot/path"


@dataclass
class Delivered:
    msg: Message


@dataclass
class FakeCommands:
    """The path topic: the commands handed over one per ``receive``."""

    queue: deque[Message]

    def receive(self, timeout_s: float) -> Delivered | None:
        return Delivered(self.queue.popleft()) if self.queue else None


@dataclass
class CommandedNode:
    """What `run_commanded` uses of a `vibrissa.runtime.Node`, without sockets."""

    commands: list[Message]
    fqn: str = "/robot/wrench_source"
    stop_requested: bool = False
    publishers: dict[str, FakePublisher] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)

    def create_publisher(self, topic: str, *args: Any, **kwargs: Any) -> FakePublisher:
        return self.publishers.setdefault(topic, FakePublisher(topic))

    def create_subscriber(self, topics: dict[str, Any], **kwargs: Any) -> FakeCommands:
        assert list(topics) == [PATH] and topics[PATH] is PathSegment
        return FakeCommands(deque(self.commands))

    def resolve(self, topic: str) -> str:
        return topic

    def set_state(self, state: str, detail: str = "") -> None:
        pass


def params(**kwargs: Any) -> WrenchSourceParams:
    values: dict[str, Any] = {"path_topic": PATH, "pose_rate_hz": 0.0, "epoch_s": 1000.0}
    return WrenchSourceParams(mode="scene", scene=str(DEMO), **(values | kwargs))


def segment(position: Any, orientation: Any, segment_id: int = 0, mode: str = "append",
            speed_mps: float = 0.1, turn_rate_rps: float = 1.0, frame_id: str = "world"
            ) -> PathSegment:
    return PathSegment(stamp=0.0, frame_id=frame_id, segment_id=segment_id, mode=mode,
                       position=position, orientation=orientation, speed_mps=speed_mps,
                       turn_rate_rps=turn_rate_rps)


def end() -> EndOfStream:
    return EndOfStream(stamp=0.0, source="/explorer", count=1)


def run(commands: list[Message], **kwargs: Any) -> tuple[list[Any], list[Any], CommandedNode]:
    node = CommandedNode(commands)
    run_commanded(node, params(**kwargs))  # type: ignore[arg-type]
    return node.publishers["wrench"].sent, node.publishers["/robot/pose"].sent, node


def test_the_scenes_path_commanded_gives_its_wrenches_and_poses() -> None:
    """The demo's path as waypoints, one per sample (its speed, 0.1 m/s, is the limit):
    the same wrench rows and phases as the fixed path within 1e-12 N (Step 1's step is the
    limits' bound, not the path's largest motion: the touches are bisected on another
    coordinate, the equilibria are solved to 1e-12 L), a pose per sample, then the ends."""
    scene = load_scene(DEMO)
    q = scene.path.R_WR.as_quat()
    scene = dataclasses.replace(scene, path=robot_path(np.arange(len(q)) / 500.0,
                                                       scene.path.p_WR, q))
    wrenches, poses, node = run([segment(scene.path.p_WR[1:], q[1:]), end()])
    assert wrenches[-1] == "EOS" and poses[-1] == "EOS"
    wrenches, poses = wrenches[:-1], poses[:-1]
    results = simulate(scene, workers=1)
    assert len(wrenches) == len(poses) == len(scene.path.t)
    assert [w.seq for w in wrenches] == list(range(len(wrenches)))
    expected = [m for _, m in scene_stream(scene, results, params())
                if isinstance(m, WhiskerWrenchArray)]
    assert [encode(p) for p in poses] == [encode(m) for _, m in scene_stream(
        scene, results, params()) if isinstance(m, RobotPose)]
    for got, want in zip(wrenches, expected, strict=True):
        assert got.stamp == want.stamp and got.whisker_ids == want.whisker_ids
        np.testing.assert_allclose(got.f0, want.f0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.m0, want.m0, rtol=0, atol=1e-12)
    assert sum(len(w.whisker_ids) for w in wrenches) == len(wrenches) * len(scene.whiskers)
    assert any(np.any(w.f0 != 0) for w in wrenches)  # it touched
    assert node.counters == {"commands_accepted": 1, "commands_rejected": 0,
                             "unresolved_rows": 0}
    assert all(r.phase[-1] == SamplePhase.NONE for r in results)


def waypoints() -> tuple[np.ndarray, np.ndarray]:
    """Four waypoints past the demo's ball, turning as the demo's path does."""
    scene = load_scene(DEMO)
    rows = [0, 400, 700, 1100, 1699]
    return scene.path.p_WR[rows], scene.path.R_WR[rows].as_quat()


def test_two_segments_appended_are_one_segment_of_both() -> None:
    p, q = waypoints()
    one, one_poses, _ = run([segment(p[1:], q[1:]), end()], noise_force_n=1e-4)
    two, two_poses, node = run([segment(p[1:3], q[1:3], 1), segment(p[3:], q[3:], 2), end()],
                               noise_force_n=1e-4)
    assert node.counters == {"commands_accepted": 2, "commands_rejected": 0,
                             "unresolved_rows": 0}
    assert len(one) > 1000 and any(np.any(w.f0 != 0) for w in one[:-1])
    assert [encode(m) for m in one[:-1]] == [encode(m) for m in two[:-1]]
    assert [encode(m) for m in one_poses[:-1]] == [encode(m) for m in two_poses[:-1]]


def test_bad_commands_are_counted_and_logged_and_the_robot_goes_on(
        caplog: pytest.LogCaptureFixture) -> None:
    p, q = waypoints()
    bad = [segment(p[1:2], q[1:2], 1, speed_mps=0.0),
           segment(p[1:2], q[1:2], 2, frame_id="odom"),
           segment(p[1:2], [[0.0, 0.0, 0.0, 2.0]], 3),
           segment(p[1:2] + 0.5, q[1:2], 4),  # a jump
           segment(p[1:2], q[1:2], 5, speed_mps=1.0)]  # beyond max_speed_mps
    with caplog.at_level(logging.WARNING):
        wrenches, poses, node = run([*bad, segment(p[1:2], q[1:2], 6), end()])
    assert node.counters == {"commands_accepted": 1, "commands_rejected": 5,
                             "unresolved_rows": 0}
    for k in range(1, 6):
        assert f"path segment {k} refused" in caplog.text
    assert "frame 'odom' is not 'world'" in caplog.text
    np.testing.assert_array_equal(poses[-2].position, p[1])  # it drove the good one
    assert wrenches[-1] == poses[-1] == "EOS"


def test_the_stream_ends_on_the_commanders_end_with_the_robot_standing() -> None:
    """No command at all: the start's pose goes out at once, then the ends; a pose grid of
    its own rate ends with a pose at the path's end."""
    wrenches, poses, _ = run([end()])
    assert wrenches == ["EOS"] and len(poses) == 2 and poses[-1] == "EOS"
    assert poses[0].stamp == 1000.0
    p, q = waypoints()
    wrenches, poses, _ = run([segment(p[1:2], q[1:2]), end()], pose_rate_hz=30.0)
    stamps = [m.stamp - 1000.0 for m in poses[:-1]]
    n = len(wrenches) - 1
    assert stamps[0] == 0.0 and stamps[-1] == pytest.approx((n - 1) / 500.0, abs=1e-9)
    np.testing.assert_allclose(np.diff(stamps[:-1]), 1 / 30.0, rtol=1e-9)


def test_a_segment_after_the_commanders_end_is_refused_counted_and_logged(
        caplog: pytest.LogCaptureFixture) -> None:
    """The commander said it was done: a segment it sends after is not driven, and not lost
    without a word either."""
    p, q = waypoints()
    with caplog.at_level(logging.WARNING):
        wrenches, poses, node = run([segment(p[1:2], q[1:2], 1), end(),
                                     segment(p[2:3], q[2:3], 2)])
    assert node.counters["commands_accepted"] == 1 and node.counters["commands_rejected"] == 1
    assert "path segment 2 refused: it came after the commander's EndOfStream" in caplog.text
    np.testing.assert_array_equal(poses[-2].position, p[1])  # it stopped at the first one
    assert wrenches[-1] == poses[-1] == "EOS"


def test_a_segment_too_long_to_queue_is_refused_and_the_robot_goes_on(
        caplog: pytest.LogCaptureFixture) -> None:
    """A finite leg whose driving time overflows, or a crawl: refused by the queue's bound
    (``max_queued_s``), logged and counted; the node drives the next segment."""
    p, q = waypoints()
    far = [[*p[1, :2], p[1, 2]], [1e300, 0.0, 0.0]]
    with caplog.at_level(logging.WARNING):
        wrenches, poses, node = run([segment(far, [q[1], q[1]], 1),
                                     segment(p[1:2], q[1:2], 2, speed_mps=1e-300),
                                     segment(p[1:2], q[1:2], 3), end()])
    assert node.counters["commands_accepted"] == 1 and node.counters["commands_rejected"] == 2
    assert "path segment 1 refused: it takes inf s to drive" in caplog.text
    assert "path segment 2 refused" in caplog.text and "max_queued_s 600" in caplog.text
    np.testing.assert_array_equal(poses[-2].position, p[1])
    assert wrenches[-1] == poses[-1] == "EOS"


def test_the_commanded_mode_is_checked_when_the_parameters_load() -> None:
    with pytest.raises(ValueError, match="parameter 'path_topic' must be empty with"):
        params(passes=2)
    with pytest.raises(ValueError, match="max_speed_mps must be a finite number > 0"):
        params(max_speed_mps=0.0)
    with pytest.raises(ValueError, match="parameter 'path_topic'"):
        params(path_topic="bad name")


def test_poses_on_their_own_rate_cover_every_wrench_and_end_where_the_robot_stands() -> None:
    """A straight 35 mm at 0.1 m/s: 175 samples, the last at t = 0.35 s, where 35 x 0.01 s
    rounds past it (a grid pose there was NaN, off the path); the robot then stands at the
    segment's end, whose pose goes out, so that every wrench lies within the poses."""
    scene = load_scene(DEMO)
    start, rotation = scene.path.p_WR[0], scene.path.R_WR[0].as_quat()
    wrenches, poses, _ = run([segment([start + [0.035, 0.0, 0.0]], [rotation]), end()],
                             pose_rate_hz=100.0)
    assert wrenches[-1] == "EOS" and poses[-1] == "EOS"
    stamps = [w.stamp for w in wrenches[:-1]]
    assert len(stamps) == 176  # t = 0 (where it stands) to 0.35 s
    assert all(np.isfinite(p.position).all() for p in poses[:-1])
    assert poses[0].stamp <= stamps[0] and poses[-2].stamp == stamps[-1]
    np.testing.assert_array_equal(poses[-2].position, start + [0.035, 0.0, 0.0])


@dataclass
class OneWhenIdle(FakeCommands):
    """The path topic of a commander that sends the next segment only once the robot
    stands (the explorer's way: it plans where the last plan ended)."""

    def receive(self, timeout_s: float) -> Delivered | None:
        return super().receive(timeout_s) if timeout_s > 0 else None


def test_a_robot_that_stands_between_segments_gives_one_pose_per_stamp_and_covers_its_wrenches(
        ) -> None:
    """Two 35 mm segments, the robot standing between them at t = 0.35 s, where the pose grid
    (35 x 0.01 s) rounds past the sample time: the pose where it stood and the grid's next one
    were two poses of one stamp, and the reconstructor refused the second."""
    scene = load_scene(DEMO)
    start, rotation = scene.path.p_WR[0], scene.path.R_WR[0].as_quat()
    node = CommandedNode([])
    commands = OneWhenIdle(deque([segment([start + [0.035, 0.0, 0.0]], [rotation], 1),
                                  segment([start + [0.035, 0.0, 0.0], start + [0.07, 0.0, 0.0]],
                                          [rotation, rotation], 2), end()]))
    node.create_subscriber = lambda topics, **kw: commands  # type: ignore[method-assign]
    run_commanded(node, params(pose_rate_hz=100.0))  # type: ignore[arg-type]
    wrenches = node.publishers["wrench"].sent[:-1]
    poses = node.publishers["/robot/pose"].sent[:-1]
    pose_stamps = np.array([p.stamp for p in poses])
    assert len(wrenches) > 2 * 175 and np.all(np.diff(pose_stamps) > 0)
    wrench_stamps = np.array([w.stamp for w in wrenches])
    assert pose_stamps[0] <= wrench_stamps.min() and wrench_stamps.max() <= pose_stamps[-1]
    np.testing.assert_array_equal(poses[-1].position, start + [0.07, 0.0, 0.0])


@pytest.mark.slow
def test_the_jumps_of_a_commanded_path_go_out_after_their_wrench(tmp_path: Path) -> None:
    """A tip on a ball slowing to a hold (tests/core/test_sampling.py), its path commanded:
    the snap-off, the landing and the snap-through of the fixed path, in that order, each a
    SnapEvent stamped as a wrench that went out before it, with that wrench as ``after``."""
    from tests.core.test_sampling import yawing_scene
    from vibrissa.msgs import SnapEvent
    from vibrissa.scene import snaps

    scene = yawing_scene(50.0, 40.0, 0.5, 0.02, 4)
    q = scene.path.R_WR.as_quat()
    scene = dataclasses.replace(scene, path=robot_path(np.arange(len(q)) / 500.0,
                                                       scene.path.p_WR, q))
    ball, (rod,) = scene.objects[0], scene.whiskers
    mount = rod.X_RC.quaternion_xyzw.tolist()
    (tmp_path / "scene.yaml").write_text(
        f"mu: {scene.mu}\nobjects:\n  - {{name: ball, shape: sphere, radius_m: "
        f"{float(ball.sizes['radius_m'])!r}, position_m: "
        f"{[float(v) for v in ball.X_WO.translation]}}}\nwhiskers:\n  - {{name: w, length_m: "
        f"{rod.length_m!r}, ei_nm2: {rod.ei_nm2!r}, mount: {{position_m: [0, 0, 0], "
        f"quaternion_xyzw: {[float(v) for v in mount]}}}}}\npath: path.csv\n")
    (tmp_path / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + "".join(
        f"{float(t)!r},0,0,0,{','.join(repr(float(v)) for v in qk)}\n"
        for t, qk in zip(scene.path.t, q, strict=True)))
    # the robot turns in place at its path's rate, which is the limit: Step 1's step is the
    # path's own (`PathLimits.rod_step`)
    turn_rps = float((scene.path.R_WR[1] * scene.path.R_WR[0].inv()).magnitude()) * 500.0
    node = CommandedNode([segment(scene.path.p_WR[1:], q[1:], speed_mps=1e-6,
                                  turn_rate_rps=turn_rps), end()])
    run_commanded(node, WrenchSourceParams(  # type: ignore[arg-type]
        mode="scene", scene=str(tmp_path / "scene.yaml"), path_topic=PATH, pose_rate_hz=0.0,
        epoch_s=1000.0, max_speed_mps=1e-6, max_turn_rate_rps=turn_rps))
    events = [m for m in node.publishers["events"].sent if m != "EOS"]
    assert node.publishers["events"].sent[-1] == "EOS"
    (result,) = simulate(scene, workers=1)
    want = snaps(result, ["ball"])
    assert [e.kind for e in events] == [w.kind for w in want] == [
        "snap-off", "landing", "snap-through"]
    wrenches = {w.stamp: w for w in node.publishers["wrench"].sent if w != "EOS"}
    for event, w in zip(events, want, strict=True):
        assert isinstance(event, SnapEvent) and event.object == "ball"
        assert abs(event.stamp - (1000.0 + w.t)) <= 2.5 / 500  # the commanded step is its own
        told = wrenches[event.stamp]
        np.testing.assert_array_equal(event.f0_after, told.f0[0])


@pytest.mark.slow
def test_a_snap_off_onto_an_unresolved_sample_goes_out_without_its_after_wrench(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A robot standing with its body in a ball (a scene file refuses that with an ``explore``
    key, not without one) turns and drives: its rod, in contact near the clamp, snaps off where
    its unloaded shape is inside the ball and no landing is found, so the sample after is
    unresolved (no row in the stream). The SnapEvent goes out with the wrench before and
    without one after (on the wire: the field left out), and the stream goes on."""
    from vibrissa.msgs import SnapEvent
    from vibrissa.msgs.codec import decode

    (tmp_path / "scene.yaml").write_text(
        "mu: 0.2\nobjects:\n  - {name: ball, shape: sphere, radius_m: 0.03, position_m: "
        "[0.01, 0.0, 0.03]}\nwhiskers:\n  - {name: w03, length_m: 0.05, ei_nm2: 0.00023, mount: "
        "{position_m: [0.005176380902, 0.019318516526, 0.015], quaternion_xyzw: "
        "[-0.6830127018922193, 0.1830127018922193, 0, 0.7071067811865476]}}\n"
        "path: path.csv\n")
    (tmp_path / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0,0,0,0,0,0,1\n")
    s = 0.5 ** 0.5
    look = [[0, 0, 0, 1], [0, 0, s, s], [0, 0, 1, 0], [0, 0, s, -s], [0, 0, 0, -1]]
    c, d = np.cos(np.pi / 8), np.sin(np.pi / 8)
    route = [[0, 0, 0, -1], [0, 0, 0, 1], [0, 0, d, c], [0, 0, c, d], [0, 0, c, -d],
             [0, 0, d, -c], [0, 0, -d, -c]]
    node = CommandedNode([
        segment(np.zeros((5, 3)), look, speed_mps=0.05),
        segment([[0, 0, 0], [0.004, 0, 0], *[[0.032, 0.028, 0]] * 5], route, speed_mps=0.05),
        end()])
    with caplog.at_level(logging.WARNING):
        run_commanded(node, WrenchSourceParams(  # type: ignore[arg-type]
            mode="scene", scene=str(tmp_path / "scene.yaml"), path_topic=PATH,
            pose_rate_hz=0.0, epoch_s=1000.0))
    events = [m for m in node.publishers["events"].sent if m != "EOS"]
    assert node.publishers["events"].sent[-1] == "EOS"
    wrenches = {w.stamp: w for w in node.publishers["wrench"].sent if w != "EOS"}
    unresolved = [e for e in events if isinstance(e, SnapEvent) and e.f0_after is None]
    assert unresolved and all(e.kind == "snap-off" and e.m0_after is None for e in unresolved)
    for event in unresolved:
        assert event.f0_before is not None and np.isfinite(event.f0_before).all()
        assert wrenches[event.stamp].whisker_ids == []  # no row at the sample told
        back = decode(encode(event))
        assert isinstance(back, SnapEvent) and back.f0_after is None and back.m0_after is None
        np.testing.assert_array_equal(back.f0_before, event.f0_before)
    # the stream went on: wrenches after the first of them, the last the robot's end
    assert max(wrenches) > unresolved[0].stamp + 1.0
    # every row left out is counted, and the start of the run of them logged
    assert node.counters["unresolved_rows"] == sum(1 for w in wrenches.values()
                                                   if not w.whisker_ids) > 0
    assert "whisker 'w03': no equilibrium found from path time" in caplog.text
    for event in events:  # as the real publisher does (a NaN there stopped the node)
        encode(event)

    # the same path fixed: simulate's results tell the same jumps, summary.json with null for
    # the wrench of an unresolved sample (strict JSON: no NaN)
    poses = [p for p in node.publishers["/robot/pose"].sent if isinstance(p, RobotPose)]
    scene = load_scene(tmp_path / "scene.yaml")
    scene = dataclasses.replace(scene, path=robot_path(
        np.array([p.stamp - 1000.0 for p in poses]), np.array([p.position for p in poses]),
        np.array([p.orientation for p in poses])))
    (result,) = simulate(scene, workers=1)
    write_results(tmp_path / "out", scene, [result])

    def no_nan(token: str) -> None:
        raise AssertionError(f"{token} in summary.json")

    summary = json.loads((tmp_path / "out" / "summary.json").read_text(), parse_constant=no_nan)
    told = summary["whiskers"]["w03"]["snaps"]
    assert [(s["kind"], s["f0_after"] is None) for s in told] == [
        (e.kind, e.f0_after is None) for e in events]


def test_a_commanded_robot_in_a_scene_without_objects_is_free_all_along(tmp_path: Path
                                                                       ) -> None:
    """No objects (an empty room): every commanded sample goes out, each row a free rod's
    zero wrench, and the stream ends on the commander's EndOfStream."""
    (tmp_path / "scene.yaml").write_text(
        "mu: 0.2\nobjects: []\nwhiskers:\n  - {name: w, length_m: 0.05, ei_nm2: 0.00023, "
        "mount: {position_m: [0.02, 0, 0.015], quaternion_xyzw: [0, 0.7071067811865476, 0, "
        "0.7071067811865476]}}\nexplore: {start: {position_m: [0, 0, 0]}, workspace_m: "
        "[[-0.1, -0.1, 0], [0.1, 0.1, 0.1]], body_radius_m: 0.02}\n")
    s = 0.5 ** 0.5
    node = CommandedNode([segment([[0, 0, 0], [0.03, 0, 0], [0.03, 0, 0]],
                                  [[0, 0, 0, 1], [0, 0, 0, 1], [0, 0, s, s]]), end()])
    run_commanded(node, WrenchSourceParams(  # type: ignore[arg-type]
        mode="scene", scene=str(tmp_path / "scene.yaml"), path_topic=PATH, pose_rate_hz=0.0,
        epoch_s=1000.0))
    wrenches = [w for w in node.publishers["wrench"].sent if w != "EOS"]
    assert node.publishers["wrench"].sent[-1] == "EOS"
    # 30 mm at 0.1 m/s and a quarter turn at 1 rad/s, 500 samples/s: 150 + 785 samples
    assert len(wrenches) >= 900
    assert all(w.whisker_ids == ["w"] and not w.f0.any() and not w.m0.any() for w in wrenches)
