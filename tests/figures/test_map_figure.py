"""The map's figure (map.png) as drawn: the meshes shaded by vertex and interpolated, one colour
maximum in the header and the colour bar, the objects' names off the data in the top view, the
robot's path and mounts in the 3D view of any scene, the contacts over the meshes."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.collections import TriMesh
from matplotlib.text import Annotation
from mpl_toolkits.mplot3d.art3d import Line3D, Path3DCollection, Poly3DCollection

from tests.mapping.test_mapper_objects import accumulate, messages, write_scene
from vibrissa.figures.map_figure import (
    MM,
    SUBDIVISIONS,
    MapLayers,
    MeshLayer,
    colour_scale,
    draw_map,
    map_layers,
    plot_map,
    subdivided,
)
from vibrissa.frames import Transform
from vibrissa.mapping import TrueObject, fit_frame
from vibrissa.nodes.mapper import MapperParams
from vibrissa.scene import Whisker, robot_path
from vibrissa.surfaces import parse_surface

ROCK_CENTRE = np.array([0.0, -0.045, 0.02])  # a user's scene: one 12 mm sphere beside a path
ROCK_RADIUS = 0.012
RIGHT = [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]  # +90 deg about x: the rods point along -y


def rock_layers() -> MapLayers:
    """A one-object map of a scene as a user writes one: a straight path 120 mm long, 45 mm
    from a 12 mm sphere (further than a quarter of its size), two whiskers, contact lines on
    the sphere's side facing the path, and its known mesh: a band of that side."""
    theta = np.linspace(0.6, 2.2, 12)
    phi = np.linspace(np.pi / 4, 3 * np.pi / 4, 16)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit = np.stack([np.cos(p) * np.sin(t), np.sin(p) * np.sin(t), np.cos(t)], axis=-1)
    vertices = ROCK_CENTRE + ROCK_RADIUS * unit.reshape(-1, 3) * np.array([1.0, -1.0, 1.0])
    cols = len(phi)
    quads = [(i * cols + j, i * cols + j + 1, (i + 1) * cols + j, (i + 1) * cols + j + 1)
             for i in range(len(theta) - 1) for j in range(cols - 1)]
    triangles = np.array([tri for a, b, c, d in quads for tri in ((a, b, c), (b, d, c))])
    values = 1e-5 * (1.0 + np.cos(5.0 * np.arange(len(vertices))))  # vertex to vertex: noisy
    points = vertices[::3]
    ids = ["left" if k % 2 else "right" for k in range(len(points))]
    rock = TrueObject("rock", parse_surface(
        f"sphere:r={ROCK_RADIUS},cx={ROCK_CENTRE[0]},cy={ROCK_CENTRE[1]},cz={ROCK_CENTRE[2]}"))
    samples = 50
    path = robot_path(np.linspace(0.0, 2.0, samples),
                      np.column_stack([np.linspace(-0.06, 0.06, samples), np.zeros((samples, 2))]),
                      np.tile([0.0, 0.0, 0.0, 1.0], (samples, 1)))
    whiskers = [Whisker("left", 0.06, 2.3e-4, Transform.from_quaternion(RIGHT, [0.0, -0.01, 0.015])),
                Whisker("right", 0.05, 2.3e-4,
                        Transform.from_quaternion(RIGHT, [-0.01, -0.01, 0.025]))]
    return MapLayers(title="world map: 1 object", points=points, whisker_ids=ids,
                     labels=np.zeros(len(points), dtype=np.int64),
                     meshes=[MeshLayer("rock", vertices, triangles, values, np.zeros((0, 3)),
                                       np.zeros((0, 3), dtype=np.int64), 1e-5)],
                     colour_by="distance to the true surface", true_objects=[rock], path=path,
                     whiskers=whiskers)


def axes_of(figure: Any) -> tuple[Any, Any]:
    """The 3D view and the top view."""
    [view] = [ax for ax in figure.axes if ax.name == "3d"]
    [top] = [ax for ax in figure.axes if ax.get_title().startswith("top view")]
    return view, top


def test_a_users_scene_shows_its_path_and_mounts_in_the_3d_view() -> None:
    layers = rock_layers()
    assert layers.path is not None
    view, _ = axes_of(draw_map(layers))
    lines = [line for line in view.get_lines() if isinstance(line, Line3D)]
    black = [line for line in lines if line.get_color() == "k"]
    assert len(black) == 1
    x, y, z = black[0].get_data_3d()
    shown = np.isfinite(np.asarray(x, dtype=np.float64))
    # the path is in view where the rods could touch the sphere: all of this short one
    assert shown.all() and np.ptp(np.asarray(x)[shown]) > 0.9 * 120.0
    mounts = [line for line in lines if line.get_color() != "k"]
    assert len(mounts) == 3 * len(layers.whiskers)  # at the start, the middle and the end
    lo, hi = view.get_xlim(), view.get_ylim()
    for line in mounts:
        mx, my, _ = (np.asarray(a, dtype=np.float64) for a in line.get_data_3d())
        assert np.all((lo[0] <= mx) & (mx <= lo[1]) & (hi[0] <= my) & (my <= hi[1]))


def test_the_contacts_are_drawn_over_the_meshes() -> None:
    view, _ = axes_of(draw_map(rock_layers()))
    assert view.computed_zorder is False  # matplotlib's depth sort put the mesh on top
    meshes = [c for c in view.collections if isinstance(c, Poly3DCollection)]
    points = [c for c in view.collections if isinstance(c, Path3DCollection)]
    contacts = [c for c in points if len(c.get_offsets()) > 10]
    assert meshes and contacts
    assert min(c.get_zorder() for c in contacts) > max(m.get_zorder() for m in meshes)
    path = [line for line in view.get_lines() if line.get_color() == "k"]
    assert min(line.get_zorder() for line in path) > max(m.get_zorder() for m in meshes)


def test_the_meshes_are_shaded_by_vertex_and_interpolated() -> None:
    layers = rock_layers()
    [mesh] = layers.meshes
    view, top = axes_of(draw_map(layers))
    # the top view: Gouraud shading of the vertex values themselves
    [trimesh] = [c for c in top.collections if isinstance(c, TriMesh)]
    assert np.allclose(np.asarray(trimesh.get_array()), mesh.values * MM)
    # the 3D view: each triangle cut in SUBDIVISIONS**2, coloured by the values interpolated
    [known] = [c for c in view.collections if isinstance(c, Poly3DCollection)
               and len(c.get_facecolor()) > 1]
    assert len(known.get_facecolor()) == SUBDIVISIONS**2 * len(mesh.triangles)
    cells, centre = subdivided(mesh.vertices, mesh.triangles, mesh.values, SUBDIVISIONS)
    assert cells.shape == (SUBDIVISIONS**2 * len(mesh.triangles), 3, 3)
    # the cells tile each triangle: their areas add up to its area, their centres' values
    # are the vertex values interpolated (a linear field: its value at the centre)
    area = 0.5 * np.linalg.norm(np.cross(cells[:, 1] - cells[:, 0], cells[:, 2] - cells[:, 0]),
                                axis=1)
    v = mesh.vertices[mesh.triangles]
    whole = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    assert np.allclose(area.reshape(len(whole), -1).sum(axis=1), whole, rtol=1e-9)
    field = np.array([1.0, -2.0, 0.5])
    _, linear = subdivided(mesh.vertices, mesh.triangles, mesh.vertices @ field, SUBDIVISIONS)
    assert np.allclose(linear, cells.mean(axis=1) @ field, atol=1e-15)
    # within a triangle the colour changes (a flat colour per triangle was the checkerboard)
    assert np.ptp(centre.reshape(len(whole), -1), axis=1).min() > 0


def test_the_object_names_in_the_top_view_are_off_the_data() -> None:
    layers = rock_layers()
    _, top = axes_of(draw_map(layers))
    assert not [t for t in top.texts if not isinstance(t, Annotation)]  # no name on the data
    [label] = [t for t in top.texts if isinstance(t, Annotation)]
    assert label.get_text() == "rock"
    x, y = label.xyann
    lo = (ROCK_CENTRE[:2] - ROCK_RADIUS) * MM
    hi = (ROCK_CENTRE[:2] + ROCK_RADIUS) * MM
    assert not (lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1])  # beside the sphere
    contacts = np.asarray(layers.points)[:, :2] * MM
    path = layers.path.p_WR[:, :2] * MM if layers.path is not None else np.zeros((0, 2))
    clear = np.min(np.linalg.norm(np.concatenate([contacts, path]) - [x, y], axis=1))
    assert clear > 2.0, clear  # mm
    assert label.arrow_patch is not None  # a line from the name to its object


@pytest.fixture(scope="module")
def fitted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, MapLayers]:
    """The two-object map of tests/mapping/test_mapper_objects.py, the scene known."""
    tmp = tmp_path_factory.mktemp("map_figure")
    params = MapperParams(out_dir=str(tmp), scene=str(write_scene(tmp)), plot=False)
    frame = fit_frame("world", accumulate(messages()).frames["world"], params.settings,
                      params.truth("world"))
    return frame, map_layers(frame, params.world)


def test_the_colour_bar_and_the_header_give_the_same_maximum(fitted: tuple[Any, MapLayers]
                                                              ) -> None:
    frame, layers = fitted
    largest = max(obj.mesh_to_surface_max for obj in frame.result.objects) * MM
    assert frame.result.mesh_to_surface_max * MM == pytest.approx(largest)
    assert f"{largest:.2g} mm at most" in layers.subtitle  # the header
    end, top = colour_scale(layers.meshes)
    assert top == pytest.approx(largest, rel=1e-12) and 0 < end < top
    figure = draw_map(layers)
    [bar] = [ax for ax in figure.axes if ax.get_label() == "<colorbar>"]
    label = bar.get_ylabel()
    assert f"up to {largest:.2g}" in label and "99th percentile" in label, label
    assert bar.get_ylim()[1] == pytest.approx(end)


def test_the_colour_bar_ends_at_the_largest_when_nothing_is_above() -> None:
    layers = rock_layers()
    flat = dataclasses.replace(layers.meshes[0],
                               values=np.full(len(layers.meshes[0].vertices), 2e-6))
    figure = draw_map(dataclasses.replace(layers, meshes=[flat]))
    [bar] = [ax for ax in figure.axes if ax.get_label() == "<colorbar>"]
    assert "top: the largest, 0.002" in bar.get_ylabel()
    assert bar.get_ylim()[1] == pytest.approx(2e-3)


STATUS = "periodic map, update 7 of a live stream, 12 345 points <at> $x$, 2026-11-29 03:12:04 UTC"


@pytest.mark.slow
def test_the_status_line_is_under_the_title_of_map_png(fitted: tuple[Any, MapLayers],
                                                       tmp_path: Path) -> None:
    frame, layers = fitted
    assert layers.status == "" and map_layers(frame, status=STATUS).status == STATUS
    live = dataclasses.replace(layers, status=STATUS)
    figure = draw_map(live)
    [line] = [t for t in figure.texts if t.get_text() == STATUS]
    assert not line.get_parse_math()  # drawn as written: no mathtext of "$x$"
    [title] = [t for t in figure.texts if t.get_text() == layers.title]
    [notes] = [t for t in figure.texts if t.get_text() == layers.subtitle]
    assert notes.get_position()[1] < line.get_position()[1] < title.get_position()[1]
    # without a status nothing is added; with it, map.png differs in the header only
    assert len(draw_map(layers).texts) == len(figure.texts) - 1
    plot_map(tmp_path / "plain.png", layers)
    plot_map(tmp_path / "live.png", live)
    import matplotlib.image

    plain, shown = (matplotlib.image.imread(tmp_path / f"{name}.png") for name in ("plain", "live"))
    assert plain.shape == shown.shape
    differs = np.flatnonzero(np.any(plain != shown, axis=(1, 2)))
    assert len(differs) and differs.max() < 0.1 * len(plain)  # in the top tenth: the header
