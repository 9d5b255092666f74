"""``vibrissa study noise``: the files it writes, their columns and figures, argument errors.

A coarse step (0.005 L) keeps the run to a few seconds; the physics is tested in
tests/core/test_noise_study.py.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from PIL import Image

from vibrissa.cli.main import main

NOISE_COLUMNS = ["noise_fraction", "sigma_force_n", "sigma_moment_nm", "phase", "samples",
                 "points_fraction", "error_median_mm", "error_p95_mm", "predicted_median_mm",
                 "predicted_p95_mm"]
ROD_ERROR_COLUMNS = ["parameter", "relative_error", "phase", "samples", "points_fraction",
                     "error_median_mm", "error_p95_mm", "predicted_median_mm", "predicted_p95_mm"]


def read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        return list(reader.fieldnames or []), list(reader)


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("noise") / "out"
    done = subprocess.run(
        [sys.executable, "-m", "vibrissa.cli.main", "study", "noise", "-o", str(out),
         "--step", "0.005", "--rod-length-m", "0.08", "--rod-ei-nm2", "5e-5"],
        capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    return out, done.stderr


def test_noise_csv(study_dir: tuple[Path, str]) -> None:
    header, rows = read_rows(study_dir[0] / "noise.csv")
    assert header == NOISE_COLUMNS
    fractions = sorted({float(row["noise_fraction"]) for row in rows})
    assert len(fractions) == 9
    assert fractions[0] == pytest.approx(1e-5) and fractions[-1] == pytest.approx(1e-1)
    assert {row["phase"] for row in rows} == {"tip", "tangential"}
    assert len(rows) == 2 * len(fractions)
    summary = json.loads((study_dir[0] / "summary.json").read_text())
    for row in rows:
        # the stated noise definition: std = fraction x the peak force / moment
        fraction = float(row["noise_fraction"])
        assert float(row["sigma_force_n"]) == pytest.approx(fraction * summary["peak_force_n"])
        assert float(row["sigma_moment_nm"]) == pytest.approx(fraction * summary["peak_moment_nm"])
        assert float(row["error_p95_mm"]) >= float(row["error_median_mm"]) > 0
        assert 0.0 < float(row["points_fraction"]) <= 1.0


def test_rod_errors_csv(study_dir: tuple[Path, str]) -> None:
    header, rows = read_rows(study_dir[0] / "rod_errors.csv")
    assert header == ROD_ERROR_COLUMNS
    assert {row["parameter"] for row in rows} == {"L", "EI"}
    errors = sorted({float(row["relative_error"]) for row in rows})
    assert errors[0] == pytest.approx(-0.05) and errors[-1] == pytest.approx(0.05)
    assert 0.0 in errors
    # a tip contact past a rod assumed too short gives no point: an empty cell, not a number
    empty = [row for row in rows if row["parameter"] == "L" and row["phase"] == "tip"
             and float(row["relative_error"]) < 0]
    assert empty and all(row["error_median_mm"] == "" for row in empty)


def test_summary_states_the_rod_and_the_definitions(study_dir: tuple[Path, str]) -> None:
    summary = json.loads((study_dir[0] / "summary.json").read_text())
    assert summary["study"] == "noise"
    assert summary["rod"] == {"length_m": 0.08, "ei_nm2": 5e-5}
    assert "peak |f0|" in summary["noise"]
    assert set(summary["predicted"]) == {"noise", "rod_errors"}
    assert summary["contact_samples"]["tip"] > 0 and summary["contact_samples"]["tangential"] > 0
    assert math.isfinite(summary["elapsed_s"])


def test_figures_are_pngs(study_dir: tuple[Path, str]) -> None:
    for name in ("noise.png", "rod_errors.png"):
        path = study_dir[0] / name
        assert path.stat().st_size > 10_000
        with Image.open(path) as image:
            assert image.format == "PNG"
            assert image.size[0] > 800 and image.size[1] > 400


def test_progress_on_stderr(study_dir: tuple[Path, str]) -> None:
    stderr = study_dir[1]
    assert "study: sweeps finished 3/3" in stderr
    assert "L = 80 mm, EI = 5e-05 N m^2" in stderr
    assert "2 figures" in stderr


@pytest.mark.parametrize("argv", [
    ["study", "noise"],  # no -o
    ["study", "noise", "-o", "x", "--rod-length-m", "-1"],
    ["study", "noise", "-o", "x", "--rod-ei-nm2", "0"],
    ["study", "noise", "-o", "x", "--step", "nan"],
    ["study", "nois", "-o", "x"],
])
def test_bad_arguments_exit_2(argv: list[str]) -> None:
    with pytest.raises(SystemExit) as exc, contextlib.redirect_stderr(io.StringIO()):
        main(argv)
    assert exc.value.code == 2


def test_rod_options_are_for_the_noise_study(tmp_path: Path) -> None:
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["study", "paper", "-o", str(tmp_path), "--rod-ei-nm2", "1e-4"])
    assert code == 2
    assert "--rod-ei-nm2" in err.getvalue()
    assert not any(tmp_path.iterdir())
