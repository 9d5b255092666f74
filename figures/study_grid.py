"""The main outcome of a study grid (matplotlib, Agg): per case, the peak clamp force against
friction, marked by how the sweep ended, and the largest reconstruction error of Step 2."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
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
    case_error = [(int(c), float(e)) for c, e in zip(summary["case"], summary["max_reconstruction_error"],
                                                     strict=True) if not math.isnan(e) and e > 0]
    if case_error:
        errors.scatter(*zip(*case_error, strict=True), s=8,
                       c=[colour[str(summary["surface_m"][c])] for c, _e in case_error])
        errors.set_yscale("log")
    errors.set_xlabel("case")
    errors.set_ylabel("max reconstruction error (L)")
    for surface in surfaces[:10]:
        errors.plot([], [], "o", color=colour[surface], label=surface)
    errors.legend(fontsize="x-small", title="object (m)")
    figure.suptitle(f"study {title}: {len(ends)} cases")
    return figure


def write_grid_figure(summary: Mapping[str, Sequence[Any]], title: str, path: Path) -> Path:
    """`grid_figure` as PNG at ``path``."""
    figure = grid_figure(summary, title)
    figure.savefig(path, dpi=DPI)
    plt.close(figure)
    return path
