"""Grids of whole scenes along robot paths: the rows of `vibrissa simulate`, statics at the
clamp, Step 2 on the true contacts, friction and rods replaced, the same tables however run,
the store keyed by the scene's content, bad files named."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.spatial.transform import Rotation

from vibrissa.cli.main import main
from vibrissa.formats.scene_file import load_scene
from vibrissa.grid_study import SCENE_EQUILIBRIUM_COLUMNS
from vibrissa.scene import simulate
from vibrissa.studies.grid_file import GridFileError, load_grid
from vibrissa.studies.grid_run import SCENE_PARAMETER_COLUMNS, same_bits

# Two rods of their own on a yawing drive past a ball and a turned egg (tip and tangential
# contact, snap-offs); 120 samples.
SCENE = """\
mu: 0.25
objects:
  - {name: ball, shape: sphere, radius_m: 0.015, position_m: [0.03, 0.0, 0.04]}
  - {name: egg, shape: ellipsoid, semi_axes_m: [0.012, 0.008, 0.01], position_m: [-0.03, 0.01, 0.045],
     quaternion_xyzw: [0, 0, 0.3826834, 0.9238795]}
whiskers:
  - {name: w0, length_m: 0.05, ei_nm2: 2.0e-5, mount: {position_m: [0.0, 0.0, 0.0]}}
  - {name: w1, length_m: 0.04, ei_nm2: 1.0e-5,
     mount: {position_m: [0.0, -0.01, 0.0], quaternion_xyzw: [0.0998334, 0, 0, 0.9950042]}}
path: path.csv
"""
GRID = """\
name: two
scenes: [scene.yaml]
mu: [0.0, 0.8]
rods: [{length_m: 0.045, ei_nm2: 1.5e-5}]
"""
CASES = """\
name: four
cases:
  - {scene: scene.yaml}
  - {scene: scene.yaml, mu: 0.0}
  - {scene: scene.yaml, mu: 0.8}
  - {scene: scene.yaml, mu: 0.8, length_m: 0.045, ei_nm2: 1.5e-5}
"""
SAMPLES = 120


def write_scene(folder: Path, x_end: float = -0.06) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    yaw = 0.3 * np.arange(SAMPLES) / SAMPLES
    x = np.linspace(0.10, x_end, SAMPLES)
    lines = ["t,x,y,z,qx,qy,qz,qw"] + [
        f"{0.01 * i},{x[i]},0.0,0.0,0.0,0.0,{np.sin(yaw[i] / 2)},{np.cos(yaw[i] / 2)}"
        for i in range(SAMPLES)]
    (folder / "path.csv").write_text("\n".join(lines) + "\n")
    (folder / "scene.yaml").write_text(SCENE)
    return folder / "scene.yaml"


def grid(folder: Path, text: str = GRID) -> Path:
    write_scene(folder)
    (folder / "grid.yaml").write_text(text)
    return folder / "grid.yaml"


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    folder = tmp_path_factory.mktemp("scenes")
    path = grid(folder, CASES)
    out = folder / "out"
    assert main(["study", "grid", str(path), "-o", str(out), "--workers", "1"]) == 0
    return {"folder": folder, "out": out, "equilibria": pq.read_table(out / "equilibria.parquet").to_pydict(),
            "summary": pq.read_table(out / "summary.parquet").to_pydict()}


def rows(table: dict[str, list[object]], case: int) -> dict[str, np.ndarray]:
    keep = np.asarray(table["case"]) == case
    return {name: np.asarray(column, dtype=object if isinstance(column[0], str) else None)[keep]
            for name, column in table.items()}


def test_the_columns_are_the_documented_ones(run: dict[str, object]) -> None:
    table = run["equilibria"]
    assert isinstance(table, dict)
    assert list(table) == ["case", "key", *SCENE_PARAMETER_COLUMNS, *SCENE_EQUILIBRIUM_COLUMNS]
    assert (Path(str(run["out"])) / "grid.png").stat().st_size > 10_000
    summary = run["summary"]
    assert isinstance(summary, dict)
    assert summary["mu"] == [0.25, 0.0, 0.8, 0.8]  # the scene's own, then as given
    assert np.isnan(summary["length_m"][0]) and summary["length_m"][3] == 0.045


def test_each_case_is_vibrissa_simulate_of_its_scene(run: dict[str, object]) -> None:
    """Every row of a case is the library's Step 1 of the scene with the case's mu and rods,
    whisker by whisker, bit for bit."""
    folder = Path(str(run["folder"]))
    scene = load_scene(folder / "scene.yaml")
    table = run["equilibria"]
    assert isinstance(table, dict)
    variants = [scene, dataclasses.replace(scene, mu=0.0), dataclasses.replace(scene, mu=0.8),
                dataclasses.replace(scene, mu=0.8, whiskers=tuple(
                    dataclasses.replace(w, length_m=0.045, ei_nm2=1.5e-5) for w in scene.whiskers))]
    for case, variant in enumerate(variants):
        got = rows(table, case)
        results = simulate(variant, workers=1)
        assert len(got["t"]) == SAMPLES * len(results)
        np.testing.assert_array_equal(got["whisker"], [r.name for r in results for _ in range(SAMPLES)])
        np.testing.assert_array_equal(got["t"], np.concatenate([r.t for r in results]))
        for prefix, name in (("f0", "f0_n"), ("m0", "m0_nm"), ("p", "p_W_m")):
            ours = np.stack([got[f"{prefix}{c}"] for c in "xyz"], axis=1).astype(float)
            np.testing.assert_array_equal(ours, np.concatenate([getattr(r, name) for r in results]))


def test_statics_at_the_clamp_and_contacts_on_the_objects(run: dict[str, object]) -> None:
    """Physics, independently of the code: the clamp's moment is the contact point's lever
    times its force (m0 = p_C x f0 in the clamp frame), the contact lies on its object's
    surface, within the rod's length of the clamp, and Step 2 finds it."""
    folder = Path(str(run["folder"]))
    scene = load_scene(folder / "scene.yaml")
    mounts = {w.name: w for w in scene.whiskers}
    table = run["equilibria"]
    assert isinstance(table, dict)
    touched = 0
    for case, length in ((0, None), (2, None), (3, 0.045)):
        got = rows(table, case)
        contact = np.isin(got["phase"], ["tip", "tangential"])
        assert contact.sum() > 20
        for i in np.flatnonzero(contact):
            k = int(round(got["t"][i] / 0.01))
            whisker = mounts[str(got["whisker"][i])]
            R_WR = Rotation.from_quat(scene.path.R_WR[k].as_quat())
            p_WC = scene.path.p_WR[k] + R_WR.apply(np.array(whisker.X_RC.translation))
            R_WC = R_WR * Rotation.from_quat(whisker.X_RC.quaternion_xyzw)
            p_W = np.array([got["px"][i], got["py"][i], got["pz"][i]], float)
            p_C = R_WC.inv().apply(p_W - p_WC)
            f0 = np.array([got["f0x"][i], got["f0y"][i], got["f0z"][i]], float)
            m0 = np.array([got["m0x"][i], got["m0y"][i], got["m0z"][i]], float)
            assert np.linalg.norm(m0 - np.cross(p_C, f0)) <= 1e-9 * np.linalg.norm(f0) * 0.05
            assert np.linalg.norm(p_C) <= (length or whisker.length_m) * (1 + 1e-12)
            obj = next(o for o in scene.objects if o.name == got["object"][i])
            local = Rotation.from_quat(obj.X_WO.quaternion_xyzw).inv().apply(p_W - obj.X_WO.translation)
            if obj.shape == "sphere":
                assert abs(np.linalg.norm(local) - obj.sizes["radius_m"]) <= 1e-9
            else:
                assert abs(np.sum((local / np.asarray(obj.sizes["semi_axes_m"])) ** 2) - 1.0) <= 1e-7
            r_W = np.array([got["rx"][i], got["ry"][i], got["rz"][i]], float)
            assert np.linalg.norm(r_W - p_W) <= 1e-9
            assert got["err_m"][i] == pytest.approx(np.linalg.norm(r_W - p_W), abs=1e-15)
            touched += 1
        free = got["phase"] == "none"
        assert np.all(np.stack([got["f0x"][free], got["m0z"][free]]) == 0)
        assert np.all(got["object"][free] == "")
    assert touched > 100


def test_friction_and_rods_change_what_they_should(run: dict[str, object]) -> None:
    summary = run["summary"]
    assert isinstance(summary, dict)
    # mu 0 against 0.8: other forces along the same drive; the rods of 45 mm: contact within them
    assert summary["peak_f0_n"][1] != summary["peak_f0_n"][2]
    table = run["equilibria"]
    assert isinstance(table, dict)
    longer = rows(table, 3)
    contact = longer["phase"] != "none"
    assert np.all(longer["s1_m"][contact & (longer["phase"] != "unresolved")] <= 0.045 * (1 + 1e-12))
    for case in range(4):
        assert summary["contact_rows"][case] == int(np.sum(np.isin(rows(table, case)["phase"],
                                                                    ["tip", "tangential"])))
        assert summary["n_rows"][case] == 2 * SAMPLES
        assert summary["max_reconstruction_error_m"][case] <= 1e-9
        assert summary["n_invalid"][case] == 0
        assert summary["episodes"][case] >= 1


@pytest.mark.live
def test_serial_and_local_workers_give_the_same_tables(tmp_path: Path) -> None:
    path = grid(tmp_path)
    for name, workers in (("serial", "1"), ("workers", "2")):
        assert main(["study", "grid", str(path), "-o", str(tmp_path / name), "--workers", workers,
                     "--no-figures"]) == 0
    for table in ("equilibria", "summary"):
        assert same_bits(pq.read_table(tmp_path / "serial" / f"{table}.parquet"),
                         pq.read_table(tmp_path / "workers" / f"{table}.parquet"))


def test_the_store_is_keyed_by_the_scenes_content(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same scene again: nothing computed; its path CSV edited: every case computed again."""
    path, out = grid(tmp_path), tmp_path / "out"
    argv = ["study", "grid", str(path), "-o", str(out), "--workers", "1", "--no-figures"]
    assert main(argv) == 0
    capsys.readouterr()
    assert main(argv) == 0
    assert "2 cases (0 computed, 2 from" in capsys.readouterr().err
    write_scene(tmp_path, x_end=-0.05)
    assert main(argv) == 0
    assert "2 cases (2 computed, 0 from" in capsys.readouterr().err


BAD = [
    ("surfaces beside scenes", GRID + "surfaces: ['sphere:r=0.3']\n", "surfaces: a grid of scenes has no"),
    ("step beside scenes", GRID + "step: 0.01\n", "step: a grid of scenes has no"),
    ("a missing scene file", GRID.replace("[scene.yaml]", "[scene.yaml, nowhere.yaml]"),
     "scenes[1]: |nowhere.yaml: cannot read"),
    ("a bad scene file", None, "scenes[0]: scene.yaml: unknown key 'colour'"),
    ("a scene that is no text", GRID.replace("[scene.yaml]", "[3]"), "scenes[0]: expected a scene file"),
    ("a rod without EI", GRID.replace(", ei_nm2: 1.5e-5}", "}"), "rods[0]: ei_nm2: missing"),
    ("a rod with another key", GRID.replace("ei_nm2: 1.5e-5}", "ei_nm2: 1.5e-5, d: 1}"),
     "rods[0]: unknown key 'd'"),
    ("negative mu", GRID.replace("mu: [0.0, 0.8]", "mu: [0.0, -0.8]"), "mu[1]: mu must be >= 0"),
    ("a rod of 1e300 m", GRID.replace("length_m: 0.045", "length_m: 1e300"),
     "rods[0]: length_m: 1e+300 is outside the range"),
    ("a trail among scene cases", "cases: [{scene: scene.yaml}, {surface: 'sphere:r=0.3', y0_m: 0, mu: 0}]\n",
     "cases[1]: a grid is all scenes or all trails"),
    ("a scene case with L alone", "cases: [{scene: scene.yaml, length_m: 0.04}]\n",
     "cases[0]: ei_nm2: missing"),
    ("an unknown scene case key", "cases: [{scene: scene.yaml, y0_m: 0.1}]\n",
     "cases[0]: unknown key 'y0_m'"),
]


@pytest.mark.parametrize(("text", "message"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_scene_grids_name_the_file_and_the_key(tmp_path: Path, text: str | None, message: str) -> None:
    path = grid(tmp_path, GRID if text is None else text)
    if text is None:
        (tmp_path / "scene.yaml").write_text(SCENE + "colour: red\n")
    with pytest.raises(GridFileError) as info:
        load_grid(path)
    assert str(path) in str(info.value)
    for part in message.split("|"):
        assert part in str(info.value)


def test_a_grid_of_scenes_has_no_step(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path, out = grid(tmp_path), tmp_path / "out"
    assert main(["study", "grid", str(path), "-o", str(out), "--step", "0.01"]) == 2
    assert "--step: a grid of scenes has no step" in capsys.readouterr().err
    assert not out.exists()
