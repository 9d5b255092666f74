"""The commanded robot as a process over real sockets: the wrench source (mode ``scene`` with
``path_topic``) stands at the scene's start, drives the segments a commander (the test's
node) publishes, refuses bad ones (counted in its status, logged) and goes on, and ends its
streams, and the launch, after the commander's EndOfStream."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tests.system.test_system_pipeline import LAUNCH, Launch, Probe, entries, node, set_param
from vibrissa.formats.scene_file import load_scene
from vibrissa.msgs import EndOfStream, PathSegment, RobotPose, WhiskerWrenchArray

SCENE = LAUNCH / "robot" / "scene.yaml"
WRENCH, POSE, PATH = "/robot/wrench", "/robot/pose", "/robot/path"
FQN = "/robot/wrench_source"
DEADLINE_S = 120.0


def _source_only(tmp: Path) -> Launch:
    launch_entries = [e for e in entries("robot.yaml") if "arg" in e]
    body = node(entries("robot.yaml"), "wrench_source")
    body.pop("unless", None)
    for key, value in (("path_topic", PATH), ("pose_rate_hz", 0.0), ("wait_for", ["/probe"]),
                       ("pose_wait_for", []), ("truth_file", ""), ("epoch_s", 0.0),
                       ("scene", str(SCENE)), ("mode", "scene")):
        set_param(body, key, value)
    body["param"] = [p for p in body["param"] if p["name"] not in ("simulated", "passes", "loop")]
    launch_entries.append({"node": body})
    return Launch(tmp, launch_entries)


def _start_pose(probe: Probe, launch: Launch) -> RobotPose:
    """The robot stands at the start: its pose comes before any command (the probe's
    subscriber connects to the source as it receives)."""
    deadline = time.monotonic() + DEADLINE_S
    while time.monotonic() < deadline:
        rx = probe.sub.receive(0.2)
        if rx is not None and isinstance(rx.msg, RobotPose):
            return rx.msg
    raise AssertionError(f"no start pose within {DEADLINE_S} s\n{launch.text()}")


def _segment(segment_id: int, position: np.ndarray, orientation: np.ndarray,
             speed_mps: float = 0.1, frame_id: str = "world") -> PathSegment:
    return PathSegment(stamp=time.time(), frame_id=frame_id, segment_id=segment_id,
                       mode="append", position=position, orientation=orientation,
                       speed_mps=speed_mps, turn_rate_rps=1.0)


def test_a_commanded_robot_drives_what_comes_refuses_bad_commands_and_ends(tmp_path: Path
                                                                          ) -> None:
    path = load_scene(SCENE).path
    rows = [400, 700]
    p, q = path.p_WR[rows], path.R_WR[rows].as_quat()
    launch = _source_only(tmp_path)
    probe = Probe(launch.endpoints(), [WRENCH, POSE])
    try:
        commander = probe.node.create_publisher(PATH, PathSegment, wait_for=[FQN])
        got: dict[str, list[WhiskerWrenchArray | RobotPose]] = {WRENCH: [], POSE: []}
        ends: dict[str, EndOfStream] = {}
        got[POSE].append(_start_pose(probe, launch))
        deadline = time.monotonic() + DEADLINE_S
        np.testing.assert_array_equal(got[POSE][0].position, path.p_WR[0])
        commander.publish(_segment(1, p[:1], q[:1], speed_mps=0.0))  # zero speed
        commander.publish(_segment(2, p[:1], q[:1], frame_id="odom"))  # wrong frame
        commander.publish(_segment(3, p[:1] + 1.0, q[:1]))  # a jump
        commander.publish(_segment(4, p[:1], q[:1]))
        commander.publish(_segment(5, p[1:], q[1:]))
        commander.publish_end_of_stream(probe.node.fqn)
        while len(ends) < 2 and time.monotonic() < deadline:
            rx = probe.sub.receive(0.2)
            if rx is None:
                continue
            if isinstance(rx.msg, EndOfStream):
                ends[rx.topic] = rx.msg
            elif isinstance(rx.msg, (WhiskerWrenchArray, RobotPose)):
                got[rx.topic].append(rx.msg)
        assert set(ends) == {WRENCH, POSE}, launch.text()
        assert launch.wait() == 0, launch.text()  # the source ended, and with it the launch
        wrenches, poses = got[WRENCH], got[POSE]
        assert ends[WRENCH].count == len(wrenches) and ends[POSE].count == len(poses)
        assert len(poses) == len(wrenches) > 700  # the start, then a pose per sample
        assert [w.seq for w in wrenches] == list(range(len(wrenches)))
        np.testing.assert_array_equal(poses[-1].position, p[1])
        assert all(len(w.whisker_ids) == 8 for w in wrenches)
        assert any(np.any(w.f0 != 0) for w in wrenches)  # the whiskers touched the ball
        for k in (1, 2, 3):
            assert f"path segment {k} refused" in launch.text()
    finally:
        probe.close()
        launch.kill()


def test_the_rejections_are_counted_in_the_status(tmp_path: Path) -> None:
    path = load_scene(SCENE).path
    launch = _source_only(tmp_path)
    probe = Probe(launch.endpoints(), [WRENCH, POSE])
    try:
        commander = probe.node.create_publisher(PATH, PathSegment, wait_for=[FQN])
        _start_pose(probe, launch)
        q = path.R_WR[:1].as_quat()
        commander.publish(_segment(1, path.p_WR[:1], q * 2.0))  # not a unit quaternion
        commander.publish(_segment(2, path.p_WR[10:11], q, speed_mps=5.0))  # too fast
        status = probe.status_of(FQN, lambda s: s.counters.get("commands_rejected", 0) == 2,
                                 timeout=DEADLINE_S)
        assert status.state == "running" and launch.proc.poll() is None
        later = time.time()  # it goes on
        assert probe.status_of(FQN, lambda s: s.stamp > later).counters["commands_accepted"] == 0
        commander.publish_end_of_stream(probe.node.fqn)
        assert launch.wait() == 0, launch.text()
    finally:
        probe.close()
        launch.kill()
