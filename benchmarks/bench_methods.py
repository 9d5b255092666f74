"""The mapper's three surface methods (``MapSettings.method``) on the same clouds: the table and
the figure of docs/MAPPING.md ("Choosing the surface method").

Each method runs `vibrissa.mapping.estimate_surface` on the same points and outward normals with
the mapper's default settings but the method (box grown by 0.2 of the diagonal, 64 cells):

* ``gp``: the Gaussian-process implicit surface; what it shows is its known part.
* ``poisson``: Open3D's screened Poisson (`vibrissa.mapping.open3d_surface`); all of it shown.
* ``ball_pivoting``: Open3D's ball pivoting; all of it shown.

Clouds (L = 1 m, so m): ``lines`` the demo's five contact lines on its paraboloid
(launch/demo.yaml: ``paraboloid:a=0.5,b=1,h=0.4``, y0 = -0.4 ... 0.4, mu 0.2, step 0.001,
normals from the contact forces as the mapper takes them); ``dense`` the same paraboloid
touched by 60 trails, y0 = -0.75 ... 0.75; ``scan`` 6 000 points spread over the whole
posed ellipsoid ``ellipsoid:rx=0.3,ry=0.22,rz=0.15,cx=0.05,cy=-0.02,cz=0.8,yaw=0.5`` with its
true normals (the directions of a Fibonacci lattice scaled by its radii: a closed object sampled
all round, as a depth scan would).

Columns: ``time s`` the surface's fit and mesh, the median of ``--repeat`` runs after one
warm-up run (numba's compilation and Open3D's import excluded); ``max mm``, ``mean mm`` the
distance of the shown vertices to the true surface (`vibrissa.mapping.TrueObject.distance`, as
report.json's ``mesh_to_surface_*``); ``triangles`` shown (GP: known of all); ``std`` whether it
has one. Open3D runs on one thread (as the mapper runs it), BLAS on one.

Usage: ``python benchmarks/bench_methods.py [--repeat 3] [--png docs/images/mapping_methods.png]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402
import numpy.typing as npt  # noqa: E402

from vibrissa import Trail, parse_surface, simulate_sweeps  # noqa: E402
from vibrissa.mapping import MapSettings, TrueObject, contact_normals, estimate_surface  # noqa: E402
from vibrissa.mapping.settings import METHODS  # noqa: E402
from vibrissa.mapping.surface import ObjectSurface  # noqa: E402
from vibrissa.surfaces import Ellipsoid  # noqa: E402
from vibrissa.sweep import contact_lines  # noqa: E402

FloatArray = npt.NDArray[np.float64]

PARABOLOID = "paraboloid:a=0.5,b=1,h=0.4"
SCAN = "ellipsoid:rx=0.3,ry=0.22,rz=0.15,cx=0.05,cy=-0.02,cz=0.8,yaw=0.5"
CLOUDS = ("lines", "dense", "scan")
SCALE_MM = 5.0
"""The figure's colour scale: 0 to this distance to the truth, mm (beyond: its top colour)."""


@dataclass(frozen=True)
class Cloud:
    name: str
    points: FloatArray
    normals: FloatArray
    truth: TrueObject


def make_cloud(name: str) -> Cloud:
    """The cloud ``name`` of `CLOUDS` (see module)."""
    if name == "scan":
        surface = parse_surface(SCAN)
        k = np.arange(6000) + 0.5
        z = 1.0 - 2.0 * k / len(k)
        phi = np.pi * (1.0 + 5.0**0.5) * k
        u = np.c_[np.sqrt(1.0 - z**2) * np.cos(phi), np.sqrt(1.0 - z**2) * np.sin(phi), z]
        assert isinstance(surface, Ellipsoid)
        points = surface.pose.apply(u * surface.radii)  # the ellipsoid's point of direction u
        return Cloud(name, points, surface.normal(points), TrueObject("ellipsoid", surface))
    surface = parse_surface(PARABOLOID)
    y0s = (-0.4, -0.2, 0.0, 0.2, 0.4) if name == "lines" else np.linspace(-0.75, 0.75, 60)
    points, forces, lines = contact_lines(simulate_sweeps(
        surface, [Trail(float(y0), 0.2) for y0 in y0s], 0.001))
    return Cloud(name, points, contact_normals(points, forces, lines),
                 TrueObject("paraboloid", surface))


@dataclass(frozen=True)
class Row:
    cloud: str
    points: int
    method: str
    time_s: float
    max_mm: float
    mean_mm: float
    triangles: str
    surface: ObjectSurface


def measure(cloud: Cloud, method: str, repeat: int) -> Row:
    """One method on one cloud: warm-up, then ``repeat`` timed runs."""
    settings = MapSettings(method=method)
    estimate_surface(cloud.points, cloud.normals, settings)
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        surface = estimate_surface(cloud.points, cloud.normals, settings)
        times.append(time.perf_counter() - start)
    vertices, triangles, _ = surface.part(known=True)
    distance = cloud.truth.distance(vertices) * 1e3
    shown = f"{len(triangles):,}".replace(",", " ")
    if surface.uncertainty:
        shown += f" of {len(triangles) + len(surface.part(known=False)[1]):,}".replace(",", " ")
    return Row(cloud.name, len(cloud.points), method, float(np.median(times)),
               float(distance.max()), float(distance.mean()), shown, surface)


def plot(rows: list[Row], clouds: dict[str, Cloud], path: str) -> None:
    """The figure: a row per cloud, a column per method, each mesh coloured by its distance to
    the true surface (the GP's unknown part in the view in faint grey), every k-th point in red."""
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = Figure(figsize=(14, 4.2 * len(clouds)))
    fig.subplots_adjust(left=0.0, right=0.9, bottom=0.0, top=0.95, wspace=0.0, hspace=0.12)
    cmap, norm = matplotlib.colormaps["viridis"], Normalize(0.0, SCALE_MM, clip=True)
    axes = []
    for i, row in enumerate(rows):
        cloud = clouds[row.cloud]
        ax = fig.add_subplot(len(clouds), len(METHODS), i + 1, projection="3d",
                             computed_zorder=False)
        axes.append(ax)
        vertices, triangles, _ = row.surface.part(known=True)
        value = cloud.truth.distance(vertices)[triangles].mean(axis=1) * 1e3
        # the view: the points and every method's shown mesh of this cloud
        near = [cloud.points, *[r.surface.part(known=True)[0] for r in rows
                                if r.cloud == row.cloud]]
        lo = np.min([p.min(axis=0) for p in near if len(p)], axis=0) * 1e3
        hi = np.max([p.max(axis=0) for p in near if len(p)], axis=0) * 1e3
        pad = 0.02 * float(np.max(hi - lo))
        lo, hi = lo - pad, hi + pad
        unknown_v, unknown_t, _ = row.surface.part(known=False)
        inside = np.all((unknown_v * 1e3 >= lo) & (unknown_v * 1e3 <= hi), axis=1)
        unknown_t = unknown_t[inside[unknown_t].all(axis=1)]
        if len(unknown_t):
            ax.add_collection3d(Poly3DCollection(unknown_v[unknown_t] * 1e3, facecolors="0.85",
                                                 edgecolors="none", alpha=0.25, zorder=1))
        rgba = cmap(norm(value))
        ax.add_collection3d(Poly3DCollection(vertices[triangles] * 1e3, facecolors=rgba,
                                             edgecolors=rgba, linewidths=0.2, zorder=2))
        shown = cloud.points[:: max(1, len(cloud.points) // 1500)] * 1e3
        ax.scatter(*shown.T, s=0.2, color="r", alpha=0.6, depthshade=False, zorder=3)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(tuple(hi - lo), zoom=1.1)
        ax.view_init(elev=40, azim=-60)
        ax.set_axis_off()
        std = "std, known part" if row.surface.uncertainty else "NO UNCERTAINTY"
        ax.set_title(f"{row.cloud} ({row.points:,} points): {row.method}\n".replace(",", " ")
                     + f"{std}; {row.triangles} triangles\nmax {row.max_mm:.3g} mm, mean "
                     f"{row.mean_mm:.3g} mm from the true surface", fontsize=9)
    bar = fig.colorbar(ScalarMappable(norm, cmap), ax=axes, shrink=0.4, pad=0.02,
                       extend="max")
    bar.set_label("distance to the true surface [mm]\n(grey: the GP's unknown part, not on "
                  "the map; red: the points)")
    fig.savefig(path, dpi=80)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed runs after the warm-up")
    parser.add_argument("--png", default="", help="write the figure here")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1, got {args.repeat}")
    print(f"surface methods: {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f}", flush=True)
    clouds = {name: make_cloud(name) for name in CLOUDS}
    rows = [measure(clouds[name], method, args.repeat) for name in CLOUDS for method in METHODS]
    print("| cloud | points | method | time s | max mm | mean mm | triangles (GP: known of all) "
          "| std |")
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(f"| {row.cloud} | {row.points:,} | {row.method} | {row.time_s:.2f} | "
              f"{row.max_mm:.3g} | {row.mean_mm:.3g} | {row.triangles} | "
              f"{'yes' if row.surface.uncertainty else 'no'} |".replace(",", " "))
    if args.png:
        plot(rows, clouds, args.png)
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
