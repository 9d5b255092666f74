"""The noise study's tables from a :class:`vibrissa.noise_study.NoiseStudyResult` (its figures:
`vibrissa.figures.noise`).

``noise.csv`` and ``rod_errors.csv`` are tidy: one row per setting and contact phase, units in
the column names (mm, N, N m); ``summary.json`` says how they were made.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vibrissa.cli import tables
from vibrissa.formats.csv_text import cell, write_csv
from vibrissa.noise_study import ErrorStats, NoiseStudyResult

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


def _stats_cells(stats: ErrorStats) -> list[str]:
    return [stats.phase, str(stats.samples), cell(stats.points_fraction),
            cell(stats.error_median_mm), cell(stats.error_p95_mm),
            cell(stats.predicted_median_mm), cell(stats.predicted_p95_mm)]


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
