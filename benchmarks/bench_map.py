"""Map benchmark: three surface estimates of the same whisker contact clouds, against the truth.

Methods, each on the same cloud (points in line order, normals from the contact forces as the
mapper takes them: ``vibrissa.mapping.contact_normals``):

* ``poisson``: the mapper's former mesh, ``fit_surface`` here (Open3D screened Poisson,
  depth 8, one thread, trimmed to 0.6 line spacings of the data). The baseline of every ratio.
* ``gp``: the Gaussian-process implicit surface, ``vibrissa.mapping.gp_surface.fit`` and ``mesh`` on
  the mapper's box and grid (``MapSettings``: the points' box grown by 0.2 of its diagonal, 64 cells
  along its longest side). What it shows is its *known* triangles; the rest is unknown.
* ``rbf``: the classic RBF implicit surface (Carr et al. 2001): ``scipy.interpolate.
  RBFInterpolator`` (thin-plate spline r^2 log r, degree-1 polynomial, interpolating) of f = 0
  at the points and f = +-delta at the points moved by +-delta along their normals (delta =
  ``RBF_OFFSET`` of the cloud's radius), on the GP's active points (``gp_surface.
  select_active``, same number), in the GP's normalised coordinates; its zero set meshed by
  scikit-image's marching cubes on the full grid of the GP's box. All of it is shown.

Columns (errors in mm; L = 1 m, so the clouds are in m):

* ``time s``: fit + mesh, median of ``--repeat`` runs after one warm-up run (numba's
  compilation, Open3D's import and first call excluded); ``x poisson``: its ratio to Poisson's
  time on the same cloud in the same run.
* The *touched region*: where the object was touched and between its lines: points on the
  touching side of the true object (its outward normal at the closest point has a positive
  component along the cloud's mean normal) whose projection along the mean normal falls in the
  2-D convex hull of the projected contact points (as in tests/mapping/test_gp_surface.py).
* ``max``, ``mean``: |signed distance| to the true surface of the shown mesh vertices in the
  touched region.
* ``cover %``: share of the touched region the shown mesh covers: a grid of ``cell`` / 2 over
  the hull (``cell`` the GP's grid cell) counts a node covered when a shown vertex in the
  touched region projects within ``cell`` of it.
* ``out max``: largest |signed distance| of a shown vertex outside the touched region, how far
  off what a method shows where it has no data between its lines is.
* ``same``: all runs (warm-up included) give bit-identical vertex arrays.
* ``tris``: triangles shown (GP: known; in brackets all of its mesh).
* ``3sd %`` (GP only): share of the true-surface points (the closest points of all its mesh's
  vertices in the touched region) with |f| <= 3 std (``GPSurface.std``), the calibration.

Clouds (Step 1, ``simulate_sweeps``, mu 0.2): ``demo`` the paraboloid of launch/demo.yaml with
its 5 trails (~10^4 points); ``sphere`` the 0.3 m sphere with the same trails (the outer two miss
it); ``line`` the paraboloid with the y0 = 0.2 trail only; ``ellipsoid`` a posed ellipsoid with
7 trails; ``dense`` the paraboloid with 60 trails, ~10^5 points (not in the default list: it
adds about a minute and a half).

Threads: one BLAS thread (``OPENBLAS_NUM_THREADS`` etc. set to 1 unless already set), Open3D's
Poisson one thread (as the mapper runs it, for determinism). On this 2-core machine, shared with
other work, OpenBLAS's two threads made the GP's Cholesky factorisations 3-20 times slower and
erratic (a 1524 x 1524 factor: 0.13-0.77 s against 0.05 s on one thread). Not a test.

Usage: ``python benchmarks/bench_map.py [--clouds demo,sphere,line,ellipsoid,dense]
[--methods poisson,gp,rbf] [--repeat 3]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from scipy.spatial import Delaunay, cKDTree  # noqa: E402

from vibrissa.mapping import (  # noqa: E402
    MapSettings,
    contact_normals,
    gp_surface,
    line_spacing,
    too_little_for_a_surface,
)
from vibrissa.surfaces import Surface, parse_surface  # noqa: E402
from vibrissa.sweep import Trail, contact_lines, simulate_sweeps  # noqa: E402

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

PARABOLOID = "paraboloid:a=0.5,b=1,h=0.4"  # launch/demo.yaml
DEMO_TRAILS = (-0.4, -0.2, 0.0, 0.2, 0.4)
CLOUDS: dict[str, tuple[str, tuple[float, ...]]] = {
    "demo": (PARABOLOID, DEMO_TRAILS),
    "sphere": ("sphere:r=0.3,cx=0,cy=0,cz=0.8", DEMO_TRAILS),
    "line": (PARABOLOID, (0.2,)),
    "ellipsoid": ("ellipsoid:rx=0.4,ry=0.3,rz=0.2,cx=0.1,cy=-0.2,cz=0.9,roll=0.3,pitch=-0.2,"
                  "yaw=1.0", (-0.5, -0.4, -0.3, -0.2, -0.1, 0.0, 0.1)),
    "dense": (PARABOLOID, tuple(float(y) for y in np.linspace(-0.75, 0.75, 60))),
}
DEFAULT_CLOUDS = ("demo", "sphere", "line", "ellipsoid")
METHODS = ("poisson", "gp", "rbf")
MU = 0.2
STEP = 0.001
MAP = MapSettings()  # the mapper's box and grid
RBF_OFFSET = 0.01
"""Carr et al.'s off-surface offset delta, as a fraction of the cloud's radius."""


@dataclass(frozen=True)
class Cloud:
    """A contact cloud: points (N, 3) m in line order, outward normals (N, 3), line of each
    point (N,), the true surface."""

    name: str
    points: FloatArray
    normals: FloatArray
    lines: IntArray
    truth: Surface


@dataclass(frozen=True)
class Estimate:
    """What a method shows: vertices (V, 3) m and triangles (T, 3); ``total`` triangles of its
    whole mesh; the GP fit (for its std), else None."""

    vertices: FloatArray
    triangles: IntArray
    total: int
    gp: gp_surface.GPSurface | None = None
    all_vertices: FloatArray | None = None


def make_cloud(name: str) -> Cloud:
    """The cloud ``name`` of ``CLOUDS`` from Step 1."""
    spec, y0s = CLOUDS[name]
    truth = parse_surface(spec)
    p, f, ln = contact_lines(simulate_sweeps(truth, [Trail(y0, MU) for y0 in y0s], STEP))
    return Cloud(name, p, contact_normals(p, f, ln), ln, truth)


def box(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The mapper's meshing box of a cloud (``MapSettings.margin``)."""
    pad = MAP.margin * float(np.linalg.norm(np.ptp(points, axis=0)))
    return points.min(axis=0) - pad, points.max(axis=0) + pad


# --- the methods ----------------------------------------------------------------------------


# The mapper's former mesh, kept here as the baseline: screened Poisson on the oriented cloud,
# one thread (with more its parallel sums round differently from run to run), voxel-downsampled
# to a quarter of a Poisson cell, trimmed to trim_factor x the line spacing from the data.

@dataclass(frozen=True)
class FitParams:
    """Parameters of :func:`fit_surface`.

    Attributes
    ----------
    depth
        Octree depth of the Poisson reconstruction (cell = bounding box / 2**depth).
    trim_distance
        Drop mesh vertices farther than this from the cloud, units of the cloud (m); 0 = auto
        (``trim_factor`` x the typical spacing between lines).
    trim_factor
        Multiple of the line spacing kept around the data when ``trim_distance`` is 0.
    line_break
        Consecutive points farther apart than this many times the median spacing along the
        lines start a new line.
    """

    depth: int = 8
    trim_distance: float = 0.0
    trim_factor: float = 0.6
    line_break: float = 20.0


@dataclass(frozen=True)
class SurfaceFit:
    """A fitted mesh.

    Attributes
    ----------
    vertices : ndarray, shape (V, 3)
        In the cloud's frame and units.
    triangles : ndarray of int, shape (T, 3)
        Vertex indices.
    method : str
        Method and parameters, for ``SurfaceMesh.method`` and the report.
    trim_distance : float
        The trimming distance used, cloud units.
    line_spacing : float
        Estimated spacing between neighbouring lines, cloud units (inf with one line).
    """

    vertices: FloatArray
    triangles: IntArray
    method: str
    trim_distance: float
    line_spacing: float



def fit_surface(
    points: FloatArray,
    normals: FloatArray,
    lines: IntArray | None = None,
    params: FitParams | None = None,
) -> SurfaceFit:
    """Screened Poisson mesh of an oriented contact cloud, trimmed to the data (see module).

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
        Contact points and outward unit normals (:func:`contact_normals`).
    lines : ndarray of int, shape (N,), optional
        Line labels, for the automatic trimming distance; one line when omitted.
    params
        Fitting parameters.

    Returns
    -------
    SurfaceFit
        Empty (no vertices, ``method`` says why) for points that cannot carry a surface
        (``too_little_for_a_surface``).
    """
    params = params or FitParams()
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    lines = np.zeros(len(points), dtype=np.int64) if lines is None else lines
    spacing = line_spacing(points, lines) if len(points) else float("inf")
    extent = float(np.linalg.norm(np.ptp(points, axis=0))) if len(points) else 0.0
    trim = params.trim_distance or (
        params.trim_factor * spacing if np.isfinite(spacing) else 0.05 * extent
    )
    method = (f"poisson(depth={params.depth}, normals=contact force minus line tangent, "
              f"trim={trim:.4g})")
    too_little = too_little_for_a_surface(points)
    if too_little is not None:
        return SurfaceFit(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64),
                          f"none: {too_little}", trim, spacing)
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals)
    cloud = cloud.voxel_down_sample(extent / 2**params.depth / 4)
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        cloud, depth=params.depth, linear_fit=True, n_threads=1)
    vertices = np.asarray(mesh.vertices)
    distance = cKDTree(points).query(vertices)[0]
    mesh.remove_vertices_by_mask(distance > trim)
    mesh.remove_unreferenced_vertices()
    mesh.remove_degenerate_triangles()
    return SurfaceFit(np.asarray(mesh.vertices).copy(),
                      np.asarray(mesh.triangles).astype(np.int64), method, trim, spacing)



def run_poisson(cloud: Cloud) -> Estimate:
    fit = fit_surface(cloud.points, cloud.normals, cloud.lines)
    return Estimate(fit.vertices, fit.triangles, len(fit.triangles))


def run_gp(cloud: Cloud) -> Estimate:
    surface = gp_surface.fit(cloud.points, cloud.normals)
    lo, hi = box(cloud.points)
    mesh = gp_surface.mesh(surface, lo, hi, MAP.cells)
    vertices, triangles, _ = mesh.part(True)
    return Estimate(vertices, triangles, len(mesh.triangles), surface, mesh.vertices)


def run_rbf(cloud: Cloud) -> Estimate:
    """Carr et al. 2001 on the GP's active points, meshed on the GP's grid (see module)."""
    from scipy.interpolate import RBFInterpolator
    from skimage.measure import marching_cubes

    points = cloud.points
    center = points.mean(axis=0)
    scale = float(np.max(np.linalg.norm(points - center, axis=1)))
    u = (points - center) / scale
    n = cloud.normals / np.linalg.norm(cloud.normals, axis=1, keepdims=True)
    active = gp_surface.select_active(u, gp_surface.GPParams().max_active)
    u, n = u[active], n[active]
    delta = RBF_OFFSET  # units of the radius s
    rbf = RBFInterpolator(np.concatenate([u, u + delta * n, u - delta * n]),
                          np.concatenate([np.zeros(len(u)), np.full(len(u), delta),
                                          np.full(len(u), -delta)]),
                          kernel="thin_plate_spline", degree=1)
    lo, hi = box(points)
    cell = float(np.max(hi - lo)) / MAP.cells
    shape = np.ceil((hi - lo) / cell).astype(np.int64) + 1
    axes = [lo[i] + cell * np.arange(shape[i]) for i in range(3)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    f = rbf((nodes - center) / scale).reshape(*shape)
    if not (f.min() < 0 < f.max()):
        return Estimate(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0)
    vertices, triangles, _, _ = marching_cubes(f, 0.0, spacing=(cell, cell, cell))
    return Estimate(vertices.astype(np.float64) + lo, triangles.astype(np.int64), len(triangles))


RUNS: dict[str, Callable[[Cloud], Estimate]] = {"poisson": run_poisson, "gp": run_gp,
                                                "rbf": run_rbf}


# --- the measures ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Region:
    """The touched region of a cloud (see module): the mean normal ``axis``, the plane's basis
    e1, e2 and the hull of the projected points."""

    axis: FloatArray
    e1: FloatArray
    e2: FloatArray
    hull: Delaunay

    @classmethod
    def of(cls, cloud: Cloud) -> Region:
        axis = cloud.normals.mean(axis=0)
        axis /= np.linalg.norm(axis)
        e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        return cls(axis, e1, e2, Delaunay(np.c_[cloud.points @ e1, cloud.points @ e2]))

    def project(self, points: FloatArray) -> FloatArray:
        return np.c_[points @ self.e1, points @ self.e2]

    def inside(self, points: FloatArray, truth: Surface) -> NDArray[np.bool_]:
        """Which points (N, 3) are in the touched region."""
        if not len(points):
            return np.zeros(0, dtype=bool)
        facing = truth.normal(truth.closest_point(points)) @ self.axis > 0
        return facing & (self.hull.find_simplex(self.project(points)) >= 0)

    def grid(self, spacing: float) -> FloatArray:
        """Nodes (G, 2) of a square grid of ``spacing`` inside the hull, in the plane."""
        q = self.hull.points
        lo, hi = q.min(axis=0), q.max(axis=0)
        xs, ys = (np.arange(lo[i], hi[i] + spacing, spacing) for i in range(2))
        nodes = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
        return nodes[self.hull.find_simplex(nodes) >= 0]


@dataclass(frozen=True)
class Row:
    """One line of the table (see module); lengths in mm, shares in [0, 1]."""

    cloud: str
    points: int
    method: str
    seconds: float
    max_mm: float
    mean_mm: float
    cover: float
    out_max_mm: float
    same: bool
    triangles: int
    total: int
    three_sd: float


def measure(cloud: Cloud, region: Region, method: str, repeat: int) -> Row:
    """Time ``method`` on ``cloud`` (a warm-up, then ``repeat`` runs) and measure its first
    estimate against the truth."""
    run = RUNS[method]
    first = run(cloud)  # warm-up: compilation, imports
    times, same = [], True
    for _ in range(repeat):
        start = time.perf_counter()
        again = run(cloud)
        times.append(time.perf_counter() - start)
        same &= again.vertices.tobytes() == first.vertices.tobytes()
    est = first
    truth = cloud.truth
    inside = region.inside(est.vertices, truth)
    error = np.abs(truth.signed_distance(est.vertices)) if len(est.vertices) else np.zeros(0)
    touched = error[inside]
    outside = error[~inside]
    lo, hi = box(cloud.points)
    cell = float(np.max(hi - lo)) / MAP.cells
    nodes = region.grid(cell / 2)
    cover = 0.0
    if inside.any() and len(nodes):
        distance, _ = cKDTree(region.project(est.vertices[inside])).query(nodes)
        cover = float(np.mean(distance <= cell))
    three_sd = float("nan")
    if est.gp is not None and est.all_vertices is not None:
        on = truth.closest_point(est.all_vertices[region.inside(est.all_vertices, truth)])
        if len(on):
            f, _ = est.gp.evaluate(on)
            three_sd = float(np.mean(np.abs(f) <= 3 * est.gp.std(on)))
    return Row(cloud.name, len(cloud.points), method, float(np.median(times)),
               1e3 * float(touched.max()) if len(touched) else float("nan"),
               1e3 * float(touched.mean()) if len(touched) else float("nan"), cover,
               1e3 * float(outside.max()) if len(outside) else 0.0, same,
               len(est.triangles), est.total, three_sd)


def print_table(rows: list[Row]) -> None:
    base = {r.cloud: r.seconds for r in rows if r.method == "poisson"}
    header = (f"{'cloud':<10}{'points':>8} {'method':<8}{'time s':>8}{'x poisson':>10}"
              f"{'max mm':>9}{'mean mm':>9}{'cover %':>9}{'out max mm':>11}{'same':>6}"
              f"{'tris':>16}{'3sd %':>8}")
    print(header)
    print("-" * len(header))
    for r in rows:
        ratio = f"{r.seconds / base[r.cloud]:.2f}" if r.cloud in base else "-"
        tris = f"{r.triangles} ({r.total})" if r.method == "gp" else f"{r.triangles}"
        three = f"{100 * r.three_sd:.1f}" if np.isfinite(r.three_sd) else "-"
        print(f"{r.cloud:<10}{r.points:>8} {r.method:<8}{r.seconds:>8.3f}{ratio:>10}"
              f"{r.max_mm:>9.2f}{r.mean_mm:>9.3f}{100 * r.cover:>9.1f}{r.out_max_mm:>11.1f}"
              f"{'yes' if r.same else 'NO':>6}{tris:>16}{three:>8}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clouds", default=",".join(DEFAULT_CLOUDS),
                        help=f"comma-separated, of {', '.join(CLOUDS)}")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help=f"comma-separated, of {', '.join(METHODS)}")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs after the warm-up")
    args = parser.parse_args(argv)
    clouds = args.clouds.split(",")
    methods = args.methods.split(",")
    for name in clouds:
        if name not in CLOUDS:
            parser.error(f"unknown cloud {name!r}; known: {', '.join(CLOUDS)}")
    for name in methods:
        if name not in RUNS:
            parser.error(f"unknown method {name!r}; known: {', '.join(METHODS)}")
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1, got {args.repeat}")
    print(f"map benchmark: {os.cpu_count()} cores, BLAS threads "
          f"{os.environ['OPENBLAS_NUM_THREADS']}, time = fit + mesh, median of {args.repeat} "
          f"runs after a warm-up (compilation excluded); errors vs the true surface, mm (L = 1 m)")
    rows = []
    for name in clouds:
        start = time.perf_counter()
        cloud = make_cloud(name)
        print(f"  {name}: {CLOUDS[name][0]}, {len(np.unique(cloud.lines))} lines touching of "
              f"{len(CLOUDS[name][1])}, {len(cloud.points)} points "
              f"(Step 1: {time.perf_counter() - start:.1f} s)", flush=True)
        region = Region.of(cloud)
        rows += [measure(cloud, region, method, args.repeat) for method in methods]
    print()
    print_table(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
