"""Mapper node: accumulates contact points, fits a surface at end of stream, writes the map.

Subscribes
----------
``topics`` (default ``[contact]``) : ContactPoint or ContactPointArray
    Points in SI (m, N), each in its ``frame_id``; each row of an array is a point of its
    whisker; ``EndOfStream`` from every expected source ends the accumulation.

Publishes
---------
``cloud_topic`` (default ``contact_cloud``) : ContactCloud
    Every point with its contact normal, one message per ``frame_id``, then ``EndOfStream``.
``mesh_topic`` (default ``surface_mesh``) : SurfaceMesh
    The fitted mesh per ``frame_id`` (``method`` names the method and its parameters, the
    distance fields are filled when ``true_surface`` is given), then ``EndOfStream``.

Files in ``out_dir`` (for frame ``world``; another frame F gets the suffix ``_F``):
``cloud.ply`` (points + normals), ``mesh.ply``, ``map.png`` (cloud and mesh over the true
surface), ``report.json`` and ``report.txt``. Then the node exits 0 (the demo launch ends
on it with ``on_exit: shutdown``), or ``EXIT_EMPTY_MAP`` (3) when the streams ended without a
single contact point (only the reports are written, and they say so), or ``EXIT_LOST_DATA`` (4)
when input messages were lost (the report lists every input stream: sent, received, lost),
unless ``allow_loss``. Stopped (SIGINT,
SIGTERM) before the streams end, it writes nothing and exits 0; a stop during the fit ends
the process at once (Open3D does not return to Python until it is done).

Fitting: screened Poisson on contact normals taken from the contact force with its component
along the contact line removed, trimmed to the data; see ``vibrissa.nodes.surface_fit`` for
why. Errors against ``true_surface`` (a ``parse_surface`` spec in units of L, placed in the
points' frame): cloud -> surface = max/mean |signed distance| of the points (the
reconstruction error), mesh -> surface = max/mean over mesh vertices.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vibrissa.msgs import ContactCloud, ContactPoint, ContactPointArray, EndOfStream, SurfaceMesh
from vibrissa.nodes.surface_fit import (
    FitParams,
    SurfaceFit,
    contact_normals,
    fit_surface,
    split_lines,
    too_little_for_a_surface,
    write_ply,
)
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.node import EXIT_LOST_DATA
from vibrissa.runtime.params import require, require_non_negative, require_parsed, require_positive
from vibrissa.runtime.signals import default_actions
from vibrissa.surfaces import Surface, parse_surface
from vibrissa.units import RodScale
from vibrissa.wire.topics import resolve_topic, validate_name
from vibrissa.wire.transport import StreamEnd

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

EXIT_EMPTY_MAP = 3
"""Exit status of a mapper whose streams ended without a single contact point."""

MAX_DEPTH = 12
"""Deepest Poisson octree: 4096^3 cells, beyond what a contact cloud can fill."""


@dataclass(frozen=True)
class MapperParams:
    """Parameters of the mapper node.

    Attributes
    ----------
    topics
        ContactPoint / ContactPointArray topics, relative to the namespace unless absolute.
    expected_sources
        How many distinct ``EndOfStream`` sources end the accumulation, or their node names
        (relative names resolve in the namespace).
    out_dir
        Folder of the output files (created).
    true_surface
        Surface spec of the object, units of L, in the points' frame; empty: no error report.
    rod_length_m
        L, m (scales ``true_surface``); the mapper converts lengths only, so it needs no EI.
    depth, trim_distance_m, trim_factor
        Poisson octree depth; mesh trimming distance, m (0 = ``trim_factor`` x the spacing
        between contact lines); see ``vibrissa.nodes.surface_fit.FitParams``.
    timeout_s
        Fit what has arrived after this long without a message, s (0 = wait for the ends).
    plot
        Write ``map.png``.
    allow_loss
        Exit 0 even when input messages were lost (the report says so either way); by
        default a lossy map exits ``EXIT_LOST_DATA`` (4).
    cloud_topic, mesh_topic
        Output topics.
    wait_for
        Nodes that must subscribe to the outputs before they go out (default: nobody).
    rod
        L as ``vibrissa.units.RodScale`` (derived, not a parameter).
    """

    topics: tuple[str, ...] = ("contact",)
    expected_sources: int | tuple[str, ...] = 1
    out_dir: str = "out/mapper"
    true_surface: str = ""
    rod_length_m: float = 1.0
    depth: int = 8
    trim_distance_m: float = 0.0
    trim_factor: float = 0.6
    timeout_s: float = 0.0
    plot: bool = True
    allow_loss: bool = False
    cloud_topic: str = "contact_cloud"
    mesh_topic: str = "surface_mesh"
    wait_for: tuple[str, ...] = ()
    rod: RodScale = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        require_positive("rod_length_m", self.rod_length_m)
        object.__setattr__(self, "rod", RodScale(self.rod_length_m))
        require(len(self.topics) > 0, "topics", self.topics, "one or more topic names")
        for topic in self.topics:
            require_parsed("topics", topic, validate_name)
        for name in (self.cloud_topic, self.mesh_topic):
            require_parsed("cloud_topic/mesh_topic", name, validate_name)
        for name in self.wait_for:
            require_parsed("wait_for", name, validate_name)
        if isinstance(self.expected_sources, int):
            require(self.expected_sources >= 1, "expected_sources", self.expected_sources,
                    "a count >= 1 or a list of node names")
        else:
            for name in self.expected_sources:
                require_parsed("expected_sources", name, validate_name)
        require(bool(self.out_dir), "out_dir", self.out_dir, "a folder")
        if self.true_surface:
            require_parsed("true_surface", self.true_surface, parse_surface)
        require(1 <= self.depth <= MAX_DEPTH, "depth", self.depth,
                f"an octree depth in [1, {MAX_DEPTH}]")
        require_non_negative("trim_distance_m", self.trim_distance_m)
        require_non_negative("trim_factor", self.trim_factor)
        require_non_negative("timeout_s", self.timeout_s)


PARAMS = MapperParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


@dataclass
class FrameCloud:
    """Contact points of one frame, in arrival order."""

    whisker_ids: list[str] = field(default_factory=list)
    seqs: list[int] = field(default_factory=list)
    points: list[FloatArray] = field(default_factory=list)
    forces: list[FloatArray] = field(default_factory=list)

    def add(self, msg: ContactPoint | ContactPointArray) -> None:
        """Append every row of a message (a ContactPoint is one row), each with its whisker
        and the message's ``seq``."""
        whisker_ids = [msg.whisker_id] if isinstance(msg, ContactPoint) else msg.whisker_ids
        self.whisker_ids += whisker_ids
        self.seqs += [msg.seq] * len(whisker_ids)
        self.points += list(np.reshape(msg.point, (-1, 3)))
        self.forces += list(np.reshape(msg.force, (-1, 3)))

    def ordered(self) -> tuple[FloatArray, FloatArray, list[str]]:
        """Points (N, 3), forces (N, 3), whisker ids, sorted by (whisker, seq): line order."""
        order = sorted(range(len(self.seqs)), key=lambda i: (self.whisker_ids[i], self.seqs[i]))
        points = np.array([self.points[i] for i in order]).reshape(-1, 3)
        forces = np.array([self.forces[i] for i in order]).reshape(-1, 3)
        return points, forces, [self.whisker_ids[i] for i in order]


class Accumulator:
    """The mapper's state without sockets: points per frame and ended sources."""

    def __init__(self, expected: int | Sequence[str]) -> None:
        self.expected = expected
        self.frames: dict[str, FrameCloud] = {}
        self.ended: set[str] = set()

    def add(self, msg: object) -> None:
        """Take a ContactPoint, a ContactPointArray or an EndOfStream."""
        if isinstance(msg, ContactPoint) or (isinstance(msg, ContactPointArray)
                                             and msg.whisker_ids):  # not a tick without contact
            self.frames.setdefault(msg.frame_id, FrameCloud()).add(msg)
        elif isinstance(msg, EndOfStream):
            self.ended.add(msg.source)

    @property
    def done(self) -> bool:
        """Whether every expected source has ended."""
        if isinstance(self.expected, int):
            return len(self.ended) >= self.expected
        return set(self.expected) <= self.ended

    @property
    def n_points(self) -> int:
        """Points so far, all frames."""
        return sum(len(f.seqs) for f in self.frames.values())


@dataclass
class FrameResult:
    """Fit and errors of one frame (distances in m)."""

    frame_id: str
    n_points: int
    method: str
    n_vertices: int
    n_triangles: int
    line_spacing_m: float | None
    cloud_to_surface_max: float | None = None
    cloud_to_surface_mean: float | None = None
    mesh_to_surface_max: float | None = None
    mesh_to_surface_mean: float | None = None
    files: dict[str, str] = field(default_factory=dict)


def surface_errors(surface: Surface, rod: RodScale, points: FloatArray
                   ) -> tuple[float | None, float | None]:
    """Max and mean |signed distance| (m) of ``points`` (m) to ``surface`` (units of L)."""
    if len(points) == 0:
        return None, None
    distance = np.abs(surface.signed_distance(points / rod.length_m)) * rod.length_m
    return float(distance.max()), float(distance.mean())


def fit_frame(frame_id: str, cloud: FrameCloud, params: MapperParams,
              surface: Surface | None) -> tuple[FrameResult, SurfaceFit, FloatArray, FloatArray]:
    """Normals, fit and errors of one frame; returns (result, fit, points, normals)."""
    points, forces, _ = cloud.ordered()
    lines = split_lines(points)
    normals = contact_normals(points, forces, lines)
    fit = fit_surface(points, normals, lines, FitParams(
        depth=params.depth, trim_distance=params.trim_distance_m,
        trim_factor=params.trim_factor))
    result = FrameResult(
        frame_id, len(points), fit.method, len(fit.vertices), len(fit.triangles),
        fit.line_spacing if np.isfinite(fit.line_spacing) else None)
    if surface is not None:
        result.cloud_to_surface_max, result.cloud_to_surface_mean = surface_errors(
            surface, params.rod, points)
        result.mesh_to_surface_max, result.mesh_to_surface_mean = surface_errors(
            surface, params.rod, fit.vertices)
    return result, fit, points, normals


def plot_map(path: Path, points: FloatArray, fit: SurfaceFit, surface: Surface | None,
             rod: RodScale, title: str) -> None:
    """PNG of the cloud (dots) and the mesh (surface) over the true surface (wireframe)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(9, 7))
    ax: Any = fig.add_subplot(projection="3d")
    if surface is not None and too_little_for_a_surface(points) is None:
        # A grid over the cloud's principal plane, projected onto the true surface.
        center = points.mean(axis=0)
        _, _, axes = np.linalg.svd(points - center, full_matrices=False)
        uv = (points - center) @ axes[:2].T
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        pad = 0.1 * (hi - lo)
        gu, gv = np.meshgrid(np.linspace(lo[0] - pad[0], hi[0] + pad[0], 25),
                             np.linspace(lo[1] - pad[1], hi[1] + pad[1], 25))
        grid = center + gu.reshape(-1, 1) * axes[0] + gv.reshape(-1, 1) * axes[1]
        on = surface.closest_point(grid / rod.length_m) * rod.length_m
        xs, ys, zs = (on[:, k].reshape(gu.shape) for k in range(3))
        ax.plot_wireframe(xs, ys, zs, color="0.6", linewidth=0.5, label="true surface")
    if len(fit.triangles):
        v = fit.vertices
        ax.plot_trisurf(v[:, 0], v[:, 1], v[:, 2], triangles=fit.triangles, color="tab:orange",
                        alpha=0.45, linewidth=0, shade=True)
    if len(points):
        shown = points[:: max(1, len(points) // 4000)]
        ax.scatter(shown[:, 0], shown[:, 1], shown[:, 2], s=1.5, c="tab:blue", depthshade=False,
                   label=f"contacts ({len(points)})")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _suffix(frame_id: str) -> str:
    """File name suffix of a frame: ``""`` for ``world``, ``_<frame_id>`` for a short name of
    letters, digits, ``-`` and ``_``, else a cut-down name with a hash of the whole id, so that
    any two frames get distinct files and every name fits the file system."""
    if frame_id == "world":
        return ""
    safe = "".join(c if c.isascii() and (c.isalnum() or c in "-_") else "_" for c in frame_id)
    if safe == frame_id and len(frame_id) <= 64:
        return f"_{frame_id}"
    return f"_{safe[:40]}-{hashlib.sha1(frame_id.encode()).hexdigest()[:10]}"


@contextmanager
def _whole(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to, renamed to ``path`` once written and
    removed if writing fails (e.g. a full disk): a reader never sees half a file."""
    partial = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        yield partial
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def write_outputs(acc: Accumulator, params: MapperParams, out_dir: Path,
                  streams: Sequence[StreamEnd] = (), lost: int = 0,
                  ) -> tuple[dict[str, Any], list[tuple[ContactCloud, SurfaceMesh]]]:
    """Fit every frame, write PLYs, PNGs and the reports; returns (report, messages).

    ``streams`` are the input streams that ended (what each said was sent, what arrived,
    what was lost) and ``lost`` the input messages lost in all, for the report.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    surface = parse_surface(params.true_surface) if params.true_surface else None
    results: list[FrameResult] = []
    messages: list[tuple[ContactCloud, SurfaceMesh]] = []
    for frame_id, cloud in sorted(acc.frames.items()):
        t0 = time.monotonic()
        result, fit, points, normals = fit_frame(frame_id, cloud, params, surface)
        sfx = _suffix(frame_id)
        files = {"cloud": out_dir / f"cloud{sfx}.ply"}
        with _whole(files["cloud"]) as partial:
            write_ply(str(partial), points, normals=normals)
        if len(fit.vertices):
            files["mesh"] = out_dir / f"mesh{sfx}.ply"
            with _whole(files["mesh"]) as partial:
                write_ply(str(partial), fit.vertices, fit.triangles)
        else:
            log.warning("no surface for frame %r: %s (the cloud is written)", frame_id,
                        fit.method.removeprefix("none: "))
        if params.plot:
            files["png"] = out_dir / f"map{sfx}.png"
            with _whole(files["png"]) as partial:
                plot_map(partial, points, fit, surface, params.rod,
                         f"{frame_id}: {len(points)} contacts, {fit.method}")
        result.files = {k: str(v) for k, v in files.items()}
        results.append(result)
        stamp = time.time()
        messages.append((
            ContactCloud(stamp=stamp, frame_id=frame_id, points=points, normals=normals,
                         whisker_ids=cloud.ordered()[2]),
            SurfaceMesh(stamp=stamp, frame_id=frame_id, vertices=fit.vertices,
                        triangles=fit.triangles.astype(np.int32), method=fit.method,
                        n_points=len(points),
                        cloud_to_surface_max=result.cloud_to_surface_max,
                        cloud_to_surface_mean=result.cloud_to_surface_mean,
                        mesh_to_surface_max=result.mesh_to_surface_max,
                        mesh_to_surface_mean=result.mesh_to_surface_mean),
        ))
        log.info("fitted %s: %d points -> %d triangles in %.1f s", frame_id, len(points),
                 len(fit.triangles), time.monotonic() - t0)
    report: dict[str, Any] = {
        "n_points": acc.n_points,
        "sources_ended": sorted(acc.ended),
        "true_surface": params.true_surface or None,
        "rod_length_m": params.rod_length_m,
        "max_reconstruction_error_m": max(
            (r.cloud_to_surface_max for r in results if r.cloud_to_surface_max is not None),
            default=None),
        "frames": [asdict(r) for r in results],
        "lost": lost,
        "streams": [asdict(stream) for stream in streams],
    }
    report_json = out_dir / "report.json"
    report_txt = out_dir / "report.txt"
    report["files"] = {"report_json": str(report_json), "report_txt": str(report_txt)}
    with _whole(report_json) as partial:
        partial.write_text(json.dumps(report, indent=2) + "\n")
    with _whole(report_txt) as partial:
        partial.write_text(format_report(report))
    return report, messages


def format_report(report: dict[str, Any]) -> str:
    """The human-readable report."""
    def mm(value: float | None) -> str:
        return "n/a" if value is None else f"{value * 1e3:.4g} mm"

    empty = " - THE MAP IS EMPTY" if report["n_points"] == 0 else ""
    lines = [f"contact points: {report['n_points']}{empty} (sources: "
             f"{', '.join(report['sources_ended']) or 'none ended'})",
             f"true surface: {report['true_surface'] or 'not given'} "
             f"(L = {report['rod_length_m']} m)",
             f"max reconstruction error (cloud -> true surface): "
             f"{mm(report['max_reconstruction_error_m'])}"]
    if report["lost"]:
        lines.append(f"LOST: {report['lost']} contact message(s) never arrived")
    for stream in report["streams"]:
        lines.append(f"input {stream['topic']} from {stream['source']}: {stream['sent']} sent, "
                     f"{stream['received']} received, {stream['lost']} lost")
    for frame in report["frames"]:
        lines += [
            f"frame {frame['frame_id']}: {frame['n_points']} points",
            f"  method: {frame['method']}",
            f"  mesh: {frame['n_vertices']} vertices, {frame['n_triangles']} triangles",
            f"  cloud -> surface: max {mm(frame['cloud_to_surface_max'])}, "
            f"mean {mm(frame['cloud_to_surface_mean'])}",
            f"  mesh -> surface:  max {mm(frame['mesh_to_surface_max'])}, "
            f"mean {mm(frame['mesh_to_surface_mean'])}",
        ]
        lines += [f"  {name}: {path}" for name, path in frame["files"].items()]
    return "\n".join(lines) + "\n"


def run(node: Node, params: MapperParams) -> dict[str, Any] | None:
    """Accumulate until every source ended (or ``timeout_s`` idle), then map; the report
    (``None`` when stopped before the streams ended: nothing is fitted or written)."""
    expected: int | list[str] = (
        params.expected_sources if isinstance(params.expected_sources, int)
        else [resolve_topic(n, node.namespace) for n in params.expected_sources])
    acc = Accumulator(expected)
    subscriber = node.create_subscriber(
        {t: (ContactPoint, ContactPointArray) for t in params.topics}, hwm=200_000)
    cloud_pub = node.create_publisher(params.cloud_topic, ContactCloud, wait_for=params.wait_for)
    mesh_pub = node.create_publisher(params.mesh_topic, SurfaceMesh, wait_for=params.wait_for)
    node.set_state("running", f"waiting for {expected} source(s) to end")
    last = time.monotonic()
    while not node.stop_requested and not acc.done:
        rx = subscriber.receive(0.1)
        if rx is not None:
            acc.add(rx.msg)
            last = time.monotonic()
        elif params.timeout_s > 0 and time.monotonic() - last > params.timeout_s:
            log.warning("%s: nothing for %.1f s; mapping what arrived (ended: %s)", node.fqn,
                        params.timeout_s, sorted(acc.ended))
            break
    if node.stop_requested:
        log.warning("%s: stopped before the end of the streams: no map written (%d contact "
                    "points received, sources ended: %s)", node.fqn, acc.n_points,
                    ", ".join(sorted(acc.ended)) or "none")
        return None
    node.set_state("running", f"fitting {acc.n_points} points")
    with default_actions():  # Open3D holds the interpreter while fitting: a stop ends us at once
        report, messages = write_outputs(acc, params, Path(params.out_dir),
                                         list(subscriber.ended_streams),
                                         subscriber.totals()["lost"])
    if report["lost"]:
        log.error("%s: %d contact message(s) were lost on the way to the map%s", node.fqn,
                  report["lost"], " (allowed: allow_loss)" if params.allow_loss else "")
    for cloud, mesh in messages:
        cloud_pub.publish(cloud)
        mesh_pub.publish(mesh)
    cloud_pub.publish_end_of_stream(node.fqn)
    mesh_pub.publish_end_of_stream(node.fqn)
    if report["n_points"] == 0:
        log.error("%s: the map is empty: no contact point arrived (sources ended: %s); a "
                  "trail whose straight rod clears the object never touches it, see the "
                  "wrench source's log", node.fqn, ", ".join(sorted(acc.ended)) or "none")
    print(f"map of {report['n_points']} contact points written to {params.out_dir}:",
          flush=True)
    for frame in report["frames"]:
        for path in frame["files"].values():
            print(f"  {path}", flush=True)
    for path in report["files"].values():
        print(f"  {path}", flush=True)
    print(format_report(report), end="", flush=True)
    return report


def main(argv: Sequence[str] | None = None) -> int:
    """Run the mapper node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.mapper")
    configure_logging()
    params = load_params(MapperParams, args.params_file, args.params)
    Path(params.out_dir).mkdir(parents=True, exist_ok=True)  # fail now, not after the sweeps
    with Node.from_args(args) as node:
        report = run(node, params)
    if report is not None and report["n_points"] == 0:
        return EXIT_EMPTY_MAP
    if report is not None and report["lost"] and not params.allow_loss:
        return EXIT_LOST_DATA
    return 0


if __name__ == "__main__":
    run_main(main)
