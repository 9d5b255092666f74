"""``vibrissa simulate SCENE.yaml -o DIR [--workers N]``: Step 1 of a robot's whiskers along its
path past objects placed in the world (``vibrissa.scene``), in SI.

SCENE.yaml (world frame W, z up)::

    mu: 0.25
    objects:
      - {name: ball, shape: sphere, radius_m: 0.03, position_m: [0.13, 0.03, 0.05],
         quaternion_xyzw: [0, 0, 0, 1]}
      # ellipsoid: semi_axes_m: [a, b, c]; paraboloid: a_per_m, b_per_m, h_m
    whiskers:
      - {name: w0, length_m: 0.05, ei_nm2: 2.0e-5,
         mount: {position_m: [0.01, -0.02, 0.0], quaternion_xyzw: [0.17, 0, 0, 0.98]}}
    path: path.csv        # columns t,x,y,z,qx,qy,qz,qw: robot poses X_WR; relative to the scene

Output: ``DIR/<whisker>.csv`` (``SCENE_COLUMNS``, one row per path sample) and
``DIR/summary.json`` (per whisker: contact episodes, phase changes, samples per phase).

Also Step 2 of such a scene offline: ``vibrissa reconstruct WRENCHES.csv --scene SCENE.yaml -o
POINTS.csv`` (``WRENCH_COLUMNS`` in, ``POINT_COLUMNS`` out, row for row).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from vibrissa.cli import tables
from vibrissa.cli.tables import cell, write_csv
from vibrissa.frames import Transform
from vibrissa.scene import (
    SHAPES,
    RobotPath,
    SamplePhase,
    Scene,
    SceneObject,
    Whisker,
    WhiskerResult,
    reconstruct_along,
    robot_path,
    simulate,
)
from vibrissa.status import ContactPhase

FloatArray = NDArray[np.float64]

SCENE_COLUMNS: dict[str, tuple[str, str]] = {
    "t": ("s", "time of the path sample"),
    "phase": ("-", "none, tip, tangential or unresolved (the straight rod inside an object "
                   "after a snap-off, or a sample Step 1 stepped over)"),
    "s1": ("m", "arc length from the clamp to the contact (empty without one)"),
    "f0x": ("N", "clamp reaction force on the rod, in the clamp frame C, x"),
    "f0y": ("N", "clamp reaction force, C's y"),
    "f0z": ("N", "clamp reaction force, C's z (the rod's axis at the clamp)"),
    "m0x": ("N m", "clamp reaction moment on the rod about the clamp point, C's x"),
    "m0y": ("N m", "clamp reaction moment, C's y"),
    "m0z": ("N m", "clamp reaction moment, C's z (0: no twist)"),
    "px": ("m", "true contact point in W, x (empty without one)"),
    "py": ("m", "true contact point in W, y"),
    "pz": ("m", "true contact point in W, z"),
    "object": ("-", "name of the object touched (empty: none)"),
}
"""The columns of ``DIR/<whisker>.csv``: (unit, meaning)."""

_OBJECT_SIZES = {"sphere": ("radius_m",), "ellipsoid": ("semi_axes_m",),
                 "paraboloid": ("a_per_m", "b_per_m", "h_m")}
_PATH_COLUMNS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")


class SceneError(ValueError):
    """A scene or path file that cannot be used; the message names the file and the key or
    row."""


def load_scene(path: str | Path) -> Scene:
    """Read SCENE.yaml and its path CSV into a `vibrissa.scene.Scene`; `SceneError` names the
    file and the key (or row) of the first problem."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise SceneError(f"{path}: {exc}") from None
    where = path.name
    body = _mapping(doc, where, ("mu", "objects", "whiskers", "path"), ("mu", "whiskers", "path"))
    mu = _number(body["mu"], f"{where}: mu")
    objects = tuple(_object(item, f"{where}: objects[{i}]")
                    for i, item in enumerate(_list(body.get("objects", []), f"{where}: objects")))
    whiskers = tuple(_whisker(item, f"{where}: whiskers[{i}]")
                     for i, item in enumerate(_list(body["whiskers"], f"{where}: whiskers")))
    if not isinstance(body["path"], str):
        raise SceneError(f"{where}: path: expected a file name, got {body['path']!r}")
    try:
        return Scene(mu, objects, whiskers, load_path(path.parent / body["path"]))
    except SceneError:
        raise
    except ValueError as exc:
        raise SceneError(f"{where}: {exc}") from None


def load_path(path: Path) -> RobotPath:
    """Read a path CSV (``t,x,y,z,qx,qy,qz,qw``) into a `RobotPath`."""
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path}: {exc}") from None
    if not rows or [c.strip() for c in rows[0]] != list(_PATH_COLUMNS):
        raise SceneError(f"{path.name}: the header must be {','.join(_PATH_COLUMNS)}, got "
                         f"{','.join(rows[0]) if rows else 'an empty file'}")
    values = np.empty((len(rows) - 1, 8))
    for i, row in enumerate(rows[1:]):
        if len(row) != 8:
            raise SceneError(f"{path.name}: row {i + 1}: expected 8 values, got {len(row)}")
        try:
            values[i] = [float(cell) for cell in row]
        except ValueError:
            raise SceneError(f"{path.name}: row {i + 1}: not a number in {row}") from None
        if not np.all(np.isfinite(values[i])):
            raise SceneError(f"{path.name}: row {i + 1}: values must be finite, got {row}")
    try:
        return robot_path(values[:, 0], values[:, 1:4], values[:, 4:8])
    except ValueError as exc:
        raise SceneError(f"{path.name}: {exc}") from None


def _mapping(value: Any, where: str, allowed: tuple[str, ...], required: tuple[str, ...]
             ) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise SceneError(f"{where}: expected a mapping, got {type(value).__name__}")
    for key in value:
        if key not in allowed:
            raise SceneError(f"{where}: unknown key {key!r} (allowed: {', '.join(allowed)})")
    for key in required:
        if key not in value:
            raise SceneError(f"{where}: missing {key!r}")
    return value


def _list(value: Any, where: str) -> list[Any]:
    if not isinstance(value, list):
        raise SceneError(f"{where}: expected a list, got {type(value).__name__}")
    return value


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise SceneError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _vector(value: Any, where: str, n: int) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise SceneError(f"{where}: expected {n} numbers, got {value!r}")
    return [_number(v, f"{where}[{i}]") for i, v in enumerate(value)]


def _pose(body: dict[str, Any], where: str) -> Transform:
    position = _vector(body.get("position_m", [0.0, 0.0, 0.0]), f"{where}.position_m", 3)
    q = _vector(body.get("quaternion_xyzw", [0.0, 0.0, 0.0, 1.0]), f"{where}.quaternion_xyzw", 4)
    norm = float(np.linalg.norm(q))
    if not abs(norm - 1.0) <= 1e-6:
        raise SceneError(f"{where}.quaternion_xyzw: {q} is not a unit quaternion (norm {norm:.9g})")
    return Transform.from_quaternion(q, position)


def _object(value: Any, where: str) -> SceneObject:
    shape = value.get("shape") if isinstance(value, dict) else None
    if shape not in SHAPES:
        raise SceneError(f"{where}.shape: expected one of {', '.join(SHAPES)}, got {shape!r}")
    sizes = _OBJECT_SIZES[shape]
    body = _mapping(value, where, ("name", "shape", *sizes, "position_m", "quaternion_xyzw"),
                    ("name", "shape", *sizes))
    values: dict[str, Any] = {}
    for key in sizes:
        values[key] = (_vector(body[key], f"{where}.{key}", 3) if key == "semi_axes_m"
                       else _number(body[key], f"{where}.{key}"))
    try:
        return SceneObject(str(body["name"]), shape, values, _pose(body, where))
    except ValueError as exc:
        raise SceneError(f"{where}: {exc}") from None


def _whisker(value: Any, where: str) -> Whisker:
    body = _mapping(value, where, ("name", "length_m", "ei_nm2", "mount"),
                    ("name", "length_m", "ei_nm2"))
    length, ei = _number(body["length_m"], f"{where}.length_m"), _number(body["ei_nm2"], f"{where}.ei_nm2")
    if not (length > 0 and ei > 0):
        raise SceneError(f"{where}: length_m and ei_nm2 must be > 0, got {length}, {ei}")
    mount = _mapping(body.get("mount", {}), f"{where}.mount", ("position_m", "quaternion_xyzw"), ())
    return Whisker(str(body["name"]), length, ei, _pose(mount, f"{where}.mount"))


def write_results(out: Path, scene: Scene, results: list[WhiskerResult]) -> list[Path]:
    """``<whisker>.csv`` per whisker and ``summary.json``; returns the files written."""
    written = []
    names = [obj.name for obj in scene.objects]
    for result in results:
        rows = (
            [cell(result.t[i]), SamplePhase(result.phase[i]).label, cell(result.s1_m[i]),
             *(cell(v) for v in result.f0_n[i]), *(cell(v) for v in result.m0_nm[i]),
             *(cell(v) for v in result.p_W_m[i]),
             names[result.object[i]] if result.object[i] >= 0 else ""]
            for i in range(len(result.t))
        )
        target = out / f"{result.name}.csv"
        write_csv(target, tuple(SCENE_COLUMNS), rows)
        written.append(target)
    summary = {
        "units": {"t": "s", "length": "m", "force": "N", "moment": "N m",
                  "wrench": "clamp reaction on the rod about the clamp point, in the clamp frame"},
        "whiskers": {
            r.name: {
                "episodes": [{"object": e.object, "t_first_contact": e.t_first_contact,
                              "end": e.end,
                              "phase_changes": [{"t": t, "from": a, "to": b}
                                                for t, a, b in e.phase_changes]}
                             for e in r.episodes],
                "samples_per_phase": r.counts(),
            }
            for r in results
        },
    }
    target = out / "summary.json"
    target.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    written.append(target)
    return written


def print_sample_progress(whisker: str, sample: int, samples: int) -> None:
    """A worker's progress line on stderr (module level: worker processes unpickle it)."""
    print(f"  {whisker}: sample {sample} of {samples}", file=sys.stderr, flush=True)


def run_simulate(args: argparse.Namespace) -> int:
    """The ``simulate`` subcommand."""
    scene = load_scene(args.scene)
    total = len(scene.whiskers)
    samples = len(scene.path.t)
    print(f"simulating {total} whisker(s) x {samples} path samples past "
          f"{len(scene.objects)} object(s)", file=sys.stderr, flush=True)

    def progress(done: int, _total: int) -> None:
        if done:
            print(f"  {done}/{total} whiskers done", file=sys.stderr, flush=True)

    results = simulate(scene, workers=args.workers, progress=progress,
                       sample_progress=print_sample_progress)
    for path in write_results(Path(args.out), scene, results):
        print(f"wrote {path}")
    return 0


WRENCH_COLUMNS = ("t", "whisker", "f0x", "f0y", "f0z", "m0x", "m0y", "m0z")
"""The columns ``vibrissa reconstruct WRENCHES.csv --scene`` reads (more are ignored)."""

POINT_COLUMNS = {
    "t": ("s", "the input row's time"),
    "whisker": ("-", "the input row's whisker"),
    "px": ("m", "contact point, x in W (empty: no consistent contact)"),
    "py": ("m", "contact point, y in W"),
    "pz": ("m", "contact point, z in W"),
    "s1": ("m", "arc length of the contact from the clamp"),
    "phase": ("-", "none, tip or tangential"),
    "status": ("-", "ok, the ContactStatus flags joined by |, or no_pose (t outside the path)"),
}
"""The columns of POINTS.csv: (unit, meaning)."""


def read_wrenches(path: Path) -> tuple[list[str], FloatArray, list[str], FloatArray, FloatArray]:
    """WRENCHES.csv: the t texts, t (s), whisker names, f0 (N) and m0 (N m) in clamp frames;
    `SceneError` names the file and the column or row. An empty wrench cell is a missing value
    (Step 2 flags it ``non_finite_input``)."""
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path}: {exc}") from None
    header = [c.strip() for c in rows[0]] if rows else []
    missing = [name for name in WRENCH_COLUMNS if name not in header]
    if missing:
        raise SceneError(f"{path.name}: missing column(s) {', '.join(missing)} (the columns are "
                         f"{','.join(WRENCH_COLUMNS)})")
    at = {name: header.index(name) for name in WRENCH_COLUMNS}
    t_text, names = [], []
    values = np.empty((len(rows) - 1, 7))
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise SceneError(f"{path.name}: row {i + 1}: expected {len(header)} values, "
                             f"got {len(row)}")
        t_text.append(row[at["t"]].strip())
        names.append(row[at["whisker"]].strip())
        for j, name in enumerate(("t", *WRENCH_COLUMNS[2:])):
            text = row[at[name]].strip()
            try:
                values[i, j] = float(text) if text or name != "t" else math.nan
            except ValueError:
                raise SceneError(f"{path.name}: row {i + 1}, column {name}: {text!r} is not a "
                                 f"number") from None
        if not math.isfinite(values[i, 0]):
            raise SceneError(f"{path.name}: row {i + 1}: t must be a finite number")
    return t_text, values[:, 0], names, values[:, 1:4], values[:, 4:7]


def run_reconstruct(args: argparse.Namespace) -> int:
    """``vibrissa reconstruct WRENCHES.csv --scene SCENE.yaml -o POINTS.csv``."""
    scene = load_scene(args.scene)
    t_text, t, names, f0, m0 = read_wrenches(Path(args.input))
    try:
        rec = reconstruct_along(scene, t, names, f0, m0)
    except ValueError as exc:
        raise SceneError(f"{Path(args.input).name}: {exc}") from None
    status = [tables.status_name(int(rec.status[i])) if rec.pose_ok[i] else "no_pose"
              for i in range(len(t))]
    rows = ([t_text[i], names[i], *(cell(v) for v in rec.point_m[i]), cell(rec.s1_m[i]),
             ContactPhase(rec.phase[i]).label, status[i]] for i in range(len(t)))
    write_csv(Path(args.output), tuple(POINT_COLUMNS), rows)
    found = int(np.sum(np.isfinite(rec.point_m[:, 0])))
    counts = Counter(name for name in status if name not in ("ok", "axial_load"))
    line = f"reconstruct: {len(t)} rows, {found} with a contact"
    if counts:
        line += f", {sum(counts.values())} without (" + ", ".join(
            f"{name}: {n}" for name, n in sorted(counts.items())) + ")"
    print(f"{line} -> {args.output}", file=sys.stderr)
    return 0


def _workers(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def register(subparsers: Any) -> None:
    """Add the ``simulate`` subcommand to the ``vibrissa`` dispatcher."""
    columns = "\n".join(f"  {name} [{unit}]: {meaning}"
                        for name, (unit, meaning) in SCENE_COLUMNS.items())
    parser = subparsers.add_parser(
        "simulate",
        help="Step 1 of a robot's whiskers along its path past objects (SCENE.yaml, SI)",
        description=f"{__doc__.split(chr(10))[0]}\n\nColumns of DIR/<whisker>.csv:\n{columns}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("scene", metavar="SCENE.yaml")
    parser.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--workers", type=_workers, default=None, metavar="N",
                        help="processes for the whiskers (default: all cores)")
    parser.set_defaults(func=run_simulate)
