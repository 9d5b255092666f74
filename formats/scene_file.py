"""Scene files (SCENE.yaml and its path CSV) and robot descriptions, read strictly: every
error names the file and the key or row.

A scene file (SI, world frame W, z up) holds ``mu``, ``objects`` (name, shape sphere |
ellipsoid | paraboloid, sizes, ``position_m``, ``quaternion_xyzw``), ``whiskers`` (name,
``length_m``, ``ei_nm2``, ``mount`` X_RC, optionally ``sensor`` X_CS: the force/torque
sensor's frame in the clamp frame, identity when left out, and the rod's ``taper_ratio``,
``precurvature_1pm`` and ``poisson_ratio``: `vibrissa.scene.Whisker`) and ``path`` (a
CSV ``t,x,y,z,qx,qy,qz,qw`` of robot poses X_WR, relative to the scene file), and optionally
``explore`` (`load_explore`: the start pose, workspace box and body radius of an exploration;
a file with ``explore`` may leave ``path`` out, and then stands still at the start). Its ``whiskers`` are also the robot
description the nodes load (`load_robot`): one file, one truth.

The YAML is read strictly (`vibrissa.formats.yaml_numbers.load_strict`: no aliases, no repeated
keys, only ``true``/``false`` as booleans). Names of whiskers and objects are `NAME_RULE`'s:
they become file names (``vibrissa simulate``) and frame names (``<whisker>/clamp``). Numbers
must be within `LIMITS` (a rod of 1e308 m is a typo, and its units overflow).
"""

from __future__ import annotations

import re
from array import array
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vibrissa.exploration import Explore
from vibrissa.formats import yaml_numbers
from vibrissa.formats.csv_text import csv_records
from vibrissa.formats.errors import SceneError
from vibrissa.formats.files import read_text
from vibrissa.frames import Transform, non_unit_quaternion
from vibrissa.scene import SHAPES, RobotPath, Scene, SceneObject, Whisker, robot_path
from vibrissa.units import finite_number, number_text

__all__ = ["LIMITS", "NAME_RULE", "SceneError", "check_name", "load_explore", "load_path",
           "load_robot", "load_scene", "scene_files", "shown"]

_OBJECT_SIZES = {"sphere": ("radius_m",), "ellipsoid": ("semi_axes_m",),
                 "paraboloid": ("a_per_m", "b_per_m", "h_m")}
_PATH_COLUMNS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")
_SCENE_KEYS = ("mu", "objects", "whiskers", "path", "explore")
MAX_PATH_ROWS = 10_000_000
"""Rows of a path CSV at most (2.8 h at 1 kHz; 640 MB as floats): a file that is not a path,
or a pipe that never ends, is refused, not read without end."""

NAME_RULE = "1-64 of A-Z a-z 0-9 _ - ., not starting with . or -"
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")

LIMITS = {"length_m": (1e-4, 10.0), "ei_nm2": (1e-15, 1e4), "size_m": (1e-6, 1e6),
          "per_m": (1e-6, 1e6), "position_m": (-1e7, 1e7), "mu": (0.0, 10.0)}
"""Closed ranges of a scene's numbers: rod length L, m; bending stiffness EI, N m^2 (a 50-um
nylon hair is ~1e-9, a 5-mm steel rod ~6); an object's radius and semi-axes, m; a paraboloid's
curvatures a_per_m, b_per_m, 1/m; any position (objects, mounts, sensors, path, and a
paraboloid's vertex height h_m), m; the friction coefficient. Within them no unit conversion
or square overflows."""


def load_scene(path: str | Path) -> Scene:
    """Read SCENE.yaml and its path CSV into a `vibrissa.scene.Scene`; `SceneError` names the
    file and the key (or row) of the first problem. A file with ``explore`` and without
    ``path`` has the path of one sample at the start pose (`vibrissa.exploration.Explore.start_path`)."""
    path = Path(path)
    doc = _read_yaml(path)
    where = path.name
    body = _mapping(doc, where, _SCENE_KEYS,
                    ("mu", "whiskers") if isinstance(doc, dict) and "explore" in doc
                    else ("mu", "whiskers", "path"))
    mu = _number(body["mu"], f"{where}: mu", "mu")
    objects = tuple(_object(item, f"{where}: objects[{i}]")
                    for i, item in enumerate(_list(body.get("objects", []), f"{where}: objects")))
    whiskers = _whiskers(body["whiskers"], where)
    explore = _explore(body["explore"], where) if "explore" in body else None
    if "path" not in body:
        assert explore is not None  # required above otherwise
        robot = explore.start_path()
    elif not isinstance(body["path"], str):
        raise SceneError(f"{where}: path: expected a file name, got {shown(body['path'])}")
    else:
        try:
            robot = load_path(path.parent / body["path"])
        except SceneError as exc:
            raise SceneError(f"{where}: path: {exc}") from None
    if explore is not None and (entered := explore.objects_in_body(objects)):
        raise SceneError(
            f"{where}: explore.start: the robot's body (a vertical cylinder of radius "
            f"{explore.body_radius_m} m around base_link, at the workspace's heights) is inside "
            f"{', '.join(repr(name) for name in entered)} at the start; it must never enter an "
            "object: move the start or the object")
    try:
        return Scene(mu, objects, whiskers, robot)
    except ValueError as exc:
        raise SceneError(f"{where}: {exc}") from None


def scene_files(path: str | Path) -> list[Path]:
    """The files a scene is read from: SCENE.yaml and its path CSV when it has one (as
    `load_scene` found them; call it after `load_scene`)."""
    path = Path(path)
    doc = _read_yaml(path)
    return [path] + ([path.parent / doc["path"]] if "path" in doc else [])


def load_explore(path: str | Path) -> Explore | None:
    """The ``explore`` key of a scene file (`vibrissa.exploration.Explore`), or None when it has
    none; the rest of the file is not read beyond its top-level keys."""
    path = Path(path)
    body = _mapping(_read_yaml(path), path.name, _SCENE_KEYS, ())
    return _explore(body["explore"], path.name) if "explore" in body else None


def load_robot(path: str | Path) -> tuple[Whisker, ...]:
    """The robot description: the ``whiskers`` of a scene file (or of a file holding only
    them), each with its name, ``length_m``, ``ei_nm2``, ``mount`` and ``sensor``; the rest of a scene
    file is not read."""
    path = Path(path)
    doc = _read_yaml(path)
    if not isinstance(doc, dict) or "whiskers" not in doc:
        raise SceneError(f"{path.name}: missing 'whiskers' (a robot description lists them)")
    return _whiskers(doc["whiskers"], path.name)


def _read_yaml(path: Path) -> Any:
    text = read_text(path)  # bounded; its errors name the file
    try:
        return yaml_numbers.load_strict(text)
    except RecursionError:
        raise SceneError(f"{path.name}: nested too deeply") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise SceneError(f"{path.name}: {where}{exc.problem or exc.context or 'invalid YAML'}"
                         ) from None
    except yaml.YAMLError as exc:
        raise SceneError(f"{path.name}: invalid YAML: {exc}") from None


def check_name(name: Any, where: str) -> str:
    """``name`` if it is a text by `NAME_RULE`, else `SceneError` naming ``where``."""
    if not isinstance(name, str):
        raise SceneError(f"{where}: expected a name ({NAME_RULE}), got {type(name).__name__} "
                         f"{shown(name)}: quote it if it is meant as text")
    if not _NAME.fullmatch(name):
        raise SceneError(f"{where}: {shown(name)} is not a name ({NAME_RULE})")
    return name


def shown(value: Any) -> str:
    """``repr(value)``, cut to 60 characters: a value in a one-line message."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _whiskers(value: Any, where: str) -> tuple[Whisker, ...]:
    whiskers = tuple(_whisker(item, f"{where}: whiskers[{i}]")
                     for i, item in enumerate(_list(value, f"{where}: whiskers")))
    if not whiskers:
        raise SceneError(f"{where}: whiskers: a robot needs at least one")
    names = [w.name for w in whiskers]
    for i, name in enumerate(names):
        if name in names[:i]:
            raise SceneError(f"{where}: whiskers[{i}]: the name {name!r} is taken by "
                             f"whiskers[{names.index(name)}]")
    return whiskers


def load_path(path: Path) -> RobotPath:
    """Read a path CSV (``t,x,y,z,qx,qy,qz,qw``) into a `RobotPath`, row by row (at most
    `MAX_PATH_ROWS`); errors name the file, the row and the column, never a cell's text."""
    records = csv_records(path)
    first = next(records, None)
    header = [c.strip() for c in first[1]] if first else []
    if header != list(_PATH_COLUMNS):
        missing = [c for c in _PATH_COLUMNS if c not in header]
        got = ("an empty file" if first is None else
               f"a first row without {', '.join(missing)}" if missing else
               f"{','.join(header)}" if len(header) == len(_PATH_COLUMNS) else
               f"a first row of {len(header)} cells")
        raise SceneError(f"{path.name}: the header must be {','.join(_PATH_COLUMNS)}, got {got}")
    values = array("d")
    low, high = LIMITS["position_m"]
    for i, (_, row) in enumerate(records, 1):
        if i > MAX_PATH_ROWS:
            raise SceneError(f"{path.name}: more than {MAX_PATH_ROWS} rows")
        if len(row) != 8:
            raise SceneError(f"{path.name}: row {i}: expected 8 values, got {len(row)}")
        for column, text in zip(_PATH_COLUMNS, row, strict=True):
            try:
                value = number_text(text)
            except ValueError:
                raise SceneError(f"{path.name}: row {i}, column {column}: not a number") from None
            if not (np.isfinite(value) and (column not in "xyz" or abs(value) <= high)):
                raise SceneError(f"{path.name}: row {i}, column {column}: values must be finite, "
                                 f"positions within [{low:g}, {high:g}] m, got {value!r}")
            values.append(value)
    table = np.frombuffer(values, dtype=float).reshape(-1, 8)
    if len(table) < 2:  # a path CSV moves the robot (standing still: ``explore`` without it)
        raise SceneError(f"{path.name}: a path needs at least 2 samples, got {len(table)}")
    try:
        return robot_path(table[:, 0], table[:, 1:4], table[:, 4:8])
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


def _number(value: Any, where: str, limits: str | None = None) -> float:
    """A finite number, within ``LIMITS[limits]`` when given."""
    if not finite_number(value):
        raise SceneError(f"{where}: expected a finite number, got {shown(value)}")
    if limits is not None:
        low, high = LIMITS[limits]
        if not low <= value <= high:
            raise SceneError(f"{where}: {value!r} is outside [{low:g}, {high:g}]")
    return float(value)


def _vector(value: Any, where: str, n: int, limits: str | None = None) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise SceneError(f"{where}: expected {n} numbers, got {shown(value)}")
    return [_number(v, f"{where}[{i}]", limits) for i, v in enumerate(value)]


def _pose(body: dict[str, Any], where: str) -> Transform:
    position = _vector(body.get("position_m", [0.0, 0.0, 0.0]), f"{where}.position_m", 3,
                       "position_m")
    q = _vector(body.get("quaternion_xyzw", [0.0, 0.0, 0.0, 1.0]), f"{where}.quaternion_xyzw", 4)
    bad = non_unit_quaternion(q)
    if bad is not None:
        raise SceneError(f"{where}.quaternion_xyzw: {q} is not a unit quaternion "
                         f"(norm {bad[1]:.9g})")
    return Transform.from_quaternion(q, position)


def _object(value: Any, where: str) -> SceneObject:
    if not isinstance(value, dict):
        raise SceneError(f"{where}: expected a mapping, got {type(value).__name__} {shown(value)}")
    shape = value.get("shape")
    if shape not in SHAPES:
        raise SceneError(f"{where}.shape: expected one of {', '.join(SHAPES)}, got {shape!r}")
    sizes = _OBJECT_SIZES[shape]
    body = _mapping(value, where, ("name", "shape", *sizes, "position_m", "quaternion_xyzw"),
                    ("name", "shape", *sizes))
    values: dict[str, Any] = {}
    for key in sizes:
        if key == "semi_axes_m":
            values[key] = _vector(body[key], f"{where}.{key}", 3, "size_m")
        elif key == "h_m":  # the vertex's height: either side of the origin
            values[key] = _number(body[key], f"{where}.{key}", "position_m")
        else:
            values[key] = _number(body[key], f"{where}.{key}",
                                  "per_m" if key.endswith("_per_m") else "size_m")
    pose = _pose(body, where)  # its errors name the field already
    name = check_name(body["name"], f"{where}.name")
    try:
        return SceneObject(name, shape, values, pose)
    except ValueError as exc:
        raise SceneError(f"{where}: {exc}") from None


def _explore(value: Any, where: str) -> Explore:
    where = f"{where}: explore"
    body = _mapping(value, where, ("start", "workspace_m", "body_radius_m"),
                    ("start", "workspace_m", "body_radius_m"))
    start_body = _mapping(body["start"], f"{where}.start", ("position_m", "quaternion_xyzw"),
                          ("position_m",))
    start = _pose(start_body, f"{where}.start")
    box = body["workspace_m"]
    if not isinstance(box, list) or len(box) != 2:
        raise SceneError(f"{where}.workspace_m: expected [[xmin, ymin, zmin], [xmax, ymax, "
                         f"zmax]], got {shown(box)}")
    low, high = (_vector(corner, f"{where}.workspace_m[{i}]", 3, "position_m")
                 for i, corner in enumerate(box))
    radius = _number(body["body_radius_m"], f"{where}.body_radius_m", "size_m")
    try:
        return Explore(start, (low[0], low[1], low[2]), (high[0], high[1], high[2]), radius)
    except ValueError as exc:
        raise SceneError(f"{where}: {exc}") from None


_ROD_KEYS = ("taper_ratio", "precurvature_1pm", "poisson_ratio")


def _whisker(value: Any, where: str) -> Whisker:
    body = _mapping(value, where, ("name", "length_m", "ei_nm2", "mount", "sensor", *_ROD_KEYS),
                    ("name", "length_m", "ei_nm2", "mount"))
    name = check_name(body["name"], f"{where}.name")
    length = _number(body["length_m"], f"{where}.length_m", "length_m")
    ei = _number(body["ei_nm2"], f"{where}.ei_nm2", "ei_nm2")
    mount = _mapping(body["mount"], f"{where}.mount", ("position_m", "quaternion_xyzw"), ())
    sensor = _mapping(body.get("sensor", {}), f"{where}.sensor", ("position_m", "quaternion_xyzw"), ())
    rod = {key: _number(body[key], f"{where}.{key}") for key in _ROD_KEYS if key in body}
    try:
        return Whisker(name, length, ei, _pose(mount, f"{where}.mount"),
                       _pose(sensor, f"{where}.sensor"), **rod)
    except ValueError as exc:  # the rod's shape (vibrissa.rods.RodShape)
        raise SceneError(f"{where}: {exc}") from None
