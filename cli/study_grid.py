"""``vibrissa study grid GRID.yaml -o DIR`` and the paper's study as the shipped grid.

DIR gets ``equilibria.parquet`` (every equilibrium, the case's parameters as columns; a grid of
scenes: every whisker's every path sample),
``summary.parquet`` (one row per case), ``grid.png`` and the store ``cases/`` that a rerun on the
same DIR resumes from (`vibrissa.studies.grid_run`); with ``--csv`` also both tables as CSV.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from vibrissa.grid_study import GridCase
from vibrissa.studies.grid_file import PAPER_GRID, Grid, GridFileError, load_grid
from vibrissa.studies.grid_run import CaseStore, GridRun, case_key, compute, equilibria_per_second, run_grid
from vibrissa.study import StudyCase, StudyResult
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import ProgressCallback

CASES_FOLDER = "cases"
TABLES = ("equilibria", "summary")


class GridProgress:
    """``study: cases k/n, m equilibria, t s`` on stderr: one line across all workers, updated
    in place on a terminal."""

    def __init__(self) -> None:
        self.start = time.perf_counter()
        self.tty = sys.stderr.isatty()

    def __call__(self, done: int, total: int, equilibria: int) -> None:
        text = (f"study: cases {done}/{total}, {equilibria} equilibria computed, "
                f"{time.perf_counter() - self.start:.1f} s")
        if self.tty:
            print(f"\r{text}", end="\n" if done == total else "", file=sys.stderr, flush=True)
        else:
            print(text, file=sys.stderr, flush=True)


def run_paper(step: float, progress: ProgressCallback | None = None) -> StudyResult:
    """The paper's study (`PAPER_GRID`, every case's step replaced by ``step``), computed on all
    local cores; ``progress(finished_sweeps, total_sweeps)``."""
    grid = load_grid(PAPER_GRID, step)
    start = time.perf_counter()
    results: list[StudyCase | None] = [None] * len(grid.cases)
    if progress:
        progress(0, len(results))
    done = 0
    for indices, computed in compute(grid.cases):
        for i, result in zip(indices, computed, strict=True):
            results[i] = result
        done += len(indices)
        if progress:
            progress(done, len(results))
    cases = [result for result in results if result is not None]
    surface = parse_surface(grid.cases[0].surface_m)
    return StudyResult(surface, float(step), cases, time.perf_counter() - start)


def write_paper_tables(out: Path, result: StudyResult) -> GridRun:
    """The paper's study as a grid's tables in ``out`` (its cases stored in ``out/cases``)."""
    store = CaseStore(out / CASES_FOLDER)
    cases = [GridCase(result.surface.spec, case.y0, case.mu, result.step) for case in result.cases]
    for case, computed in zip(cases, result.cases, strict=True):
        store.write(case_key(case), case, computed)
    run = run_grid(Grid("paper", tuple(cases)), store)
    write_tables(out, run, csv=False)
    return run


def write_tables(out: Path, run: GridRun, csv: bool) -> list[Path]:
    """``equilibria.parquet`` and ``summary.parquet`` (and ``.csv`` with ``csv``) in ``out``."""
    from vibrissa.formats.files import whole_file

    paths = []
    for name, table in zip(TABLES, (run.equilibria, run.summary), strict=True):
        path = out / f"{name}.parquet"
        with whole_file(path) as partial:
            pq.write_table(table, partial)
        paths.append(path)
        if csv:
            path = out / f"{name}.csv"
            with whole_file(path) as partial:
                pa_csv.write_csv(table, partial)
            paths.append(path)
    return paths


def study_grid(args: argparse.Namespace) -> int:
    """``vibrissa study grid``: the grid file checked whole before anything runs."""
    if args.grid_file is None:
        print("vibrissa study: error: study grid needs GRID.yaml", file=sys.stderr)
        return 2
    try:
        grid = load_grid(args.grid_file, args.step)
    except GridFileError as exc:
        print(f"vibrissa study: error: {exc}", file=sys.stderr)
        return 2
    return run_and_write(grid, args.output, args.workers, args.scheduler, args.csv,
                         not args.no_figures)


def run_and_write(grid: Grid, out: Path, workers: int | None, scheduler: str | None, csv: bool,
                  figure: bool) -> int:
    """Run ``grid`` into ``out`` (resuming from its store) and write the tables and PNG."""
    run = run_grid(grid, CaseStore(out / CASES_FOLDER), workers, scheduler, GridProgress())
    paths = write_tables(out, run, csv)
    summary = run.summary.to_pydict()
    key, unit = (("max_reconstruction_error_m", "m") if "scene" in summary
                 else ("max_reconstruction_error", "L"))
    errors = [e for e in summary[key] if e == e]
    worst = f"{max(errors):.3g} {unit}" if errors else "n/a"
    print(f"study: {grid.name}: {len(grid.cases)} cases ({run.computed} computed, {run.reused} "
          f"from {out / CASES_FOLDER}), {run.equilibria.num_rows} equilibria, "
          f"{run.computed_equilibria} computed in {run.elapsed_s:.1f} s "
          f"({equilibria_per_second(run):.0f}/s), max reconstruction "
          f"error {worst} -> {', '.join(str(p) for p in paths)}", file=sys.stderr)
    if figure:
        from vibrissa.figures.study_grid import write_grid_figure  # matplotlib only when drawing

        path = write_grid_figure(summary, grid.name, out / "grid.png")
        print(f"study: {path}", file=sys.stderr)
    return 0
