"""The reconstructor as a process on a robot, fed by the test over loopback: a pose stream that
stops while the wrenches go on makes them count as ``no_pose`` after ``pose_timeout_s``, and
the node keeps running, a pose stamped far ahead costs the stream a few poses, and a bad robot
description stops the launch naming the problem."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from tests.system.test_system_pipeline import LAUNCH, Launch, Probe, entries, node, set_param
from vibrissa.formats.scene_file import load_scene
from vibrissa.frames import clamp_frame
from vibrissa.msgs import ContactPointArray, RobotPose, WhiskerWrenchArray
from vibrissa.reconstruct import reconstruct_si

SCENE = LAUNCH / "robot" / "scene.yaml"
WRENCH, POSE, CONTACT = "/robot/wrench", "/robot/pose", "/robot/contact"
FQN = "/robot/reconstructor"
TIMEOUT_S = 0.5


def _reconstructor_only(tmp: Path, robot: Path) -> Launch:
    launch_entries = [e for e in entries("robot.yaml") if "arg" in e]
    body = node(entries("robot.yaml"), "reconstructor")
    body.pop("respawn", None)
    set_param(body, "wait_for", ["/probe"])
    set_param(body, "robot", str(robot))
    set_param(body, "pose_timeout_s", TIMEOUT_S)
    launch_entries.append({"node": body})
    return Launch(tmp, launch_entries)


def _arrays(probe: Probe, n: int, timeout_s: float = 20.0) -> list[ContactPointArray]:
    """The next ``n`` ContactPointArrays (fewer if they do not come within ``timeout_s``)."""
    got: list[ContactPointArray] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        rx = probe.sub.receive(0.1)
        if rx is not None and isinstance(rx.msg, ContactPointArray):
            got.append(rx.msg)
    return got


def _pose(stamp: float) -> RobotPose:
    """The robot driving along x at 0.1 m/s, turning about z at 0.5 rad/s."""
    yaw = 0.5 * stamp
    return RobotPose(stamp=stamp, frame_id="world", child_frame_id="base_link",
                     position=[0.1 * stamp, 0.0, 0.0],
                     orientation=[0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])


def test_a_pose_stream_that_stops_gives_no_pose_and_the_node_goes_on(tmp_path: Path) -> None:
    whiskers = load_scene(SCENE).whiskers
    names = [w.name for w in whiskers]
    # a wrench each whisker's Step 2 finds a contact for: a lateral push at the clamp
    f0 = np.array([[0.1 * w.scale.force_n, 0.0, 0.0] for w in whiskers])
    m0 = np.array([[0.0, 0.05 * w.scale.moment_nm, 0.0] for w in whiskers])

    def tick(seq: int, stamp: float | None = None) -> WhiskerWrenchArray:
        return WhiskerWrenchArray(stamp=0.01 * seq if stamp is None else stamp, seq=seq,
                                  whisker_ids=names, frame_ids=[clamp_frame(n) for n in names],
                                  f0=f0, m0=m0)

    launch = _reconstructor_only(tmp_path, SCENE)
    probe = Probe(launch.endpoints(), [CONTACT])
    try:
        wrenches = probe.node.create_publisher(WRENCH, WhiskerWrenchArray, wait_for=[FQN])
        poses = probe.node.create_publisher(POSE, RobotPose, wait_for=[FQN])
        assert probe.node.wait_for_subscribers(WRENCH, [FQN], 30.0), launch.text()
        assert probe.node.wait_for_subscribers(POSE, [FQN], 30.0), launch.text()
        # poses up to 0.5 s, then the pose stream stops; wrenches up to 1.0 s
        for k in range(51):
            poses.publish(_pose(0.01 * k))
        sent = time.monotonic()
        for seq in range(101):
            wrenches.publish(tick(seq))
        # the wrenches go on (a wrench every 0.1 s, stamped within the poses, seq 1000 on):
        # what waits is let through once one came pose_timeout_s after it
        got: list[ContactPointArray] = []
        going_on: list[ContactPointArray] = []
        prods = 0
        while len(got) < 101 or len(going_on) < prods:
            assert time.monotonic() < sent + 20, launch.text()
            if len(got) <= 51 and time.monotonic() > sent + 0.1 * prods:
                wrenches.publish(tick(1000 + prods, stamp=0.25))
                prods += 1
            rx = probe.sub.receive(0.02)
            if rx is not None and isinstance(rx.msg, ContactPointArray):
                (got if rx.msg.seq < 1000 else going_on).append(rx.msg)
                if rx.msg.seq == 51:
                    waited = time.monotonic() - sent
        assert [a.seq for a in got] == list(range(101)), launch.text()  # every tick answered
        assert [a.seq for a in going_on] == list(range(1000, 1000 + prods))
        assert all(a.whisker_ids == names for a in going_on)
        assert all(a.whisker_ids == names for a in got[:51])  # placed: the poses cover them
        assert all(a.whisker_ids == [] for a in got[51:])  # newer than the last pose
        assert TIMEOUT_S <= waited < TIMEOUT_S + 2.0  # a bounded wait, then on without a pose
        # placed through the robot pose at the stamp and the mount (composed here with scipy),
        # each whisker with its own L and EI
        for a in got[:51]:
            X = _pose(a.stamp)
            R_WR = Rotation.from_quat(X.orientation)
            for i, whisker in enumerate(whiskers):
                R_WC = R_WR * whisker.X_RC.rotation
                p_WC = X.position + R_WR.apply(np.array(whisker.X_RC.translation))
                ref = reconstruct_si(R_WC.as_quat()[None], p_WC[None], f0[i:i + 1],
                                     m0[i:i + 1], whisker.scale)
                assert ref.valid[0]
                np.testing.assert_allclose(a.point[i], ref.point_m[0], rtol=0,
                                           atol=1e-12 * whisker.length_m)
        status = probe.status_of(FQN, lambda s: s.counters.get("no_pose", 0) >= 50 * len(names))
        assert status.counters["no_pose"] == 50 * len(names)
        # the node goes on: the poses resume and the next wrenches are placed again
        for k in range(51, 121):
            poses.publish(_pose(0.01 * k))
        for seq in range(101, 121):
            wrenches.publish(tick(seq))
        more = _arrays(probe, 20)
        assert [a.seq for a in more] == list(range(101, 121))
        assert all(a.whisker_ids == names for a in more)
        status = probe.status_of(FQN, lambda s: s.counters.get("contacts", 0)
                                 >= (71 + prods) * len(names))
        assert status.counters["no_pose"] == 50 * len(names) and status.state == "running"
        # a row of a whisker the robot does not have: counted, named, the others placed
        ghost = tick(119)
        ghost = WhiskerWrenchArray(
            stamp=ghost.stamp, seq=121, whisker_ids=[*names, "ghost"],
            frame_ids=[*ghost.frame_ids, clamp_frame("ghost")], f0=np.vstack([f0, f0[:1]]),
            m0=np.vstack([m0, m0[:1]]))
        wrenches.publish(ghost)
        (last,) = _arrays(probe, 1)
        assert last.seq == 121 and last.whisker_ids == names
        status = probe.status_of(FQN, lambda s: s.counters.get("unknown_whisker", 0) >= 1)
        assert status.counters["unknown_whisker"] == 1
        launch.wait_line(r"whisker 'ghost' is not in the robot description")
        # one pose stamped far ahead pushes the history past the stream: the next two poses
        # are refused, the third starts the history again, and the wrenches are placed again
        taken = status.counters["robot_poses"]
        poses.publish(_pose(1e300))
        for k in range(121, 131):
            poses.publish(_pose(0.01 * k))
        status = probe.status_of(FQN, lambda s: s.counters.get("robot_poses", 0) >= taken + 9)
        assert status.counters["robot_poses"] == taken + 9
        assert status.counters["bad_robot_pose"] == 2 and status.counters["pose_time_jumps"] == 1
        launch.wait_line(r"start again at t=1.23, behind the kept history \(newest t=1e\+300\)")
        for seq in range(124, 129):
            wrenches.publish(tick(seq))
        again = _arrays(probe, 5)
        assert [a.seq for a in again] == list(range(124, 129))
        assert all(a.whisker_ids == names for a in again)
    finally:
        probe.close()
        launch.kill()


def test_a_bad_robot_description_stops_the_launch_naming_the_problem(tmp_path: Path) -> None:
    for body, words in (
        ("whiskers:\n  - {name: w0, length_m: 0.05, ei_nm2: 1.0e-4}\n", "missing 'mount'"),
        ("whiskers:\n  - {name: w0, length_m: -0.05, ei_nm2: 1.0e-4, mount: {}}\n", "length_m"),
    ):
        robot = tmp_path / "robot.yaml"
        robot.write_text(body)
        launch = _reconstructor_only(tmp_path, robot)
        try:
            rc = launch.wait(60)
        finally:
            launch.kill()
        assert rc != 0
        assert "parameter 'robot'" in launch.text() and words in launch.text(), launch.text()
