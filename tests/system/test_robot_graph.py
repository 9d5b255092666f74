"""The robot node graph with real processes (launch/robot.yaml): wrenches in clamp frames and a
lagging pose stream give the library's contact points on the true surfaces, and a bag of the
wrench and pose topics replays to the same points bit for bit."""

from __future__ import annotations

import json
import os
import re
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.system.test_system_pipeline import LAUNCH, TIMEOUT_S, Launch, Probe, entries, node, set_param
from vibrissa.formats.scene_file import load_scene
from vibrissa.msgs import ContactPointArray, EndOfStream
from vibrissa.runtime.node import EXIT_LOST_DATA
from vibrissa.scene import SamplePhase, reconstruct_along, simulate
from vibrissa.status import ContactStatus

SCENE = LAUNCH / "robot" / "scene.yaml"
CONTACT, WRENCH, POSE = "/robot/contact", "/robot/wrench", "/robot/pose"


def _run(tmp: Path, launch_entries: list[dict[str, Any]], *words: str
         ) -> tuple[int, list[ContactPointArray], EndOfStream, Launch, dict[str, int]]:
    launch = Launch(tmp, launch_entries, *words)
    probe = Probe(launch.endpoints(), [CONTACT])
    try:
        arrays, eos = probe._until_end(ContactPointArray, TIMEOUT_S)
        status = probe.status_of("/robot/reconstructor",
                                 lambda s: s.counters.get("published", 0) >= eos.count, 30)
        rc = launch.wait()
    finally:
        probe.close()
        launch.kill()
    return rc, arrays, eos, launch, dict(status.counters)


@pytest.fixture(scope="module")
def robot_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """launch/robot.yaml with the pose stream 50 ms late, the probe, and a recorder of the
    wrench and pose topics."""
    tmp = tmp_path_factory.mktemp("robot")
    bag = tmp / "robot.mcap"
    launch = entries("robot.yaml")
    source = node(launch, "wrench_source")
    set_param(source, "wait_for", ["reconstructor", "/recorder"])
    set_param(node(launch, "reconstructor"), "wait_for", ["/mapper", "/probe"])
    # every wrench waits for its pose, however late a loaded machine sends the last ones (they
    # can come more than the default 0.5 s after their wrenches)
    set_param(node(launch, "reconstructor"), "pose_timeout_s", 30.0)
    launch.insert(len(launch) - 1, {"node": {
        "pkg": "vibrissa", "exec": "recorder", "name": "recorder",
        "param": [{"name": "output", "value": str(bag)}, {"name": "topics", "value": [WRENCH, POSE]}]}})
    # epoch:=0: stamped with the path's own clock, the library's keys
    rc, arrays, eos, ended, counters = _run(tmp, launch, f"out:={tmp / 'out'}", "pose_delay:=0.05",
                                            f"scene:={SCENE}", "epoch:=0")
    yield {"rc": rc, "arrays": arrays, "eos": eos, "text": ended.text(), "tmp": tmp, "bag": bag,
           "counters": counters, "out": tmp / "out"}


def test_the_robot_demo_gives_the_library_points_on_the_true_surfaces(robot_run: dict[str, Any]
                                                                       ) -> None:
    assert robot_run["rc"] == 0, robot_run["text"]
    scene = load_scene(SCENE)
    results = simulate(scene, workers=1)
    lengths = {w.name: w.length_m for w in scene.whiskers}
    # the library: Step 1 along the path, then Step 2 of its wrenches through the poses
    t = np.repeat(scene.path.t, len(results))
    names = [r.name for r in results] * len(scene.path.t)
    f0 = np.stack([r.f0_n for r in results], axis=1).reshape(-1, 3)
    m0 = np.stack([r.m0_nm for r in results], axis=1).reshape(-1, 3)
    resolved = np.stack([r.phase != SamplePhase.UNRESOLVED for r in results], axis=1).reshape(-1)
    rec = reconstruct_along(scene, t[resolved], [n for n, ok in zip(names, resolved, strict=True) if ok],
                            f0[resolved], m0[resolved])
    valid = rec.pose_ok & np.isin(rec.status, [ContactStatus.OK, ContactStatus.AXIAL_LOAD])
    expected = {(float(stamp), name): point for stamp, name, point, ok in zip(
        t[resolved], [n for n, ok in zip(names, resolved, strict=True) if ok], rec.point_m, valid, strict=True) if ok}
    arrays: list[ContactPointArray] = robot_run["arrays"]
    assert [a.seq for a in arrays] == list(range(len(scene.path.t)))
    got = {(a.stamp, w): p for a in arrays for w, p in zip(a.whisker_ids, a.point, strict=True)}
    assert got.keys() == expected.keys()
    assert len(got) > 1000 and {w for _, w in got} >= {"w00", "w01", "w10", "w11"}
    surfaces = [obj.surface(1.0) for obj in scene.objects]
    for key, point in got.items():
        length = lengths[key[1]]
        assert np.abs(point - expected[key]).max() <= 1e-12 * length, key
        on = min(abs(float(s.signed_distance(point[None])[0])) for s in surfaces)
        assert on <= 1e-9 * length, (key, on)
    assert all(a.frame_id == "world" for a in arrays)
    # a lag of 50 ms costs no point: every wrench waited for its pose
    counters = robot_run["counters"]
    assert counters["no_pose"] == 0 and counters["unknown_whisker"] == 0
    assert counters["robot_poses"] > 300
    out = robot_run["out"]
    assert (out / "cloud.ply").is_file() and (out / "map.png").stat().st_size > 20_000


def test_the_map_has_one_object_per_touched_object_with_its_whiskers(
        robot_run: dict[str, Any]) -> None:
    """The mapper's objects against the simulator's record of which object each contact was
    on: the same names, the same points per object and per whisker, a mesh file each."""
    assert robot_run["rc"] == 0, robot_run["text"]
    scene = load_scene(SCENE)
    touched: dict[str, dict[str, int]] = {}
    got = {(a.stamp, w) for a in robot_run["arrays"] for w in a.whisker_ids}
    for result in simulate(scene, workers=1):
        for stamp, k in zip(scene.path.t, result.object, strict=True):
            if (float(stamp), result.name) in got:
                assert k >= 0, (stamp, result.name)
                per = touched.setdefault(scene.objects[k].name, {})
                per[result.name] = per.get(result.name, 0) + 1
    assert set(touched) == {"ball", "egg"}
    report = json.loads((robot_run["out"] / "report.json").read_text())
    (frame,) = report["frames"]
    assert frame["frame_id"] == "world" and frame["noise_points"] == 0
    objects = {obj["name"]: obj for obj in frame["objects"]}
    assert objects.keys() == touched.keys()
    for name, obj in objects.items():
        assert {w["whisker_id"]: w["n_points"] for w in obj["whiskers"]} == touched[name]
        assert obj["n_points"] == sum(touched[name].values())
        assert obj["true_object"] == name and obj["cloud_to_surface_max"] <= 1e-9 * 0.06
        assert obj["n_triangles"] > 100 and Path(obj["files"]["mesh"]).is_file()


def test_a_bag_of_the_wrench_and_pose_topics_replays_to_the_same_points(
        robot_run: dict[str, Any]) -> None:
    """mode:=replay of the bag, into the folder that holds it as robot.mcap: the same points,
    and the bag is left as it was (a replay records nothing)."""
    assert robot_run["rc"] == 0, robot_run["text"]
    launch = entries("robot.yaml")
    set_param(node(launch, "reconstructor"), "wait_for", ["/mapper", "/probe"])
    tmp: Path = robot_run["tmp"]
    bag: Path = robot_run["bag"]
    assert bag.name == "robot.mcap"  # where robot.yaml's recorder would write with out:=tmp
    recorded = bag.read_bytes()
    rc, arrays, _, ended, counters = _run(tmp, launch, f"out:={tmp}", f"scene:={SCENE}",
                                          "mode:=replay", f"bag:={bag}", "replay_rate:=0")
    assert rc == 0, ended.text()
    assert "bag_recorder" not in ended.text()
    assert counters["no_pose"] == 0, (counters, ended.text())  # every tick found its pose
    assert arrays == robot_run["arrays"]  # every field, bit for bit
    assert bag.read_bytes() == recorded


def test_a_killed_reconstructor_respawns_and_the_loss_is_counted(robot_run: dict[str, Any]) -> None:
    """kill -9 of the reconstructor a third of the way along the path, with respawn: the
    respawned one places the rest (the same points as the undisturbed run, bit for bit), the
    run ends by itself, and what went by while it was down is counted as lost."""
    assert robot_run["rc"] == 0, robot_run["text"]
    tmp: Path = robot_run["tmp"]
    launch_entries = entries("robot.yaml")
    set_param(node(launch_entries, "reconstructor"), "wait_for", ["/mapper", "/probe"])
    samples = len(load_scene(SCENE).path.t)
    launch = Launch(tmp, launch_entries, f"out:={tmp / 'respawn'}", f"scene:={SCENE}",
                    "rate:=100", "respawn:=true")  # 100 path samples/s: 17 s, room to respawn
    probe = Probe(launch.endpoints(), [CONTACT])
    arrays: list[ContactPointArray] = []
    try:
        pid = int(launch.wait_line(r"started 'reconstructor' \(pid (\d+)\)").group(1))
        deadline = time.monotonic() + TIMEOUT_S
        while (not arrays or arrays[-1].seq < samples // 3) and time.monotonic() < deadline:
            rx = probe.sub.receive(0.2)
            if rx is not None and isinstance(rx.msg, ContactPointArray):
                arrays.append(rx.msg)
        os.kill(pid, signal.SIGKILL)
        more, _ = probe._until_end(ContactPointArray, TIMEOUT_S)
        arrays += more
        rc = launch.wait()
    finally:
        probe.close()
        launch.kill()
    text = launch.text()
    assert rc == EXIT_LOST_DATA, text  # it completed, with loss
    assert "respawned 'reconstructor'" in text
    seqs = [a.seq for a in arrays]
    assert seqs == sorted(seqs) and seqs[-1] == samples - 1  # to the path's end
    missing = samples - len(set(seqs))
    assert missing > 0
    match = re.search(r"data did not arrive in full: 'reconstructor' lost (\d+)", text)
    assert match and int(match.group(1)) > 0, text
    # what the respawned node placed is what the undisturbed run placed
    before = {a.seq: a for a in robot_run["arrays"]}
    for array in arrays:
        same = before[array.seq]
        for w, p in zip(array.whisker_ids, array.point, strict=True):
            assert np.array_equal(p, same.point[same.whisker_ids.index(w)]), (array.seq, w)
