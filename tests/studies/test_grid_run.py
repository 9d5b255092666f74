"""Running grids: the same tables serially, on local processes and on a Dask LocalCluster;
resuming from the store after a kill; only the touched cases recomputed; Step 2's error."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from vibrissa.cli import tables
from vibrissa.cli.main import main
from vibrissa.grid_study import EQUILIBRIUM_COLUMNS, GridCase
from vibrissa.studies.grid_file import load_grid
from vibrissa.studies.grid_run import PARAMETER_COLUMNS, CaseStore, run_grid, same_bits
from vibrissa.surfaces import parse_surface

# Eight short sweeps: tip and tangential contact, stick (mu 0.4), a paraboloid and a sphere
# that the trail at y0 = 0.35 misses (no contact: NaN in its summary).
TINY = """\
surfaces: ["paraboloid:a=0.5,b=1,h=0.4", "sphere:r=0.3,cz=0.8"]
y0_m: [0.0, 0.35]
mu: [0.0, 0.4]
step: 0.02
rods: [{length_m: 1.0, ei_nm2: 1.0}]
"""
CASE_FILE_CHARS = 64 + len(".parquet")


def grid_file(folder: Path, text: str = TINY) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "grid.yaml"
    path.write_text(text)
    return path


def stored(out: Path) -> list[Path]:
    """The finished case files of ``out``'s store (not a partial file a kill left)."""
    folder = out / "cases"
    return [p for p in folder.glob("*.parquet")
            if len(p.name) == CASE_FILE_CHARS and not p.name.startswith(".")] if folder.is_dir() else []


def read_tables(out: Path) -> tuple[pa.Table, pa.Table]:
    return pq.read_table(out / "equilibria.parquet"), pq.read_table(out / "summary.parquet")


def same_tables(a: Path, b: Path) -> bool:
    """The tables of two output folders are the same, bit for bit."""
    return all(same_bits(x, y) for x, y in zip(read_tables(a), read_tables(b), strict=True))


def test_a_grid_writes_its_tables_and_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["study", "grid", str(grid_file(tmp_path)), "-o", str(out), "--workers", "1",
                 "--csv"]) == 0
    equilibria, summary = read_tables(out)
    assert equilibria.column_names == ["case", "key", *PARAMETER_COLUMNS, *EQUILIBRIUM_COLUMNS]
    assert set(tables.SWEEP_COLUMNS) <= set(equilibria.column_names)  # the sweep CSV's names
    assert summary.num_rows == 8 and summary.column("case").to_pylist() == list(range(8))
    assert sum(summary.column("n_steps").to_pylist()) == equilibria.num_rows > 0
    assert {"end", "x0_end", "phase_changes", "peak_f0", "peak_f0_n",
            "max_reconstruction_error"} <= set(summary.column_names)
    for name in ("equilibria.csv", "summary.csv"):
        assert (out / name).read_text().count("\n") == (equilibria if name[0] == "e" else summary).num_rows + 1
    assert (out / "grid.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "8 cases (8 computed, 0 from" in capsys.readouterr().err


def test_step_2_finds_the_true_surface(tmp_path: Path) -> None:
    """The largest reconstruction error of the summary is tiny, and so is the distance of every
    reconstructed point to the object measured here, independently of the stored column."""
    out = tmp_path / "out"
    assert main(["study", "grid", str(grid_file(tmp_path)), "-o", str(out), "--workers", "1",
                 "--no-figures"]) == 0
    equilibria, summary = read_tables(out)
    errors = np.array(summary.column("max_reconstruction_error").to_pylist())
    assert np.isnan(errors).sum() == 2  # the sphere's trails at y0 = 0.35: no contact
    assert 0 < np.nanmax(errors) < 1e-9
    rows = equilibria.to_pydict()
    ok = np.array(rows["status"]) == 0
    assert ok.sum() > 0.9 * len(ok)
    point = np.column_stack([rows["rx"], rows["ry"], rows["rz"]])[ok]
    surfaces = np.array(rows["surface_m"])[ok]
    for spec in set(surfaces):
        surface = parse_surface(spec)  # the rod is 1 m: units of L are metres
        distance = np.abs(surface.signed_distance(point[surfaces == spec]))
        assert distance.max() < 1e-9


def test_a_rod_of_2_m_sees_the_object_at_half_size(tmp_path: Path) -> None:
    """Dimensionless mechanics (eq. 1): an object of twice the size and a trail twice as far,
    felt by a rod twice as long, is the same case in units of L; the force in N scales by
    EI/L^2."""
    text = ("cases:\n  - {surface: 'sphere:r=0.3,cz=0.8', y0_m: 0.1, mu: 0.3, step: 0.02}\n"
            "  - {surface: 'sphere:r=0.6,cz=1.6', y0_m: 0.2, mu: 0.3, step: 0.02, length_m: 2.0, "
            "ei_nm2: 3.0}\n")
    run = run_grid(load_grid(grid_file(tmp_path, text)), CaseStore(tmp_path / "cases"), workers=1)
    rows = run.equilibria.to_pydict()
    case = np.array(rows["case"])
    for name in ("x0", "f0x", "f0y", "f0z", "m0x", "m0y", "m0z", "px", "rx", "s1"):
        column = np.array(rows[name], dtype=float)
        np.testing.assert_array_equal(column[case == 0], column[case == 1])
    peak = run.summary.to_pydict()
    assert peak["peak_f0"][0] == peak["peak_f0"][1] > 0
    assert peak["peak_f0_n"][1] == pytest.approx(peak["peak_f0"][1] * 3.0 / 4.0, rel=1e-15)


@pytest.mark.live
def test_serial_local_workers_and_a_local_cluster_give_the_same_tables(tmp_path: Path) -> None:
    """Serial, 2 local processes, a LocalCluster of 2 started by the command and a running
    cluster reached by its address: the same tables, to the bit."""
    path = grid_file(tmp_path)
    runs = {"serial": ["--workers", "1"], "workers": ["--workers", "2"],
            "cluster": ["--workers", "2", "--scheduler", "local"]}
    for name, flags in runs.items():
        assert main(["study", "grid", str(path), "-o", str(tmp_path / name), "--no-figures",
                     *flags]) == 0
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster:
        assert main(["study", "grid", str(path), "-o", str(tmp_path / "address"), "--no-figures",
                     "--scheduler", cluster.scheduler_address]) == 0
    for name in ("workers", "cluster", "address"):
        assert same_tables(tmp_path / "serial", tmp_path / name), name
        assert (tmp_path / "serial" / "equilibria.parquet").read_bytes() == (
            tmp_path / name / "equilibria.parquet").read_bytes()


def test_changing_one_parameter_recomputes_only_the_cases_it_touches(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["study", "grid", str(grid_file(tmp_path)), "-o", str(out), "--workers", "1",
                 "--no-figures"]) == 0
    changed = grid_file(tmp_path / "changed", TINY.replace("mu: [0.0, 0.4]", "mu: [0.0, 0.3]"))
    capsys.readouterr()
    assert main(["study", "grid", str(changed), "-o", str(out), "--workers", "1", "--no-figures"]) == 0
    assert "8 cases (4 computed, 4 from" in capsys.readouterr().err  # the mu 0.3 ones
    fresh = tmp_path / "fresh"
    assert main(["study", "grid", str(changed), "-o", str(fresh), "--workers", "1", "--no-figures"]) == 0
    assert same_tables(out, fresh)
    assert len(stored(out)) == 12  # the mu 0.4 cases stay in the store


def test_a_killed_grid_resumes_and_computes_only_the_missing_cases(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Finer steps than TINY: several seconds in all, so that the kill lands half-way.
    path = grid_file(tmp_path, TINY.replace("step: 0.02", "step: 0.004"))
    out = tmp_path / "out"
    command = ("import sys; from vibrissa.cli.main import main; "
               "sys.exit(main(sys.argv[1:]))")
    process = subprocess.Popen([sys.executable, "-c", command, "study", "grid", str(path), "-o",
                                str(out), "--workers", "1", "--no-figures"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while not stored(out) and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        os.kill(process.pid, signal.SIGKILL)
    finally:
        process.kill()
        process.wait(timeout=60)
    assert process.returncode == -signal.SIGKILL, "the grid ended before it was killed"
    finished = len(stored(out))
    assert 0 < finished < 8
    assert not (out / "equilibria.parquet").exists()
    capsys.readouterr()
    assert main(["study", "grid", str(path), "-o", str(out), "--workers", "1", "--no-figures"]) == 0
    assert f"8 cases ({8 - finished} computed, {finished} from" in capsys.readouterr().err
    whole = tmp_path / "whole"
    assert main(["study", "grid", str(path), "-o", str(whole), "--workers", "1", "--no-figures"]) == 0
    assert same_tables(out, whole)


@pytest.mark.slow
def test_the_paper_study_on_workers_is_the_papers_numbers() -> None:
    """`vibrissa study paper` (the shipped grid on all cores) gives the sweeps of the batched
    `vibrissa.study.run_study`, to the bit."""
    from vibrissa.cli.study_grid import run_paper
    from vibrissa.study import run_study

    grid, batched = run_paper(0.02), run_study(step=0.02)
    assert len(grid.cases) == len(batched.cases) == 25
    for ours, theirs in zip(grid.cases, batched.cases, strict=True):
        assert (ours.y0, ours.mu) == (theirs.y0, theirs.mu)
        for name in ("x0", "f0", "m0", "contact", "s1", "phase", "state"):
            np.testing.assert_array_equal(getattr(ours.sweep, name), getattr(theirs.sweep, name))
        np.testing.assert_array_equal(ours.error, theirs.error)
        assert ours.sweep.end == theirs.sweep.end


def test_grid_case_refuses_bad_values() -> None:
    with pytest.raises(ValueError, match="mu must be >= 0"):
        GridCase("sphere:r=0.3,cz=0.8", 0.0, -0.1, 0.01)
    with pytest.raises(ValueError, match="unknown key"):
        GridCase("sphere:r=0.3,q=0.8", 0.0, 0.1, 0.01)


def test_a_grid_of_tapered_and_pre_curved_rods(tmp_path: Path) -> None:
    """Rods that taper and are pre-curved in a trail grid: each case swept by its own rod
    (the Kirchhoff rod), its contacts reconstructed from its wrenches, its key its own; the
    straight uniform rod's key is the one it had before rods had shapes."""
    text = """\
surfaces: ["sphere:r=0.3,cz=0.6"]
y0_m: [0.1]
mu: [0.3]
step: 0.01
rods: [{length_m: 1.0, ei_nm2: 1.0},
       {length_m: 1.0, ei_nm2: 1.0, taper_ratio: 0.5, precurvature_1pm: 1.5},
       {length_m: 0.5, ei_nm2: 2.0, taper_ratio: 0.5, precurvature_1pm: 3.0, poisson_ratio: 0.4}]
"""
    grid = load_grid(grid_file(tmp_path, text))
    assert [c.shape.uniform for c in grid.cases] == [True, False, False]
    assert grid.cases[2].shape.precurvature == 1.5  # 3 / m on a 0.5 m rod
    out = tmp_path / "out"
    assert main(["study", "grid", str(grid_file(tmp_path, text)), "-o", str(out),
                 "--workers", "1"]) == 0
    equilibria, summary = read_tables(out)
    assert summary.column("taper_ratio").to_pylist() == [1.0, 0.5, 0.5]
    assert summary.column("end").to_pylist() == ["detachment"] * 3
    assert max(summary.column("max_reconstruction_error").to_pylist()) < 1e-6
    keys = summary.column("key").to_pylist()
    assert len(set(keys)) == 3
    uniform = GridCase("sphere:r=0.3,cz=0.6", 0.1, 0.3, 0.01)
    assert "taper_ratio" not in uniform.inputs()
    with pytest.raises(ValueError, match="taper_ratio"):
        load_grid(grid_file(tmp_path, text.replace("taper_ratio: 0.5, precurvature_1pm: 1.5",
                                                   "taper_ratio: 0.0")))
