"""The noise study's tables and figures from a :class:`vibrissa.noise_study.NoiseStudyResult`.

``noise.csv`` and ``rod_errors.csv`` are tidy: one row per setting and contact phase, units in
the column names (mm, N, N m). ``noise.png``: error against wrench noise, log-log, measured
median and 95th percentile beside the predicted ones (first-order covariance). ``rod_errors.png``:
error against a relative error of L or EI, measured beside the first-order prediction. matplotlib
(Agg) is imported only when drawing.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vibrissa.cli import tables
from vibrissa.formats.csv_text import cell, write_csv
from vibrissa.noise_study import ErrorStats, NoiseStudyResult

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

STATS_COLUMNS = ("phase", "samples", "points_fraction", "error_median_mm", "error_p95_mm",
                 "predicted_median_mm", "predicted_p95_mm")
NOISE_COLUMNS = ("noise_fraction", "sigma_force_n", "sigma_moment_nm", *STATS_COLUMNS)
ROD_ERROR_COLUMNS = ("parameter", "relative_error", *STATS_COLUMNS)
NOISE_DEFINITION = (
    "Gaussian wrench noise, independent per component: std of each force component = "
    "noise_fraction x peak |f0| (N), of each moment component = noise_fraction x peak |m0| "
    "(N m), peaks over all contact samples of the study")
PREDICTION = {
    "noise": "median and 95th percentile of |z|, z ~ N(0, covariance_m2) drawn once per valid "
             "point (first-order covariance from reconstruct_si with wrench_cov = diag(sigma^2))",
    "rod_errors": "|e| |dP/de| at the true wrench, first order, from the closed-form Jacobian "
                  "of Step 2 (vibrissa.uncertainty.point_jacobian)",
}
DPI = 130
PHASE_COLOR = {"tip": "tab:blue", "tangential": "tab:red"}


def _stats_cells(stats: ErrorStats) -> list[str]:
    return [stats.phase, str(stats.samples), cell(stats.points_fraction),
            cell(stats.error_median_mm), cell(stats.error_p95_mm),
            cell(stats.predicted_median_mm), cell(stats.predicted_p95_mm)]


def rod_label(result: NoiseStudyResult) -> str:
    """``L = 50 mm, EI = 2e-05 N m^2``."""
    return f"L = {result.rod.length_m * 1e3:g} mm, EI = {result.rod.ei_nm2:g} N m^2"


def write_noise_study(out: Path, result: NoiseStudyResult) -> list[Path]:
    """``noise.csv``, ``rod_errors.csv`` and ``summary.json`` into ``out``; returns the paths."""
    noise_path, rod_path, summary_path = (out / name for name in
                                          ("noise.csv", "rod_errors.csv", "summary.json"))
    write_csv(noise_path, NOISE_COLUMNS, (
        [cell(row.noise_fraction), cell(row.sigma_force_n), cell(row.sigma_moment_nm),
         *_stats_cells(row.stats)] for row in result.noise))
    write_csv(rod_path, ROD_ERROR_COLUMNS, (
        [row.parameter, cell(row.relative_error), *_stats_cells(row.stats)]
        for row in result.rod_errors))
    samples = result.samples
    tables.write_json(summary_path, {
        "study": "noise",
        "surface": result.surface.spec,
        "rod": {"length_m": result.rod.length_m, "ei_nm2": result.rod.ei_nm2},
        "trails": [{"y0": sweep.y0, "mu": float(sweep.trail.mu), "n_steps": sweep.n_steps,
                    "end": sweep.end} for sweep in result.sweeps],
        "step": result.step,
        "contact_samples": {"tip": int(np.sum(samples.phase == 1)),
                            "tangential": int(np.sum(samples.phase == 2))},
        "peak_force_n": samples.peak_force_n,
        "peak_moment_nm": samples.peak_moment_nm,
        "noise": NOISE_DEFINITION,
        "draws": result.draws,
        "seed": result.seed,
        "error": "|p_reconstructed - p_true| (3D, mm) over the valid points of Step 1's phase; "
                 "points_fraction = valid points / samples (draws included)",
        "predicted": PREDICTION,
        "elapsed_s": result.elapsed_s,
        "files": ["noise.csv", "rod_errors.csv"],
    })
    return [noise_path, rod_path, summary_path]


def noise_figures(result: NoiseStudyResult, out: Path) -> list[Path]:
    """``noise.png`` and ``rod_errors.png`` into ``out``; returns the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, figure in (("noise.png", fig_noise(result)), ("rod_errors.png", fig_rod(result))):
        path = out / name
        figure.savefig(path, dpi=DPI)
        plt.close(figure)
        paths.append(path)
    return paths


def _series(rows: list[tuple[float, ErrorStats]], phase: str, field: str
            ) -> tuple[np.ndarray, np.ndarray]:
    chosen = [(x, getattr(s, field)) for x, s in rows if s.phase == phase]
    return np.array([x for x, _ in chosen]), np.array([y for _, y in chosen], dtype=float)


def _draw_errors(ax: Axes, rows: list[tuple[float, ErrorStats]], phase: str,
                 prediction: bool = True) -> None:
    color = PHASE_COLOR[phase]
    for field, style, label in (("error_median_mm", "-o", "measured median"),
                                ("error_p95_mm", "-s", "measured 95th pct"),
                                ("predicted_median_mm", "--", "predicted median"),
                                ("predicted_p95_mm", ":", "predicted 95th pct")):
        if field.startswith("predicted") and not prediction:
            continue
        x, y = _series(rows, phase, field)
        ax.plot(x, y, style, color=color, ms=4, lw=1.3 if style.startswith("-") else 1.8,
                mfc="none" if "s" in style else color, label=label)
    ax.grid(True, which="both", lw=0.3)


def _draw_points(ax: Axes, rows: list[tuple[float, ErrorStats]]) -> None:
    for phase, color in PHASE_COLOR.items():
        x, y = _series(rows, phase, "points_fraction")
        ax.plot(x, y, "-o", color=color, ms=3, label=f"{phase} contact")
    ax.set_ylim(-0.03, 1.03)
    ax.set_ylabel("points found / contact samples")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=8)


def fig_noise(result: NoiseStudyResult) -> Figure:
    """Error (mm) against wrench noise, tip and tangential, measured beside predicted."""
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 3, figsize=(15, 5), layout="constrained",
                                width_ratios=(1, 1, 0.7))
    rows = [(row.noise_fraction, row.stats) for row in result.noise]
    for ax, phase in zip(axes[:2], PHASE_COLOR, strict=True):
        _draw_errors(ax, rows, phase)
        ax.set(xscale="log", yscale="log", xlabel="wrench noise std / peak wrench of the sweeps",
               ylabel="|reconstructed - true contact| [mm]", title=f"{phase} contact")
        ax.legend(fontsize=8)
    _draw_points(axes[2], rows)
    axes[2].set(xscale="log", xlabel="wrench noise std / peak wrench",
                title="contacts that give a point")
    samples = result.samples
    figure.suptitle(
        f"Step 2 error against wrench noise: rod {rod_label(result)}; peak |f0| = "
        f"{samples.peak_force_n:.3g} N, peak |m0| = {samples.peak_moment_nm:.3g} N m; "
        f"noise std per component = fraction x peak; {result.draws} draws per sample\n"
        f"predicted: |z|, z ~ N(0, first-order covariance of the point); "
        f"{len(result.sweeps)} sweeps past {result.surface.spec}", fontsize=10)
    return figure


def fig_rod(result: NoiseStudyResult) -> Figure:
    """Error (mm) against a relative error of L and of EI, measured beside first order (one
    error scale for both: a wrong L moves points by round-off only)."""
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(2, 2, figsize=(12, 8), layout="constrained", sharex=True,
                                sharey="row", height_ratios=(2, 1))
    for column, parameter in enumerate(("L", "EI")):
        rows = [(100.0 * row.relative_error, row.stats) for row in result.rod_errors
                if row.parameter == parameter]
        ax = axes[0, column]
        for phase in PHASE_COLOR:
            _draw_errors(ax, rows, phase)
        handles, labels = ax.get_legend_handles_labels()
        labels = [f"{phase}: {label}" for phase in PHASE_COLOR for label in labels[:4]]
        ax.legend(handles, labels, fontsize=7, ncol=2)
        ax.set(ylabel="|reconstructed - true contact| [mm]",
               title=f"Step 2 told {parameter} x (1 + e), no noise")
        _draw_points(axes[1, column], rows)
        axes[1, column].set_xlabel(f"relative error e of {parameter} [%]")
    axes[0, 0].annotate("a wrong L moves no point (the elastica from the clamp to the contact "
                        "does not involve L);\nit moves the tip: contacts past the assumed tip "
                        "are lost", (0.02, 0.97), xycoords="axes fraction", va="top", fontsize=8)
    figure.suptitle(f"Step 2 error against errors in L and EI: rod {rod_label(result)}; "
                    "predicted: first order, |e| |dP/de| from the Jacobian of Step 2",
                    fontsize=10)
    return figure
