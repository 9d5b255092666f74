"""map.png of an exploration: its coverage against the path length beside the legend, a point
per map; a map that is not an exploration's keeps the figure it had (no plot)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from tests.figures.test_map_figure import rock_layers
from vibrissa.figures.map_figure import MM, draw_map, plot_map

HISTORY = ((0.0, 0.0), (0.12, 0.25), (0.31, 0.4), (0.5, 0.38))  # m, share


def test_an_exploration_plots_its_coverage_against_the_path_length(tmp_path: Path) -> None:
    figure = draw_map(dataclasses.replace(rock_layers(), coverage=HISTORY))
    [plot] = [ax for ax in figure.axes if ax.get_title().startswith("coverage")]
    [line] = plot.get_lines()
    x, y = (np.asarray(a, dtype=np.float64) for a in line.get_data())
    np.testing.assert_allclose(x, [h[0] * MM for h in HISTORY])
    np.testing.assert_allclose(y, [h[1] * 100.0 for h in HISTORY])
    assert plot.get_ylim() == (0.0, 100.0)
    assert plot.get_title() == "coverage of the true surface in reach, final 38.0%"
    plot_map(tmp_path / "map.png", dataclasses.replace(rock_layers(), coverage=HISTORY))
    assert (tmp_path / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_map_that_is_no_exploration_has_no_coverage_plot() -> None:
    layers = rock_layers()
    assert layers.coverage is None
    figure = draw_map(layers)
    assert len(figure.axes) == 4  # 3D view, colour bar, top view, legend
    assert not [ax for ax in figure.axes if ax.get_title().startswith("coverage")]
    with_plot = draw_map(dataclasses.replace(layers, coverage=HISTORY))
    assert len(with_plot.axes) == len(figure.axes) + 1
