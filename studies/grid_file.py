"""Grid files: a study as YAML, read strictly into its cases before anything runs.

Lists whose product is the grid (each key a list, or one value for a list of one)::

    name: paper                                  # optional; default the file's stem
    surfaces: ["paraboloid:a=0.5,b=1,h=0.4"]     # parse_surface specs, lengths in m
    y0_m: [-0.4, -0.2, 0.0, 0.2, 0.4]            # trail offsets, m
    mu: [0.0, 0.1, 0.2, 0.3, 0.4]
    step: 0.001                                  # units of L; default 0.001
    rods: [{length_m: 1.0, ei_nm2: 1.0}]         # default one rod of 1 m, 1 N m^2; each may
                                                 # taper and be pre-curved (SHAPE_KEYS)

or an explicit list of cases (``cases: [{surface, y0_m, mu, step, length_m, ei_nm2, ...}, ...]``,
``step``, the rod's keys defaulting as above), not both. The product runs surfaces,
then rods, steps, y0_m and mu (innermost).

Or whole scenes along their robot paths instead of surfaces and trails::

    scenes: [../launch/robot/scene.yaml]         # scene files, relative to the grid file
    mu: [0.0, 0.2, 0.5]                          # optional; default each scene's own
    rods: [{length_m: 0.05, ei_nm2: 2.3e-4}]     # optional; replace every whisker's; default its own

(``cases: [{scene, mu, length_m, ei_nm2}, ...]`` likewise); the product runs scenes, then
rods and mu (innermost). A grid is all trails or all scenes: its tables have one set of
columns. Every error names the file and the key.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from vibrissa.formats import yaml_numbers
from vibrissa.formats.errors import SceneError
from vibrissa.formats.files import read_text
from vibrissa.formats.scene_file import LIMITS, load_scene
from vibrissa.grid_study import GridCase, SceneCase
from vibrissa.scene import Scene
from vibrissa.surfaces import parse_surface
from vibrissa.units import RodScale, finite_number

PAPER_GRID = Path(__file__).with_name("paper.yaml")
"""The paper's study (Sec. III) as a grid file: ``vibrissa study paper``."""

DEFAULT_STEP = 0.001
DEFAULT_ROD = {"length_m": 1.0, "ei_nm2": 1.0}
SHAPE_KEYS = ("taper_ratio", "precurvature_1pm", "poisson_ratio")
"""A trail grid's rod may taper and be pre-curved, as a scene file's whisker
(`vibrissa.scene.Whisker`); a scene grid's rods replace only L and EI."""
PRODUCT_KEYS = ("surfaces", "y0_m", "mu", "step", "rods")
SCENE_PRODUCT_KEYS = ("scenes", "mu", "rods")
CASE_KEYS = ("surface", "y0_m", "mu", "step", "length_m", "ei_nm2", *SHAPE_KEYS)
SCENE_CASE_KEYS = ("scene", "mu", "length_m", "ei_nm2")
ROD_KEYS = ("length_m", "ei_nm2")
TOP_KEYS = ("name", *PRODUCT_KEYS, "scenes", "cases")


class GridFileError(ValueError):
    """A grid file that cannot be run: the message names the file and the key."""


@dataclass(frozen=True)
class Grid:
    """A study read from a grid file: its ``name`` and its cases in grid order, all trails
    (`GridCase`) or all scenes (`SceneCase`)."""

    name: str
    cases: tuple[GridCase, ...] | tuple[SceneCase, ...]


def load_grid(path: str | Path, step: float | None = None) -> Grid:
    """The grid of the file ``path``; ``step`` (units of L), when given, replaces every trail
    case's (a grid of scenes has none: its paths set the samples).

    Raises
    ------
    GridFileError
        Naming the file and the key: a missing or unreadable file, invalid YAML, an unknown
        key, a value of the wrong type, an empty list, a bad surface spec, scene file or rod.
    """
    path = Path(path)
    try:
        doc = yaml_numbers.load_strict(read_text(path))
    except SceneError as exc:
        raise GridFileError(str(exc)) from None
    except (yaml.YAMLError, RecursionError) as exc:
        raise GridFileError(f"{path}: invalid YAML: {exc}") from None
    where = str(path)
    if not isinstance(doc, dict):
        raise GridFileError(f"{where}: expected a mapping of keys ({', '.join(TOP_KEYS)})")
    _known(doc, TOP_KEYS, where)
    name = doc.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise GridFileError(f"{where}: name: expected a text, got {name!r}")
    if "scenes" in doc or (isinstance(doc.get("cases"), list) and any(
            isinstance(item, dict) and "scene" in item for item in doc["cases"])):
        if step is not None:
            raise GridFileError(f"{where}: --step: a grid of scenes has no step (its robot paths "
                                f"set the samples)")
        return Grid(name, _scene_cases(doc, path, where))
    if "cases" in doc:
        given = [key for key in PRODUCT_KEYS if key in doc]
        if given:
            raise GridFileError(f"{where}: cases: give either cases or the lists "
                                f"({', '.join(given)}), not both")
        items = _values(doc, "cases", where, single=False)
        cases = [_case(item, f"{where}: cases[{i}]") for i, item in enumerate(items)]
    else:
        for key in ("surfaces", "y0_m", "mu"):
            if key not in doc:
                raise GridFileError(f"{where}: {key}: missing (or give cases)")
        surfaces = [_surface(v, f"{where}: surfaces[{i}]")
                    for i, v in enumerate(_values(doc, "surfaces", where))]
        rods = [_trail_rod(v, f"{where}: rods[{i}]")
                for i, v in enumerate(_values(doc, "rods", where, default=[DEFAULT_ROD]))]
        steps, y0s, mus = (
            [_number(v, f"{where}: {key}[{i}]", key)
             for i, v in enumerate(_values(doc, key, where, default=default))]
            for key, default in (("step", [DEFAULT_STEP]), ("y0_m", None), ("mu", None)))
        cases = [GridCase(surface, y0, mu, dx, **rod)
                 for surface, rod, dx, y0, mu in itertools.product(surfaces, rods, steps, y0s, mus)]
    if step is not None:
        cases = [dataclasses.replace(c, step=step) for c in cases]
    return Grid(name, tuple(cases))


def _scene_cases(doc: dict[str, Any], path: Path, where: str) -> tuple[SceneCase, ...]:
    """A grid of scenes: the product of ``scenes``, ``rods`` and ``mu``, or its ``cases``."""
    read: dict[str, Scene] = {}

    def scene(value: Any, key: str) -> tuple[str, Scene]:
        if not isinstance(value, str) or not value:
            raise GridFileError(f"{where}: {key}: expected a scene file (text), got {value!r}")
        if value not in read:
            try:
                read[value] = load_scene(path.parent / value)
            except SceneError as exc:
                raise GridFileError(f"{where}: {key}: {exc}") from None
        return value, read[value]

    def case(name: str, read_scene: Scene, mu: float | None, rod: RodScale | None, key: str
             ) -> SceneCase:
        rod_m = (math.nan, math.nan) if rod is None else (rod.length_m, rod.ei_nm2)
        try:
            return SceneCase(name, read_scene, read_scene.mu if mu is None else mu, *rod_m)
        except ValueError as exc:
            raise GridFileError(f"{where}: {key}: {exc}") from None

    if "cases" in doc:
        given = [key for key in SCENE_PRODUCT_KEYS if key in doc]
        if given:
            raise GridFileError(f"{where}: cases: give either cases or the lists "
                                f"({', '.join(given)}), not both")
        cases = []
        for i, item in enumerate(_values(doc, "cases", where, single=False)):
            at = f"cases[{i}]"
            if not isinstance(item, dict) or "scene" not in item:
                raise GridFileError(f"{where}: {at}: a grid is all scenes or all trails: expected "
                                    f"a mapping with scene ({', '.join(SCENE_CASE_KEYS)})")
            _known(item, SCENE_CASE_KEYS, f"{where}: {at}")
            mu = _number(item["mu"], f"{where}: {at}: mu", "mu") if "mu" in item else None
            rod = _scene_rod(item, f"{where}: {at}")
            cases.append(case(*scene(item["scene"], f"{at}: scene"), mu, rod, at))
        return tuple(cases)
    trail_keys = [key for key in ("surfaces", "y0_m", "step") if key in doc]
    if trail_keys:
        raise GridFileError(f"{where}: {trail_keys[0]}: a grid of scenes has no "
                            f"{', '.join(trail_keys)} (its objects and robot paths are the scenes')")
    scenes = [scene(value, f"scenes[{i}]") for i, value in enumerate(_values(doc, "scenes", where))]
    rods: list[RodScale | None] = [None]
    if "rods" in doc:
        rods = [_scene_rod(v, f"{where}: rods[{i}]", required=True)
                for i, v in enumerate(_values(doc, "rods", where))]
    mus: list[float | None] = [None]
    if "mu" in doc:
        mus = [_number(v, f"{where}: mu[{i}]", "mu") for i, v in enumerate(_values(doc, "mu", where))]
    return tuple(case(name, read_scene, mu, rod, f"scenes: {name}")
                 for (name, read_scene), rod, mu in itertools.product(scenes, rods, mus))


def _scene_rod(item: Any, where: str, required: bool = False) -> RodScale | None:
    """A scene's rod: both of ``length_m`` and ``ei_nm2``, or (unless ``required``) neither:
    the scene's own."""
    if not isinstance(item, dict):
        raise GridFileError(f"{where}: expected a mapping (length_m, ei_nm2), "
                            f"got {type(item).__name__}")
    if required:
        _known(item, ROD_KEYS, where)
    given = [key for key in ROD_KEYS if key in item]
    if not given and not required:
        return None
    if len(given) < 2:
        missing = next(key for key in ROD_KEYS if key not in given)
        raise GridFileError(f"{where}: {missing}: missing (a scene's rods are replaced by both "
                            f"length_m and ei_nm2, or neither)")
    rod = _rod({key: item[key] for key in ROD_KEYS}, where)
    for key in ROD_KEYS:  # the scene files' limits: a whisker's units must not overflow
        low, high = LIMITS[key]
        if not low <= getattr(rod, key) <= high:
            raise GridFileError(f"{where}: {key}: {getattr(rod, key)!r} is outside the range "
                                f"[{low:g}, {high:g}] a scene's whiskers take")
    return rod


def _known(doc: dict[Any, Any], allowed: tuple[str, ...], where: str) -> None:
    for key in doc:
        if key not in allowed:
            raise GridFileError(f"{where}: unknown key {key!r} (allowed: {', '.join(allowed)})")


def _values(doc: dict[str, Any], key: str, where: str, default: list[Any] | None = None,
            single: bool = True) -> list[Any]:
    """``doc[key]`` as a non-empty list (one value is a list of one where ``single``)."""
    value = doc.get(key, default)
    if not isinstance(value, list):
        if not single:
            raise GridFileError(f"{where}: {key}: expected a list, got {type(value).__name__}")
        value = [value]
    if not value:
        raise GridFileError(f"{where}: {key}: an empty list (a grid needs at least one value)")
    return value


def _number(value: Any, where: str, key: str) -> float:
    if not finite_number(value):
        raise GridFileError(f"{where}: expected a finite number, got {type(value).__name__} "
                            f"{value!r}")
    if key == "mu" and value < 0:
        raise GridFileError(f"{where}: mu must be >= 0, got {value!r}")
    if key == "step" and not value > 0:
        raise GridFileError(f"{where}: step must be > 0, got {value!r}")
    return float(value)


def _surface(value: Any, where: str) -> str:
    if not isinstance(value, str):
        raise GridFileError(f"{where}: expected a surface spec (text), got {type(value).__name__}")
    try:
        parse_surface(value)
    except ValueError as exc:
        raise GridFileError(f"{where}: {exc}") from None
    return value


def _rod(value: Any, where: str) -> RodScale:
    if not isinstance(value, dict):
        raise GridFileError(f"{where}: expected a mapping (length_m, ei_nm2), "
                            f"got {type(value).__name__}")
    _known(value, ROD_KEYS, where)
    length_m, ei_nm2 = (_number(value.get(key, DEFAULT_ROD[key]), f"{where}: {key}", key)
                        for key in ROD_KEYS)
    try:
        return RodScale(length_m, ei_nm2)
    except ValueError as exc:
        raise GridFileError(f"{where}: {exc}") from None


def _case(value: Any, where: str) -> GridCase:
    if not isinstance(value, dict):
        raise GridFileError(f"{where}: expected a mapping ({', '.join(CASE_KEYS)}), "
                            f"got {type(value).__name__}")
    _known(value, CASE_KEYS, where)
    for key in ("surface", "y0_m", "mu"):
        if key not in value:
            raise GridFileError(f"{where}: {key}: missing")
    surface = _surface(value["surface"], f"{where}: surface")
    rod = _trail_rod({key: value[key] for key in (*ROD_KEYS, *SHAPE_KEYS) if key in value}, where)
    y0, mu, step = (_number(value.get(key, DEFAULT_STEP), f"{where}: {key}", key)
                    for key in ("y0_m", "mu", "step"))
    return GridCase(surface, y0, mu, step, **rod)


def _trail_rod(value: Any, where: str) -> dict[str, float]:
    """A trail grid's rod: `_rod`'s L and EI and the `SHAPE_KEYS` given, as `GridCase`'s
    keyword arguments."""
    if not isinstance(value, dict):
        raise GridFileError(f"{where}: expected a mapping ({', '.join((*ROD_KEYS, *SHAPE_KEYS))}), "
                            f"got {type(value).__name__}")
    _known(value, (*ROD_KEYS, *SHAPE_KEYS), where)
    scale = _rod({key: value[key] for key in ROD_KEYS if key in value}, where)
    rod = {"length_m": scale.length_m, "ei_nm2": scale.ei_nm2}
    rod.update({key: _number(value[key], f"{where}: {key}", key) for key in SHAPE_KEYS
                if key in value})
    try:
        GridCase("sphere:r=1", 0.0, 0.0, DEFAULT_STEP, **rod)  # the shape's own checks
    except ValueError as exc:
        raise GridFileError(f"{where}: {exc}") from None
    return rod
