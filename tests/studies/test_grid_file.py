"""Grid files: read strictly, every bad file refused before anything runs, naming file and key."""

from __future__ import annotations

from pathlib import Path

import pytest

from vibrissa.cli.main import main
from vibrissa.grid_study import GridCase
from vibrissa.studies.grid_file import CASE_KEYS, PAPER_GRID, ROD_KEYS, TOP_KEYS, GridFileError, load_grid
from vibrissa.study import PAPER_MU, PAPER_STEP, PAPER_SURFACE, PAPER_Y0

GOOD = """\
surfaces: ["paraboloid:a=0.5,b=1,h=0.4", "sphere:r=0.3,cz=0.8"]
y0_m: [0.0, 0.2]
mu: [0.0, 0.3]
step: 0.02
rods: [{length_m: 1.0, ei_nm2: 1.0}, {length_m: 2.0, ei_nm2: 0.5}]
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "grid.yaml"
    path.write_text(text)
    return path


def test_lists_make_the_product_in_grid_order(tmp_path: Path) -> None:
    grid = load_grid(write(tmp_path, GOOD))
    assert grid.name == "grid"
    assert len(grid.cases) == 2 * 2 * 2 * 2
    assert grid.cases[0] == GridCase("paraboloid:a=0.5,b=1,h=0.4", 0.0, 0.0, 0.02, 1.0, 1.0)
    assert grid.cases[1] == GridCase("paraboloid:a=0.5,b=1,h=0.4", 0.0, 0.3, 0.02, 1.0, 1.0)  # mu innermost
    assert grid.cases[4] == GridCase("paraboloid:a=0.5,b=1,h=0.4", 0.0, 0.0, 0.02, 2.0, 0.5)
    assert grid.cases[-1] == GridCase("sphere:r=0.3,cz=0.8", 0.2, 0.3, 0.02, 2.0, 0.5)


def test_explicit_cases_and_defaults(tmp_path: Path) -> None:
    grid = load_grid(write(tmp_path, "name: two\ncases:\n"
                           "  - {surface: 'sphere:r=0.3,cz=0.8', y0_m: 0.1, mu: 0.2}\n"
                           "  - {surface: 'sphere:r=0.3,cz=0.8', y0_m: 0.1, mu: 0.2, step: 0.01, "
                           "length_m: 0.05, ei_nm2: 2e-4}\n"))
    assert grid.name == "two"
    assert grid.cases == (GridCase("sphere:r=0.3,cz=0.8", 0.1, 0.2, 0.001),
                          GridCase("sphere:r=0.3,cz=0.8", 0.1, 0.2, 0.01, 0.05, 2e-4))


def test_the_shipped_paper_grid_is_the_papers_study() -> None:
    grid = load_grid(PAPER_GRID)
    assert grid.name == "paper"
    assert [(c.surface_m, c.y0_m, c.mu, c.step, c.length_m, c.ei_nm2) for c in grid.cases] == [
        (PAPER_SURFACE, y0, mu, PAPER_STEP, 1.0, 1.0) for y0 in PAPER_Y0 for mu in PAPER_MU]
    assert {c.step for c in load_grid(PAPER_GRID, step=0.01).cases} == {0.01}


BAD = [
    ("unknown top key", GOOD + "muu: [0.1]\n", "unknown key 'muu'"),
    ("unknown rod key", GOOD.replace("ei_nm2: 0.5", "ei: 0.5"), "rods[1]: unknown key 'ei'"),
    ("unknown case key", "cases: [{surface: 'sphere:r=0.3', y0_m: 0, mu: 0, u: 1}]\n",
     "cases[0]: unknown key 'u'"),
    ("wrong type", GOOD.replace("mu: [0.0, 0.3]", "mu: [0.0, fast]"), "mu[1]: expected a finite number"),
    ("wrong type of step", GOOD.replace("step: 0.02", "step: {dx: 1}"), "step[0]: expected a finite number"),
    ("a bool is no number", GOOD.replace("y0_m: [0.0, 0.2]", "y0_m: [true]"), "y0_m[0]: expected a finite number"),
    ("rods not mappings", GOOD.replace("rods: [{length_m: 1.0, ei_nm2: 1.0},", "rods: [1.0,"),
     "rods[0]: expected a mapping"),
    ("empty list", GOOD.replace("mu: [0.0, 0.3]", "mu: []"), "mu: an empty list"),
    ("empty surfaces", GOOD.replace('surfaces: ["paraboloid:a=0.5,b=1,h=0.4", "sphere:r=0.3,cz=0.8"]',
                                    "surfaces: []"), "surfaces: an empty list"),
    ("bad surface spec", GOOD.replace("sphere:r=0.3,cz=0.8", "sphere:r=0.3,zz=0.8"),
     "surfaces[1]: surface spec 'sphere:r=0.3,zz=0.8': unknown key 'zz'"),
    ("bad surface kind", GOOD.replace("sphere:r=0.3,cz=0.8", "cube:a=1"), "surfaces[1]: surface spec"),
    ("negative mu", GOOD.replace("mu: [0.0, 0.3]", "mu: [-0.1]"), "mu[0]: mu must be >= 0"),
    ("zero step", GOOD.replace("step: 0.02", "step: 0"), "step[0]: step must be > 0"),
    ("a rod of no length", GOOD.replace("length_m: 2.0", "length_m: 0"), "rods[1]: length_m and ei_nm2 must be > 0"),
    ("missing mu", GOOD.replace("mu: [0.0, 0.3]\n", ""), "mu: missing"),
    ("both lists and cases", GOOD + "cases: []\n", "cases: give either cases or the lists"),
    ("not a mapping", "- 1\n- 2\n", "expected a mapping of keys"),
    ("invalid YAML", "mu: [0.1\n", "invalid YAML"),
    ("a duplicate key", GOOD + "mu: [0.1]\n", "duplicate key 'mu'"),
]


@pytest.mark.parametrize(("text", "message"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_files_name_the_file_and_the_key(tmp_path: Path, text: str, message: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(GridFileError) as info:
        load_grid(path)
    assert str(path) in str(info.value)
    assert message in str(info.value)


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(GridFileError, match=f"{tmp_path / 'nowhere.yaml'}: cannot read"):
        load_grid(tmp_path / "nowhere.yaml")


@pytest.mark.parametrize(("text", "message"), [BAD[0][1:], BAD[3][1:], BAD[7][1:], BAD[9][1:]])
def test_the_command_refuses_a_bad_file_before_anything_runs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, message: str) -> None:
    path, out = write(tmp_path, text), tmp_path / "out"
    assert main(["study", "grid", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and message in err
    assert not out.exists()
    assert main(["study", "grid", str(tmp_path / "missing.yaml"), "-o", str(out)]) == 2
    assert f"{tmp_path / 'missing.yaml'}: cannot read" in capsys.readouterr().err
    assert not out.exists()


def test_the_documented_keys_are_the_loaders() -> None:
    """docs/STUDIES.md's table of keys names every key the loader takes, and no other."""
    page = (Path(__file__).parents[2] / "docs" / "STUDIES.md").read_text(encoding="utf-8")
    table = page.split("| key | type | default | meaning |")[1].split("\n\n")[0]
    documented = [line.split("`")[1] for line in table.splitlines() if line.startswith("| `")]
    assert documented == list(TOP_KEYS)
    for key in (*CASE_KEYS, *ROD_KEYS):
        assert f"`{key}`" in table


@pytest.mark.parametrize(("argv", "message"), [
    (["study", "grid"], "study grid needs GRID.yaml"),
    (["study", "paper", "--workers", "2"], "--workers: for study grid"),
    (["study", "noise", "GRID.yaml"], "GRID.yaml: for study grid"),
    (["study", "paper", "--scheduler", "local", "--csv"], "--scheduler, --csv: for study grid"),
    (["study", "grid", "GRID.yaml", "--rod-length-m", "0.05"], "a grid's rods are its key rods"),
])
def test_the_command_refuses_arguments_of_another_study(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str) -> None:
    out = tmp_path / "out"
    assert main([*argv, "-o", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_workers_must_be_a_whole_number_of_one_or_more(capsys: pytest.CaptureFixture[str]) -> None:
    for value in ("0", "two", "1.5"):
        with pytest.raises(SystemExit) as info:
            main(["study", "grid", "g.yaml", "-o", "out", "--workers", value])
        assert info.value.code == 2
        assert "--workers" in capsys.readouterr().err


def test_the_shipped_robot_friction_grid_is_the_robot_demo_at_three_frictions() -> None:
    from vibrissa.grid_study import SceneCase

    grid = load_grid(Path(__file__).parents[2] / "studies" / "robot_friction.yaml")
    assert [case.mu for case in grid.cases] == [0.0, 0.2, 0.5]
    assert all(isinstance(case, SceneCase) and len(case.scene.whiskers) == 8 for case in grid.cases)
