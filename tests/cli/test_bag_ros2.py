"""`vibrissa bag export --format ros2` and `vibrissa bag import`: the robot demo's wrenches and
poses read back from the ROS 2 bag by two independent decoders (rosbags, mcap_ros2) hold the
same values, with the sensor's sign; a ROS 2 bag imported and replayed through the real nodes
gives the library's contact points; bad input is one line and exit 2."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap_ros2.reader import read_ros2_messages
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys.stores import ros2_jazzy as ros

from tests.system.test_export_stamps import ros2_times
from tests.system.test_system_pipeline import LAUNCH, TIMEOUT_S, Launch, Probe, entries, node, set_param
from vibrissa.cli.main import main as vibrissa_main
from vibrissa.formats.scene_file import load_robot, load_scene
from vibrissa.msgs import (
    ContactPointArray,
    EndOfStream,
    NodeStatus,
    RobotPose,
    WhiskerWrenchArray,
    codec,
)
from vibrissa.msgs.codec import encode
from vibrissa.nodes.wrench_source import WrenchSourceParams, scene_stream
from vibrissa.scene import SamplePhase, reconstruct_along, simulate
from vibrissa.status import ContactStatus
from vibrissa.wire.bag import BagReader, BagWriter
from vibrissa.wire.ros2_bag import TYPESTORE, import_ros2, stamp_from_ros, stamp_to_ros

SCENE = LAUNCH / "robot" / "scene.yaml"
WRENCH, POSE = "/robot/wrench", "/robot/pose"


def _ns(stamp: float) -> int:
    sec, nanosec = stamp_to_ros(stamp)
    return sec * 1_000_000_000 + nanosec


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """The robot demo's wrench and pose topics as `bag record` writes them, plus a contact
    point array and statuses, exported with `vibrissa bag export --format ros2`."""
    tmp = tmp_path_factory.mktemp("ros2")
    scene = load_scene(SCENE)
    results = simulate(scene, workers=1)
    bag = tmp / "robot.mcap"
    msgs: list[tuple[str, Any]] = []
    with BagWriter(bag) as writer:
        # poses at the path's own rate (500 Hz), so that interpolating them is the path itself
        # (at 100 Hz the chord of the arc is 0.3 um off it: launch/robot.yaml)
        params = WrenchSourceParams(mode="scene", scene=str(SCENE), pose_rate_hz=500.0)
        for stamp, msg in scene_stream(scene, results, params):
            topic = POSE if isinstance(msg, RobotPose) else WRENCH
            writer.write(topic, encode(msg), _ns(stamp) + 1000)
            msgs.append((topic, msg))
        contacts = ContactPointArray(
            stamp=0.1234567891, seq=3, frame_id="world", whisker_ids=["w11", "w00"],
            point=np.array([[0.1, -0.2, 0.3], [1 / 3, 2 / 3, 0.05]]), s1=np.array([0.02, 0.031]),
            phase=np.array([1, 2], np.int32), force=np.zeros((2, 3)), status=np.zeros(2, np.int32))
        writer.write("/robot/contact", encode(contacts), 5_000_000_000)
        writer.write("/robot/contact", encode(EndOfStream(stamp=5.0, source="/r", count=1)),
                     5_000_000_001)
        writer.write("/vibrissa/status", encode(NodeStatus(stamp=5.0, node="/r", state="running",
                                                           counters={}, publishes={},
                                                           subscribes={}, seen_topics=[])),
                     5_000_000_002)
    out = tmp / "robot_ros2"
    yield {"tmp": tmp, "scene": scene, "results": results, "bag": bag, "msgs": msgs,
           "contacts": contacts, "out": out}


def test_export_writes_a_rosbag2_folder_and_counts_what_it_skips(
        demo: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(demo["bag"]), str(demo["out"]),
                          "--robot", str(SCENE)]) == 0
    err = capsys.readouterr().err
    assert "skipped 2 (1 vibrissa/EndOfStream, 1 vibrissa/NodeStatus)" in err, err
    meta = (demo["out"] / "metadata.yaml").read_text()
    assert "storage_identifier: mcap" in meta and "serialization_format: cdr" in meta
    assert len(list(demo["out"].glob("*.mcap"))) == 1


def _rosbags_messages(out: Path) -> list[tuple[str, int, Any]]:
    with AnyReader([out]) as reader:
        qos = {c.topic: getattr(c.ext, "offered_qos_profiles", []) for c in reader.connections}
        assert [q.durability.name for q in qos["/tf_static"]] == ["TRANSIENT_LOCAL"]
        return [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]


def _mcap_ros2_messages(out: Path) -> list[tuple[str, int, Any]]:
    (file,) = out.glob("*.mcap")
    return [(m.channel.topic, m.log_time_ns, m.ros_msg) for m in read_ros2_messages(str(file))]


@pytest.mark.parametrize("decode", [_rosbags_messages, _mcap_ros2_messages])
def test_both_decoders_read_the_wrenches_poses_mounts_and_points_back(
        demo: dict[str, Any], decode: Any) -> None:
    if not demo["out"].exists():
        assert vibrissa_main(["bag", "export", "--format", "ros2", str(demo["bag"]),
                              str(demo["out"]), "--robot", str(SCENE)]) == 0
    got = decode(demo["out"])
    by_topic: dict[str, list[tuple[int, Any]]] = {}
    for topic, t, msg in got:
        by_topic.setdefault(topic, []).append((t, msg))
    (names,) = by_topic["/vibrissa/whiskers"]
    whiskers = json.loads(names[1].data)
    assert whiskers == sorted(w.name for w in demo["scene"].whiskers)
    # the wrench: one topic per whisker, the sensor's reading -f0, -m0, exactly, ns stamps
    expected_wrenches: dict[str, list[tuple[int, str, np.ndarray, np.ndarray]]] = {}
    poses: list[RobotPose] = []
    for _, msg in demo["msgs"]:
        if isinstance(msg, WhiskerWrenchArray):
            for w, frame, f0, m0 in zip(msg.whisker_ids, msg.frame_ids, msg.f0, msg.m0, strict=True):
                expected_wrenches.setdefault(w, []).append((_ns(msg.stamp), frame, f0, m0))
        else:
            poses.append(msg)
    assert len(expected_wrenches) == 8
    for w, rows in expected_wrenches.items():
        msgs = [m for _, m in by_topic[f"{WRENCH}/{w}"]]
        assert len(msgs) == len(rows)
        for (stamp_ns, frame, f0, m0), m in zip(rows, msgs, strict=True):
            assert m.header.frame_id == frame == f"{w}/clamp"
            assert m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec == stamp_ns
            force = np.array([m.wrench.force.x, m.wrench.force.y, m.wrench.force.z])
            torque = np.array([m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z])
            assert np.array_equal(force, -f0) and np.array_equal(torque, -m0)
    # the sign, once more on a touching sample: the rod pushes the sensor against f0
    k = next(i for i, r in enumerate(expected_wrenches["w00"]) if r[2][0] != 0)
    m = by_topic[f"{WRENCH}/w00"][k][1]
    assert m.wrench.force.x == -expected_wrenches["w00"][k][2][0] != 0.0
    # the robot's poses on /tf, the mounts on /tf_static
    tf = [m.transforms[0] for _, m in by_topic["/tf"]]
    assert len(tf) == len(poses)
    for pose, t in zip(poses, tf, strict=True):
        assert (t.header.frame_id, t.child_frame_id) == ("world", "base_link")
        assert t.header.stamp.sec * 1_000_000_000 + t.header.stamp.nanosec == _ns(pose.stamp)
        r = t.transform
        assert [r.translation.x, r.translation.y, r.translation.z] == pose.position.tolist()
        assert [r.rotation.x, r.rotation.y, r.rotation.z, r.rotation.w] == pose.orientation.tolist()
    ((_, static),) = by_topic["/tf_static"]
    mounts = {t.child_frame_id: t for t in static.transforms}
    for whisker in load_robot(SCENE):
        t = mounts[f"{whisker.name}/clamp"]
        assert t.header.frame_id == "base_link"
        p = [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z]
        assert p == whisker.X_RC.translation.tolist()
    # the contact points: float32 x, y, z, the whisker's index, phase, s1
    ((t_ns, cloud),) = by_topic["/robot/contact"]
    contacts: ContactPointArray = demo["contacts"]
    # logged at its stamp, not when it was recorded (5 s)
    assert t_ns == 123_456_789 and cloud.header.frame_id == "world"
    assert (cloud.header.stamp.sec, cloud.header.stamp.nanosec) == (0, 123456789)
    names_dtype = {f.name: f.offset for f in cloud.fields}
    assert list(names_dtype) == ["x", "y", "z", "whisker", "phase", "s1"]
    dtype = np.dtype({"names": list(names_dtype), "offsets": list(names_dtype.values()),
                      "formats": ["<f4", "<f4", "<f4", "<u2", "u1", "<f4"],
                      "itemsize": cloud.point_step})
    cloud_rows: Any = np.frombuffer(bytes(cloud.data), dtype)
    assert cloud.width == len(cloud_rows) == 2
    xyz = np.stack([cloud_rows["x"], cloud_rows["y"], cloud_rows["z"]], axis=1)
    assert np.array_equal(xyz, contacts.point.astype(np.float32))
    assert [whiskers[i] for i in cloud_rows["whisker"]] == contacts.whisker_ids
    assert cloud_rows["phase"].tolist() == [1, 2]
    assert np.array_equal(cloud_rows["s1"], contacts.s1.astype(np.float32))


def test_a_scene_recorded_fast_exports_at_its_stamps_spanning_the_path_from_the_epoch(
        demo: dict[str, Any], tmp_path: Path) -> None:
    """The robot's stream stamped from an epoch and recorded as fast as it was made (within
    a few ms of the recording clock, statuses between): in the ROS 2 bag every message is logged
    at its stamp, poses a ``pose_delay`` late sorted in among the wrenches, so the bag spans
    the path's 3.4 s from the epoch, and the mounts and names are at the epoch."""
    epoch = 1_767_225_600.25
    scene = demo["scene"]
    t = scene.path.t
    params = WrenchSourceParams(mode="scene", scene=str(SCENE), pose_rate_hz=100.0,
                                pose_delay_s=0.05, epoch_s=epoch)
    stream = [msg for _, msg in scene_stream(scene, demo["results"], params)]
    wrenches = [m for m in stream if isinstance(m, WhiskerWrenchArray)]
    poses = [m for m in stream if isinstance(m, RobotPose)]
    assert [m.stamp for m in wrenches] == [epoch + s for s in t.tolist()]
    assert (poses[0].stamp, poses[-1].stamp) == (epoch, epoch + t[-1])
    bag = tmp_path / "robot.mcap"
    recording_ns = 1_795_000_000_000_000_000  # the recorder's clock, 2026-11-18
    with BagWriter(bag) as writer:
        for k, msg in enumerate(stream):
            writer.write(POSE if isinstance(msg, RobotPose) else WRENCH, encode(msg),
                         recording_ns + 1000 * k)
            if k % 1000 == 0:
                writer.write("/vibrissa/status", encode(NodeStatus(
                    stamp=recording_ns / 1e9, node="/r", state="running", counters={},
                    publishes={}, subscribes={}, seen_topics=[])), recording_ns + 1000 * k)
    out = tmp_path / "ros2"
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(bag), str(out),
                          "--robot", str(SCENE)]) == 0
    stamped, unstamped = ros2_times(out)
    assert all(t_ns == stamp_ns for _, t_ns, stamp_ns in stamped)
    assert len(stamped) == sum(len(m.whisker_ids) for m in wrenches) + len(poses) + len(scene.whiskers)
    assert {t_ns for topic, t_ns, _ in stamped if topic == "/tf_static"} == {_ns(epoch)}
    assert unstamped == [_ns(epoch)]
    with AnyReader([out]) as reader:
        assert reader.start_time == _ns(epoch)
        assert reader.end_time - 1 == _ns(epoch + t[-1])
        assert abs((reader.end_time - 1 - reader.start_time) / 1e9 - (t[-1] - t[0])) < 1e-6


def test_a_stamp_before_1970_is_refused_as_a_log_time(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "old.mcap"
    with BagWriter(bag) as writer:
        writer.write(WRENCH, encode(WhiskerWrenchArray(
            stamp=-0.5, seq=0, whisker_ids=["w"], frame_ids=["w/clamp"], f0=np.zeros((1, 3)),
            m0=np.zeros((1, 3)))), 1_000)
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(bag), str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "is stamped -0.5 s, before 1970" in err and not (tmp_path / "o").exists()


def test_stamps_go_to_the_nanosecond_and_back_exactly() -> None:
    for stamp in (0.0, 0.002, 3.398, 1.5e9 + 0.25, 1_700_000_000.123456, -0.5):
        sec, nanosec = stamp_to_ros(stamp)
        assert 0 <= nanosec < 1_000_000_000
        assert stamp_from_ros(sec, nanosec) == stamp
    assert stamp_to_ros(-0.5) == (-1, 500_000_000)


def _ros2_bag(path: Path, wrenches: dict[str, list[tuple[float, tuple[float, ...]]]],
              tf: list[tuple[float, str, str, tuple[float, ...]]]) -> None:
    """A ROS 2 bag as a robot records it: WrenchStamped per whisker, TFMessage on /tf."""
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    conns = {t: writer.add_connection(t, "geometry_msgs/msg/WrenchStamped", typestore=TYPESTORE)
             for t in wrenches}
    tf_conn = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=TYPESTORE)
    rows: list[tuple[int, Any, Any, str]] = []
    for topic, samples in wrenches.items():
        for stamp, w in samples:
            sec, nanosec = stamp_to_ros(stamp)
            msg = ros.geometry_msgs__msg__WrenchStamped(
                header=ros.std_msgs__msg__Header(
                    stamp=ros.builtin_interfaces__msg__Time(sec=sec, nanosec=nanosec),
                    frame_id=f"{topic.rsplit('/', 2)[-2]}/clamp"),
                wrench=ros.geometry_msgs__msg__Wrench(
                    force=ros.geometry_msgs__msg__Vector3(x=w[0], y=w[1], z=w[2]),
                    torque=ros.geometry_msgs__msg__Vector3(x=w[3], y=w[4], z=w[5])))
            rows.append((_ns(stamp) + 7, conns[topic], msg, "geometry_msgs/msg/WrenchStamped"))
    for stamp, parent, child, pq in tf:
        sec, nanosec = stamp_to_ros(stamp)
        t = ros.geometry_msgs__msg__TransformStamped(
            header=ros.std_msgs__msg__Header(
                stamp=ros.builtin_interfaces__msg__Time(sec=sec, nanosec=nanosec), frame_id=parent),
            child_frame_id=child, transform=ros.geometry_msgs__msg__Transform(
                translation=ros.geometry_msgs__msg__Vector3(x=pq[0], y=pq[1], z=pq[2]),
                rotation=ros.geometry_msgs__msg__Quaternion(x=pq[3], y=pq[4], z=pq[5], w=pq[6])))
        rows.append((_ns(stamp), tf_conn, ros.tf2_msgs__msg__TFMessage(transforms=[t]),
                     "tf2_msgs/msg/TFMessage"))
    for t_ns, conn, msg, msgtype in sorted(rows, key=lambda r: r[0]):
        writer.write(conn, t_ns, TYPESTORE.serialize_cdr(msg, msgtype))
    writer.close()


def test_import_of_a_robot_bag_gives_wrenches_in_clamp_frames_and_poses(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "robot_ros2"
    _ros2_bag(src, {"/left/wrench": [(1.0, (1.0, 2.0, -3.0, 0.1, 0.2, 0.3)),
                                     (1.01, (0.5, 0.0, 0.0, 0.0, -0.25, 0.0))],
                    "/right/wrench": [(1.005, (0.0, -1.5, 0.0, 0.125, 0.0, 0.0))]},
              [(0.999, "odom", "base_link", (0, 0, 0, 0, 0, 0, 1)),
               (1.0, "world", "base_link", (0.1, 0.2, 0.3, 0.0, 0.0, 0.6, 0.8))])
    out = tmp_path / "imported.mcap"
    assert vibrissa_main(["bag", "import", str(src), str(out), "--wrench-topic", "/left/wrench",
                          "--wrench-topic", "/right/wrench", "--whisker", "wl",
                          "--whisker", "wr"]) == 0
    err = capsys.readouterr().err
    assert "wrote 3 wrench sample(s) (wl 2, wr 1) and 1 RobotPose" in err
    assert "1 other /tf transform(s) left out" in err
    got = [(r.topic, r.log_time_ns, codec.decode(r.payload)) for r in BagReader(out)]
    wrenches = [(t, m) for topic, t, m in got if topic == WRENCH]
    assert [m.whisker_ids for _, m in wrenches] == [["wl"], ["wr"], ["wl"]]  # one row each
    assert [m.seq for _, m in wrenches] == [0, 0, 1]
    assert [m.stamp for _, m in wrenches] == [1.0, 1.005, 1.01]
    assert [t for t, _ in wrenches] == [_ns(1.0) + 7, _ns(1.005) + 7, _ns(1.01) + 7]
    first: WhiskerWrenchArray = wrenches[0][1]
    assert first.frame_ids == ["left/clamp"] and not first.has_pose
    # the sign back: f0 is the clamp's reaction on the rod, minus the sensor's reading
    assert first.f0.tolist() == [[-1.0, -2.0, 3.0]] and first.m0.tolist() == [[-0.1, -0.2, -0.3]]
    (pose,) = [m for topic, _, m in got if topic == POSE]
    assert (pose.frame_id, pose.child_frame_id, pose.stamp) == ("world", "base_link", 1.0)
    assert pose.position.tolist() == [0.1, 0.2, 0.3]
    assert pose.orientation.tolist() == [0.0, 0.0, 0.6, 0.8]


def test_an_exported_bag_imports_and_replays_through_the_nodes_to_the_library_points(
        demo: dict[str, Any]) -> None:
    """ROS 2 bag of the robot demo -> `vibrissa bag import` -> wrench_source (replay) ->
    reconstructor with the robot description: the library's Step 2 of the same wrenches."""
    if not demo["out"].exists():
        assert vibrissa_main(["bag", "export", "--format", "ros2", str(demo["bag"]),
                              str(demo["out"]), "--robot", str(SCENE)]) == 0
    scene, results, tmp = demo["scene"], demo["results"], demo["tmp"]
    imported = tmp / "imported.mcap"
    # without --wrench-topic: every WrenchStamped topic, each whisker named by its topic
    assert vibrissa_main(["bag", "import", str(demo["out"]), str(imported)]) == 0
    launch_entries = entries("robot.yaml")
    set_param(node(launch_entries, "reconstructor"), "wait_for", ["/mapper", "/probe"])
    launch = Launch(tmp, launch_entries, f"out:={tmp / 'replay'}", f"scene:={SCENE}",
                    "mode:=replay", f"bag:={imported}", "replay_rate:=0")
    probe = Probe(launch.endpoints(), ["/robot/contact"])
    try:
        points, _ = probe.collect(TIMEOUT_S)
        rc = launch.wait()
    finally:
        probe.close()
        launch.kill()
    assert rc == 0, launch.text()
    # the library: Step 2 of the simulated wrenches through the path's poses
    t = np.repeat(scene.path.t, len(results))
    names = np.array([r.name for r in results] * len(scene.path.t))
    f0 = np.stack([r.f0_n for r in results], axis=1).reshape(-1, 3)
    m0 = np.stack([r.m0_nm for r in results], axis=1).reshape(-1, 3)
    ok = np.stack([r.phase != SamplePhase.UNRESOLVED for r in results], axis=1).reshape(-1)
    rec = reconstruct_along(scene, t[ok], list(names[ok]), f0[ok], m0[ok])
    valid = rec.pose_ok & np.isin(rec.status, [ContactStatus.OK, ContactStatus.AXIAL_LOAD])
    # keys to the ns: a path time such as 2.5500000000000003 s comes back as the ns it rounds to
    expected = {(_ns(float(s)), str(n)): p for s, n, p, v in zip(t[ok], names[ok], rec.point_m, valid,
                                                             strict=True) if v}
    got = {(_ns(p.stamp), w): point for p in points if isinstance(p, ContactPointArray)
           for w, point in zip(p.whisker_ids, p.point, strict=True)}
    assert got.keys() == expected.keys() and len(got) > 1000
    lengths = {w.name: w.length_m for w in scene.whiskers}
    for key, point in got.items():
        # the stamps came back rounded to the ns (up to 0.5 ns off the path's times), and the
        # poses are interpolated there: the robot moves 0.12 m/s, 6e-11 m in 0.5 ns
        assert np.abs(point - expected[key]).max() <= 1e-8 * lengths[key[1]], key
    assert all(p.frame_id == "world" for p in points)


@pytest.mark.parametrize("case", ["missing_topic", "wrong_type", "not_a_bag", "no_bag",
                                  "no_such_transform"])
def test_import_refuses_bad_input_in_one_line_with_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    src = tmp_path / "ros2"
    _ros2_bag(src, {"/w0/wrench": [(1.0, (1.0, 0, 0, 0, 0, 0))]},
              [(1.0, "odom", "base_link", (0, 0, 0, 0, 0, 0, 1))])
    not_a_bag = tmp_path / "notes"
    not_a_bag.mkdir()
    (not_a_bag / "metadata.yaml").write_text("hello: [")
    words, expected = {
        "missing_topic": ([str(src), "--wrench-topic", "/w1/wrench"],
                          f"{src} has no topic /w1/wrench (it has: /tf, /w0/wrench)"),
        "wrong_type": ([str(src), "--wrench-topic", "/tf"],
                       f"{src}: topic /tf is tf2_msgs/msg/TFMessage, expected "
                       "geometry_msgs/msg/WrenchStamped"),
        "not_a_bag": ([str(not_a_bag), "--wrench-topic", "/w0/wrench"],
                      f"{not_a_bag} is not a readable ROS 2 bag"),
        "no_bag": ([str(tmp_path / "nowhere"), "--wrench-topic", "/w0/wrench"],
                   f"no ROS 2 bag at {tmp_path / 'nowhere'}"),
        "no_such_transform": ([str(src), "--wrench-topic", "/w0/wrench"],
                              f"{src}: no transform world -> base_link on /tf "
                              "(it has: odom -> base_link)"),
    }[case]
    out = tmp_path / "out.mcap"
    assert vibrissa_main(["bag", "import", words[0], str(out), *words[1:]]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vibrissa bag import: error: {expected}"), err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


@pytest.mark.parametrize("target", ["data", "metadata", "new_in_bag", "existing"])
def test_import_never_writes_over_its_input_nor_an_existing_file_unasked(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], target: str) -> None:
    """Import once emptied the bag's own data file when told to write there (and then called
    the bag damaged), and wrote over its metadata.yaml or any file without a word."""
    src = tmp_path / "ros2"
    _ros2_bag(src, {"/w0/wrench": [(1.0, (1.0, 0, 0, 0, 0, 0))]},
              [(1.0, "world", "base_link", (0, 0, 0, 0, 0, 0, 1))])
    (data,) = src.glob("*.mcap")
    other = tmp_path / "victim.yaml"
    other.write_text("keep me\n")
    out = {"data": data, "metadata": src / "metadata.yaml", "new_in_bag": src / "out.mcap",
           "existing": other}[target]
    before = {f: f.read_bytes() for f in [*src.iterdir(), other]}
    assert vibrissa_main(["bag", "import", str(src), str(out)]) == 2
    err = capsys.readouterr().err
    expected = ("exists (--overwrite replaces it)" if target == "existing"
                else f"would write into the input bag {src}")
    assert err == f"vibrissa bag import: error: {out} {expected}\n"
    assert {f: f.read_bytes() for f in [*src.iterdir(), other]} == before
    if target == "existing":  # asked to: it does
        assert vibrissa_main(["bag", "import", str(src), str(out), "--overwrite"]) == 0
        assert len(list(BagReader(out))) == 2


def test_export_refuses_an_existing_folder_and_a_bad_robot(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "b.mcap"
    with BagWriter(bag) as writer:
        writer.write("/w/wrench", encode(WhiskerWrenchArray(
            stamp=0.0, seq=0, whisker_ids=["w"], frame_ids=["w/clamp"], f0=[[1, 2, 3]],
            m0=[[0, 0, 0]])), 0)
    (tmp_path / "taken").mkdir()
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(bag), str(tmp_path / "taken")]) == 2
    assert "exists" in capsys.readouterr().err
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(bag), str(tmp_path / "o"),
                          "--robot", str(bag)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("vibrissa bag export: error:") and len(err.strip().splitlines()) == 1
    # and the row of one whisker goes to its row topic, with the sensor's sign
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(bag), "-o", str(tmp_path / "ok")]) == 0
    ((topic, _, msg),) = [m for m in _mcap_ros2_messages(tmp_path / "ok") if m[0] != "/vibrissa/whiskers"]
    assert topic == "/w/wrench/w" and (msg.wrench.force.x, msg.wrench.force.y) == (-1.0, -2.0)


LEGACY = Path(__file__).parents[1] / "data" / "legacy_types"
"""``legacy.mcap``, a bag of the retired single types WhiskerWrench and ContactPoint beside
arrays, and ``ros2/``, its ROS 2 export written while those were live types."""


def test_the_ros2_export_of_a_bag_of_the_retired_types_is_as_it_was(tmp_path: Path) -> None:
    """A retired WhiskerWrench still goes to its own topic (an array's rows to
    ``<topic>/<whisker>``), a ContactPoint to a PointCloud2 of one point: the same ROS 2
    messages byte for byte, in the same order, on the same topics; only their log times are now
    their stamps (the recording's clock is not carried)."""
    out = tmp_path / "ros2"
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(LEGACY / "legacy.mcap"),
                          str(out)]) == 0

    def messages(folder: Path) -> list[tuple[str, str, int, bytes]]:
        with AnyReader([folder]) as reader:
            return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]

    def untimed(metadata: Path) -> dict[str, Any]:
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
        for record in (info, *info["files"]):
            del record["starting_time"], record["duration"]
        return info  # type: ignore[no-any-return]

    got, want = messages(out), messages(LEGACY / "ros2")
    assert len(got) == 26
    assert [(c, ty, raw) for c, ty, _, raw in got] == [(c, ty, raw) for c, ty, _, raw in want]
    assert {t for t, *_ in got} >= {"/w0/wrench", "/w1/wrench", "/w0/contact", "/w1/contact",
                                    "/robot/wrench/a0", "/robot/wrench/a2"}
    stamped, unstamped = ros2_times(out)
    assert all(t_ns == stamp_ns for _, t_ns, stamp_ns in stamped)
    assert unstamped == [10_000_000_000]  # the first stamp, 10 s
    assert untimed(out / "metadata.yaml") == untimed(LEGACY / "ros2" / "metadata.yaml")


def test_the_foxglove_export_has_the_live_views_channels_at_the_bags_times(
        demo: dict[str, Any]) -> None:
    """`vibrissa bag export --format foxglove`: the bridge's channels in Foxglove's schemas,
    read back with the plain mcap reader: wrench series equal to the bag's f0 and m0 at the
    bag's log times, the robot poses and mounts on /tf, the contacts as a foxglove.PointCloud."""
    from mcap.reader import make_reader

    out = demo["tmp"] / "fox.mcap"
    assert vibrissa_main(["bag", "export", "--format", "foxglove", str(demo["bag"]), str(out),
                          "--robot", str(SCENE)]) == 0
    schemas: dict[str, tuple[str, str]] = {}
    rows: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    counts: Counter[str] = Counter()
    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            schemas[channel.topic] = (schema.name, schema.encoding)
            counts[channel.topic] += 1
            if channel.topic.startswith("/whiskers/"):
                rows.setdefault(channel.topic, []).append((message.log_time,
                                                           json.loads(message.data)))
    assert schemas["/tf"] == ("foxglove.FrameTransforms", "protobuf")
    assert schemas["/contacts"] == ("foxglove.PointCloud", "protobuf")
    names = [w.name for w in demo["scene"].whiskers]
    assert set(rows) == {f"/whiskers/{w}/wrench" for w in names}
    poses = [m for t, m in demo["msgs"] if t == POSE]
    assert counts["/tf"] >= len(poses) + 1  # every pose, and the mounts
    arrays = [m for t, m in demo["msgs"] if t == WRENCH]
    for k, w in enumerate(names):
        got = rows[f"/whiskers/{w}/wrench"]
        assert len(got) == len(arrays)
        for (log_time, row), array in zip(got, arrays, strict=True):
            assert log_time == _ns(array.stamp) + 1000  # the bag's log time
            assert row["frame_id"] == f"{w}/clamp" and row["seq"] == array.seq
            assert [row["f0"][a] for a in "xyz"] == array.f0[k].tolist()
            assert [row["m0"][a] for a in "xyz"] == array.m0[k].tolist()


def test_import_counts_and_leaves_out_non_finite_samples(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a ROS bag may hold NaN (a sensor's dropout) or inf: such samples are left out and
    # counted, the others imported
    nan, inf = float("nan"), float("inf")
    src = tmp_path / "nan_ros2"
    _ros2_bag(src, {"/robot/wrench/w0": [(1.0, (1.0, 0.0, 0.0, 0.0, 0.0, 0.0)),
                                         (1.01, (nan, 0.0, 0.0, 0.0, 0.0, 0.0)),
                                         (1.02, (0.0, 0.0, 0.0, 0.0, inf, 0.0))]},
              [(1.0, "world", "base_link", (0, 0, 0, 0, 0, 0, 1)),
               (1.01, "world", "base_link", (nan, 0, 0, 0, 0, 0, 1))])
    out = tmp_path / "imported.mcap"
    assert vibrissa_main(["bag", "import", str(src), str(out)]) == 0
    err = capsys.readouterr().err
    assert "wrote 1 wrench sample(s) (w0 1) and 1 RobotPose" in err
    assert "refused by the codec (NaN, inf or a bad name): /robot/wrench/w0 2, /tf 1" in err
    assert len(list(BagReader(out))) == 2


@pytest.fixture(scope="module")
def small_ros2_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, bytes]:
    """A ROS 2 bag of 2 whiskers x 12 wrenches and 12 poses, and its mcap file's bytes."""
    src = tmp_path_factory.mktemp("fuzz") / "ros2"
    rng = np.random.default_rng(5)
    _ros2_bag(src, {f"/w{j}/wrench": [(1.0 + 0.01 * k, tuple(rng.normal(size=6)))
                                      for k in range(12)] for j in range(2)},
              [(1.0 + 0.01 * k, "world", "base_link", (0.1 * k, 0, 0, 0, 0, 0, 1))
               for k in range(12)])
    (mcap,) = src.glob("*.mcap")
    return src, mcap.read_bytes()


@pytest.mark.slow
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.one_of(st.none(), st.integers(0, 94)),
       edits=st.lists(st.tuples(st.integers(0, 10**9), st.binary(min_size=1, max_size=40)),
                      max_size=4))
def test_a_damaged_ros2_bag_is_refused_or_its_losses_are_counted(
        tmp_path: Path, small_ros2_bag: tuple[Path, bytes], cut: int | None,
        edits: list[tuple[int, bytes]]) -> None:
    """Bytes of the bag's file overwritten, the file cut short, or both: the import either refuses
    the bag in a clear ValueError and writes nothing, or accounts for every message the bag
    lists on a wanted topic (written, refused, undecodable or unread)."""
    src, data = small_ros2_bag
    damaged = bytearray(data if cut is None else data[:len(data) * cut // 95])
    for at, chunk in edits:
        if damaged:
            i = at % len(damaged)
            damaged[i:i + len(chunk)] = chunk
    case = tmp_path / f"case{len(list(tmp_path.iterdir()))}"
    case.mkdir()
    (case / "metadata.yaml").write_bytes((src / "metadata.yaml").read_bytes())
    (case / next(src.glob("*.mcap")).name).write_bytes(bytes(damaged))
    out = case / "out.mcap"
    topics = {"/w0/wrench": "w0", "/w1/wrench": "w1"}
    try:
        result = import_ros2(case, out, topics)
    except ValueError as exc:
        assert str(exc).startswith(f"{case} is not a readable ROS 2 bag: ")
        assert not out.exists()
        return
    for topic, name in topics.items():
        accounted = (result.wrenches[name] + result.refused[topic] + result.undecodable[topic]
                     + result.unread[topic])
        assert accounted >= 12, (topic, result)
    assert result.lost == sum(result.undecodable.values()) + sum(result.unread.values())
    assert sum(1 for r in BagReader(out)) == sum(result.wrenches.values()) + result.poses


@pytest.mark.slow
@pytest.mark.parametrize("keep", [0.999, 0.5, 20 / 1e9])
def test_a_cut_ros2_bag_is_imported_as_far_as_it_reads(
        demo: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        keep: float) -> None:
    """The exported demo's .mcap cut at 99.9 % and 50 %: what was before the cut arrives as the
    uncut import has it, the summary names the damage, exit 4 (the whole bag was refused:
    "File end magic is invalid"). Cut inside its header (20 bytes): one line, exit 2."""
    ros2 = tmp_path / "ros2"
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(demo["bag"]), str(ros2)]) == 0
    whole = tmp_path / "whole.mcap"
    assert vibrissa_main(["bag", "import", str(ros2), str(whole)]) == 0
    (mcap,) = ros2.glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[:max(20, int(len(data) * keep))])
    capsys.readouterr()
    out = tmp_path / "cut.mcap"
    status = vibrissa_main(["bag", "import", str(ros2), str(out)])
    err = capsys.readouterr().err
    if keep < 1e-6:
        assert status == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
        assert err.startswith(f"vibrissa bag import: error: {ros2} is not a readable ROS 2 bag: "
                              f"{mcap.name} is cut off inside its MCAP header (20 bytes"), err
        assert not out.exists()
        return
    assert status == 4, err
    assert "DAMAGED bag: cut off at the end;" in err and "unreadable bytes" in err, err
    expected = [(r.topic, r.log_time_ns, r.payload) for r in BagReader(whole)]
    got = [(r.topic, r.log_time_ns, r.payload) for r in BagReader(out)]
    assert got == expected[:len(got)]
    assert len(got) > (0.98 if keep > 0.9 else 0.3) * len(expected)
    if len(got) < len(expected):
        assert "LOST, listed in the bag's metadata but not readable" in err
