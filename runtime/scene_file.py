"""Scene files (SCENE.yaml and its path CSV) and robot descriptions, read strictly: every
error names the file and the key or row.

A scene file (SI, world frame W, z up) holds ``mu``, ``objects`` (name, shape sphere |
ellipsoid | paraboloid, sizes, ``position_m``, ``quaternion_xyzw``), ``whiskers`` (name,
``length_m``, ``ei_nm2``, ``mount`` X_RC, optionally ``sensor`` X_CS: the force/torque
sensor's frame in the clamp frame, identity when left out) and ``path`` (a CSV ``t,x,y,z,qx,qy,qz,qw`` of robot
poses X_WR, relative to the scene file). Its ``whiskers`` are also the robot description the
nodes load (`load_robot`): one file, one truth.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vibrissa.frames import Transform
from vibrissa.runtime import yaml_numbers
from vibrissa.scene import SHAPES, RobotPath, Scene, SceneObject, Whisker, robot_path

__all__ = ["SceneError", "load_path", "load_robot", "load_scene"]

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
    doc = _read_yaml(path)
    where = path.name
    body = _mapping(doc, where, ("mu", "objects", "whiskers", "path"), ("mu", "whiskers", "path"))
    mu = _number(body["mu"], f"{where}: mu")
    objects = tuple(_object(item, f"{where}: objects[{i}]")
                    for i, item in enumerate(_list(body.get("objects", []), f"{where}: objects")))
    whiskers = _whiskers(body["whiskers"], where)
    if not isinstance(body["path"], str):
        raise SceneError(f"{where}: path: expected a file name, got {body['path']!r}")
    try:
        return Scene(mu, objects, whiskers, load_path(path.parent / body["path"]))
    except SceneError:
        raise
    except ValueError as exc:
        raise SceneError(f"{where}: {exc}") from None


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
    try:
        return yaml_numbers.load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise SceneError(f"{path}: {exc}") from None


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
    pose = _pose(body, where)  # its errors name the field already
    try:
        return SceneObject(str(body["name"]), shape, values, pose)
    except ValueError as exc:
        raise SceneError(f"{where}: {exc}") from None


def _whisker(value: Any, where: str) -> Whisker:
    body = _mapping(value, where, ("name", "length_m", "ei_nm2", "mount", "sensor"),
                    ("name", "length_m", "ei_nm2", "mount"))
    length, ei = _number(body["length_m"], f"{where}.length_m"), _number(body["ei_nm2"], f"{where}.ei_nm2")
    if not (length > 0 and ei > 0):
        raise SceneError(f"{where}: length_m and ei_nm2 must be > 0, got {length}, {ei}")
    mount = _mapping(body["mount"], f"{where}.mount", ("position_m", "quaternion_xyzw"), ())
    sensor = _mapping(body.get("sensor", {}), f"{where}.sensor", ("position_m", "quaternion_xyzw"), ())
    return Whisker(str(body["name"]), length, ei, _pose(mount, f"{where}.mount"),
                   _pose(sensor, f"{where}.sensor"))
