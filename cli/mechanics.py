"""``vibrissa sweep``, ``vibrissa reconstruct`` and ``vibrissa study``: Step 1, Step 2, the paper.

All numbers are in the paper's units (eq. 1): lengths in L, forces in EI/L^2, moments in EI/L.
Bad arguments end with exit status 2 and a message naming the argument, like argparse's own.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

from vibrissa import noise_study
from vibrissa.cli import tables
from vibrissa.cli.main import EXIT_USAGE
from vibrissa.formats.csv_text import refuse_overwrite
from vibrissa.formats.scene_file import SceneError
from vibrissa.reconstruct import reconstruct
from vibrissa.status import SweepEnd
from vibrissa.study import PAPER_STEP, PAPER_SURFACE, StudyResult, reconstruction_error
from vibrissa.surfaces import SPEC_LIMITS, Surface, parse_surface
from vibrissa.sweep import CLAMP_TOUCH_L, ProgressCallback, simulate_sweep
from vibrissa.units import RodScale, number_text

EXIT_NO_CONTACT = 3
"""``vibrissa sweep``: the trail never touches the object."""


def _surface(text: str) -> Surface:
    try:
        return parse_surface(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _finite(text: str) -> float:
    try:
        value = number_text(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not finite")
    return value


def _offset(text: str) -> float:
    low, high = SPEC_LIMITS["position"]
    value = _finite(text)
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"must be within [{low:g}, {high:g}], got {text}")
    return value


def _positive(text: str) -> float:
    value = _finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def _non_negative(text: str) -> float:
    value = _finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def _workers(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return value


def _fail(command: str, message: str) -> int:
    print(f"vibrissa {command}: error: {message}", file=sys.stderr)
    return EXIT_USAGE


def register(subparsers: Any) -> None:
    """Add ``sweep``, ``reconstruct`` and ``study`` to the ``vibrissa`` command."""
    p = subparsers.add_parser(
        "sweep", help="Step 1: simulate one frictional sweep, write its support reactions",
        description="Simulate one quasi-static sweep of the clamp along -x at y0 (paper units, "
        "eq. 1) and write one CSV row per equilibrium plus a JSON summary beside it.",
        epilog=f"columns of SWEEP.csv (units of eq. 1: L rod length, EI bending stiffness):\n"
        f"{tables.columns_help(tables.SWEEP_COLUMNS)}\n\n"
        f"exit status: 0 swept, 1 no equilibrium after the first contact, {EXIT_USAGE} bad "
        f"arguments, {EXIT_NO_CONTACT} no contact (the straight rod clears the object all "
        "along the trail).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--surface", type=_surface, default=parse_surface(PAPER_SURFACE),
                   metavar="SPEC", help=f"object, e.g. {PAPER_SURFACE} (the default)")
    p.add_argument("--y0", type=_offset, required=True, metavar="Y",
                   help="trail offset, units of L (within +-1e3, as the object's position)")
    p.add_argument("--mu", type=_non_negative, required=True, help="friction coefficient, >= 0")
    p.add_argument("--step", type=_positive, default=PAPER_STEP, metavar="DX",
                   help=f"clamp step along -x, units of L (default {PAPER_STEP})")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="SWEEP.csv")
    p.set_defaults(func=_sweep)

    p = subparsers.add_parser(
        "reconstruct", help="Step 2: contact points from clamp positions and support reactions",
        description="Read x0, y0 (z0 = 0 unless given) and f0x..m0z from a CSV and write, "
        "row for row, the clamp position and the reconstructed contact point.",
        epilog="columns of RCP.csv (units of eq. 1: L rod length, EI bending stiffness):\n"
        f"{tables.columns_help(('x0', 'y0', 'z0', *tables.RECONSTRUCTION_COLUMNS[2:], 'err'))}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("input", type=Path, metavar="SWEEP.csv")
    p.add_argument("--surface", type=_surface, metavar="SPEC",
                   help="object to measure the error against (adds column err)")
    p.add_argument("--scene", type=Path, metavar="SCENE.yaml",
                   help="read WRENCHES.csv instead (columns t,whisker,f0x..m0z: clamp frames, "
                   "N, N m) and write POINTS.csv (t,whisker,px,py,pz,s1,phase,status: W, m), "
                   "the clamps posed by the scene's path at each t and its whiskers' mounts")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="RCP.csv")
    p.set_defaults(func=_reconstruct)

    p = subparsers.add_parser(
        "study", help="run a study grid, the paper's study (Step 1, Step 2, figures) or the noise study",
        description="grid: the study of GRID.yaml (docs/STUDIES.md): every case's Step 1 and Step 2,\n"
        "on all local cores (--workers) or a Dask cluster (--scheduler); writes\n"
        "DIR/equilibria.parquet, DIR/summary.parquet, DIR/grid.png and the store DIR/cases/ that a\n"
        "rerun on DIR resumes from.\n\n"
        "paper: the 25 sweeps of Sec. III (y0 = -0.4:0.2:0.4, mu = 0:0.1:0.4 past\n"
        f"{PAPER_SURFACE}), their reconstruction and Figs. 6-10: the shipped grid\n"
        "studies/paper.yaml, also written as the grid's tables.\n\n"
        "noise: Step 2's error in mm for a stated rod (--rod-length-m, --rod-ei-nm2), per\n"
        "contact phase (tip, tangential), on the trails y0 = "
        f"{', '.join(map(str, noise_study.NOISE_Y0))} with mu = {noise_study.NOISE_MU}\n"
        "past the same object:\n"
        "  - against wrench noise: Gaussian, std per component = fraction x the peak |f0| (forces)\n"
        "    and x the peak |m0| (moments) of the sweeps, fractions 1e-5..1e-1, "
        f"{noise_study.DRAWS} seeded draws\n"
        "    per sample; predicted: |z|, z ~ N(0, first-order covariance of each point);\n"
        "  - against an error of L or of EI (-5..+5 %, no noise); predicted: first order,\n"
        "    |e| |dP/de| from the Jacobian of Step 2 (zero for L: the elastica from the clamp to\n"
        "    the contact does not involve L; a wrong L only loses contacts past the assumed tip).\n"
        "Error: median and 95th percentile of |reconstructed - true point| over the points found.\n"
        "Writes DIR/noise.csv, DIR/rod_errors.csv, DIR/summary.json, DIR/noise.png and\n"
        "DIR/rod_errors.png.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("study", choices=["grid", "paper", "noise"], help="which study")
    p.add_argument("grid_file", nargs="?", type=Path, metavar="GRID.yaml",
                   help="grid: the study's file")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR")
    p.add_argument("--step", type=_positive, metavar="DX",
                   help=f"clamp step along -x, units of L (default {PAPER_STEP}; grid: replaces "
                   "the file's)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--rod-length-m", type=_positive, metavar="M",
                   help=f"noise study: rod length L, m (default {noise_study.ROD_LENGTH_M})")
    p.add_argument("--rod-ei-nm2", type=_positive, metavar="EI",
                   help="noise study: bending stiffness EI, N m^2 "
                   f"(default {noise_study.ROD_EI_NM2})")
    p.add_argument("--workers", type=_workers, metavar="N",
                   help="grid: local worker processes, or a LocalCluster's workers (default: all "
                   "cores; 1: in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS|local",
                   help="grid: run on the Dask distributed scheduler at ADDRESS "
                   "(tcp://host:8786), or on a LocalCluster started for the run (local)")
    p.add_argument("--csv", action="store_true", help="grid: also write the tables as CSV")
    p.set_defaults(func=_study)


def _sweep(args: argparse.Namespace) -> int:
    if args.output.suffix == ".json":  # the summary goes to OUT.json beside the CSV
        return _fail("sweep", f"-o {args.output}: the summary is written to the CSV's name "
                     "with .json; name the CSV otherwise, e.g. .csv")
    start = time.perf_counter()
    sweep = simulate_sweep(args.surface, args.y0, args.mu, step=args.step)
    output: Path = args.output
    tables.write_sweep_csv(output, sweep)
    tables.write_json(output.with_suffix(".json"), tables.sweep_summary(sweep, args.surface.spec))
    if sweep.end is not SweepEnd.NO_CONTACT:
        print(f"sweep: {sweep.n_steps} equilibria, ended by {sweep.end} at "
              f"x0={sweep.x0_end:.6g}, {len(sweep.phase_changes)} phase changes, "
              f"{time.perf_counter() - start:.1f} s -> {output}", file=sys.stderr)
    if sweep.end is SweepEnd.NO_CONTACT:
        print(f"sweep: no contact: the straight rod on the trail y0={args.y0:g} clears "
              f"{args.surface.spec} all along it; the CSV holds its header only "
              f"(exit {EXIT_NO_CONTACT})", file=sys.stderr)
        return EXIT_NO_CONTACT
    if sweep.end is not SweepEnd.NO_EQUILIBRIUM:
        return 0
    if sweep.s_touch < CLAMP_TOUCH_L:
        print(f"sweep: error: {args.surface.spec} meets the clamp itself (the straight rod "
              "touches it at s = 0): no equilibrium of the rod holds it off; move the object "
              "or the trail", file=sys.stderr)
    else:
        print("sweep: error: no equilibrium found for the first step after the first contact "
              f"(a solver failure); a larger --step, e.g. {2 * args.step:g}, may get past it",
              file=sys.stderr)
    return 1


def _reconstruct(args: argparse.Namespace) -> int:
    if args.scene is not None:
        if args.surface is not None:
            return _fail("reconstruct", "--surface is for SWEEP.csv; a scene has its objects")
        from vibrissa.cli.scenes import run_reconstruct  # scenes only when asked for

        return run_reconstruct(args)
    try:
        refuse_overwrite([args.output], [args.input])
    except SceneError as exc:
        return _fail("reconstruct", str(exc))
    try:
        table = tables.read_wrench_csv(args.input)
    except tables.TableError as exc:
        return _fail("reconstruct", f"argument SWEEP.csv: {exc}")
    rec = reconstruct(table.p0, table.f0, table.m0)
    error = reconstruction_error(args.surface, rec.point) if args.surface is not None else None
    tables.write_reconstruction_csv(args.output, table, rec, error)
    invalid = Counter(tables.status_name(int(s)) for s in rec.status[~rec.valid])
    line = f"reconstruct: {len(rec.status)} rows, {int(rec.valid.sum())} with a contact"
    if invalid:
        line += f", {sum(invalid.values())} without (" + ", ".join(
            f"{name}: {count}" for name, count in sorted(invalid.items())) + ")"
    if error is not None and rec.valid.any():
        line += f"; max err {float(error[rec.valid].max()):.3g} L"
    print(f"{line} -> {args.output}", file=sys.stderr)
    return 0


class _Progress:
    """``sweeps finished k/n, t s`` on stderr; one updating line on a terminal."""

    def __init__(self) -> None:
        self.start = time.perf_counter()
        self.tty = sys.stderr.isatty()

    def __call__(self, done: int, total: int) -> None:
        text = f"study: sweeps finished {done}/{total}, {time.perf_counter() - self.start:.1f} s"
        if self.tty:
            print(f"\r{text}", end="\n" if done == total else "", file=sys.stderr, flush=True)
        else:
            print(text, file=sys.stderr, flush=True)


def sweep_stem(y0: float, mu: float) -> str:
    """File stem of a study sweep, e.g. ``y0_+0.2_mu_0.3``."""
    return f"y0_{y0:+.1f}_mu_{mu:.1f}"


def run_study(step: float, progress: ProgressCallback | None = None) -> StudyResult:
    """The paper's study: the shipped grid ``studies/paper.yaml`` at ``step``, on all cores."""
    from vibrissa.cli.study_grid import run_paper  # pyarrow only for a study

    return run_paper(step, progress)


def _study(args: argparse.Namespace) -> int:
    out: Path = args.output
    if args.study == "grid":
        if args.rod_length_m is not None or args.rod_ei_nm2 is not None:
            return _fail("study", "--rod-length-m and --rod-ei-nm2 are for the noise study; a "
                         "grid's rods are its key rods")
        from vibrissa.cli.study_grid import study_grid

        return study_grid(args)
    grid_only = [flag for flag, given in (("GRID.yaml", args.grid_file is not None),
                                          ("--workers", args.workers is not None),
                                          ("--scheduler", args.scheduler is not None),
                                          ("--csv", args.csv)) if given]
    if grid_only:
        return _fail("study", f"{', '.join(grid_only)}: for study grid")
    args.step = PAPER_STEP if args.step is None else args.step
    if args.study == "noise":
        return _noise_study(args)
    if args.rod_length_m is not None or args.rod_ei_nm2 is not None:
        return _fail("study", "--rod-length-m and --rod-ei-nm2 are for the noise study")
    result = run_study(step=args.step, progress=_Progress())
    write_study(out, result)
    from vibrissa.cli.study_grid import write_paper_tables

    write_paper_tables(out, result)
    worst = "n/a" if result.max_error is None else f"{result.max_error:.3g} L"
    print(f"study: Step 1 + Step 2 in {result.elapsed_s:.1f} s, max reconstruction error "
          f"{worst} -> {out / 'summary.json'}", file=sys.stderr)
    if not args.no_figures:
        from vibrissa.figures import paper  # matplotlib only when drawing

        start = time.perf_counter()
        paths = paper.paper_figures(result, out)
        print(f"study: {len(paths)} figures in {time.perf_counter() - start:.1f} s -> {out}",
              file=sys.stderr)
    return 0


def _noise_study(args: argparse.Namespace) -> int:
    from vibrissa.cli import noise_files
    from vibrissa.figures import noise  # matplotlib only when drawing

    out: Path = args.output
    rod = RodScale(args.rod_length_m or noise_study.ROD_LENGTH_M,
                   args.rod_ei_nm2 or noise_study.ROD_EI_NM2)
    result = noise_study.run_noise_study(rod, step=args.step, progress=_Progress())
    noise_files.write_noise_study(out, result)
    tangential = [row.stats for row in result.noise if row.stats.phase == "tangential"]
    print(f"study: noise: Step 1 + Step 2 in {result.elapsed_s:.1f} s, {len(result.samples)} "
          f"contact samples, rod {noise.rod_label(result)}; tangential median error "
          f"{tangential[0].error_median_mm:.3g} mm at noise {result.noise[0].noise_fraction:g} "
          f"to {tangential[-1].error_median_mm:.3g} mm at {result.noise[-1].noise_fraction:g} "
          f"-> {out / 'summary.json'}", file=sys.stderr)
    if not args.no_figures:
        start = time.perf_counter()
        paths = noise.noise_figures(result, out)
        print(f"study: {len(paths)} figures in {time.perf_counter() - start:.1f} s -> {out}",
              file=sys.stderr)
    return 0


def write_study(out: Path, result: StudyResult) -> None:
    """``summary.json`` and ``sweeps/<stem>.csv`` (+ ``.json``) for every sweep of ``result``."""
    spec = result.surface.spec
    entries = []
    for case in result.cases:
        csv_path = out / "sweeps" / f"{sweep_stem(case.y0, case.mu)}.csv"
        tables.write_sweep_csv(csv_path, case.sweep)
        tables.write_json(csv_path.with_suffix(".json"), tables.sweep_summary(case.sweep, spec))
        entries.append({**case.summary(), "csv": str(csv_path.relative_to(out))})
    tables.write_json(out / "summary.json", {
        "study": "paper",
        "surface": spec,
        "step": result.step,
        "y0": result.y0_values,
        "mu": result.mu_values,
        "elapsed_s": result.elapsed_s,
        "max_reconstruction_error": result.max_error,
        "units": tables.UNITS,
        "sweeps": entries,
    })
