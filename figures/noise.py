"""The noise study's figures from a :class:`vibrissa.noise_study.NoiseStudyResult` (matplotlib,
Agg, imported only when drawing).

``noise.png``: error against wrench noise, log-log, measured median and 95th percentile beside
the predicted ones (first-order covariance). ``rod_errors.png``: error against a relative error
of L or EI, measured beside the first-order prediction.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vibrissa.noise_study import ErrorStats, NoiseStudyResult

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

DPI = 130
PHASE_COLOR = {"tip": "tab:blue", "tangential": "tab:red"}


def rod_label(result: NoiseStudyResult) -> str:
    """``L = 50 mm, EI = 2e-05 N m^2``."""
    return f"L = {result.rod.length_m * 1e3:g} mm, EI = {result.rod.ei_nm2:g} N m^2"


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
