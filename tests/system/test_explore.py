"""The robot explores by itself with real processes (launch/explore.yaml, its default scene): the
launch ends by itself within its path budget, the robot's body never enters an object (its
poses in the bag against the true objects' footprints, computed here from the scene file's
shapes), the report carries the coverage against path length, and a replay of its bag
(launch/robot.yaml mode:=replay), as recorded and as fast as possible, gives the same map bit
for bit."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from tests.system.test_first_hour import Launch
from vibrissa.msgs import RobotPose
from vibrissa.msgs.codec import decode
from vibrissa.wire.bag import BagReader

LAUNCH = Path(__file__).parents[2] / "launch"
SCENE = LAUNCH / "explore" / "scene.yaml"
DOMAIN = 1000 + os.getpid() % 500 * 2  # +0..+1; away from the other tests' ranges
BUDGET_M = 0.25


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def footprint_gap(obj: dict, xy: np.ndarray) -> np.ndarray:
    """Horizontal distance (N,) m from points xy (N, 2) to the object's footprint on the floor
    (its shadow from above; negative inside), for the scene's upright shapes."""
    centre = np.array(obj["position_m"][:2])
    if obj["shape"] == "sphere":
        return np.linalg.norm(xy - centre, axis=1) - obj["radius_m"]
    if obj["shape"] == "paraboloid":  # turned over: z = -h - a x^2 - b y^2, widest on the floor
        assert obj["a_per_m"] == obj["b_per_m"] and obj["quaternion_xyzw"] == [1, 0, 0, 0]
        radius = np.sqrt(-obj["h_m"] / obj["a_per_m"])
        return np.linalg.norm(xy - centre, axis=1) - radius
    assert obj["shape"] == "ellipsoid"
    rotation = Rotation.from_quat(obj["quaternion_xyzw"])
    assert np.allclose(rotation.apply([0.0, 0.0, 1.0]), [0.0, 0.0, 1.0])  # a turn about z
    a, b, _ = obj["semi_axes_m"]
    angles = np.linspace(0.0, 2 * np.pi, 3600, endpoint=False)
    outline = rotation.apply(np.column_stack([a * np.cos(angles), b * np.sin(angles),
                                              np.zeros_like(angles)]))[:, :2] + centre
    local = rotation.inv().apply(np.column_stack([xy - centre, np.zeros(len(xy))]))
    inside = (local[:, 0] / a) ** 2 + (local[:, 1] / b) ** 2 < 1.0
    gap = np.min(np.linalg.norm(xy[:, None] - outline[None], axis=2), axis=1)
    return np.where(inside, -gap, gap)


@pytest.mark.timeout(1600)  # the three launches' deadlines
def test_the_robot_explores_by_itself_never_enters_an_object_and_its_bag_replays_the_map(
        tmp_path: Path) -> None:
    out = tmp_path / "explore"
    launch = Launch(LAUNCH / "explore.yaml", f"out:={out}", f"budget_m:={BUDGET_M}",
                    domain=DOMAIN)
    assert launch.wait(700) == 0, launch.text()
    text = launch.text()
    assert "exploration ended:" in text and "'explorer' finished (exit 0)" in text, text
    report = json.loads((out / "report.json").read_text())
    assert (report["final"], report["ended_by"]) == (True, "streams")
    exploration = report["exploration"]
    assert exploration["planner"] == "uncertainty"
    assert 0.5 * BUDGET_M < exploration["path_length_m"] <= BUDGET_M + 0.01, text
    lengths, coverage = np.array(exploration["coverage"]).T
    assert np.all(np.diff(lengths) >= 0) and np.all((coverage >= 0) & (coverage <= 1))
    assert exploration["coverage_final"] == coverage[-1] > 0.05  # it found something

    scene = yaml.safe_load(SCENE.read_text())
    body_m = scene["explore"]["body_radius_m"]
    poses = [decode(r.payload) for r in BagReader(out / "explore.mcap") if r.topic == "/robot/pose"]
    xy = np.array([p.position[:2] for p in poses if isinstance(p, RobotPose)])
    assert len(xy) > 1000
    for obj in scene["objects"]:
        # the body stays out: it may touch, never overlap (the ball bulges at its equator,
        # between the rods' heights)
        assert footprint_gap(obj, xy).min() >= body_m, obj["name"]

    replay = tmp_path / "replay"
    again = Launch(LAUNCH / "robot.yaml", "mode:=replay", f"bag:={out / 'explore.mcap'}",
                   f"scene:={SCENE}", "cluster_eps:=0.01", f"out:={replay}",
                   domain=DOMAIN + 1)  # as recorded, with the exploration's radius
    assert again.wait(400) == 0, again.text()
    plys = sorted(p.name for p in out.glob("*.ply"))
    assert plys == sorted(p.name for p in replay.glob("*.ply"))  # no file of an earlier map
    assert {f"mesh_{obj['name']}.ply" for obj in report["frames"][0]["objects"]
            if obj["files"]} == {name for name in plys if name.startswith("mesh_")}
    for name in plys:  # digests: a diff of megabytes is no help
        assert digest(replay / name) == digest(out / name), name
    assert json.loads((replay / "report.json").read_text())["n_points"] == report["n_points"]

    # as fast as possible: 30 000 messages would overrun the proxy's queue for the
    # reconstructor (its tail and EndOfStream dropped, the graph waiting for an end)
    fast = tmp_path / "fast"
    again = Launch(LAUNCH / "robot.yaml", "mode:=replay", f"bag:={out / 'explore.mcap'}",
                   "replay_rate:=0", f"scene:={SCENE}", "cluster_eps:=0.01", f"out:={fast}",
                   domain=DOMAIN + 1)
    assert again.wait(400) == 0, again.text()
    for name in plys:
        assert digest(fast / name) == digest(out / name), name
