"""The mapper's exploration report: a real mapper process fed contacts on a ball and poses of the
robot base over sockets reports the path length (the sum of the pose steps, summed here on its
own), the coverage of each map with the path length at it, and the final map's coverage as the
definition gives it on the same points (`vibrissa.mapping.coverage`); a base moving between
contacts keeps the timeout of silence off, a base standing still does not. Without
``explore_planner`` the report's ``exploration`` is null; its parameters are checked at start."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from vibrissa.mapping import Accumulator
from vibrissa.mapping.coverage import coverage, coverage_samples
from vibrissa.msgs import ContactPhase, ContactPointArray, ContactStatus, NodeStatus, RobotPose
from vibrissa.nodes.mapper import SCENE_FRAME, MapperParams, fit_frames, receive, write_outputs
from vibrissa.wire import STATUS_TOPIC, Endpoints, Publisher, Subscriber

TOPIC = "/w/contact"
POSE_TOPIC = "/robot/pose"
CENTRE = np.array([0.0, 0.0, 0.02])
RADIUS = 0.02
ROWS, PER_ROW = 24, 20


def write_scene(folder: Path, explore: bool = True) -> Path:
    doc: dict[str, Any] = {
        "mu": 0.2,
        "objects": [{"name": "ball", "shape": "sphere", "radius_m": RADIUS,
                     "position_m": CENTRE.tolist()}],
        "whiskers": [{"name": "w0", "length_m": 0.05, "ei_nm2": 2e-4, "mount": {}},
                     {"name": "w1", "length_m": 0.03, "ei_nm2": 2e-4, "mount": {}}]}
    if explore:
        doc["explore"] = {"start": {"position_m": [0.0, 0.0, 0.06]},
                          "workspace_m": [[-0.1, -0.1, 0.05], [0.1, 0.1, 0.1]],
                          "body_radius_m": 0.02}
    else:
        (folder / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0.06,0,0,0,1\n"
                                         "1,0.01,0,0.06,0,0,0,1\n")
        doc["path"] = "path.csv"
    path = folder / "scene.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def contact(i: int) -> ContactPointArray:
    """The i-th contact: rows of points along circles of latitude of the ball's upper half, a
    whisker per row, the contact force along the outward normal."""
    row, k = (i // PER_ROW) % ROWS, i % PER_ROW
    theta, phi = 0.15 + 1.3 * row / ROWS, 2 * np.pi * k / PER_ROW
    normal = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    return ContactPointArray(stamp=float(i), seq=i, whisker_ids=[f"w{row}"], frame_id="world",
                             point=[(CENTRE + RADIUS * normal).tolist()], s1=[0.02],
                             phase=[ContactPhase.TIP], force=[(1e-3 * normal).tolist()],
                             status=[ContactStatus.OK])


def pose(stamp: float, p: np.ndarray, frame: str = "world", child: str = "base_link"
         ) -> RobotPose:
    return RobotPose(stamp=stamp, frame_id=frame, child_frame_id=child, position=p.tolist(),
                     orientation=[0.0, 0.0, 0.0, 1.0])


def start_mapper(tmp_path: Path, endpoints: Endpoints, scene: Path, *params: str
                 ) -> subprocess.Popen[str]:
    words = [w for p in [f"topics:=[{TOPIC}]", f"out_dir:={tmp_path / 'out'}", "plot:=false",
                         "cells:=16", "map_period_s:=0.5", "write_period_s:=1",
                         f"scene:={scene}", "explore_planner:=lawnmower",
                         f"pose_topic:={POSE_TOPIC}", *params]
             for w in ("--param", p)]
    return subprocess.Popen(
        [sys.executable, "-m", "vibrissa.nodes.mapper", "--name", "mapper", *words],
        env={**os.environ, **endpoints.to_env()}, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)


def wait_heard(pubs: list[Publisher], statuses: Subscriber) -> None:
    """Ping until the mapper hears every topic."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        for pub in pubs:
            pub.ping("/test")
        rx = statuses.receive(0.1)
        if (rx is not None and rx.msg.node == "/mapper"
                and {TOPIC, POSE_TOPIC} <= set(rx.msg.seen_topics)):
            return
    pytest.fail("the mapper never heard the topics")


def test_the_report_holds_the_path_length_and_the_coverage_of_each_map(
        tmp_path: Path, endpoints: Endpoints) -> None:
    scene = write_scene(tmp_path)
    mapper = start_mapper(tmp_path, endpoints, scene, "timeout_s:=3")
    rng = np.random.default_rng(3)
    p = np.array([0.0, 0.0, 0.06])
    length = 0.0  # the path length, summed here
    n_contacts = ROWS * PER_ROW
    try:
        with Publisher(TOPIC, ContactPointArray, endpoints) as pub, \
                Publisher(POSE_TOPIC, RobotPose, endpoints) as poses, \
                Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses:
            wait_heard([pub, poses], statuses)
            poses.publish(pose(0.0, p))
            poses.publish(pose(0.0, p + 1.0, frame="map"))  # another frame: not the base's
            for i in range(n_contacts):
                pub.publish(contact(i))
                if i % 10 == 0:
                    step = rng.normal(scale=1e-3, size=3)
                    p = p + step
                    length += math.sqrt(float(step @ step))
                    poses.publish(pose(float(i), p))
                    time.sleep(0.01)  # a stream over seconds: several map updates
            # the base travels on without a contact for longer than timeout_s
            moving_until = time.monotonic() + 4.5
            while time.monotonic() < moving_until:
                step = np.array([1e-4, 0.0, 0.0])
                p = p + step
                length += 1e-4
                poses.publish(pose(1e3, p))
                time.sleep(0.05)
            assert mapper.poll() is None, "a moving base is not silence"
            # then it stands still, its pose repeated: silence, the timeout ends the map
            deadline = time.monotonic() + 120
            while mapper.poll() is None and time.monotonic() < deadline:
                poses.publish(pose(1e3, p))
                time.sleep(0.05)
            out, _ = mapper.communicate(timeout=60)
    finally:
        if mapper.poll() is None:
            mapper.kill()
            mapper.communicate()
    assert mapper.returncode == 0, out
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert (report["final"], report["ended_by"], report["n_points"]) == (True, "timeout",
                                                                       n_contacts)
    exploration = report["exploration"]
    assert exploration["planner"] == "lawnmower"
    assert exploration["path_length_m"] == pytest.approx(length, rel=1e-12), out
    history = exploration["coverage"]
    assert len(history) >= 2  # the updates while the contacts came, and the final map
    lengths = [entry[0] for entry in history]
    assert all(0.0 <= a <= b for a, b in zip(lengths, lengths[1:], strict=False))
    assert lengths[-1] <= exploration["path_length_m"]
    assert all(0.0 <= entry[1] <= 1.0 for entry in history)
    assert exploration["coverage_final"] == history[-1][1]
    # the final map's coverage, by the definition, on the same points fitted here
    acc = Accumulator(1)
    for i in range(n_contacts):
        receive(acc, contact(i))
    params = MapperParams(out_dir=str(tmp_path / "here"), plot=False, cells=16, scene=str(scene),
                          explore_planner="lawnmower")
    [world] = fit_frames(acc, params)
    assert world.result.frame_id == SCENE_FRAME
    samples = coverage_samples(params.truth(SCENE_FRAME), [-0.1, -0.1, 0.05], [0.1, 0.1, 0.1],
                               reach_m=0.05)  # the longest whisker's length
    assert len(samples) > 4000  # the whole ball lies within reach: 4 pi r^2 / (1 mm)^2
    expected = coverage(samples, world.vertices, 1e-3)
    assert 0.0 < expected < 1.0  # the upper half is touched, the lower is not
    assert exploration["coverage_final"] == expected
    text = (tmp_path / "out" / "report.txt").read_text()
    assert f"exploration (lawnmower): path {length * 1e3:.4g} mm, coverage " \
           f"{expected:.1%} of the true surface in reach ({len(history)} map(s))" in text
    assert "Traceback" not in out


def map_after_a_step(tmp_path: Path, endpoints: Endpoints, contacts: int, end_poses: bool
                     ) -> tuple[int, str, dict[str, Any]]:
    """A mapper hears the base move 5 mm (and the pose stream end, with ``end_poses``), then
    ``contacts`` contacts and their stream's end: its exit code, output and report."""
    mapper = start_mapper(tmp_path, endpoints, write_scene(tmp_path))
    try:
        with Publisher(TOPIC, ContactPointArray, endpoints) as pub, \
                Publisher(POSE_TOPIC, RobotPose, endpoints) as poses, \
                Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses:
            wait_heard([pub, poses], statuses)
            poses.publish(pose(0.0, np.zeros(3)))
            poses.publish(pose(1.0, np.array([0.0, 0.003, 0.004])))
            if end_poses:
                poses.publish_end_of_stream("/robot")
            deadline = time.monotonic() + 60  # taken in before the contacts come
            while time.monotonic() < deadline:
                rx = statuses.receive(0.1)
                if (rx is not None and rx.msg.node == "/mapper"
                        and rx.msg.counters["received"] >= 2 + end_poses):
                    break
            else:
                pytest.fail("the mapper never received the poses")
            for i in range(contacts):
                pub.publish(contact(i))
            pub.publish_end_of_stream("/contacts")
            out, _ = mapper.communicate(timeout=120)
    finally:
        if mapper.poll() is None:
            mapper.kill()
            mapper.communicate()
    return mapper.returncode, out, json.loads((tmp_path / "out" / "report.json").read_text())


def test_the_end_of_the_pose_stream_ends_nothing(tmp_path: Path, endpoints: Endpoints) -> None:
    code, out, report = map_after_a_step(tmp_path, endpoints, 60, end_poses=True)
    assert code == 0, out  # the pose stream's end is no contact source's: it ended nothing
    assert (report["ended_by"], report["sources_ended"], report["n_points"]) == (
        "streams", ["/contacts"], 60)
    assert report["exploration"]["path_length_m"] == pytest.approx(0.005, rel=1e-12)


def test_an_exploration_that_touched_nothing_ends_with_an_empty_map_and_says_so(
        tmp_path: Path, endpoints: Endpoints) -> None:
    code, out, report = map_after_a_step(tmp_path, endpoints, 0, end_poses=False)
    assert code == 3, out  # EXIT_EMPTY_MAP
    assert "the map is empty: the exploration touched nothing" in out, out
    assert report["n_points"] == 0
    assert report["exploration"]["path_length_m"] == pytest.approx(0.005, rel=1e-12)
    assert report["exploration"]["coverage_final"] == 0.0


def test_without_explore_planner_the_exploration_is_null(tmp_path: Path) -> None:
    acc = Accumulator(1)
    for i in range(60):
        receive(acc, contact(i))
    params = MapperParams(out_dir=str(tmp_path), plot=False, cells=16,
                          scene=str(write_scene(tmp_path)))
    report, _ = write_outputs(acc, params, tmp_path)
    assert report.exploration is None
    assert json.loads((tmp_path / "report.json").read_text())["exploration"] is None
    assert "exploration" not in (tmp_path / "report.txt").read_text()


@pytest.mark.parametrize(("explore", "params", "message"), [
    (True, {"explore_planner": "lawnmower", "scene": ""}, r"'explore_planner'.*without a scene"),
    (False, {"explore_planner": "lawnmower"}, r"'explore_planner'.*has no explore key"),
    (True, {"pose_topic": POSE_TOPIC}, r"'pose_topic'.*without explore_planner"),
    (True, {"explore_planner": "x", "pose_topic": TOPIC, "topics": (TOPIC,)},
     r"'pose_topic'.*other than the contact topics"),
    (True, {"explore_planner": "x", "coverage_tol_m": 0.0}, r"coverage_tol_m"),
])
def test_bad_exploration_parameters_are_refused_at_start(
        tmp_path: Path, explore: bool, params: dict[str, Any], message: str) -> None:
    scene = str(write_scene(tmp_path, explore))
    with pytest.raises(ValueError, match=message):
        MapperParams(**{"scene": scene, **params})
