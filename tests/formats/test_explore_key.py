"""A scene file's ``explore``: the start pose, the workspace box and the body radius of an
exploration, read strictly (each bad value named by file and key); a file with ``explore`` and
no ``path`` stands still at the start (a path of one sample at t = 0)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from vibrissa.exploration import Explore
from vibrissa.formats.scene_file import SceneError, load_explore, load_scene, scene_files
from vibrissa.frames import Transform

Q = [0.0, 0.0, 0.3826834323650898, 0.9238795325112867]  # 45 degrees about z
EXPLORE = {"start": {"position_m": [0.0, -0.05, 0.02], "quaternion_xyzw": Q},
           "workspace_m": [[-0.1, -0.1, 0.0], [0.3, 0.1, 0.05]], "body_radius_m": 0.03}


def scene_doc(**changes: object) -> dict[str, object]:
    doc: dict[str, object] = {
        "mu": 0.2,
        "objects": [{"name": "ball", "shape": "sphere", "radius_m": 0.02,
                     "position_m": [0.07, -0.065, 0.025]}],
        "whiskers": [{"name": "w0", "length_m": 0.05, "ei_nm2": 2e-4, "mount": {}}],
        "explore": EXPLORE}
    doc.update(changes)
    return {k: v for k, v in doc.items() if v is not None}


def write(tmp_path: Path, doc: dict[str, object]) -> Path:
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_a_scene_with_explore_and_no_path_stands_at_the_start(tmp_path: Path) -> None:
    path = write(tmp_path, scene_doc())
    explore = load_explore(path)
    assert explore is not None
    assert explore.workspace_min_m == (-0.1, -0.1, 0.0)
    assert explore.workspace_max_m == (0.3, 0.1, 0.05)
    assert explore.body_radius_m == 0.03
    np.testing.assert_array_equal(explore.start.translation, [0.0, -0.05, 0.02])
    np.testing.assert_allclose(explore.start.rotate([1.0, 0.0, 0.0]),
                               [0.5**0.5, 0.5**0.5, 0.0], atol=1e-15)
    scene = load_scene(path)
    np.testing.assert_array_equal(scene.path.t, [0.0])
    np.testing.assert_array_equal(scene.path.p_WR, [[0.0, -0.05, 0.02]])
    np.testing.assert_allclose(scene.path.R_WR.as_quat(), [Q], atol=1e-15)
    assert scene_files(path) == [path]


def test_a_scene_with_explore_and_a_path_keeps_its_path(tmp_path: Path) -> None:
    (tmp_path / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0.1,0,0,0,0,0,1\n")
    path = write(tmp_path, scene_doc(path="path.csv"))
    scene = load_scene(path)
    np.testing.assert_array_equal(scene.path.t, [0.0, 1.0])
    explore = load_explore(path)
    assert explore is not None and explore.workspace_max_m == (0.3, 0.1, 0.05)
    assert scene_files(path) == [path, tmp_path / "path.csv"]


def test_a_scene_without_explore_has_none_and_still_needs_its_path(tmp_path: Path) -> None:
    path = write(tmp_path, scene_doc(explore=None))
    assert load_explore(path) is None
    with pytest.raises(SceneError, match=r"^scene\.yaml: missing 'path'$"):
        load_scene(path)


def test_a_path_csv_of_one_row_is_still_refused(tmp_path: Path) -> None:
    (tmp_path / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n")
    with pytest.raises(SceneError, match=r"path: path\.csv: a path needs at least 2 samples, "
                                         r"got 1$"):
        load_scene(write(tmp_path, scene_doc(path="path.csv")))


BAD = [
    ({"extra": 1}, r"explore: unknown key 'extra'"),
    ({"start": None}, r"explore: missing 'start'"),
    ({"workspace_m": None}, r"explore: missing 'workspace_m'"),
    ({"body_radius_m": None}, r"explore: missing 'body_radius_m'"),
    ({"start": {"quaternion_xyzw": Q}}, r"explore\.start: missing 'position_m'"),
    ({"start": {"position_m": [0, 0, 0.01], "pos": 1}}, r"explore\.start: unknown key 'pos'"),
    ({"start": {"position_m": [0, 0]}}, r"explore\.start\.position_m: expected 3 numbers"),
    ({"start": {"position_m": [0, 0, 0.01], "quaternion_xyzw": [0, 0, 0, 2]}},
     r"explore\.start\.quaternion_xyzw: \[0\.0, 0\.0, 0\.0, 2\.0\] is not a unit quaternion"),
    ({"start": {"position_m": [0, 0, ".nan"]}},
     r"explore\.start\.position_m\[2\]: expected a finite number"),
    ({"workspace_m": [[0, 0, 0]]}, r"explore\.workspace_m: expected \[\[xmin"),
    ({"workspace_m": [[0, 0, 0], [1, 1]]}, r"explore\.workspace_m\[1\]: expected 3 numbers"),
    ({"workspace_m": [[0, 0, 0], [1, 1, "x"]]},
     r"explore\.workspace_m\[1\]\[2\]: expected a finite number"),
    ({"workspace_m": [[0, 0, 0], [1, 1, 1e8]]},
     r"explore\.workspace_m\[1\]\[2\]: 100000000\.0 is outside"),
    ({"workspace_m": [[-0.1, -0.1, 0.05], [0.3, 0.1, 0.05]]},
     r"explore: workspace_m: the min .* must be below the max"),
    ({"workspace_m": [[0.1, -0.1, 0.0], [0.3, 0.1, 0.05]]},
     r"explore: start\.position_m \[0\.0, -0\.05, 0\.02\] is outside the workspace"),
    ({"body_radius_m": 0}, r"explore\.body_radius_m: 0 is outside"),
    ({"body_radius_m": -0.01}, r"explore\.body_radius_m: -0\.01 is outside"),
    ({"body_radius_m": "big"}, r"explore\.body_radius_m: expected a finite number"),
]


@pytest.mark.parametrize(("change", "message"), BAD)
def test_a_bad_explore_names_the_file_and_the_key(tmp_path: Path, change: dict[str, object],
                                                   message: str) -> None:
    explore = {k: v for k, v in {**EXPLORE, **change}.items() if v is not None}
    path = write(tmp_path, scene_doc(explore=explore))
    for load in (load_explore, load_scene):
        with pytest.raises(SceneError, match=r"^scene\.yaml: " + message):
            load(path)


def test_explore_must_be_a_mapping(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match=r"^scene\.yaml: explore: expected a mapping, got list$"):
        load_explore(write(tmp_path, scene_doc(explore=[1, 2])))


def test_the_explore_dataclass_checks_itself() -> None:
    start = Transform(None, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="body_radius_m"):
        Explore(start, (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), 0.0)
    with pytest.raises(ValueError, match="outside the workspace"):
        Explore(Transform(None, [2.0, 0.0, 0.0]), (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), 0.1)
    explore = Explore(start, (-1, -1, -1), (1, 1, 1), 1)  # type: ignore[arg-type]
    assert explore.workspace_min_m == (-1.0, -1.0, -1.0) and explore.body_radius_m == 1.0
    assert all(isinstance(v, float) for v in explore.workspace_max_m)


@pytest.mark.parametrize("gap_m, refused", [(-0.003, True), (0.003, False)])
def test_a_start_with_the_body_in_an_object_is_refused_naming_it(
        tmp_path: Path, gap_m: float, refused: bool) -> None:
    """The body at the start, a vertical cylinder of 30 mm (EXPLORE), and a ball of 20 mm at
    the workspace's mid-height, its centre 50 mm + ``gap_m`` away across the floor: closer
    than the two radii it is inside the ball, and the file is refused; 3 mm apart it is not."""
    start = np.array(EXPLORE["start"]["position_m"])  # type: ignore[index]
    direction = np.array([0.6, 0.8, 0.0])
    centre = start + (0.05 + gap_m) * direction
    centre[2] = 0.025
    ball = {"name": "ball", "shape": "sphere", "radius_m": 0.02, "position_m": centre.tolist()}
    far = {"name": "far", "shape": "sphere", "radius_m": 0.02, "position_m": [0.25, 0.05, 0.02]}
    path = write(tmp_path, scene_doc(objects=[far, ball]))
    if refused:
        with pytest.raises(SceneError, match=r"explore\.start: .* inside 'ball' at the start"):
            load_scene(path)
    else:
        assert [o.name for o in load_scene(path).objects] == ["far", "ball"]


def test_an_object_above_the_workspace_is_not_in_the_body(tmp_path: Path) -> None:
    """The body is checked at the workspace's heights (0 to 50 mm): a ball over the start from
    53 mm up does not count."""
    ball = {"name": "lamp", "shape": "sphere", "radius_m": 0.02, "position_m": [0.0, -0.05, 0.073]}
    assert load_scene(write(tmp_path, scene_doc(objects=[ball]))).objects[0].name == "lamp"
    ball["position_m"] = [0.0, -0.05, 0.068]  # from 48 mm up: in the body
    with pytest.raises(SceneError, match="inside 'lamp'"):
        load_scene(write(tmp_path, scene_doc(objects=[ball])))


@pytest.mark.parametrize("gap_m, inside", [(-0.012, True), (0.012, False)])
def test_a_large_body_is_checked_in_bounded_memory(gap_m: float, inside: bool) -> None:
    """A body of 0.5 m radius over 2 m of heights (2 mm everywhere: 4e8 points, 10 GB) is
    sampled more coarsely (at most `BODY_SAMPLES` points, a layer at a time): a ball of 0.1 m
    whose centre lies 0.6 m + ``gap_m`` across the floor (12 mm into the body, or short of
    it, more than the sampling's step) is found inside or not. Over heights of +-1e7 m, whose
    layers lie 800 m apart, a ball of 1 km that the body enters at the height of its centre
    is found."""
    from vibrissa.exploration import BODY_SAMPLES
    from vibrissa.scene import SceneObject

    explore = Explore(Transform(), (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0), 0.5)
    centre = (0.6 + gap_m) * np.array([0.6, 0.8, 0.0]) + [0.0, 0.0, 0.3]
    ball = SceneObject("ball", "sphere", {"radius_m": 0.1}, Transform(translation=centre))
    assert explore.objects_in_body([ball]) == (["ball"] if inside else [])
    huge = Explore(Transform(), (-1e7, -1e7, -1e7), (1e7, 1e7, 1e7), 0.03)
    near = SceneObject("near", "sphere", {"radius_m": 1e3}, Transform(translation=[1e3, 0, 0.0]))
    assert huge.objects_in_body([near]) == ["near"]
    assert BODY_SAMPLES <= 2_000_000
