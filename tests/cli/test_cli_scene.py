"""``vibrissa simulate SCENE.yaml -o DIR``: the file formats of the issue's contract, and one
clear line for every bad input."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from vibrissa.cli.main import main

SCENE = """\
mu: 0.25
objects:
  - name: ball
    shape: sphere
    radius_m: 0.015
    position_m: [0.03, 0.0, 0.04]
  - name: egg
    shape: ellipsoid
    semi_axes_m: [0.012, 0.008, 0.01]
    position_m: [-0.03, 0.01, 0.045]
    quaternion_xyzw: [0, 0, 0.3826834, 0.9238795]
whiskers:
  - name: w0
    length_m: 0.05
    ei_nm2: 2.0e-5
    mount: {position_m: [0.0, 0.0, 0.0]}
  - name: w1
    length_m: 0.04
    ei_nm2: 1.0e-5
    mount: {position_m: [0.0, -0.01, 0.0], quaternion_xyzw: [0.0998334, 0, 0, 0.9950042]}
path: path.csv
"""
CONTRACT = ["t", "phase", "s1", "f0x", "f0y", "f0z", "m0x", "m0y", "m0z", "px", "py", "pz"]


def write_path(folder: Path, n: int = 300) -> None:
    yaw = 0.3 * np.arange(n) / n
    x = np.linspace(0.10, -0.06, n)
    lines = ["t,x,y,z,qx,qy,qz,qw"] + [
        f"{0.01 * i},{x[i]},0.0,0.0,0.0,0.0,{np.sin(yaw[i] / 2)},{np.cos(yaw[i] / 2)}"
        for i in range(n)]
    (folder / "path.csv").write_text("\n".join(lines) + "\n")


def test_simulate_writes_a_csv_per_whisker_and_a_summary(tmp_path: Path, capsys) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    out = tmp_path / "out"
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(out), "--workers", "1"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    # the last line on stderr sums up summary.json
    ends = [e["end"] for w in summary["whiskers"].values() for e in w["episodes"]]
    totals = {p: sum(w["samples_per_phase"][p] for w in summary["whiskers"].values())
              for p in ("none", "tip", "tangential", "unresolved")}
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"{len(ends)} contact episodes (") and "another-object" not in last
    assert sum(totals.values()) == 2 * 300
    assert all(f"{ends.count(end)} {end}" in last for end in set(ends))
    assert last.endswith("samples: " + ", ".join(f"{n} {p}" for p, n in totals.items()))
    for name in ("w0", "w1"):
        with (out / f"{name}.csv").open() as handle:
            rows = list(csv.reader(handle))
        assert rows[0][: len(CONTRACT)] == CONTRACT and len(rows) == 301
        assert rows[0][len(CONTRACT):] == ["object", "refined", "s2", "p2x", "p2y", "p2z", "object2"]
        assert {row[13] for row in rows[1:]} <= {"0", "1"}
        phases = [row[1] for row in rows[1:]]
        assert set(phases) <= {"none", "tip", "tangential", "unresolved"}
        counts = summary["whiskers"][name]["samples_per_phase"]
        assert counts == {p: phases.count(p) for p in ("none", "tip", "tangential", "unresolved")}
        for row in rows[1:]:
            if row[1] == "none":
                assert row[9:12] == ["", "", ""] and all(float(v) == 0.0 for v in row[3:9])
            elif row[1] in ("tip", "tangential"):
                assert all(v != "" for v in row[2:12])
    episodes = summary["whiskers"]["w0"]["episodes"]
    assert [e["object"] for e in episodes] == ["ball", "egg"]
    assert episodes[0]["end"] in ("detachment", "snap-off", "path-end")
    assert 0.0 < episodes[0]["t_first_contact"] < episodes[1]["t_first_contact"] < 3.0


def test_simulate_writes_the_wrenches_that_reconstruct_takes(tmp_path: Path) -> None:
    """DIR/wrenches.csv, sample by sample and whisker by whisker, goes straight into
    ``vibrissa reconstruct --scene``, which gives back the simulated contact points."""
    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path, n=120)
    out = tmp_path / "out"
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(out), "--workers", "1"]) == 0
    per_whisker = {}
    for name in ("w0", "w1"):
        with (out / f"{name}.csv").open() as handle:
            per_whisker[name] = list(csv.DictReader(handle))
    with (out / "wrenches.csv").open() as handle:
        table = list(csv.reader(handle))
    assert table[0] == ["t", "whisker", "f0x", "f0y", "f0z", "m0x", "m0y", "m0z"]
    assert len(table) == 1 + 2 * 120
    for k, row in enumerate(table[1:]):
        sample = per_whisker[row[1]][k // 2]
        assert row[1] == ("w0", "w1")[k % 2]
        assert row[0] == sample["t"] and row[2:] == [sample[c] for c in CONTRACT[3:9]]
    points = tmp_path / "points.csv"
    assert main(["reconstruct", str(out / "wrenches.csv"), "--scene", str(tmp_path / "scene.yaml"),
                 "-o", str(points)]) == 0
    with points.open() as handle:
        result = list(csv.DictReader(handle))
    touching = 0
    for k, got in enumerate(result):
        sample = per_whisker[got["whisker"]][k // 2]
        if sample["phase"] in ("tip", "tangential"):
            touching += 1
            error = np.linalg.norm([float(got[c]) - float(sample[c]) for c in ("px", "py", "pz")])
            assert got["phase"] == sample["phase"] and error < 1e-9 * 0.04, (got, sample)
    assert touching > 20


def test_a_whisker_named_like_the_file_of_all_wrenches_is_refused_before_simulating(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE.replace("name: w1", "name: wrenches"))
    write_path(tmp_path)
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "out")]) == 2
    assert "whisker 'wrenches': its results would replace wrenches.csv" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_an_exploration_scene_without_a_path_is_refused_naming_the_file_and_the_key(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE.replace(
        "path: path.csv", "explore: {start: {position_m: [0.2, 0.0, 0.0]}, workspace_m: "
        "[[0.15, -0.1, 0.0], [0.3, 0.1, 0.05]], body_radius_m: 0.02}"))
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "scene.yaml: path: `vibrissa simulate` needs a path of 2 samples or more" in err
    assert not (tmp_path / "out").exists()


def test_a_path_whose_times_span_no_finite_time_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two finite stamps 3.4e308 s apart: their span overflows (summary.json's times were
    Infinity, which is not JSON)."""
    (tmp_path / "scene.yaml").write_text(SCENE)
    (tmp_path / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n-1.7e308,0.1,0,0,0,0,0,1\n"
                                       "1.7e308,-0.06,0,0,0,0,0,1\n")
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "out")]) == 2
    assert "path times must be finite and span a finite time" in capsys.readouterr().err


@pytest.mark.parametrize(("change", "message"), [
    (("radius_m: 0.015", "radius: 0.015"), "scene.yaml: objects[0]: unknown key 'radius'"),
    (("    ei_nm2: 2.0e-5\n", ""), "scene.yaml: whiskers[0]: missing 'ei_nm2'"),
    (("    mount: {position_m: [0.0, 0.0, 0.0]}\n", ""), "scene.yaml: whiskers[0]: missing 'mount'"),
    (("length_m: 0.04", "length_m: -0.04"),
     "scene.yaml: whiskers[1].length_m: -0.04 is outside [0.0001, 10]"),
    (("name: w1", "name: w0"), "scene.yaml: whiskers[1]: the name 'w0' is taken by whiskers[0]"),
    (("shape: sphere", "shape: cube"), "scene.yaml: objects[0].shape: expected one of sphere"),
    (("[0, 0, 0.3826834, 0.9238795]", "[0, 0, 0.5, 0.9]"),
     "objects[1].quaternion_xyzw: [0.0, 0.0, 0.5, 0.9] is not a unit quaternion"),
    # |q|^2 overflows: refused by its norm, without numpy's overflow warning on the way
    (("[0, 0, 0.3826834, 0.9238795]", "[0, 0, 1e308, 1e308]"),
     "objects[1].quaternion_xyzw: [0.0, 0.0, 1e+308, 1e+308] is not a unit quaternion (norm inf)"),
    (("mu: 0.25", "mu: high"), "scene.yaml: mu: expected a finite number"),
    (("mu: 0.25", "mu: 1" + "0" * 400), "scene.yaml: mu: expected a finite number, got 1000"),
    (("radius_m: 0.015", "radius_m: 1" + "0" * 400), "objects[0].radius_m: expected a finite"),
    # YAML 1.2's numbers: no sexagesimal (1:30 is not 90), no underscores, no hex
    (("mu: 0.25", "mu: 1:30"), "scene.yaml: mu: expected a finite number, got '1:30'"),
    (("radius_m: 0.015", "radius_m: 0_015"), "objects[0].radius_m: expected a finite number, "
                                              "got '0_015'"),
    (("mu: 0.25", "mu: 0x1"), "scene.yaml: mu: expected a finite number, got '0x1'"),
    (("path: path.csv", "path: nowhere.csv"), "nowhere.csv"),
    (("length_m: 0.05", "length_m: -0.05"), "whiskers[0].length_m: -0.05 is outside"),
    # numbers that overflow the rod's units or the geometry: refused, not simulated
    (("length_m: 0.05", "length_m: 1e308"), "whiskers[0].length_m: 1e+308 is outside"),
    (("ei_nm2: 2.0e-5", "ei_nm2: 1e308"), "whiskers[0].ei_nm2: 1e+308 is outside"),
    # the rod's shape (vibrissa.rods.RodShape)
    (("ei_nm2: 2.0e-5", "ei_nm2: 2.0e-5\n    taper_ratio: 0"),
     "whiskers[0]: whisker 'w0': taper_ratio must be in [0.05, 1], got 0"),
    (("ei_nm2: 2.0e-5", "ei_nm2: 2.0e-5\n    taper_ratio: thin"),
     "whiskers[0].taper_ratio: expected a finite number, got 'thin'"),
    (("ei_nm2: 2.0e-5", "ei_nm2: 2.0e-5\n    precurvature_1pm: 1000"),
     "whiskers[0]: whisker 'w0': precurvature_1pm must be within +-2 pi / length_m = "
     "+-125.664 /m, got 1000.0"),
    (("ei_nm2: 2.0e-5", "ei_nm2: 2.0e-5\n    poisson_ratio: 0.7"),
     "whiskers[0]: whisker 'w0': poisson_ratio must be in [0, 0.5], got 0.7"),
    (("ei_nm2: 2.0e-5", "ei_nm2: 2.0e-5\n    curvature: 3"), "whiskers[0]: unknown key"),
    (("radius_m: 0.015", "radius_m: 1e200"), "objects[0].radius_m: 1e+200 is outside"),
    (("radius_m: 0.015", "radius_m: -0.015"), "objects[0].radius_m: -0.015 is outside"),
    (("mount: {position_m: [0.0, 0.0, 0.0]}", "mount: {position_m: [1e308, 0.0, 0.0]}"),
     "whiskers[0].mount.position_m[0]: 1e+308 is outside"),
    # names become file and frame names
    (("name: w0", "name: ../escaped"), "whiskers[0].name: '../escaped' is not a name"),
    (("name: w0", "name: /tmp/x"), "whiskers[0].name: '/tmp/x' is not a name"),
    (("name: w0", "name: ''"), "whiskers[0].name: '' is not a name"),
    (("name: w0", "name: 010"), "whiskers[0].name: expected a name"),
    (("name: w0", "name: [a, b]"), "whiskers[0].name: expected a name"),
    (("name: ball", "name: ~"), "objects[0].name: expected a name"),
    # the YAML itself: repeated keys, aliases, syntax, with the file and line
    (("mu: 0.25", "mu: 5\nmu: 0.25"), "scene.yaml: line 2, column 1: duplicate key 'mu'"),
    (("mu: 0.25", "m: &m [1, 2]\nmu: *m"), "scene.yaml: line 2, column 5: aliases (*m) are not"),
    (("mu: 0.25", "mu: [0.25"), "scene.yaml: line"),
])
@pytest.mark.filterwarnings("error")  # a warning on the way would be a second line
def test_a_bad_scene_is_one_line_naming_file_and_key(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      change: tuple[str, str], message: str) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE.replace(*change))
    write_path(tmp_path)
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


@pytest.mark.parametrize(("row", "line", "message"), [
    (5, "0.04,0.1,0,0,0,0,0.5,0.9", "path.csv: row 5: quaternion"),
    (3, "0.0,0.1,0,0,0,0,0,1", "path times must increase strictly (row 3)"),
    (2, "0.01,0.1,0,0,0,0,0", "path.csv: row 2: expected 8 values, got 7"),
    (4, "0.03,abc,0,0,0,0,0,1", "path.csv: row 4, column x: not a number"),
    (5, "0.04,0.1,0,0,0,0,1e308,1e308",
     "path.csv: row 5: quaternion [0.0, 0.0, 1e+308, 1e+308] is not a unit quaternion (norm inf)"),
])
@pytest.mark.filterwarnings("error")
def test_a_bad_path_row_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str], row: int,
                                 line: str, message: str) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    lines = (tmp_path / "path.csv").read_text().splitlines()
    lines[row] = line
    (tmp_path / "path.csv").write_text("\n".join(lines) + "\n")
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err


def test_reconstruct_from_wrenches_in_clamp_frames_recovers_the_true_points(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The issue's offline interface: Step 2 through the scene's poses, row for row, from the
    wrenches `vibrissa simulate` wrote (shuffled, with rows between samples and off the path)."""
    from scipy.spatial.transform import Rotation, Slerp

    from vibrissa.reconstruct import reconstruct_si
    from vibrissa.units import RodScale

    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    out = tmp_path / "out"
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(out), "--workers", "1"]) == 0
    rows, truth = [], []
    for name in ("w0", "w1"):
        with (out / f"{name}.csv").open() as handle:
            for row in list(csv.DictReader(handle)):
                if row["phase"] == "unresolved":
                    continue
                rows.append([row["t"], name, *(row[c] for c in CONTRACT[3:9])])
                truth.append((row["phase"], [row[c] for c in ("px", "py", "pz")]))
    between = ["0.555", "w1", "0.001", "-0.002", "0.0005", "2e-5", "1e-5", "0"]  # mid-sample (m0 . f0 = 0)
    missing = ["0.5", "w0", "0.001", "", "0", "0", "0", "0"]  # an empty cell: a missing value
    off = ["3.5", "w0", "0.001", "0", "0", "0", "0", "0"]  # after the path's last pose
    order = np.random.default_rng(3).permutation(len(rows))
    table = [rows[i] for i in order] + [between, missing, off]
    text = "extra,t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n" + "".join(
        "x," + ",".join(r) + "\n" for r in table)
    (tmp_path / "wrenches.csv").write_text(text)
    points = tmp_path / "points.csv"
    assert main(["reconstruct", str(tmp_path / "wrenches.csv"), "--scene",
                 str(tmp_path / "scene.yaml"), "-o", str(points)]) == 0
    with points.open() as handle:
        result = list(csv.reader(handle))
    assert result[0] == ["t", "whisker", "px", "py", "pz", "s1", "phase", "status"]
    result = result[1:]
    assert [r[:2] for r in result] == [r[:2] for r in table]  # same rows, same order
    touching = 0
    for got, i in zip(result, order, strict=False):
        phase, p_true = truth[i]
        length = 0.05 if got[1] == "w0" else 0.04
        if phase == "none":
            assert got[2:5] == ["", "", ""] and got[6] == "none" and got[7] == "no_force"
        else:
            touching += 1
            assert got[6] == phase and got[7] in ("ok", "axial_load")
            error = np.linalg.norm(np.array(got[2:5], float) - np.array(p_true, float))
            assert error < 1e-9 * length, (got, p_true)
    assert touching > 100
    # between two samples: the pose is interpolated (position linear, orientation slerp)
    t = np.arange(300) * 0.01
    yaw = 0.3 * np.arange(300) / 300
    x = np.linspace(0.10, -0.06, 300)
    R_WR = Slerp(t, Rotation.from_euler("z", yaw[:, None]))([0.555])
    p_WR = np.array([[np.interp(0.555, t, x), 0.0, 0.0]])
    mount = Rotation.from_quat([0.0998334, 0, 0, 0.9950042])
    q_WC = (R_WR * mount).as_quat()
    p_WC = p_WR + R_WR.apply([0.0, -0.01, 0.0])
    expected = reconstruct_si(q_WC, p_WC, np.array([[0.001, -0.002, 0.0005]]),
                              np.array([[2e-5, 1e-5, 0.0]]), RodScale(0.04, 1e-5))
    got = result[-3]
    assert np.allclose(np.array(got[2:5], float), expected.point_m[0], rtol=0, atol=1e-12)
    assert result[-2][2:5] == ["", "", ""] and result[-2][7] == "non_finite_input"
    assert result[-1][2:5] == ["", "", ""] and result[-1][7] == "no_pose"  # never extrapolated
    err = capsys.readouterr().err
    assert f"reconstruct: {len(table)} rows, {touching + 1} with a contact" in err, err


@pytest.mark.parametrize(("text", "message"), [
    ("t,whisker,f0x,f0y,f0z,m0x,m0y\n", "wrenches.csv: missing column(s) m0z"),
    ("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n0.1,w9,0,0,0,0,0,0\n",
     "wrenches.csv: row 1: whisker 'w9' is not in scene.yaml (w0, w1)"),
    ("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n,w0,0,0,0,0,0,0\n",
     "wrenches.csv: row 1: t must be a finite number"),
    ("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n0.1,w0,0,zero,0,0,0,0\n",
     "wrenches.csv: row 1, column f0y: 'zero' is not a number"),
    ("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n0.1_5,w0,0,0,0,0,0,0\n",  # Python's, not a CSV number
     "wrenches.csv: row 1, column t: '0.1_5' is not a number"),
    ("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z,t\n0.1,w0,0,0,0,0,0,0,0.2\n",
     "wrenches.csv: column(s) t appear more than once"),
    ("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z,,\n0.1,w0,0,0,0,0,0,0\n",  # a row short of the header
     "wrenches.csv: row 1: expected 10 values, got 8"),
    # after blank lines a row is named by its file line too (POINTS.csv has no blank rows)
    ("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n\n\n0.1,w0,0,0,0,0,0,0\n0.1,w0,0,x,0,0,0,0\n",
     "wrenches.csv: row 2 (line 5), column f0y: 'x' is not a number"),
])
def test_reconstruct_with_a_scene_names_what_is_wrong(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, message: str) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    (tmp_path / "wrenches.csv").write_text(text)
    assert main(["reconstruct", str(tmp_path / "wrenches.csv"), "--scene",
                 str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_reconstruct_reads_what_spreadsheets_write_and_an_empty_table(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    header = "t,whisker,f0x,f0y,f0z,m0x,m0y,m0z"
    row = "0.5,w0,0.001,-0.002,0.0005,1e-05,2e-05,0"
    points = tmp_path / "p.csv"
    # a byte order mark, CRLF line ends, a blank line and a trailing one, unnamed columns of
    # trailing commas: the same one row
    for text in ("\ufeff" + header + "\r\n" + row + "\r\n", header + "\n\n" + row + "\n\n",
                 header + ",,\n" + row + ",,\n"):
        (tmp_path / "wrenches.csv").write_text(text, encoding="utf-8")
        assert main(["reconstruct", str(tmp_path / "wrenches.csv"), "--scene",
                     str(tmp_path / "scene.yaml"), "-o", str(points)]) == 0
        rows = points.read_text().splitlines()
        assert len(rows) == 2 and rows[1].startswith("0.5,w0,"), rows
    (tmp_path / "wrenches.csv").write_text(header + "\n")  # no rows: no points, not an error
    assert main(["reconstruct", str(tmp_path / "wrenches.csv"), "--scene",
                 str(tmp_path / "scene.yaml"), "-o", str(points)]) == 0
    assert points.read_text() == "t,whisker,px,py,pz,s1,phase,status\n"
    assert "reconstruct: 0 rows, 0 with a contact" in capsys.readouterr().err


def test_an_output_never_replaces_an_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                           ) -> None:
    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    wrenches = tmp_path / "wrenches.csv"
    wrenches.write_text("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n0.5,w0,0,0,0,0,0,0\n")
    before = {p: p.read_bytes() for p in (wrenches, tmp_path / "scene.yaml", tmp_path / "path.csv")}
    for output in before:
        assert main(["reconstruct", str(wrenches), "--scene", str(tmp_path / "scene.yaml"),
                     "-o", str(output)]) == 2
        assert f"would overwrite the input {output}" in capsys.readouterr().err
    # a whisker named as the path file, simulated into the scene's folder
    (tmp_path / "scene.yaml").write_text(SCENE.replace("name: w0", "name: path"))
    before[tmp_path / "scene.yaml"] = (tmp_path / "scene.yaml").read_bytes()
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path)]) == 2
    assert "path.csv: would overwrite the input" in capsys.readouterr().err
    assert all(p.read_bytes() == b for p, b in before.items())
    (tmp_path / "afile").write_text("")  # an output folder that is a file: said before solving
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "afile")]) == 2
    assert "afile: exists and is not a folder" in capsys.readouterr().err
    # a folder under a file cannot be made: said before solving too (no progress lines)
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "afile" / "sub")]) == 2
    err = capsys.readouterr().err
    assert "Not a directory" in err and "simulating" not in err


def test_the_whiskers_of_a_scene_file_are_the_robot_description(tmp_path: Path) -> None:
    from vibrissa.formats.scene_file import SceneError, load_robot

    (tmp_path / "scene.yaml").write_text(SCENE)  # its path file need not exist for this
    w0, w1 = load_robot(tmp_path / "scene.yaml")
    assert (w0.name, w0.length_m, w0.ei_nm2, w1.name, w1.length_m) == ("w0", 0.05, 2e-5, "w1", 0.04)
    assert np.allclose(w1.X_RC.quaternion_xyzw, [0.0998334, 0, 0, 0.9950042])
    (tmp_path / "robot.yaml").write_text("whiskers:\n  - {name: a, length_m: 0.03, ei_nm2: 1e-5}\n")
    with pytest.raises(SceneError, match=r"robot.yaml: whiskers\[0\]: missing 'mount'"):
        load_robot(tmp_path / "robot.yaml")
    (tmp_path / "robot.yaml").write_text("mu: 0.2\n")
    with pytest.raises(SceneError, match="robot.yaml: missing 'whiskers'"):
        load_robot(tmp_path / "robot.yaml")


def test_simulate_says_when_a_rod_met_a_second_object(tmp_path: Path, capsys) -> None:
    """A rod leaning on ball a runs into ball b low on its path (the scene of
    tests/core/test_random_scenes_rod.py): the episode ends another-object and a second-contact
    episode goes on with both balls, in summary.json, the CSV's second-contact columns and the
    closing lines, which say what that means."""
    (tmp_path / "scene.yaml").write_text("""\
mu: 0.3
objects:
  - {name: a, shape: sphere, radius_m: 0.015, position_m: [0.015, 0.0, 0.04]}
  - {name: b, shape: sphere, radius_m: 0.005, position_m: [0.0175, 0.0, 0.0075]}
whiskers:
  - {name: w, length_m: 0.05, ei_nm2: 1.0e-4, mount: {position_m: [0, 0, 0]}}
path: path.csv
""")
    x = np.linspace(-0.0025, 0.045, 951)
    (tmp_path / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + "".join(
        f"{0.01 * i},{x[i]},0,0,0,0,0,1\n" for i in range(len(x))))
    out = tmp_path / "out"
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(out), "--workers", "1"]) == 0
    summary = json.loads((out / "summary.json").read_text())["whiskers"]["w"]
    first, both, *_rest = summary["episodes"]
    assert (first["object"], first["end"]) == ("a", "another-object")
    assert (both["start"], both["object"], both["second_object"]) == ("second-contact", "a", "b")
    two = summary["samples_with_two_contacts"]
    assert two > 10 and summary["samples_per_phase"]["unresolved"] == 0
    rows = (out / "w.csv").read_text().splitlines()
    assert sum(row.endswith(",b") for row in rows[1:]) == two  # object2 is the last column
    err = capsys.readouterr().err.strip().splitlines()
    assert f"1 with a second contact (the rod leaning on two objects: {two} samples)" in err[-2]
    assert "it goes on with both contacts" in err[-1]


@pytest.mark.parametrize("ball_m, x0_m, step_m, unresolved, line", [
    # the clamp starts inside a ball 0.1 m ahead and drives out: inside while x > 0.085 m
    ([0.1, 0.0, 0.0], 0.1005, -0.001, 16,
     "  w0: 16 sample(s) unresolved with the clamp inside ball (from t = 0 s): no rod fits there"),
    # the rod (up from the clamp) starts through a ball 0.03 m above the clamp: inside while
    # x < 0.015 m, its clamp outside
    ([0.0, 0.0, 0.03], 0.0005, 0.001, 15,
     "  w0: 15 sample(s) unresolved from the path's start: its rod starts inside ball, with no "
     "touch to follow a contact from"),
])
def test_simulate_says_why_samples_at_the_start_are_unresolved(
        tmp_path: Path, capsys, ball_m: list[float], x0_m: float, step_m: float, unresolved: int,
        line: str) -> None:
    """A robot whose whisker (pointing up) starts with its clamp, or only its rod, inside a ball
    of 0.015 m and drives out of it 1 mm a sample: those samples are unresolved, the rest free,
    and the closing lines say why."""
    (tmp_path / "scene.yaml").write_text(f"""\
mu: 0.25
objects:
  - {{name: ball, shape: sphere, radius_m: 0.015, position_m: {ball_m}}}
whiskers:
  - {{name: w0, length_m: 0.05, ei_nm2: 2.0e-5, mount: {{position_m: [0, 0, 0]}}}}
path: path.csv
""")
    (tmp_path / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + "".join(
        f"{0.01 * i},{x0_m + step_m * i},0,0,0,0,0,1\n" for i in range(60)))
    assert main(["simulate", str(tmp_path / "scene.yaml"), "-o", str(tmp_path / "out")]) == 0
    assert capsys.readouterr().err.strip().splitlines()[-1] == line
    with (tmp_path / "out" / "w0.csv").open() as handle:
        phases = [row["phase"] for row in csv.DictReader(handle)]
    assert phases == ["unresolved"] * unresolved + ["none"] * (60 - unresolved)


def test_the_closing_line_of_a_scene_without_contact() -> None:
    from vibrissa.cli.scenes import episode_summary

    assert episode_summary([]) == "0 contact episodes; samples: 0 none, 0 tip, 0 tangential, 0 unresolved"


def wrench_rows(n: int) -> list[str]:
    """``n`` rows of WRENCHES.csv along the path of `write_path`, touching and not."""
    rng = np.random.default_rng(5)
    return [f"{0.01 * (i % 300)},w{i % 2},{rng.normal() * 1e-3},{rng.normal() * 1e-3},"
            f"{rng.normal() * 1e-4},{rng.normal() * 1e-5},{rng.normal() * 1e-5},0\n"
            for i in range(n)]


@pytest.mark.slow
def test_reconstruct_streams_in_chunks_to_the_same_bytes_and_writes_all_or_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Rows are read, reconstructed and written a chunk at a time: the same file whatever the
    chunk, memory bounded by the chunk (not the file), and an error in a later chunk leaves
    no output (not even the chunks before it)."""
    import tracemalloc

    from vibrissa.cli import scenes

    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    header = "t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n"
    (tmp_path / "wrenches.csv").write_text(header + "".join(wrench_rows(20000)))
    argv = ["reconstruct", str(tmp_path / "wrenches.csv"), "--scene", str(tmp_path / "scene.yaml")]
    assert main([*argv, "-o", str(tmp_path / "whole.csv")]) == 0
    monkeypatch.setattr(scenes, "CHUNK_ROWS", 1000)
    tracemalloc.start()
    try:
        assert main([*argv, "-o", str(tmp_path / "chunked.csv")]) == 0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert (tmp_path / "chunked.csv").read_bytes() == (tmp_path / "whole.csv").read_bytes()
    assert peak < 8e6, peak  # all 20 000 rows at once: ~25 MB; 1000: ~2 MB
    (tmp_path / "wrenches.csv").write_text(header + "".join(wrench_rows(2500)) + "0.1,w7,0,0,0,0,0,0\n")
    assert main([*argv, "-o", str(tmp_path / "points.csv")]) == 2
    assert not (tmp_path / "points.csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "chunked.csv", "path.csv", "scene.yaml", "whole.csv", "wrenches.csv"]
    # a link (as /dev/stdout is) is written through, not replaced by a file
    (tmp_path / "wrenches.csv").write_text(header + "".join(wrench_rows(10)))
    link = tmp_path / "link.csv"
    link.symlink_to(tmp_path / "target.csv")
    assert main([*argv, "-o", str(link)]) == 0
    assert link.is_symlink() and (tmp_path / "target.csv").read_text().count("\n") == 11


def test_reconstruct_shows_its_rows_on_a_terminal_only(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """On a terminal, the rows done after each chunk on one updating line, cleared before the
    closing line; into a file or a pipe, the closing line alone."""
    import io
    import sys

    from vibrissa.cli import scenes

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    (tmp_path / "wrenches.csv").write_text("t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n"
                                           + "".join(wrench_rows(2500)))
    argv = ["reconstruct", str(tmp_path / "wrenches.csv"), "--scene", str(tmp_path / "scene.yaml")]
    monkeypatch.setattr(scenes, "CHUNK_ROWS", 1000)
    assert main([*argv, "-o", str(tmp_path / "a.csv")]) == 0
    closing = capsys.readouterr().err
    assert closing.startswith("reconstruct: 2500 rows, ") and "\r" not in closing
    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert main([*argv, "-o", str(tmp_path / "b.csv")]) == 0
    shown = terminal.getvalue().split("\r")
    assert [line.split(",")[0] for line in shown[1:4]] == [
        f"reconstruct: {n} rows" for n in (1000, 2000, 2500)]
    assert shown[4] == "\x1b[K" + closing.replace("a.csv", "b.csv")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


@pytest.mark.parametrize("sweep_mode", [False, True])
def test_an_unreadable_cell_is_named_by_its_line_and_a_long_one_is_shortened(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], sweep_mode: bool) -> None:
    """Bytes that are not UTF-8 deep in a file: the line and the byte offset in the file (not
    in the decoder's block); a field over the csv module's limit: its line and column; a
    long value that is not a number: a line of a readable length."""
    (tmp_path / "scene.yaml").write_text(SCENE)
    write_path(tmp_path)
    header = "x0,y0,f0x,f0y,f0z,m0x,m0y,m0z\n" if sweep_mode else "t,whisker,f0x,f0y,f0z,m0x,m0y,m0z\n"
    rows = [r.replace(",w0,", ",0.0,").replace(",w1,", ",0.1,") if sweep_mode else r
            for r in wrench_rows(600)]
    argv = ["reconstruct", str(tmp_path / "wrenches.csv"), "-o", str(tmp_path / "p.csv"),
            *([] if sweep_mode else ["--scene", str(tmp_path / "scene.yaml")])]
    before = (header + "".join(rows[:299])).encode()
    bad = rows[299].encode().replace(b",", b",\xe9", 1)  # line 301 of the file
    (tmp_path / "wrenches.csv").write_bytes(before + bad + "".join(rows[300:]).encode())
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    offset = len(before) + bad.index(b"\xe9")
    assert err.endswith(f"wrenches.csv: line 301: byte 0xe9 at offset {offset} is not UTF-8 "
                        "(invalid continuation byte)"), err
    cut = rows[4].split(",")
    cut[3] = "9" * 200_000  # column f0y of line 6
    (tmp_path / "wrenches.csv").write_text(header + "".join(rows[:4]) + ",".join(cut))
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("wrenches.csv: line 6, column f0y: a field longer than 131072 "
                        "characters (an unclosed quote?)"), err[:300]
    (tmp_path / "wrenches.csv").write_text(header + "".join(rows[:4]) + rows[4].split(",")[0]
                                           + ("," + rows[4].split(",")[1]) + ","
                                           + "x" * 100_000 + ",0,0,0,0,0\n")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "row 5, column" in err and "f0x" in err and "is not a number" in err
    assert len(err) < 300, len(err)
