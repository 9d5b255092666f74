"""Figures 6-10 of the paper from a :class:`vibrissa.study.StudyResult` (matplotlib, Agg).

All axes are in the paper's dimensionless units (eq. 1): lengths in L, forces in EI/L^2,
moments in EI/L. The sweeps run along -x, so the x0 axes of Figs. 7 and 8 read right to left.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import colors  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Line3DCollection  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from vibrissa.status import ContactPhase  # noqa: E402
from vibrissa.study import StudyCase, StudyResult  # noqa: E402
from vibrissa.surfaces import Surface  # noqa: E402
from vibrissa.sweep import STICK  # noqa: E402

FloatArray = NDArray[np.float64]

FIG6_CASES = ((0.0, 0.0), (0.0, 0.4), (0.2, 0.0), (0.2, 0.4))
TIP_COLOR, TANGENTIAL_COLOR, FREE_COLOR = "tab:blue", "tab:red", "black"
DPI = 130
_REACTIONS = (
    ("f0", 0, r"$f_{0x}$"), ("f0", 1, r"$f_{0y}$"), ("f0", 2, r"$f_{0z}$"),
    ("m0", 0, r"$m_{0x}$"), ("m0", 1, r"$m_{0y}$"), ("m0", 2, r"$m_{0z}$"),
)


def paper_figures(result: StudyResult, out: Path) -> list[Path]:
    """Write Figs. 6-10 as PNG into ``out``; returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    jobs = [
        ("fig6_elastic_lines.png", lambda: fig6_elastic_lines(result)),
        ("fig7_reactions_y0_0.0.png", lambda: fig_reactions(result, 0.0, "Fig. 7")),
        ("fig8_reactions_y0_0.2.png", lambda: fig_reactions(result, 0.2, "Fig. 8")),
        ("fig9_reconstruction.png", lambda: fig9_reconstruction(result)),
        ("fig10_reconstruction_error.png", lambda: fig10_reconstruction_error(result)),
    ]
    paths = []
    for name, draw in jobs:
        figure = draw()
        path = out / name
        figure.savefig(path, dpi=DPI)
        plt.close(figure)
        paths.append(path)
    return paths


def mu_colors(mu_values: Sequence[float]) -> dict[float, tuple[float, float, float, float]]:
    """Friction coefficient -> colour, dark blue (mu = 0) to yellow (largest), as in the paper."""
    cmap = plt.get_cmap("viridis")
    top = max(max(mu_values), 1e-12)
    return {mu: cmap(0.95 * mu / top) for mu in mu_values}


def surface_mesh(
    surface: Surface, x: FloatArray, y: FloatArray, z_max: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Lower side z(x, y) of the object on a grid (where the rod touches); NaN above z_max."""
    gx, gy = np.meshgrid(x, y)
    starts = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    lo, _hi = surface.line_interval(starts, np.tile([0.0, 0.0, 1.0], (gx.size, 1)))
    gz = lo.reshape(gx.shape)
    gz = np.where(np.isfinite(gz) & (gz <= z_max), gz, np.nan)
    return gx, gy, gz


def _draw_surface(
    ax: Axes, surface: Surface, extent: float, z_max: float, alpha: float = 0.25
) -> None:
    grid = np.linspace(-extent, extent, 41)
    gx, gy, gz = surface_mesh(surface, grid, grid, z_max)
    ax.plot_surface(gx, gy, gz, color="0.6", alpha=alpha, linewidth=0.2, edgecolor="0.5",  # type: ignore[attr-defined]
                    rstride=2, cstride=2, shade=False)


def _set_3d_labels(ax: Axes) -> None:
    ax.set_xlabel("x [L]")
    ax.set_ylabel("y [L]")
    ax.set_zlabel("z [L]")  # type: ignore[attr-defined]


def _elastic_segments(
    case: StudyCase, every: int, n_points: int = 61
) -> dict[str, list[FloatArray]]:
    """Polylines of every ``every``-th rod shape, split by colour role (tip/tangential/free)."""
    sweep = case.sweep
    s = np.linspace(0.0, 1.0, n_points)
    segments: dict[str, list[FloatArray]] = {"tip": [], "tangential": [], "free": []}
    for i in range(0, sweep.n_steps, every):
        line = sweep.elastic_line(i, n_points)
        if sweep.phase[i] == ContactPhase.TANGENTIAL:
            k = int(np.searchsorted(s, sweep.s1[i]))
            segments["tangential"].append(line[: k + 1])
            segments["free"].append(line[k:])
        else:
            segments["tip"].append(line)
    return segments


def fig6_elastic_lines(result: StudyResult, every: int = 10) -> Figure:
    """Fig. 6: rod shapes along four sweeps, tip contact blue, tangential red / black past s1."""
    figure = plt.figure(figsize=(12, 10), layout="constrained")
    colors_by_role = {"tip": TIP_COLOR, "tangential": TANGENTIAL_COLOR, "free": FREE_COLOR}
    for n, (y0, mu) in enumerate(FIG6_CASES):
        ax = figure.add_subplot(2, 2, n + 1, projection="3d")
        try:
            case = result.case(y0, mu)
        except KeyError:
            ax.set_title(f"y0 = {y0:g}, mu = {mu:g}: not in this study")
            continue
        _draw_surface(ax, result.surface, 1.0, 1.05, alpha=0.15)
        for role, lines in _elastic_segments(case, every).items():
            if lines:
                ax.add_collection3d(Line3DCollection(lines, colors=colors_by_role[role],  # type: ignore[attr-defined]
                                                     linewidths=0.35))
        ax.plot(case.sweep.x0, np.full(case.sweep.n_steps, y0), 0.0, color="0.3", lw=1.0)
        ax.set(xlim=(-1.6, 1.2), ylim=(-1.0, 1.0))
        ax.set_zlim(0.0, 1.05)  # type: ignore[attr-defined]
        ax.view_init(elev=18, azim=-40)  # type: ignore[attr-defined]
        _set_3d_labels(ax)
        sweep = case.sweep
        ax.set_title(f"({'abcd'[n]}) $y_0$ = {y0:g}, $\\mu$ = {mu:g}: {sweep.n_steps} states, "
                     f"ends by {sweep.end} at $x_0$ = {sweep.x0_end:.3f}", fontsize=10)
    handles = [
        Line2D([], [], color=TIP_COLOR, label="tip contact"),
        Line2D([], [], color=TANGENTIAL_COLOR, label="tangential contact, $s < s_1$"),
        Line2D([], [], color=FREE_COLOR, label="tangential contact, $s > s_1$"),
        Line2D([], [], color="0.3", label="clamp trail $P_0$"),
    ]
    figure.legend(handles=handles, loc="outside lower center", ncol=4)
    figure.suptitle(f"Fig. 6: sweeps along $-x$, every {every}th equilibrium "
                    f"(step {result.step:g} L), object {result.surface.spec}")
    return figure


def fig_reactions(result: StudyResult, y0: float, label: str) -> Figure:
    """Figs. 7/8: the six support reactions against x0 per mu at trail ``y0``, 'o' phase changes."""
    figure, axes = plt.subplots(2, 3, figsize=(14, 7.5), sharex=True, layout="constrained")
    palette = mu_colors(result.mu_values)
    for mu in result.mu_values:
        try:
            sweep = result.case(y0, mu).sweep
        except KeyError:
            continue
        changes = np.flatnonzero(np.diff(sweep.phase) != 0) + 1
        stuck = np.flatnonzero(sweep.state == STICK)
        for ax, (name, j, _title) in zip(axes.ravel(), _REACTIONS, strict=True):
            values = getattr(sweep, name)[:, j]
            ax.plot(sweep.x0, values, color=palette[mu], lw=1.2, label=f"$\\mu$ = {mu:g}")
            ax.plot(sweep.x0[changes], values[changes], "o", mfc="none", color=palette[mu], ms=6)
            ax.plot(sweep.x0[stuck], values[stuck], "x", color=palette[mu], ms=4)
    for ax, (name, _j, title) in zip(axes.ravel(), _REACTIONS, strict=True):
        unit = "EI/L$^2$" if name == "f0" else "EI/L"
        ax.set_ylabel(f"{title} [{unit}]")
        ax.grid(True, lw=0.3)
        ax.axhline(0.0, color="0.5", lw=0.5)
    for ax in axes[1]:
        ax.set_xlabel("clamp position $x_0$ [L]   (sweep runs right to left)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    handles.append(Line2D([], [], ls="none", marker="o", mfc="none", color="k"))
    labels.append("phase change tip/tangential")
    handles.append(Line2D([], [], ls="none", marker="x", color="k"))
    labels.append("sticking contact (not in the paper)")
    figure.legend(handles, labels, loc="outside right center")
    figure.suptitle(f"{label}: support reactions at the clamp, $y_0$ = {y0:g} "
                    "(reaction of the clamp on the rod, dimensionless per eq. 1)")
    return figure


def _rcp_axes(figure: Figure) -> tuple[Axes, Axes]:
    iso = figure.add_subplot(1, 2, 1, projection="3d")
    top = figure.add_subplot(1, 2, 2)
    return iso, top


def _finish_rcp_axes(result: StudyResult, iso: Axes, top: Axes) -> None:
    iso.view_init(elev=25, azim=-60)  # type: ignore[attr-defined]
    _set_3d_labels(iso)
    iso.set(xlim=(-1.2, 1.2), ylim=(-1.0, 1.0))
    iso.set_zlim(0.3, 1.05)  # type: ignore[attr-defined]
    top.set_aspect("equal")
    top.set_xlabel("x [L]")
    top.set_ylabel("y [L]")
    top.grid(True, lw=0.3)
    for y0 in result.y0_values:
        top.axhline(y0, color="0.6", lw=0.6, ls="--")
        top.annotate(f"trail $y_0$ = {y0:+g}", (1.25, y0), fontsize=8, color="0.4", va="bottom")
    top.set_xlim(-1.3, 1.7)


def fig9_reconstruction(result: StudyResult) -> Figure:
    """Fig. 9: reconstructed contact points over the object (iso view) and from the top, by mu."""
    figure = plt.figure(figsize=(14, 6.5), layout="constrained")
    iso, top = _rcp_axes(figure)
    _draw_surface(iso, result.surface, 1.1, 1.05)
    palette = mu_colors(result.mu_values)
    for case in result.cases:
        point = case.reconstruction.point
        label = f"$\\mu$ = {case.mu:g}" if case.y0 == result.y0_values[0] else None
        iso.plot(point[:, 0], point[:, 1], point[:, 2], color=palette[case.mu], lw=1.2, label=label)
        top.plot(point[:, 0], point[:, 1], color=palette[case.mu], lw=1.0)
    iso.legend(loc="upper left", title="reconstructed contacts")
    _finish_rcp_axes(result, iso, top)
    iso.set_title("(a) object surface and reconstructed contact points")
    top.set_title("(b) top view (object hidden); dashed: clamp trails")
    figure.suptitle("Fig. 9: Step 2 contact points from the support reactions of "
                    f"{len(result.cases)} sweeps (every equilibrium)")
    return figure


def fig10_reconstruction_error(result: StudyResult) -> Figure:
    """Fig. 10: reconstructed contact points coloured by their distance to the object."""
    figure = plt.figure(figsize=(14, 6.5), layout="constrained")
    iso, top = _rcp_axes(figure)
    points = np.concatenate([case.reconstruction.point for case in result.cases])
    error = np.concatenate([case.error for case in result.cases])
    keep = np.isfinite(error)
    points, error = points[keep], error[keep]
    floor = 1e-17  # exact zeros would vanish on a log scale
    shown = np.maximum(error, floor)
    low = max(float(shown.min()), floor)
    norm = colors.LogNorm(vmin=low, vmax=max(float(shown.max()), 10 * low))
    order = np.argsort(shown)  # largest errors drawn last, on top
    kwargs = {"c": shown[order], "cmap": "plasma", "norm": norm, "s": 2, "linewidths": 0}
    iso.scatter(points[order, 0], points[order, 1], points[order, 2], **kwargs)
    mappable = top.scatter(points[order, 0], points[order, 1], **kwargs)
    _finish_rcp_axes(result, iso, top)
    figure.colorbar(mappable, ax=[iso, top], label="reconstruction error |distance to C| [L]",
                    shrink=0.8)
    worst = float(error.max()) if error.size else float("nan")
    iso.set_title("(a) isometric view")
    top.set_title("(b) top view")
    figure.suptitle(f"Fig. 10: reconstruction error of {error.size} contact points "
                    f"(max {worst:.2g} L), all sweeps and friction coefficients")
    return figure
