"""The map's figure: one PNG of a frame's map that a person reads at a glance (matplotlib).

What it shows, in mm: a 3D view and a top view (x, y) of the true objects (grey wireframes,
named; in the top view beside their outline, with a line to it) when known, the robot path
with the whisker mounts at its start, middle and end (a clamp origin X_WR X_RC and a short
segment along the clamp's +z, the rod's axis at the clamp, in the whisker's colour), the
contacts coloured by whisker, the noise points (black crosses), each object's known mesh
coloured by its distance to the true surface when that is known and by its predicted std
otherwise, per vertex and interpolated (one colour bar in mm, to a percentile of the vertices'
values; it states the largest, the header's maximum), and the unknown part of the meshes in
faint grey; a legend for every layer; under the title, the map's status line when given
(which update of a live stream or the final map, when); for an exploration, right of the top
view, its coverage of the true objects against the path length of the robot base. Names from the wire
(whiskers, objects, frames) are drawn as ``short_name`` gives them, and no text is read as
matplotlib's mathtext (a ``$`` in a name).
The 3D view is cut to the objects (contacts, meshes, true objects) and the robot within a
whisker's length of them (`view_box`), with equal scales on its axes, so that the shapes are
true, and draws the contacts and the robot over the meshes; the top view shows the whole
path.

The layers (`MapLayers`) come from a frame's map (`map_layers`), once for this figure and the
page (`vibrissa.figures.map_page`). Drawn on a ``matplotlib.figure.Figure`` with the Agg canvas,
not through ``pyplot``: no global backend or figure state in the caller (a node), and nothing
opens a window. matplotlib is imported only when drawing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from vibrissa.mapping import FrameMap, TrueObject
from vibrissa.rods import unloaded_points
from vibrissa.scene import RobotPath, Scene, Whisker
from vibrissa.surfaces import Ellipsoid, Paraboloid

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

MAX_POINTS_SHOWN = 20_000
"""Contacts drawn at most (every k-th point beyond): the figure stays quick to draw."""

MAX_LEGEND_ENTRIES = 12
"""Whiskers (and meshes) named in the legend at most; the rest are counted in one entry."""

ROD_AXIS_FRACTION = 0.25
"""Length of a mount's rod-axis segment, as a fraction of its whisker's length."""

MM = 1e3
"""Figure units per metre."""

MAX_NAME_CHARS = 32
"""The most characters of a name drawn (``short_name``)."""

SCALE_PERCENTILE = 99.0
"""The colour scale ends at this percentile of the known vertices' values: a few far vertices
do not flatten the rest; the values above it show its top colour."""

SUBDIVISIONS = 3
"""Each known triangle of the 3D view is cut into this many squared, each coloured by its vertex
values interpolated at its centre (matplotlib's 3D axes shade a polygon in one colour)."""

LABEL_GAP = 0.04
"""Distance of an object's label from its box in the top view, as a fraction of the view."""


def printable(text: str) -> str:
    """``text`` with its control characters (a line break too) as spaces."""
    return "".join(c if c.isprintable() else " " for c in text)


def short_name(name: str) -> str:
    """``name`` as the figure draws it: `printable`, and a name longer than `MAX_NAME_CHARS`
    cut to that length in its middle (``…``), so that both ends show."""
    name = printable(name)
    if len(name) <= MAX_NAME_CHARS:
        return name
    head = MAX_NAME_CHARS // 2
    return f"{name[:head]}…{name[len(name) - (MAX_NAME_CHARS - head - 1):]}"


@dataclass(frozen=True)
class MeshLayer:
    """One object's mesh, m: the known part with a value per vertex (the colour, m), the
    unknown part, and the largest std of a known triangle; ``uncertainty`` False for a mesh
    without a std (Open3D's, `vibrissa.mapping.MapSettings.method`)."""

    name: str
    vertices: FloatArray
    triangles: IntArray
    values: FloatArray
    unknown_vertices: FloatArray
    unknown_triangles: IntArray
    max_std_m: float = 0.0
    uncertainty: bool = True


@dataclass(frozen=True)
class MapLayers:
    """What the figure of one frame shows; lengths in m, in that frame.

    Attributes
    ----------
    title, subtitle
        Above the figure; the subtitle may have several lines.
    status
        One line under the title on the map's state (which update of which stream, how many
        points, when); empty: none.
    points : ndarray, shape (N, 3)
        Contact points.
    whisker_ids : sequence of str, length N
        The whisker of each point.
    labels : ndarray of int, shape (N,)
        The object of each point, -1 for noise.
    meshes : sequence of MeshLayer
        The mesh of each object (empty arrays: no mesh).
    colour_by
        What the meshes' values are, for the colour bar.
    true_objects
        The known objects (wireframes); none when the truth is not known.
    path
        The robot path X_WR (frame ``world``), or None.
    whiskers
        The whiskers on the robot (their mounts X_RC are drawn along ``path``).
    coverage : sequence of (path length m, coverage), or None
        An exploration's coverage of each map along its path
        (`vibrissa.mapping.Exploration.coverage`); None: not an exploration (no plot).
    """

    title: str
    points: FloatArray
    whisker_ids: Sequence[str]
    labels: IntArray
    meshes: Sequence[MeshLayer] = ()
    colour_by: str = "predicted std of the surface"
    true_objects: Sequence[TrueObject] = ()
    path: RobotPath | None = None
    whiskers: Sequence[Whisker] = ()
    subtitle: str = ""
    status: str = ""
    coverage: Sequence[tuple[float, float]] | None = None


def wireframe(true: TrueObject, near: FloatArray) -> FloatArray:
    """A grid (3, U, V) on the true object's surface, m: the whole surface of an ellipsoid (or
    sphere); for a paraboloid, which has no end, the part under the points ``near`` (K, 3), m
    (in its body frame's x, y, 20 % beyond them), or around its vertex without points."""
    surface = true.surface
    if isinstance(surface, Ellipsoid):
        u, v = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, 25), np.linspace(0.0, np.pi, 13))
        p_B = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1)
        p_B = p_B * surface.radii
    elif isinstance(surface, Paraboloid):
        if len(near):
            q_B = surface.pose.apply_inverse(near / true.unit_m)
            lo, hi = q_B[:, :2].min(axis=0), q_B[:, :2].max(axis=0)
            pad = 0.2 * (hi - lo) + 0.02 * float(np.max(hi - lo)) + 1e-9
            lo, hi = lo - pad, hi + pad
        else:
            half = 0.5 / max(surface.a, surface.b)
            lo, hi = np.array([-half, -half]), np.array([half, half])
        x, y = np.meshgrid(np.linspace(lo[0], hi[0], 25), np.linspace(lo[1], hi[1], 25))
        p_B = np.stack([x, y, surface.a * x**2 + surface.b * y**2 + surface.h], axis=-1)
    else:
        raise TypeError(f"no wireframe for a {type(surface).__name__}")
    shape = p_B.shape[:2]
    p_W = surface.pose.apply(p_B.reshape(-1, 3)) * true.unit_m
    return np.asarray(p_W.T.reshape(3, *shape), dtype=np.float64)


def mounts(path: RobotPath, whiskers: Sequence[Whisker]
           ) -> list[tuple[Whisker, FloatArray, FloatArray]]:
    """Each whisker's clamp at the path's start, middle and end: (whisker, clamp origins
    p_WC (K, 3), ends of the rod-axis segments (K, 3): the unloaded rod's point at
    ``ROD_AXIS_FRACTION`` of its length, on its arc where it is pre-curved), m."""
    rows = np.unique([0, len(path.t) // 2, len(path.t) - 1])
    R_WR = path.R_WR[rows]
    out = []
    for whisker in whiskers:
        p_WC = path.p_WR[rows] + R_WR.apply(np.array(whisker.X_RC.translation))
        along = unloaded_points(whisker.shape, np.array([ROD_AXIS_FRACTION]))[0]
        r_WC = (R_WR * whisker.X_RC.rotation).apply(along)
        out.append((whisker, p_WC, p_WC + whisker.length_m * r_WC))
    return out


def _colours(n: int, palette: str) -> list[Any]:
    """``n`` distinct colours: the qualitative ``palette`` while it lasts, then a sweep of
    ``turbo``."""
    import matplotlib

    cmap = matplotlib.colormaps[palette]
    size = int(getattr(cmap, "N", 256))
    if n <= size:
        return [cmap(i) for i in range(n)]
    turbo = matplotlib.colormaps["turbo"]
    return [turbo(x) for x in np.linspace(0.05, 0.95, n)]


def whisker_colours(layers: MapLayers) -> dict[str, Any]:
    """Each whisker's colour (RGBA), by name over the contacts and the robot description:
    ``tab10`` up to 10 whiskers, ``tab20`` up to 20, then a sweep of ``turbo``."""
    names = sorted({*np.asarray(layers.whisker_ids, dtype=object).tolist(),
                    *(w.name for w in layers.whiskers)})
    return dict(zip(names, _colours(len(names), "tab10" if len(names) <= 10 else "tab20"),
                    strict=True))


def thousands(n: int) -> str:
    """``5 214``: digits grouped by spaces."""
    return f"{n:,}".replace(",", " ")


def _plural(n: int, word: str) -> str:
    """``1 object``, ``2 objects``, ``5 214 contacts``."""
    return f"{thousands(n)} {word}{'' if n == 1 else 's'}"


def map_layers(frame: FrameMap, scene: Scene | None = None, status: str = "",
               coverage: Sequence[tuple[float, float]] | None = None) -> MapLayers:
    """What the pictures of a frame show: the contacts, the meshes (coloured by their distance
    to the true surface when it is known, else by their std, or in one colour without one),
    the truth when known (``frame.truth``), the robot path and whisker mounts of ``scene`` (in
    the frame's frame) when given, the map's ``status`` line (`MapLayers.status`) and an
    exploration's ``coverage`` along its path when given (`MapLayers.coverage`)."""
    result = frame.result
    whiskers = sorted(set(frame.whisker_ids))
    title = (f"{short_name(result.frame_id)} map: {_plural(len(result.objects), 'object')}, "
             f"{_plural(result.n_points, 'contact')} from {_plural(len(whiskers), 'whisker')}")
    truth = frame.truth
    notes = []
    for obj in result.objects[:6]:
        note = f"{short_name(obj.name)}: {_plural(obj.n_points, 'point')}, "
        note += (f"surface known over {_plural(obj.n_triangles, 'triangle')}"
                 f" ({obj.n_triangles / (obj.n_triangles + obj.unknown_triangles):.0%})"
                 if obj.n_triangles and obj.uncertainty else
                 f"{obj.method.split(' (')[0]} surface, {_plural(obj.n_triangles, 'triangle')}"
                 ", no uncertainty" if obj.n_triangles else obj.method.removeprefix("none: "))
        if obj.mesh_to_surface_mean is not None and obj.mesh_to_surface_max is not None:
            note += (f", {obj.mesh_to_surface_mean * 1e3:.2g} mm from the true surface on "
                     f"average, {obj.mesh_to_surface_max * 1e3:.2g} mm at most")
        elif obj.std_max_m is not None:
            note += f", std at most {obj.std_max_m * 1e3:.2g} mm"
        notes.append(note)
    if len(result.objects) > 6:
        notes.append(f"... and {len(result.objects) - 6} more objects (report.txt)")
    if result.noise_points:
        notes.append(f"noise: {_plural(result.noise_points, 'point')} in no object")
    meshes = []
    true_of = {t.name: t for t in truth}
    for obj, surface in zip(result.objects, frame.surfaces, strict=True):
        vertices, triangles, std = surface.part(known=True)
        unknown_vertices, unknown_triangles, _ = surface.part(known=False)
        true = true_of.get(obj.true_object or "") if truth else None
        meshes.append(MeshLayer(
            obj.name, vertices, triangles,
            true.distance(vertices) if true is not None else
            std if surface.uncertainty else np.zeros(len(vertices)),  # one colour
            unknown_vertices, unknown_triangles,
            max_std_m=surface.mesh.max_std if surface.mesh is not None and surface.uncertainty
            else 0.0, uncertainty=surface.uncertainty))
    flat = not truth and not all(mesh.uncertainty for mesh in meshes)
    return MapLayers(
        title=title, subtitle="\n".join(notes), points=frame.points,
        whisker_ids=frame.whisker_ids, labels=frame.labels, meshes=meshes,
        colour_by="distance to the true surface" if truth else
        "one colour: no uncertainty" if flat else "predicted std of the surface",
        true_objects=truth, path=scene.path if scene is not None else None,
        whiskers=scene.whiskers if scene is not None else (), status=status,
        coverage=coverage)


def _capped(entries: list[Any], more: str, handle: Any) -> list[Any]:
    """At most ``MAX_LEGEND_ENTRIES`` legend handles, the rest counted in one."""
    if len(entries) <= MAX_LEGEND_ENTRIES:
        return entries
    rest = len(entries) - MAX_LEGEND_ENTRIES + 1
    handle.set_label(f"... {rest} more {more}")
    return [*entries[: MAX_LEGEND_ENTRIES - 1], handle]


def bounding_box(parts: Sequence[FloatArray], margin: float) -> tuple[FloatArray, FloatArray]:
    """Corners (3,) of the box around the points of ``parts`` (each (K, 3)), grown by
    ``margin`` of its largest side on every side and to at least 2 % of it along each axis."""
    every = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in parts])
    lo, hi = every.min(axis=0), every.max(axis=0)
    side = float(np.max(hi - lo)) or 1e-3
    grow = np.maximum(margin * side, 0.5 * (0.02 * side - (hi - lo)))
    return lo - grow, hi + grow


def view_box(focus: Sequence[FloatArray], robot: Sequence[FloatArray],
             whiskers: Sequence[Whisker]) -> tuple[FloatArray, FloatArray]:
    """Corners (3,) of the 3D view, m: the objects ``focus`` (each (K, 3)) and the part of the
    robot (path and mounts, each (K, 3)) within a whisker's length of them in x and y (a
    quarter of their size without whiskers), grown by 5 %: the robot that touched them, not
    all of its path."""
    lo, hi = bounding_box(focus, 0.0)
    reach = max([0.25 * float(np.max(hi[:2] - lo[:2])), *(w.length_m for w in whiskers)])
    near = [p[np.all((p[:, :2] >= lo[:2] - reach) & (p[:, :2] <= hi[:2] + reach), axis=1)]
            for p in robot]
    return bounding_box([*focus, *near], 0.05)


def _densified(p: FloatArray, n: int = 600) -> FloatArray:
    """The polyline ``p`` (K, 3) resampled at ``n`` points evenly along its length (at least
    its own points)."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    if s[-1] == 0 or len(p) >= n:
        return p
    at = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(at, s, p[:, k]) for k in range(3)], axis=1)


def _clipped(p: FloatArray, lo: FloatArray, hi: FloatArray) -> FloatArray:
    """``p`` (K, 3) with the rows outside the box [lo, hi] set to NaN (a gap in a line)."""
    inside = np.all((p >= lo) & (p <= hi), axis=1)
    return np.where(inside[:, None], p, np.nan)


def colour_scale(meshes: Sequence[MeshLayer]) -> tuple[float, float]:
    """The meshes' colour scale, mm: its end (the `SCALE_PERCENTILE` of the known vertices'
    values; 1 without any, or when all are 0) and the largest value (0 without any), the
    maximum that the report and the figure's header give."""
    every = np.concatenate([np.asarray(mesh.values, dtype=np.float64)[np.unique(mesh.triangles)]
                            for mesh in meshes] or [np.zeros(0)]) * MM
    if not len(every):
        return 1.0, 0.0
    end = float(np.percentile(every, SCALE_PERCENTILE))
    return (end if end > 0 else 1.0), float(every.max())


def subdivided(vertices: FloatArray, triangles: IntArray, values: FloatArray, n: int
               ) -> tuple[FloatArray, FloatArray]:
    """Each triangle cut into ``n``**2 (its edges in ``n`` equal parts): their corners
    (T n**2, 3, 3) and the ``values`` (per vertex) interpolated linearly at their centres
    (T n**2,)."""
    corners, i_j = [], [(i, j) for i in range(n) for j in range(n - i)]
    for i, j in i_j:  # barycentric corners of the triangles pointing up, then down
        corners.append([(i, j), (i + 1, j), (i, j + 1)])
        if i + j + 1 < n:
            corners.append([(i + 1, j), (i + 1, j + 1), (i, j + 1)])
    ij = np.asarray(corners, dtype=np.float64) / n  # (n**2, 3, 2)
    weights = np.concatenate([1.0 - ij.sum(axis=2, keepdims=True), ij], axis=2)  # (n**2, 3, 3)
    p = np.einsum("skc,tcd->tskd", weights, vertices[triangles]).reshape(-1, 3, 3)
    centre = np.einsum("sc,tc->ts", weights.mean(axis=1), values[triangles]).reshape(-1)
    return p, centre


def label_places(boxes: Sequence[tuple[FloatArray, FloatArray]], data: FloatArray, gap: float
                 ) -> list[tuple[FloatArray, str, str]]:
    """Where each object's label goes in a 2D view, off the data: beside its box ``(lo, hi)``
    (2,) by ``gap``, above, below, left or right, on the side whose spot is furthest from the
    points ``data`` (K, 2) and from the other labels. Each: (the spot (2,), ha, va)."""
    out: list[tuple[FloatArray, str, str]] = []
    for lo, hi in boxes:
        mid = 0.5 * (lo + hi)
        sides = [(np.array([mid[0], hi[1] + gap]), "center", "bottom"),
                 (np.array([mid[0], lo[1] - gap]), "center", "top"),
                 (np.array([lo[0] - gap, mid[1]]), "right", "center"),
                 (np.array([hi[0] + gap, mid[1]]), "left", "center")]
        taken = np.concatenate([data.reshape(-1, 2), *[[at] for at, _, _ in out]])
        clearance = [float(np.min(np.linalg.norm(taken - at, axis=1))) if len(taken) else 0.0
                     for at, _, _ in sides]
        out.append(sides[int(np.argmax(clearance))])
    return out


def plot_map(path: str | Path, layers: MapLayers) -> None:
    """Write the figure of ``layers`` to ``path`` (PNG)."""
    draw_map(layers).savefig(path, dpi=100, format="png")


def draw_coverage(ax: Any, coverage: Sequence[tuple[float, float]]) -> None:
    """An exploration's coverage (%) against the path length of its base (mm), a point per
    map, on ``ax``."""
    history = np.asarray(coverage, dtype=np.float64).reshape(-1, 2)
    ax.plot(history[:, 0] * MM, history[:, 1] * 100.0, color="C0", marker=".", markersize=4,
            linewidth=1.2)
    ax.set_ylim(0.0, 100.0)
    ax.set_xlim(left=0.0, right=max(float(history[:, 0].max(initial=0.0)) * MM * 1.05, 1.0))
    ax.set_xlabel("path length of the base [mm]", fontsize=8)
    ax.set_ylabel("coverage [%]", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, linewidth=0.3, alpha=0.5)
    final = f", final {history[-1, 1]:.1%}" if len(history) else ""
    ax.set_title(f"coverage of the true surface in reach{final}", fontsize=9,
                 parse_math=False)


def draw_map(layers: MapLayers) -> Figure:
    """The figure of ``layers`` (Agg canvas)."""
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.tri import Triangulation
    from mpl_toolkits.mplot3d import Axes3D  # noqa: F401 - registers the 3d projection
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    explored = layers.coverage is not None  # a third column: the coverage, right of the top view
    fig = Figure(figsize=(20, 9) if explored else (16, 9))
    notes = layers.subtitle.count("\n") + 1 if layers.subtitle else 0
    grid = fig.add_gridspec(2, 3 if explored else 2,
                            width_ratios=[1.35, 1.0, 0.65] if explored else [1.35, 1.0],
                            height_ratios=[1.0, 0.8],
                            left=0.02, right=0.98, bottom=0.06, top=0.91 - 0.016 * notes,
                            wspace=0.2, hspace=0.15)
    # Drawn in a fixed order, not sorted by depth: the contacts on a surface stay in front of
    # its mesh, the path and the mounts in front of the objects.
    ax: Any = fig.add_subplot(grid[:, 0], projection="3d", computed_zorder=False)
    top: Any = fig.add_subplot(grid[0, 1])
    key: Any = fig.add_subplot(grid[1, 1:])
    if layers.coverage is not None:
        draw_coverage(fig.add_subplot(grid[0, 2]), layers.coverage)
    key.axis("off")
    focus: list[FloatArray] = []  # the objects, m: the limits of the 3D view
    extent: list[FloatArray] = []  # every drawn point, m: the limits of the top view
    handles: list[Any] = []

    points = np.asarray(layers.points, dtype=np.float64).reshape(-1, 3)
    ids = np.asarray(layers.whisker_ids, dtype=object)
    labels = np.asarray(layers.labels)
    shown = np.arange(0, len(points), max(1, -(-len(points) // MAX_POINTS_SHOWN)))
    focus.append(points[labels >= 0] if np.any(labels >= 0) else points)  # noise may be far
    focus += [np.asarray(mesh.vertices).reshape(-1, 3) for mesh in layers.meshes]
    near_of = np.zeros(len(shown), dtype=np.int64)
    if len(shown) and len(layers.true_objects) > 1:
        near_of = np.argmin([t.distance(points[shown]) for t in layers.true_objects], axis=0)
    grids = [wireframe(true, points[shown][near_of == i])
             for i, true in enumerate(layers.true_objects)]
    focus += [g.reshape(3, -1).T for g in grids]
    clamps = mounts(layers.path, layers.whiskers) if layers.path is not None else []
    robot = [layers.path.p_WR] if layers.path is not None else []
    robot += [a for _, p_WC, tip in clamps for a in (p_WC, tip)]
    lo, hi = view_box(focus, robot, layers.whiskers)
    extent += [*focus, points, *robot]

    colour = whisker_colours(layers)

    if layers.true_objects:
        for true, grid_m in zip(layers.true_objects, grids, strict=True):
            grid_W = grid_m * MM
            ax.plot_wireframe(*grid_W, color="0.5", linewidth=0.4, alpha=0.7, zorder=1)
            top.plot(grid_W[0], grid_W[1], color="0.7", linewidth=0.3, zorder=0.6)
            top.plot(grid_W[0].T, grid_W[1].T, color="0.7", linewidth=0.3, zorder=0.6)
            at = grid_W.reshape(3, -1)
            ax.text(at[0].mean(), at[1].mean(), at[2].max(), short_name(true.name),
                    color="0.3", fontsize=9, ha="center", va="bottom", parse_math=False,
                    zorder=8)
        handles.append(Line2D([], [], color="0.5", linewidth=0.8,
                              label=f"true {'objects' if len(layers.true_objects) > 1 else 'object'}"
                              f" ({', '.join(short_name(t.name) for t in layers.true_objects[:6])}"
                              f"{', ...' if len(layers.true_objects) > 6 else ''})"))

    if layers.path is not None:
        p = layers.path.p_WR * MM
        cut = _clipped(_densified(layers.path.p_WR), lo, hi) * MM
        ax.plot(cut[:, 0], cut[:, 1], cut[:, 2], color="k", linewidth=1.2, zorder=4)
        if np.all(np.isfinite(_clipped(layers.path.p_WR[:1], lo, hi))):
            ax.scatter(*p[0], color="k", s=25, marker="o", depthshade=False, zorder=4)
        top.plot(p[:, 0], p[:, 1], color="k", linewidth=1.2)
        top.plot(p[0, 0], p[0, 1], "ko", markersize=5)
        handles.append(Line2D([], [], color="k", linewidth=1.2, marker="o", markersize=4,
                              markevery=[0], label="robot path (dot: start)"))
        for whisker, p_WC, tip in clamps:
            c, t = p_WC * MM, tip * MM
            in_view = np.all(np.isfinite(_clipped(p_WC, lo, hi)), axis=1)
            for a, b, seen in zip(c, t, in_view, strict=True):
                if seen:
                    ax.plot(*np.stack([a, b]).T, color=colour[whisker.name], linewidth=1.6,
                            zorder=5)
                top.plot([a[0], b[0]], [a[1], b[1]], color=colour[whisker.name], linewidth=1.6)
            ax.scatter(c[in_view, 0], c[in_view, 1], c[in_view, 2], color="k", s=8,
                       depthshade=False, zorder=5)
            top.plot(c[:, 0], c[:, 1], "k.", markersize=4)
        if layers.whiskers:
            handles.append(Line2D([], [], color="0.3", linewidth=1.6, marker=".",
                                  markerfacecolor="k", markeredgecolor="k",
                                  label="whisker mounts at start, middle, end\n"
                                        "(clamp, rod axis +z, whisker colour)"))

    whisker_handles = []
    for name in colour:
        mine = shown[(ids[shown] == name) & (labels[shown] >= 0)]
        count = int(np.sum(ids == name))
        if len(mine):
            q = points[mine] * MM
            ax.scatter(q[:, 0], q[:, 1], q[:, 2], s=2.0, color=colour[name], depthshade=False,
                       zorder=6)
            top.scatter(q[:, 0], q[:, 1], s=2.5, color=colour[name], linewidths=0)
        whisker_handles.append(Line2D([], [], linestyle="", marker="o", markersize=5,
                                      color=colour[name],
                                      label=f"{short_name(name)}: {thousands(count)} contacts"))
    handles += _capped(whisker_handles, "whiskers", Line2D([], [], linestyle=""))
    noise = shown[labels[shown] < 0]
    if np.any(labels < 0):
        q = points[noise] * MM
        cut = _clipped(points[noise], lo, hi) * MM
        ax.scatter(cut[:, 0], cut[:, 1], cut[:, 2], s=14, color="k", marker="x",
                   depthshade=False, zorder=7)
        top.scatter(q[:, 0], q[:, 1], s=14, color="k", marker="x", linewidths=0.8)
        handles.append(Line2D([], [], linestyle="", marker="x", color="k",
                              label=f"noise: {thousands(int(np.sum(labels < 0)))} points "
                                    "in no object"))

    top_mm, largest_mm = colour_scale(layers.meshes)
    norm = Normalize(0.0, top_mm, clip=True)
    cmap = matplotlib.colormaps["viridis"]
    unknown = 0
    for mesh in layers.meshes:
        if len(mesh.unknown_triangles):
            u = np.asarray(mesh.unknown_vertices) * MM
            ax.add_collection3d(Poly3DCollection(u[mesh.unknown_triangles], facecolors="0.85",
                                                 edgecolors="none", alpha=0.15, zorder=2))
            unknown += len(mesh.unknown_triangles)
        if len(mesh.triangles) == 0:
            continue
        v = np.asarray(mesh.vertices) * MM
        value_mm = np.asarray(mesh.values, dtype=np.float64) * MM
        cells, cell_mm = subdivided(v, np.asarray(mesh.triangles), value_mm, SUBDIVISIONS)
        rgba = cmap(norm(cell_mm))  # opaque, edged in their own colour: no seams
        ax.add_collection3d(Poly3DCollection(cells, facecolors=rgba, edgecolors=rgba,
                                             linewidths=0.3, zorder=3))
        # opaque (a translucent one darkens its triangles' seams), over the grid and the true
        # objects, under the contacts and the robot
        top.tripcolor(Triangulation(v[:, 0], v[:, 1], mesh.triangles), value_mm,
                      shading="gouraud", cmap=cmap, norm=norm, zorder=0.8)
    known = sum(len(mesh.triangles) for mesh in layers.meshes)
    certain = all(mesh.uncertainty for mesh in layers.meshes)
    if known:
        handles.append(Patch(facecolor=cmap(0.6), alpha=0.8, label=(
            "surface estimate, known" if certain else "surface estimate, NO UNCERTAINTY")
            + f": {thousands(known)} triangles\n(colour: {layers.colour_by}"
            + (", bar)" if largest_mm > 0 or certain else ")")))
    if unknown:
        limits = sorted({float(f"{mesh.max_std_m * MM:.2g}") for mesh in layers.meshes
                         if len(mesh.unknown_triangles) and mesh.max_std_m > 0})
        std = ("" if not limits else f"std above {limits[0]:g} mm, " if len(limits) == 1 else
               f"std above {limits[0]:g}-{limits[-1]:g} mm by object, ")  # one line for any number
        handles.append(Patch(facecolor="0.85", alpha=0.5, label=f"unknown: {std}not on the map"))
    if known and (largest_mm > 0 or certain):  # the scale ends at a percentile: the vertices
        # above show its top colour; one colour (no uncertainty, no truth) needs no bar
        above = largest_mm > top_mm
        bar = fig.colorbar(ScalarMappable(norm, cmap), ax=[ax], shrink=0.5, pad=0.02,
                           location="left", extend="max" if above else "neither")
        bar.set_label(f"{layers.colour_by} [mm], per vertex\n" + (
            f"top: {SCALE_PERCENTILE:g}th percentile; arrow: up to {largest_mm:.2g}" if above
            else f"top: the largest, {largest_mm:.2g}"))

    ax.set_xlim(lo[0] * MM, hi[0] * MM)
    ax.set_ylim(lo[1] * MM, hi[1] * MM)
    ax.set_zlim(lo[2] * MM, hi[2] * MM)
    ax.set_box_aspect(tuple(hi - lo))  # equal scales: the shapes are the true shapes
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_zlabel("z [mm]")
    ax.set_title("3D view", fontsize=10)
    lo, hi = bounding_box(extent, 0.05)
    # Each object's name beside it, off the contacts and the path, with a line to it.
    outlines = [g.reshape(3, -1)[:2].T for g in grids]
    data = np.concatenate([points[shown][:, :2], *[r[:, :2] for r in robot],
                           *outlines, np.zeros((0, 2))])
    places = label_places([(o.min(axis=0), o.max(axis=0)) for o in outlines], data,
                          LABEL_GAP * float(np.max(hi[:2] - lo[:2])))
    for true, outline, (at, ha, va) in zip(layers.true_objects, outlines, places, strict=True):
        end = outline[np.argmin(np.linalg.norm(outline - at, axis=1))]
        top.annotate(short_name(true.name), xy=end * MM, xytext=at * MM, ha=ha, va=va,
                     color="0.3", fontsize=9, style="italic", parse_math=False,
                     arrowprops={"arrowstyle": "-", "color": "0.45", "linewidth": 0.6})
    if places:
        lo, hi = bounding_box([*extent, np.array([[*at, lo[2]] for at, _, _ in places])], 0.05)
    top.set_xlim(lo[0] * MM, hi[0] * MM)
    top.set_ylim(lo[1] * MM, hi[1] * MM)
    top.set_aspect("equal", adjustable="box")
    top.set_xlabel("x [mm]")
    top.set_ylabel("y [mm]")
    top.grid(True, linewidth=0.3, alpha=0.5)
    top.set_axisbelow(True)
    top.set_title("top view (looking down z)", fontsize=10)
    legend = key.legend(handles=handles, loc="upper center", fontsize=8, frameon=False,
                        borderaxespad=0.0, ncols=2 if len(handles) > 12 else 1)
    for text in legend.get_texts():
        text.set_parse_math(False)
    fig.suptitle(layers.title, fontsize=13, y=0.98, parse_math=False)
    if layers.status:  # between the title and the subtitle, in one line
        fig.text(0.5, 0.955, printable(layers.status), ha="center", va="top", fontsize=9,
                 style="italic", color="0.15", parse_math=False)
    if layers.subtitle:
        fig.text(0.5, 0.925, layers.subtitle, ha="center", va="top", fontsize=8, color="0.25",
                 parse_math=False)
    return fig
