"""The mapper with several objects, without sockets: contact lines of several whiskers on a
sphere and a rotated ellipsoid separated into objects, named after the scene, counted, fitted,
reported and drawn; the single-object map with ``true_surface`` as before."""

from __future__ import annotations

import dataclasses
import json
import os
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vibrissa.figures.map_figure import (
    MAX_NAME_CHARS,
    MapLayers,
    MeshLayer,
    draw_map,
    map_layers,
    plot_map,
    short_name,
)
from vibrissa.frames import Transform
from vibrissa.mapping import (
    Accumulator,
    TrueObject,
    cluster_points,
    fit_frame,
    is_covariance,
    whisker_lines,
)
from vibrissa.msgs import ContactPointArray, EndOfStream
from vibrissa.msgs.codec import decode, encode
from vibrissa.nodes import mapper
from vibrissa.nodes.mapper import MapperParams, receive
from vibrissa.runtime import load_params
from vibrissa.runtime.params import ParamError
from vibrissa.scene import SamplePhase, Scene, SceneObject, Whisker, robot_path, simulate
from vibrissa.surfaces import parse_surface

ROOT = Path(__file__).resolve().parents[2]

BALL_CENTRE = np.array([0.03, 0.0, 0.04])
EGG_CENTRE = [-0.03, 0.01, 0.045]
EGG_Q = [0.0, 0.0, 0.3826834, 0.9238795]  # 45 deg about z
BALL = SceneObject("ball", "sphere", {"radius_m": 0.015}, Transform(translation=BALL_CENTRE))
EGG = SceneObject("egg", "ellipsoid", {"semi_axes_m": [0.012, 0.008, 0.01]},
                  Transform.from_quaternion(EGG_Q, EGG_CENTRE))

# Contact lines as a whisker draws them: (whisker, object, polar angle, azimuths) in the object's
# body frame; whisker w1 touches the ball, then the egg.
LINES = [
    ("w0", BALL, 1.20, np.linspace(-0.8, 0.8, 60)),
    ("w1", BALL, 1.35, np.linspace(-0.8, 0.8, 60)),
    ("w1", EGG, 1.30, np.linspace(2.2, 3.8, 50)),
    ("w2", BALL, 1.50, np.linspace(-0.8, 0.8, 60)),
    ("w3", EGG, 1.50, np.linspace(2.2, 3.8, 50)),
]
STRAYS = np.array([[0.0, 0.12, 0.30], [0.0, -0.12, 0.30]])  # whisker w4: far from everything
EXPECTED = {  # built above: 3 lines of 60 on the ball, 2 of 50 on the egg
    "ball": {"n_points": 180, "whiskers": {"w0": 60, "w1": 60, "w2": 60}},
    "egg": {"n_points": 100, "whiskers": {"w1": 50, "w3": 50}},
}
SCENE = """\
mu: 0.2
objects:
  - {name: ball, shape: sphere, radius_m: 0.015, position_m: [0.03, 0.0, 0.04]}
  - {name: egg, shape: ellipsoid, semi_axes_m: [0.012, 0.008, 0.01],
     position_m: [-0.03, 0.01, 0.045], quaternion_xyzw: [0.0, 0.0, 0.3826834, 0.9238795]}
  - {name: pebble, shape: sphere, radius_m: 0.006, position_m: [0.0, 0.05, 0.03]}
whiskers:
  - {name: w0, length_m: 0.06, ei_nm2: 2.0e-5, mount: {position_m: [0.0, -0.01, 0.0]}}
  - {name: w1, length_m: 0.05, ei_nm2: 2.0e-5,
     mount: {position_m: [0.0, 0.0, 0.0], quaternion_xyzw: [0.0998334, 0, 0, 0.9950042]}}
  - {name: w2, length_m: 0.045, ei_nm2: 1.0e-5, mount: {position_m: [0.0, 0.01, 0.0]}}
  - {name: w3, length_m: 0.04, ei_nm2: 1.0e-5,
     mount: {position_m: [0.0, 0.02, 0.0], quaternion_xyzw: [-0.0998334, 0, 0, 0.9950042]}}
  - {name: w4, length_m: 0.035, ei_nm2: 1.0e-5, mount: {position_m: [0.0, 0.03, 0.0]}}
path: path.csv
"""


def line_points(obj: SceneObject, polar: float, azimuths: np.ndarray) -> np.ndarray:
    """Points (n, 3) m on the posed object at a polar angle and azimuths of its body frame."""
    unit = np.column_stack([np.cos(azimuths) * np.sin(polar), np.sin(azimuths) * np.sin(polar),
                            np.full(len(azimuths), np.cos(polar))])
    semi = (np.full(3, obj.sizes["radius_m"]) if obj.shape == "sphere"
            else np.array(obj.sizes["semi_axes_m"]))
    return obj.X_WO.apply(unit * semi)


def messages(frame_id: str = "world") -> list[Any]:
    """The lines as ticks: a ContactPointArray per tick (each whisker's next point, seq = tick),
    the strays as ContactPoints, then the end of the stream. Force on the rod: the object
    pushes it, along its outward normal (the contact force of a frictionless contact)."""
    per_whisker: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for whisker, obj, polar, azimuths in LINES:
        points = line_points(obj, polar, azimuths)
        normals = obj.surface(1.0).normal(points)
        per_whisker.setdefault(whisker, []).extend(zip(points, 0.02 * normals, strict=True))
    out: list[Any] = []
    for seq in range(max(len(rows) for rows in per_whisker.values())):
        ids = [w for w, rows in per_whisker.items() if seq < len(rows)]
        rows = [per_whisker[w][seq] for w in ids]
        out.append(ContactPointArray(
            stamp=float(seq), seq=seq, frame_id=frame_id, whisker_ids=ids,
            point=np.array([r[0] for r in rows]), s1=np.full(len(ids), 0.03),
            phase=np.full(len(ids), 2, dtype=np.int32), force=np.array([r[1] for r in rows]),
            status=np.zeros(len(ids), dtype=np.int32)))
    for i, point in enumerate(STRAYS):
        out.append(ContactPointArray(stamp=0.0, seq=i, whisker_ids=["w4"], frame_id=frame_id,
                                     point=[point], s1=[0.03], phase=[1],
                                     force=[[0.0, 0.0, -0.02]], status=[0]))
    out.append(EndOfStream(stamp=0.0, source="/reconstructor", count=len(out)))
    return out


def accumulate(msgs: list[Any]) -> Accumulator:
    acc = Accumulator(1)
    for msg in msgs:
        receive(acc, msg)
    return acc


def write_outputs(acc: Accumulator, params: MapperParams, out_dir: Path) -> tuple[dict[str, Any], Any]:
    """The mapper's files, messages and its report as report.json holds it."""
    report, sent = mapper.write_outputs(acc, params, out_dir)
    return report.as_dict(), sent


def write_scene(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "scene.yaml").write_text(SCENE)
    x = np.linspace(0.10, -0.10, 50)
    rows = ["t,x,y,z,qx,qy,qz,qw"] + [f"{0.1 * i},{x[i]},-0.03,0.0,0,0,0,1" for i in range(50)]
    (folder / "path.csv").write_text("\n".join(rows) + "\n")
    return folder / "scene.yaml"


def ply_vertices(path: Path) -> int:
    """The vertex count in a PLY header."""
    header = path.read_bytes().split(b"end_header")[0].decode("ascii")
    return int(next(line.split()[-1] for line in header.splitlines()
                    if line.startswith("element vertex")))


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) from the IHDR chunk; the signature checked."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


@pytest.fixture(scope="module")
def scene_map(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The map of the two objects with the scene known."""
    tmp = tmp_path_factory.mktemp("scene_map")
    params = MapperParams(out_dir=str(tmp / "out"), scene=str(write_scene(tmp)))
    report, sent = write_outputs(accumulate(messages()), params, tmp / "out")
    return {"report": report, "sent": sent, "out": tmp / "out", "params": params, "tmp": tmp}


def test_two_objects_are_found_named_counted_and_fitted(scene_map: dict[str, Any]) -> None:
    report, out = scene_map["report"], scene_map["out"]
    [frame] = report["frames"]
    assert [obj["name"] for obj in frame["objects"]] == ["ball", "egg"]  # by first point: w0
    for obj in frame["objects"]:
        expected = EXPECTED[obj["name"]]
        assert obj["n_points"] == expected["n_points"]
        assert {w["whisker_id"]: w["n_points"] for w in obj["whiskers"]} == expected["whiskers"]
        assert [w["whisker_id"] for w in obj["whiskers"]] == sorted(expected["whiskers"])
        assert obj["true_object"] == obj["name"]
        assert obj["cloud_to_surface_max"] < 1e-12  # exact points: rounding only
        assert obj["true_object_median_m"] < 1e-12
        assert obj["method"].startswith("gp implicit surface") and obj["n_triangles"] > 20
        assert obj["unknown_triangles"] > 0  # the boxes reach beyond what was touched
        assert obj["mesh_to_surface_mean"] < 0.3e-3 and obj["mesh_to_surface_max"] < 2e-3
        assert obj["std_max_m"] <= obj["max_std_m"]
        mesh = out / f"mesh_{obj['name']}.ply"
        assert obj["files"] == {"mesh": str(mesh)} and frame["files"][f"mesh_{obj['name']}"]
        assert ply_vertices(mesh) == obj["n_vertices"]
    assert frame["n_points"] == 282 and report["n_points"] == 282
    assert frame["noise_points"] == 2
    assert frame["noise_whiskers"] == [{"whisker_id": "w4", "n_points": 2}]
    # the strays' distance to the nearest true object, computed here from the scene objects
    pebble = SceneObject("pebble", "sphere", {"radius_m": 0.006},
                         Transform(translation=np.array([0.0, 0.05, 0.03])))
    far = np.min([np.abs(o.surface(1.0).signed_distance(STRAYS)) for o in (BALL, EGG, pebble)],
                 axis=0)
    assert frame["noise_to_surface_max"] == pytest.approx(float(far.max()), rel=1e-12)
    # the frame over its objects: the union mesh, the worst object
    assert frame["n_vertices"] == sum(o["n_vertices"] for o in frame["objects"])
    assert ply_vertices(out / "mesh.ply") == frame["n_vertices"]
    assert ply_vertices(out / "cloud.ply") == 282
    assert frame["cloud_to_surface_max"] == max(o["cloud_to_surface_max"]
                                                for o in frame["objects"])
    assert frame["mesh_to_surface_max"] == max(o["mesh_to_surface_max"] for o in frame["objects"])
    assert report["max_reconstruction_error_m"] == frame["cloud_to_surface_max"]
    assert frame["method"] == "; ".join(f"{o['name']}: {o['method']}" for o in frame["objects"])
    assert frame["clustering"]["method"] == "dbscan" and frame["clustering"]["min_points"] == 4
    assert report["scene_objects"] == ["ball", "egg", "pebble"]
    # the message carries every object's mesh, and the report.json what write_outputs returned
    cloud, mesh, unknown_mesh = (scene_map["sent"][0].cloud, scene_map["sent"][0].mesh,
                                 scene_map["sent"][0].unknown_mesh)
    assert len(cloud.points) == 282 and len(mesh.vertices) == frame["n_vertices"]
    # the unknown part goes apart, with the same stamp: the newest of the points (messages())
    assert len(unknown_mesh.triangles) == sum(o["unknown_triangles"] for o in frame["objects"])
    assert unknown_mesh.stamp == mesh.stamp == cloud.stamp == max(
        m.stamp for m in messages() if isinstance(m, ContactPointArray))
    assert json.loads((out / "report.json").read_text()) == report
    text = (out / "report.txt").read_text()
    assert "frame world: 282 points, 2 object(s), 2 noise point(s)" in text
    assert "object ball: 180 points from w0 (60), w1 (60), w2 (60); true object ball" in text
    assert "object egg: 100 points from w1 (50), w3 (50); true object egg" in text
    assert "noise: 2 point(s) in no object, from w4 (2)" in text
    assert f"at most {frame['noise_to_surface_max'] * 1e3:.4g} mm from a true object" in text


def test_each_object_gets_next_sweeps_in_the_report_and_as_messages(
        scene_map: dict[str, Any]) -> None:
    [frame] = scene_map["report"]["frames"]
    proposals = scene_map["sent"][0].proposals
    assert [(p.object, p.rank) for p in proposals] == [
        (obj["name"], rank) for obj in frame["objects"] for rank in (1, 2, 3)]
    text = (scene_map["out"] / "report.txt").read_text()
    for obj in frame["objects"]:
        mine = [p for p in proposals if p.object == obj["name"]]
        assert [p.offset for p in mine] == [s["offset_m"] for s in obj["next_sweeps"]]
        for before, after in zip(mine, mine[1:], strict=False):
            assert after.std_max_before == before.std_max_after
        assert all(p.std_max_after < p.std_max_before for p in mine)
        # in the range the object's contacts span along y, the default axis
        points = [row for row in scene_map["sent"][0][0].points]
        assert all(np.allclose(p.axis, [0.0, 1.0, 0.0]) for p in mine)
        assert all(min(q[1] for q in points) <= p.offset <= max(q[1] for q in points)
                   for p in mine)
    assert "next sweep 1: section at" in text


def test_the_png_is_an_image_a_person_can_read(scene_map: dict[str, Any]) -> None:
    import matplotlib.image

    png = scene_map["out"] / "map.png"
    assert scene_map["report"]["frames"][0]["files"]["png"] == str(png)
    width, height = png_size(png)
    assert width >= 1200 and height >= 700
    assert png.stat().st_size > 50_000
    pixels = matplotlib.image.imread(png)
    assert pixels.shape[:2] == (height, width)
    rgb = (pixels[..., :3] * 255).astype(np.int64)
    colours = np.unique(rgb[..., 0] << 16 | rgb[..., 1] << 8 | rgb[..., 2])
    assert len(colours) > 50  # not blank: wireframes, path, contacts in colours, meshes


@pytest.mark.slow
def test_identical_input_gives_identical_labels_and_files(
    scene_map: dict[str, Any], tmp_path: Path
) -> None:
    msgs = messages()
    points, _, ids, _ = accumulate(msgs).frames["world"].ordered()
    lines = whisker_lines(points, ids)
    first, second = cluster_points(points, lines), cluster_points(points, lines)
    np.testing.assert_array_equal(first.labels, second.labels)
    assert first.eps == second.eps and first.n_clusters == 2
    # again from scratch, the messages arriving in the reverse order: the same files
    params: MapperParams = scene_map["params"]
    again = tmp_path / "again"
    report, _ = write_outputs(accumulate(msgs[-2::-1] + msgs[-1:]), params, again)
    for name in ("cloud.ply", "mesh.ply", "mesh_ball.ply", "mesh_egg.ply", "map.png"):
        assert (again / name).read_bytes() == (scene_map["out"] / name).read_bytes(), name
    relocated = json.loads(json.dumps(report).replace(str(again), str(scene_map["out"])))
    assert relocated == scene_map["report"]


def test_another_process_on_one_thread_writes_the_same_files(
        scene_map: dict[str, Any]) -> None:
    # the fit's linear algebra is LAPACK, its mean a parallel numba loop: another process,
    # and one thread for both instead of the machine's, must not change a bit of the map
    other = scene_map["tmp"] / "other"
    script = ("import sys; from pathlib import Path; "
              "from tests.mapping.test_mapper_objects import accumulate, messages; "
              "from vibrissa.nodes.mapper import MapperParams, write_outputs; "
              "out = Path(sys.argv[1]); "
              "write_outputs(accumulate(messages()), MapperParams(out_dir=str(out), "
              "scene=sys.argv[2]), out)")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    subprocess.run([sys.executable, "-c", script, str(other), scene_map["params"].scene],
                   cwd=ROOT, env=env, check=True, timeout=300)
    for name in ("cloud.ply", "mesh.ply", "mesh_ball.ply", "mesh_egg.ply", "map.png"):
        assert (other / name).read_bytes() == (scene_map["out"] / name).read_bytes(), name


def test_without_a_scene_objects_are_numbered_by_their_first_point(tmp_path: Path) -> None:
    report, _ = write_outputs(accumulate(messages()),
                              MapperParams(out_dir=str(tmp_path), plot=False), tmp_path)
    [frame] = report["frames"]
    assert [(o["name"], o["n_points"]) for o in frame["objects"]] == [("object0", 180),
                                                                      ("object1", 100)]
    for obj in frame["objects"]:
        assert obj["true_object"] is None and obj["cloud_to_surface_max"] is None
        assert (tmp_path / f"mesh_{obj['name']}.ply").is_file()
    assert frame["noise_points"] == 2 and frame["noise_to_surface_max"] is None
    assert frame["cloud_to_surface_max"] is None and report["max_reconstruction_error_m"] is None


@pytest.mark.slow
def test_the_scene_is_the_truth_of_frame_world_only(scene_map: dict[str, Any],
                                                    tmp_path: Path) -> None:
    report, _ = write_outputs(accumulate(messages("arm")), scene_map["params"], tmp_path)
    [frame] = report["frames"]
    assert [o["name"] for o in frame["objects"]] == ["object0", "object1"]
    assert frame["cloud_to_surface_max"] is None
    assert (tmp_path / "mesh_object0_arm.ply").is_file()


@pytest.mark.slow
@pytest.mark.parametrize("join", [False, True])
def test_two_clusters_on_one_object_are_told_apart_or_joined(tmp_path: Path, join: bool) -> None:
    """Lines on opposite sides of the ball, 19 mm apart at the closest: with eps 6 mm DBSCAN
    makes two clusters, both on the ball, which the convex join makes one (the default)."""
    back = [(w, obj, polar, azimuths + np.pi) for w, obj, polar, azimuths in LINES
            if obj is BALL and w != "w1"]
    msgs = [m for m in messages() if getattr(m, "whisker_ids", None) != ["w4"]]  # no strays
    acc = accumulate(msgs)
    for i, (_, obj, polar, azimuths) in enumerate(back):
        points = line_points(obj, polar, azimuths)
        for k, (point, normal) in enumerate(zip(points, obj.surface(1.0).normal(points),
                                                strict=True)):
            receive(acc, ContactPointArray(
                stamp=0.0, seq=k, whisker_ids=[f"w{5 + i}"], frame_id="world", point=[point],
                s1=[0.03], phase=[2], force=[0.02 * normal], status=[0]))
    params = MapperParams(out_dir=str(tmp_path), scene=str(write_scene(tmp_path)),
                          cluster_eps_m=0.006, plot=False, join_convex=join)
    report, _ = write_outputs(acc, params, tmp_path)
    [frame] = report["frames"]
    assert frame["clustering"]["eps_m"] == 0.006 and frame["clustering"]["eps_rule"] == "given"
    assert frame["clustering"]["dbscan_clusters"] == 3
    objects = [(o["name"], o["true_object"], o["n_points"]) for o in frame["objects"]]
    text = (tmp_path / "report.txt").read_text()
    if not join:
        assert objects == [("ball", "ball", 180), ("egg", "egg", 100), ("ball-2", "ball", 120)]
        assert (tmp_path / "mesh_ball-2.ply").is_file()
        assert frame["clustering"]["joined_convex"] == [] and "joined" not in text
        return
    assert objects == [("ball", "ball", 300), ("egg", "egg", 100)]
    assert frame["clustering"]["joined_convex"] == [[0, 2]]
    assert "; 2 of its clusters joined as patches of one convex object" in text
    [ball] = [o for o in frame["objects"] if o["name"] == "ball"]
    assert ball["mesh_to_surface_max"] < 1e-3  # one surface around the ball's both sides
    assert not (tmp_path / "mesh_ball-2.ply").exists()


def test_two_objects_in_one_cluster_are_named_and_their_points_stay_exact(tmp_path: Path) -> None:
    """With eps 0.1 m the ball's and the egg's lines are one cluster: its points keep their
    distance to the nearest true object (the reconstruction error, rounding only), and the
    report says how many of them are nearer the other object."""
    params = MapperParams(out_dir=str(tmp_path), scene=str(write_scene(tmp_path)),
                          cluster_eps_m=0.1, plot=False)
    report, _ = write_outputs(accumulate(messages()), params, tmp_path)
    [frame] = report["frames"]
    [obj] = frame["objects"]  # the strays are 0.12 m out: still noise
    assert (obj["name"], obj["true_object"], obj["n_points"]) == ("ball", "ball", 280)
    assert obj["points_nearer_other"] == {"egg": 100}
    assert obj["cloud_to_surface_max"] < 1e-12 and report["max_reconstruction_error_m"] < 1e-12
    assert obj["mesh_to_surface_max"] > 1e-3  # one surface through both: not the ball's
    text = (tmp_path / "report.txt").read_text()
    assert "; TWO OBJECTS IN ONE: 100 of its points nearer egg" in text


OLD_REPORT_KEYS = {"n_points", "sources_ended", "true_surface", "rod_length_m",
                   "max_reconstruction_error_m", "frames", "lost", "streams", "files"}
OLD_FRAME_KEYS = {"frame_id", "n_points", "method", "n_vertices", "n_triangles",
                  "line_spacing_m", "cloud_to_surface_max", "cloud_to_surface_mean",
                  "mesh_to_surface_max", "mesh_to_surface_mean", "files"}


def test_a_true_surface_is_one_object_as_before(tmp_path: Path) -> None:
    """``true_surface``: no clustering, every point (the strays too) is the one object."""
    ball = "sphere:r=0.3,cx=0.6,cy=0,cz=0.8"  # units of L = 0.05 m: BALL
    report, sent = write_outputs(
        accumulate(messages()),
        MapperParams(out_dir=str(tmp_path), true_surface=ball, rod_length_m=0.05),
        tmp_path)
    assert OLD_REPORT_KEYS <= set(report)
    [frame] = report["frames"]
    assert OLD_FRAME_KEYS <= set(frame)
    [obj] = frame["objects"]
    assert obj["name"] == "object0" and obj["n_points"] == frame["n_points"] == 282
    assert frame["noise_points"] == 0
    assert frame["clustering"] == {"method": "none: true_surface is the one object"}
    for key in ("method", "n_vertices", "n_triangles", "line_spacing_m", "cloud_to_surface_max",
                "cloud_to_surface_mean", "mesh_to_surface_max", "mesh_to_surface_mean"):
        assert frame[key] == obj[key], key
    assert (tmp_path / "mesh.ply").read_bytes() == (tmp_path / "mesh_object0.ply").read_bytes()
    # the ball's points are on it; the egg's and the strays' are not (one object: as before)
    ball_points = np.concatenate([line_points(BALL, p, a) for _, o, p, a in LINES if o is BALL])
    on_ball = BALL.surface(1.0).signed_distance(ball_points)
    assert np.max(np.abs(on_ball)) < 1e-12
    assert frame["cloud_to_surface_max"] == pytest.approx(
        float(np.max(np.abs(BALL.surface(1.0).signed_distance(STRAYS)))), rel=1e-9)
    assert sent[0].mesh.method == frame["method"] and sent[0].mesh.n_points == 282
    assert "true surface: sphere:r=0.3,cx=0.6,cy=0,cz=0.8 (L = 0.05 m)" in (
        tmp_path / "report.txt").read_text()


@pytest.mark.parametrize(("overrides", "message"), [
    ({"scene": "missing.yaml"}, "parameter 'scene': missing.yaml: "),
    ({"scene": "x.yaml", "true_surface": "sphere:r=1"},
     "parameter 'scene' must be empty when true_surface is given"),
    ({"cluster_eps_m": "-0.001"}, "parameter 'cluster_eps_m' must be a finite number >= 0"),
    ({"cluster_min_points": "0"}, "parameter 'cluster_min_points' must be a count >= 1"),
])
def test_bad_parameters_are_refused_at_start(overrides: dict[str, str], message: str,
                                             tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ParamError, match=message.replace("(", r"\(")):
        load_params(MapperParams, overrides=overrides)


def test_a_scene_file_that_does_not_load_names_its_problem(tmp_path: Path) -> None:
    scene = write_scene(tmp_path)
    scene.write_text(SCENE.replace("radius_m: 0.015", "radius: 0.015"))
    with pytest.raises(ParamError, match="parameter 'scene': scene.yaml: objects\\[0\\]: "
                                         "unknown key 'radius'"):
        load_params(MapperParams, overrides={"scene": str(scene)})


def array_scene(samples: int) -> Scene:
    """8 whiskers (35-60 mm, two rows of four, fanned +-0.3 rad) on a robot driving past a
    ball, an egg and a pebble 20 mm apart: the scene of docs/NODES.md's DBSCAN table ("B" at
    600 path samples, "C" at 200)."""
    objects = (
        SceneObject("ball", "sphere", {"radius_m": 0.015}, Transform(translation=np.array([0.02, 0, 0.04]))),
        SceneObject("egg", "ellipsoid", {"semi_axes_m": [0.012, 0.008, 0.01]},
                    Transform.from_quaternion(EGG_Q, [-0.02, 0.01, 0.045])),
        SceneObject("pebble", "ellipsoid", {"semi_axes_m": [0.01, 0.006, 0.008]},
                    Transform.from_xyz_rpy([-0.055, -0.01, 0.035], [0.3, 0.2, 0.4])))
    whiskers = tuple(
        Whisker(f"w{i}", length, 2e-5 * (length / 0.05) ** 4,
                Transform.from_xyz_rpy([0.0, -0.015 + 0.01 * (i % 4), 0.004 * (i // 4)],
                                       [-0.3 + 0.2 * (i % 4), 0.0, 0.0]))
        for i, length in enumerate(np.linspace(0.035, 0.06, 8)))
    yaw = 0.3 * np.arange(samples) / samples
    path = robot_path(0.01 * np.arange(samples),
                      np.column_stack([np.linspace(0.10, -0.12, samples), np.zeros((samples, 2))]),
                      Rotation.from_euler("z", yaw[:, None]).as_quat())
    return Scene(0.25, objects, whiskers, path)


@pytest.mark.parametrize(("samples", "rule"), [(600, "line extent"), (200, "line spacing")])
@pytest.mark.slow
def test_the_default_eps_separates_the_objects_a_simulated_robot_touched(
    samples: int, rule: str
) -> None:
    """Step 1 of 8 whiskers along the path (the simulator says which object each contact is
    on): the default DBSCAN gives one cluster per object, no noise, no mixed cluster, at the
    fine sampling (eps from the extent of the lines) and at a 3 times coarser one (from the
    line spacing)."""
    scene = array_scene(samples)
    results = simulate(scene, workers=1)
    points, ids, touched = [], [], []
    for result in results:
        rows = np.flatnonzero(np.isin(result.phase, [SamplePhase.TIP, SamplePhase.TANGENTIAL]))
        points.append(result.p_W_m[rows])
        ids += [result.name] * len(rows)
        touched.append(result.object[rows])
    p, truth = np.concatenate(points), np.concatenate(touched)
    assert set(truth) == {0, 1, 2}
    clusters = cluster_points(p, whisker_lines(p, ids))
    assert clusters.eps_rule == rule
    assert clusters.n_clusters == 3 and np.all(clusters.labels >= 0)
    for k in range(3):
        assert len(set(truth[clusters.labels == k])) == 1


def test_a_figure_of_many_whiskers_and_objects_is_drawn(tmp_path: Path) -> None:
    """25 whiskers and 14 meshes: past the qualitative palettes and the legend's cap."""
    rng = np.random.default_rng(5)
    points = rng.uniform(-0.05, 0.05, (500, 3))
    ids = [f"w{i % 25}" for i in range(500)]
    labels = np.arange(500) % 15 - 1  # 14 objects and some noise
    triangle = np.array([[0, 1, 2]])
    meshes = [MeshLayer(f"object{k}", points[labels == k][:3], triangle, np.full(3, 1e-3 * k),
                        points[labels == k][3:6], triangle, 5e-3) for k in range(14)]
    target = tmp_path / "many.png"
    plot_map(target, MapLayers(title="world map: 14 objects", points=points, whisker_ids=ids,
                               labels=labels, meshes=meshes))
    width, height = png_size(target)
    assert width >= 1200 and height >= 700


@pytest.mark.slow
def test_hostile_covariances_do_not_break_the_map(scene_map: dict[str, Any], tmp_path: Path
                                                  ) -> None:
    # the same points with covariances as an adversary might send them (finite, so the codec
    # takes them): negative, enormous, zero, asymmetric; the map is made and the objects are
    # the same two, within the mesh's cells of the clean map
    rng = np.random.default_rng(4)
    hostile = [np.diag([-1.0, -1.0, -1.0]), np.full((3, 3), 1e300), np.zeros((3, 3)),
               np.array([[0.0, 1e10, 0.0], [-1e10, 0.0, 0.0], [0.0, 0.0, 1e-30]])]
    msgs, negative_or_asymmetric = [], 0
    for msg in messages():
        if isinstance(msg, ContactPointArray):
            n = len(msg.whisker_ids)
            which = rng.integers(0, len(hostile), n)
            negative_or_asymmetric += int(np.sum((which == 0) | (which == 3)))
            msg = dataclasses.replace(msg, covariance=np.array([hostile[k] for k in which]))
        msgs.append(decode(encode(msg)))
    report, _ = write_outputs(accumulate(msgs), scene_map["params"], tmp_path / "out")
    [frame] = report["frames"]
    assert [obj["name"] for obj in frame["objects"]] == ["ball", "egg"]
    for obj in frame["objects"]:
        assert obj["n_triangles"] > 0 and obj["mesh_to_surface_max"] < 5e-3
    assert report["bad_covariance"] == negative_or_asymmetric > 0


def _jsjt(rank: int) -> np.ndarray:
    """J S J^T of a random J (3, 6) of ``rank`` and a diagonal S: a covariance as the
    reconstructor makes it, off by rounding only (a rank below 3 leaves eigenvalues of about
    -1e-17 x the largest)."""
    rng = np.random.default_rng(rank)
    J = rng.normal(size=(3, rank)) @ rng.normal(size=(rank, 6)) * 1e-3
    return np.asarray(J @ np.diag(rng.uniform(0.5, 2.0, 6)) @ J.T)


@pytest.mark.parametrize(("covariance", "accepted"), [
    (_jsjt(3), True),
    (_jsjt(2), True),
    (_jsjt(1), True),
    (np.zeros((3, 3)), True),
    (np.full((3, 3), 1e300), True),  # rank one, its entries near the float limit
    (np.diag([1.0, 1.0, -1e-10]), True),  # within 1e-9 of the largest eigenvalue
    (np.diag([1e-320, 1e-320, 1e-320]), True),  # subnormal
    (-1e-2 * np.eye(3), False),
    (-1e-300 * np.eye(3), False),
    (np.diag([1.0, 1.0, -1e-8]), False),
    (np.diag([1e300, 1e300, -1e292]), False),
    (np.eye(3) + np.triu(np.full((3, 3), 1e-8), 1), False),  # asymmetric beyond 1e-9
    (np.eye(3) + np.triu(np.full((3, 3), 1e-10), 1), True),
    (np.full((3, 3), np.nan), False),
])
def test_a_covariance_is_symmetric_positive_semidefinite_up_to_rounding(
        covariance: np.ndarray, accepted: bool) -> None:
    assert is_covariance(covariance[None]).tolist() == [accepted]


@pytest.mark.slow
def test_points_whose_covariance_is_not_one_are_counted_and_mapped_as_without(
        tmp_path: Path) -> None:
    """-1e-2 I, -1e-300 I and diag(-1e-4, 1e-4, 1e-4) (the fit took n^T C n as a point's
    variance: a std of up to 1 cm for the last) are counted in bad_covariance, and the map is
    bit for bit the map of the same points without covariances."""
    params = MapperParams(out_dir=str(tmp_path), plot=False)
    bad = np.array([-1e-2 * np.eye(3), -1e-300 * np.eye(3), np.diag([-1e-4, 1e-4, 1e-4])])
    clean = messages()
    hostile = [decode(encode(dataclasses.replace(
        msg, covariance=bad[np.arange(len(msg.whisker_ids)) % 3]
        if isinstance(msg, ContactPointArray) else bad[2])))
        if not isinstance(msg, EndOfStream) else msg for msg in clean]
    acc = accumulate(hostile)
    assert acc.bad_covariance == 282
    report, _ = write_outputs(acc, params, tmp_path / "hostile")
    without, _ = write_outputs(accumulate(clean), params, tmp_path / "without")
    for name in ("cloud.ply", "mesh.ply", "mesh_object0.ply", "mesh_object1.ply"):
        assert ((tmp_path / "hostile" / name).read_bytes()
                == (tmp_path / "without" / name).read_bytes()), name
    assert report["bad_covariance"] == 282 and without["bad_covariance"] == 0
    relocated = json.loads(json.dumps(report).replace("/hostile/", "/without/"))
    assert relocated["frames"] == without["frames"]
    assert ("BAD COVARIANCE: 282 contact point(s) with a covariance that is not symmetric "
            "positive semidefinite" in (tmp_path / "hostile" / "report.txt").read_text())
    assert "BAD COVARIANCE" not in (tmp_path / "without" / "report.txt").read_text()


def test_names_are_short_in_the_figure() -> None:
    assert short_name("w0") == "w0" and short_name("x" * MAX_NAME_CHARS) == "x" * MAX_NAME_CHARS
    assert short_name("head" + "x" * 10_000 + "tail") == "head" + "x" * 12 + "…" + "x" * 11 + "tail"
    assert short_name("a\nb\tc\x00") == "a b c "


@pytest.mark.slow
def test_the_figure_draws_wire_names_short_and_as_text(tmp_path: Path) -> None:
    """A 10 kB whisker id was a legend label across the figure, a frame id the title; a ``$``
    in a name made matplotlib parse it as mathtext, and fail."""
    long_whisker, long_frame, long_object = "W" * 10_000, "f" * 10_000, "ball" * 1000
    math = "w$\\frac$"
    acc = Accumulator(1)
    for msg in messages(long_frame):
        if isinstance(msg, ContactPointArray):
            msg = dataclasses.replace(msg, whisker_ids=[long_whisker if w == "w0" else
                                                        math if w == "w1" else w
                                                        for w in msg.whisker_ids])
        receive(acc, msg)
    params = MapperParams(out_dir=str(tmp_path), plot=False)
    layers = dataclasses.replace(
        map_layers(fit_frame(long_frame, acc.frames[long_frame], params.settings,
                             params.truth(long_frame))),
        true_objects=[TrueObject(long_object, parse_surface("sphere:r=0.015,cx=0.03,cz=0.04"))])
    figure = draw_map(layers)
    assert figure.get_suptitle() == layers.title
    assert layers.title.startswith(f"{short_name(long_frame)} map: 2 objects, 282 contacts")
    [legend] = [ax.get_legend() for ax in figure.axes if ax.get_legend() is not None]
    labels = [text.get_text() for text in legend.get_texts()]
    assert f"{short_name(long_whisker)}: 60 contacts" in labels
    assert f"{math}: 110 contacts" in labels
    assert f"true object ({short_name(long_object)})" in labels
    assert max(len(line) for label in labels for line in label.splitlines()) < 64
    assert not any(text.get_parse_math() for text in legend.get_texts())
    plot_map(tmp_path / "map.png", layers)  # drawn: no mathtext to parse
    assert png_size(tmp_path / "map.png") == (1600, 900)
