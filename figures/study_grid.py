"""The main outcome of a study grid (matplotlib, Agg): per case, the peak clamp force against
friction, marked by how the sweep ended (a grid of scenes: by its rods), and the largest
reconstruction error of Step 2."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from vibrissa.status import SweepEnd  # noqa: E402

DPI = 130
_MARKERS = {str(SweepEnd.DETACHMENT): "o", str(SweepEnd.SNAP_OFF): "x",
            str(SweepEnd.NO_CONTACT): ".", str(SweepEnd.NO_EQUILIBRIUM): "^"}


def grid_figure(summary: Mapping[str, Sequence[Any]], title: str) -> Figure:
    """Two panels from the summary table's columns (``case``, ``surface_m``, ``mu``, ``end``,
    ``peak_f0_n``, ``max_reconstruction_error``): peak |f0| (N) against mu, one colour per
    surface and one marker per ending; the largest reconstruction error (L, log scale) per case.
    """
    figure, (forces, errors) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    surfaces = list(dict.fromkeys(str(s) for s in summary["surface_m"]))
    colour = {s: f"C{i % 10}" for i, s in enumerate(surfaces)}
    ends = [str(e) for e in summary["end"]]
    for end in dict.fromkeys(ends):
        rows = [i for i, e in enumerate(ends) if e == end]
        forces.scatter([summary["mu"][i] for i in rows], [summary["peak_f0_n"][i] for i in rows],
                       c=[colour[str(summary["surface_m"][i])] for i in rows],
                       marker=_MARKERS.get(end, "s"), label=end)
    forces.set_xlabel("friction coefficient mu")
    forces.set_ylabel("peak |f0| (N)")
    forces.legend(title="sweep ended by", fontsize="small")
    _error_panel(errors, summary, "max_reconstruction_error", "surface_m", colour,
                 "max reconstruction error (L)", "object (m)")
    figure.suptitle(f"study {title}: {len(ends)} cases")
    return figure


def scene_grid_figure(summary: Mapping[str, Sequence[Any]], title: str) -> Figure:
    """Two panels from a grid of scenes' summary (``case``, ``scene``, ``mu``, ``length_m``,
    ``ei_nm2``, ``peak_f0_n``, ``max_reconstruction_error_m``): peak |f0| of any whisker (N)
    against mu, one colour per scene and one marker per rod; the largest distance of Step 2's
    point to the true contact (m, log scale) per case."""
    figure, (forces, errors) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    scenes = list(dict.fromkeys(str(s) for s in summary["scene"]))
    colour = {s: f"C{i % 10}" for i, s in enumerate(scenes)}
    rods = [("the scene's rods" if math.isnan(length) else f"L {length * 1e3:.4g} mm, EI {ei:.3g} N m^2")
            for length, ei in zip(summary["length_m"], summary["ei_nm2"], strict=True)]
    for k, rod in enumerate(dict.fromkeys(rods)):
        rows = [i for i, r in enumerate(rods) if r == rod]
        forces.scatter([summary["mu"][i] for i in rows], [summary["peak_f0_n"][i] for i in rows],
                       c=[colour[str(summary["scene"][i])] for i in rows],
                       marker="oxs^vD"[k % 6], label=rod)
    forces.set_xlabel("friction coefficient mu")
    forces.set_ylabel("peak |f0| of any whisker (N)")
    forces.legend(title="rods", fontsize="small")
    _error_panel(errors, summary, "max_reconstruction_error_m", "scene", colour,
                 "max distance to the true contact (m)", "scene")
    figure.suptitle(f"study {title}: {len(rods)} cases")
    return figure


def _error_panel(errors: Axes, summary: Mapping[str, Sequence[Any]], key: str, group: str,
                 colour: Mapping[str, str], ylabel: str, legend_title: str) -> None:
    """Each case's ``key`` (log scale, positive ones) coloured by its ``group`` column."""
    case_error = [(int(c), float(e)) for c, e in zip(summary["case"], summary[key], strict=True)
                  if not math.isnan(e) and e > 0]
    if case_error:
        errors.scatter([c for c, _e in case_error], [e for _c, e in case_error], s=8,
                       c=[colour[str(summary[group][c])] for c, _e in case_error])
        errors.set_yscale("log")
    errors.set_xlabel("case")
    errors.set_ylabel(ylabel)
    for name in list(colour)[:10]:
        errors.plot([], [], "o", color=colour[name], label=name)
    errors.legend(fontsize="x-small", title=legend_title)


def write_grid_figure(summary: Mapping[str, Sequence[Any]], title: str, path: Path) -> Path:
    """`grid_figure` (`scene_grid_figure` for a grid of scenes) as PNG at ``path``."""
    figure = (scene_grid_figure if "scene" in summary else grid_figure)(summary, title)
    figure.savefig(path, dpi=DPI)
    plt.close(figure)
    return path
