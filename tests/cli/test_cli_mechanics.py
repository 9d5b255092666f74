"""``vibrissa sweep``, ``reconstruct`` and ``study``: file formats, round trips, argument errors.

Coarse steps (0.01 L and up) keep these fast; the physics of the core is tested elsewhere.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from vibrissa.cli import mechanics
from vibrissa.cli.main import build_parser, main
from vibrissa.cli.tables import COLUMNS, RECONSTRUCTION_COLUMNS, SWEEP_COLUMNS
from vibrissa.study import run_study

SURFACE = "paraboloid:a=0.5,b=1,h=0.4"
REQUIRED_SWEEP_COLUMNS = (
    "x0,y0,phase,s1,psi,f0x,f0y,f0z,m0x,m0y,m0z,px,py,pz,fn,ft".split(",")
)
ROUND_TRIP_TOL = 1e-7


def read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        return list(reader.fieldnames or []), list(reader)


def column(rows: Sequence[dict[str, str]], name: str) -> np.ndarray:
    return np.array([float(row[name]) if row[name] else np.nan for row in rows])


@pytest.fixture(scope="module")
def sweep_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One sweep through both contact phases (y0 = 0.2, mu = 0.3) at step 0.01."""
    path = tmp_path_factory.mktemp("sweep") / "sweep.csv"
    args = ["sweep", "--surface", SURFACE, "--y0", "0.2", "--mu", "0.3", "--step", "0.01",
            "-o", str(path)]
    assert main(args) == 0
    return path


def test_sweep_csv_columns_and_values(sweep_csv: Path) -> None:
    header, rows = read_rows(sweep_csv)
    assert header[: len(REQUIRED_SWEEP_COLUMNS)] == REQUIRED_SWEEP_COLUMNS
    assert header == list(SWEEP_COLUMNS)
    assert header[16:] == ["state", "nx", "ny", "nz", "refined"]
    assert len(rows) > 100
    assert {row["refined"] for row in rows} == {"0"}  # plain steps on this trail
    assert {row["phase"] for row in rows} == {"tip", "tangential"}
    assert {row["state"] for row in rows} <= {"slide", "stick"}
    x0 = column(rows, "x0")
    np.testing.assert_allclose(np.diff(x0), -0.01, atol=1e-9)
    assert np.all(column(rows, "y0") == 0.2)
    # Statics of the rod from the file alone: f0 + F = 0 and m0 + (P1 - P0) x F = 0.
    f0 = np.column_stack([column(rows, f"f0{c}") for c in "xyz"])
    m0 = np.column_stack([column(rows, f"m0{c}") for c in "xyz"])
    p1 = np.column_stack([column(rows, f"p{c}") for c in "xyz"])
    p0 = np.column_stack([x0, column(rows, "y0"), np.zeros(len(rows))])
    np.testing.assert_allclose(m0 + np.cross(p1 - p0, -f0), 0.0, atol=1e-10)
    # Full precision: every float cell round-trips through repr.
    first = rows[0]["f0x"]
    assert repr(float(first)) == first


def test_sweep_json_summary(sweep_csv: Path) -> None:
    summary = json.loads(sweep_csv.with_suffix(".json").read_text())
    for key in ("end", "x0_end", "phase_changes", "n_steps", "surface", "y0", "mu", "step",
                "units"):
        assert key in summary, key
    assert summary["end"] in ("snap-off", "detachment")
    assert summary["y0"] == 0.2 and summary["mu"] == 0.3 and summary["step"] == 0.01
    assert summary["n_steps"] == len(read_rows(sweep_csv)[1])
    assert [(c["from"], c["to"]) for c in summary["phase_changes"]] == [
        ("tip", "tangential"), ("tangential", "tip")
    ]
    assert all(set(change) == {"x0", "from", "to"} for change in summary["phase_changes"])
    assert "EI/L^2" in json.dumps(summary["units"])


def test_reconstruct_round_trip(sweep_csv: Path, tmp_path: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rcp.csv"
    assert main(["reconstruct", str(sweep_csv), "--surface", SURFACE, "-o", str(out)]) == 0
    header, rows = read_rows(out)
    assert header == ["x0", "y0", "rx", "ry", "rz", "s1", "phase", "status", "err"]
    assert header == [*RECONSTRUCTION_COLUMNS, "err"]
    _, sweep_rows = read_rows(sweep_csv)
    assert len(rows) == len(sweep_rows)
    assert [(r["x0"], r["y0"]) for r in rows] == [(r["x0"], r["y0"]) for r in sweep_rows]
    for r, p in zip("xyz", "xyz", strict=True):
        np.testing.assert_allclose(column(rows, f"r{r}"), column(sweep_rows, f"p{p}"),
                                   rtol=0, atol=ROUND_TRIP_TOL)
    assert np.all(column(rows, "err") < ROUND_TRIP_TOL)
    assert [row["phase"] for row in rows] == [row["phase"] for row in sweep_rows]
    assert {row["status"] for row in rows} == {"ok"}
    assert "rows" in capsys.readouterr().err


def test_reconstruct_keeps_rows_without_contact(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "wrench.csv"
    src.write_text(
        "x0,y0,z0,f0x,f0y,f0z,m0x,m0y,m0z\n"
        "0.1,0.2,0.0,0.0,0.0,0.0,0.0,0.0,0.0\n"       # no force
        "0.1,0.2,0.0,-0.1,0.0,0.05,0.0,-0.05,0.0\n"   # a bent rod
        "0.1,0.2,0.0,,0.0,0.05,0.0,-0.05,0.0\n"       # missing value
    )
    out = tmp_path / "rcp.csv"
    assert main(["reconstruct", str(src), "-o", str(out)]) == 0
    header, rows = read_rows(out)
    assert header == ["x0", "y0", "z0", *RECONSTRUCTION_COLUMNS[2:]]
    assert len(rows) == 3
    assert [row["x0"] for row in rows] == ["0.1"] * 3 and rows[1]["z0"] == "0.0"
    assert rows[0]["rx"] == rows[0]["s1"] == "" and rows[0]["status"] == "no_force"
    assert rows[2]["rx"] == "" and "non_finite_input" in rows[2]["status"]
    err = capsys.readouterr().err
    assert "2 without" in err and "no_force: 1" in err


def test_reconstruct_uses_z0(tmp_path: Path) -> None:
    lines = ["x0,y0,f0x,f0y,f0z,m0x,m0y,m0z", "0.0,0.0,-0.1,0.0,0.05,0.0,-0.05,0.0"]
    src = tmp_path / "a.csv"
    src.write_text("\n".join(lines) + "\n")
    lifted = tmp_path / "b.csv"
    lifted.write_text(lines[0] + ",z0\n" + lines[1] + ",0.5\n")
    for path in (src, lifted):
        assert main(["reconstruct", str(path), "-o", str(path.with_suffix(".out"))]) == 0
    rz = [column(read_rows(p.with_suffix(".out"))[1], "rz")[0] for p in (src, lifted)]
    assert rz[1] - rz[0] == pytest.approx(0.5, abs=1e-12)


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["sweep", "--surface", "cube:a=1", "--y0", "0", "--mu", "0"], "--surface"),
        (["sweep", "--surface", "paraboloid:a=0.5,b=1", "--y0", "0", "--mu", "0"], "--surface"),
        (["sweep", "--y0", "0", "--mu", "0", "--step", "0"], "--step"),
        (["sweep", "--y0", "0", "--mu", "0", "--step", "-0.01"], "--step"),
        (["sweep", "--y0", "0", "--mu", "-0.1"], "--mu"),
        (["sweep", "--y0", "nan", "--mu", "0.1"], "--y0"),
        (["study", "paper", "--step", "0"], "--step"),
        # numbers whose squares overflow in Step 1 (numpy warnings, then a wrong answer)
        (["sweep", "--y0", "1e300", "--mu", "0.1"], "--y0: must be within [-1000, 1000]"),
        # a negative number with an exponent is a value, as -2000 is (argparse: an option)
        (["sweep", "--y0", "-2e3", "--mu", "0.1"], "--y0: must be within [-1000, 1000], got -2e3"),
        (["sweep", "--surface", "sphere:r=1e300", "--y0", "0", "--mu", "0"],
         "r=1e300 is outside [1e-06, 1000]"),
        (["sweep", "--surface", "sphere:r=0.3,cz=-2e6", "--y0", "0", "--mu", "0"],
         "cz=-2e6 is outside [-1000, 1000]"),
    ],
)
def test_bad_arguments_exit_2(argv: list[str], named: str, tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "-o", str(tmp_path / "x.csv")])
    assert exc.value.code == 2
    assert named in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_negative_numbers_with_exponents_are_values() -> None:
    args = build_parser("sweep").parse_args(["sweep", "--y0", "-1e-1", "--mu", "0", "-o", "x"])
    assert args.y0 == -0.1
    with pytest.raises(SystemExit):  # an option that is not one is still refused
        build_parser("sweep").parse_args(["sweep", "--y0", "-e3", "--mu", "0", "-o", "x"])


def test_reconstruct_missing_column_exit_2(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "w.csv"
    src.write_text("x0,y0,f0x,f0y,m0x,m0y,m0z\n0,0,1,0,0,0,0\n")
    assert main(["reconstruct", str(src), "-o", str(tmp_path / "r.csv")]) == 2
    err = capsys.readouterr().err
    assert "'f0z'" in err and "w.csv" in err
    assert main(["reconstruct", str(tmp_path / "none.csv"), "-o", str(tmp_path / "r.csv")]) == 2
    assert "none.csv" in capsys.readouterr().err
    assert not (tmp_path / "r.csv").exists()


@pytest.mark.parametrize(("text", "message"), [
    ("x0,y0,f0x,f0y,f0z,m0x,m0y,m0z\n0,0,-0.1,0,0.05,0,-0.05,0\n0,0,-0.1,0\n",
     "row 2: expected 8 values, got 4"),  # a file cut off in a row
    ("x0,y0,f0x,f0y,f0z,m0x,m0y,m0z\n0,0,-0.1,0,0.05,0,-0.05,0,9\n",
     "row 1: expected 8 values, got 9"),
    ("x0,y0,f0x,f0y,f0z,m0x,m0y,m0z\n0,0,-0.1,zero,0.05,0,-0.05,0\n",
     "row 1, column 'f0y': 'zero' is not a number"),
    (b"x0,y0,f0x,f0y,f0z,m0x,m0y,m0z\n0,0,\xe9,0,0,0,0,0\n",
     "line 2: byte 0xe9 at offset 34 is not UTF-8"),
])
def test_reconstruct_refuses_a_bad_row_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                 text: str | bytes, message: str) -> None:
    src = tmp_path / "w.csv"
    src.write_bytes(text if isinstance(text, bytes) else text.encode())
    assert main(["reconstruct", str(src), "-o", str(tmp_path / "r.csv")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vibrissa reconstruct: error: argument SWEEP.csv: {src}: {message}")
    assert len(err.splitlines()) == 1 and not (tmp_path / "r.csv").exists()


def test_reconstruct_reads_a_spreadsheets_byte_order_mark_and_blank_lines(tmp_path: Path) -> None:
    text = "x0,y0,f0x,f0y,f0z,m0x,m0y,m0z\n0,0,-0.1,0,0.05,0,-0.05,0\n"
    (tmp_path / "plain.csv").write_text(text)
    (tmp_path / "saved.csv").write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n\r\n").encode())
    for name in ("plain", "saved"):
        assert main(["reconstruct", str(tmp_path / f"{name}.csv"), "-o",
                     str(tmp_path / f"{name}.out")]) == 0
    assert (tmp_path / "plain.out").read_text() == (tmp_path / "saved.out").read_text()


def test_reconstruct_and_sweep_never_write_over_their_input(
        sweep_csv: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy = tmp_path / "sweep.csv"
    copy.write_bytes(sweep_csv.read_bytes())
    assert main(["reconstruct", str(copy), "-o", str(tmp_path / "." / "sweep.csv")]) == 2
    assert "would overwrite the input" in capsys.readouterr().err
    assert copy.read_bytes() == sweep_csv.read_bytes()
    # the sweep's summary goes to OUT with .json: an OUT.json would be written over by it
    assert main(["sweep", "--surface", SURFACE, "--y0", "0.2", "--mu", "0", "-o",
                 str(tmp_path / "s.json")]) == 2
    assert "name the CSV otherwise" in capsys.readouterr().err
    assert not (tmp_path / "s.json").exists()


def test_reconstruct_bad_surface_exit_2(sweep_csv: Path, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["reconstruct", str(sweep_csv), "--surface", "sphere:x=1", "-o", str(tmp_path / "r")])
    assert exc.value.code == 2
    assert "--surface" in capsys.readouterr().err


@pytest.mark.slow
def test_study_paper_no_figures(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["study", "paper", "--no-figures", "--step", "0.01", "-o", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    sweeps = summary["sweeps"]
    assert len(sweeps) == 25
    keys = {"y0", "mu", "n_steps", "x0_start", "x0_end", "end", "phase_changes",
            "max_reconstruction_error"}
    assert all(keys <= set(entry) for entry in sweeps)
    assert {(e["y0"], e["mu"]) for e in sweeps} == {
        (y0, mu) for y0 in (-0.4, -0.2, 0.0, 0.2, 0.4) for mu in (0.0, 0.1, 0.2, 0.3, 0.4)
    }
    assert max(e["max_reconstruction_error"] for e in sweeps) < 1e-9
    # The plane sweeps (y0 = 0) end by snap-off, as in the paper (Sec. III-A).
    assert all(e["end"] == "snap-off" for e in sweeps if e["y0"] == 0.0)
    assert (tmp_path / "sweeps" / "y0_+0.2_mu_0.3.csv").is_file()
    assert len(list((tmp_path / "sweeps").glob("*.csv"))) == 25
    assert not list(tmp_path.glob("*.png"))
    err = capsys.readouterr().err
    assert "25/25" in err


@pytest.mark.slow
def test_study_figures_small_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The figure path on a coarse study with only the four sweeps of Fig. 6."""

    def small_study(step: float, progress: object = None) -> object:
        return run_study(y0_values=(0.0, 0.2), mu_values=(0.0, 0.4), step=step)

    monkeypatch.setattr(mechanics, "run_study", small_study)
    assert main(["study", "paper", "--step", "0.02", "-o", str(tmp_path)]) == 0
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert [name.split("_")[0] for name in pngs] == ["fig10", "fig6", "fig7", "fig8", "fig9"]
    for name in pngs:
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000


def test_a_sweep_that_never_touches_exits_3_and_says_why(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "miss.csv"
    assert main(["sweep", "--y0", "2.0", "--mu", "0.1", "-o", str(out)]) == mechanics.EXIT_NO_CONTACT == 3
    err = capsys.readouterr().err
    assert "no contact: the straight rod on the trail y0=2 clears paraboloid" in err
    assert "nan" not in err
    header, rows = read_rows(out)
    assert header == list(SWEEP_COLUMNS) and rows == []
    assert json.loads(out.with_suffix(".json").read_text())["end"] == "no-contact"


def test_an_object_that_meets_the_clamp_itself_is_named_not_called_a_solver_failure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A sphere of radius 3 L about the origin: the trail's clamp (z = 0) runs into its equator.
    out = tmp_path / "clamp.csv"
    assert main(["sweep", "--surface", "sphere:r=3", "--y0", "0", "--mu", "0",
                 "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "meets the clamp itself (the straight rod touches it at s = 0)" in err
    assert "solver failure" not in err
    assert json.loads(out.with_suffix(".json").read_text())["end"] == "no-equilibrium"


def test_docs_and_help_give_every_column_with_its_unit() -> None:
    """docs/MECHANICS.md's table of CSV columns (``| `x0`, `y0` | L | ...``) and each
    command's --help name every column with its unit."""
    page = (Path(__file__).parents[2] / "docs" / "MECHANICS.md").read_text()
    units = {name: cells[1].strip() for line in page.splitlines() if line.startswith("| `")
             for cells in [line.split("|")[1:]] for name in re.findall(r"`([^`]+)`", cells[0])}
    sweep_help = mechanics_help("sweep")
    reconstruct_help = mechanics_help("reconstruct")
    for name, (unit, _) in COLUMNS.items():
        assert units.get(name) == unit, (name, units.get(name))
        if name in SWEEP_COLUMNS:
            assert f"  {name} [{unit}]: " in sweep_help, name
        if name in (*RECONSTRUCTION_COLUMNS, "z0", "err"):
            assert f"  {name} [{unit}]: " in reconstruct_help, name
    assert set(SWEEP_COLUMNS) | set(RECONSTRUCTION_COLUMNS) | {"z0", "err"} == set(COLUMNS)


def mechanics_help(command: str) -> str:
    with pytest.raises(SystemExit), contextlib.redirect_stdout(io.StringIO()) as out:
        main([command, "--help"])
    return out.getvalue()
