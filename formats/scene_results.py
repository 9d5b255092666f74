"""The results of ``vibrissa simulate SCENE.yaml -o DIR``, written and read back exactly:
``DIR/<whisker>.csv`` (`SCENE_COLUMNS`, one row per path sample) and ``DIR/summary.json``
(per whisker: contact episodes, phase changes, samples per phase); and written only,
``DIR/wrenches.csv``: every whisker's wrench at every path sample (`WRENCH_COLUMNS`, sample by
sample, the whiskers in the scene's order), the input of ``vibrissa reconstruct WRENCHES.csv
--scene SCENE.yaml``.

Floats are written by `vibrissa.formats.csv_text` (``repr``, NaN as an empty cell), so
`read_results` gives back the arrays of `vibrissa.scene.simulate` bit for bit (NaN where they
were NaN). Reading is strict: every error names the file, and the row and column where there
is one.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vibrissa.formats.csv_text import cells, read_csv, write_csv
from vibrissa.formats.scene_file import SceneError, check_name
from vibrissa.scene import (
    EPISODE_STARTS,
    Episode,
    SamplePhase,
    Scene,
    Snap,
    WhiskerResult,
    scene_digest,
    snaps,
)
from vibrissa.status import SweepEnd

__all__ = ["SCENE_COLUMNS", "SUMMARY_FILE", "WRENCHES_FILE", "WRENCH_COLUMNS", "read_results",
           "result_files", "write_results"]

SCENE_COLUMNS: dict[str, tuple[str, str]] = {
    "t": ("s", "time of the path sample"),
    "phase": ("-", "none, tip, tangential or unresolved (the clamp inside an object; the "
                   "straight rod inside one at the path's start or after a snap-off; the rod "
                   "met a second object; or a sample Step 1 stepped over)"),
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
    "refined": ("-", "1: Step 1 reached the sample through sub-steps, or by a longer step after "
                     "the touch, so eq. 7's friction is along a sub-step's chord, not the one "
                     "from the sample before; 0 otherwise"),
    "s2": ("m", "arc length of a second contact, where the rod leans on two objects (empty "
                "otherwise; the wrench is then both contacts')"),
    "p2x": ("m", "the second contact point in W, x (empty without one)"),
    "p2y": ("m", "the second contact point in W, y"),
    "p2z": ("m", "the second contact point in W, z"),
    "object2": ("-", "name of the second object touched (empty: none)"),
}
"""The columns of ``DIR/<whisker>.csv``: (unit, meaning). ``refined`` and the second contact's
came later: a file without them is read as all 0 and no second contact."""

_OPTIONAL = ("refined", "s2", "p2x", "p2y", "p2z", "object2")

SUMMARY_FILE = "summary.json"
WRENCHES_FILE = "wrenches.csv"

WRENCH_COLUMNS = ("t", "whisker", "f0x", "f0y", "f0z", "m0x", "m0y", "m0z")
"""The columns of ``DIR/wrenches.csv``, which ``vibrissa reconstruct WRENCHES.csv --scene``
reads (more are ignored there): s, the whisker's name, N and N m in its clamp frame."""

_NUMBERS = ("t", "s1", "f0x", "f0y", "f0z", "m0x", "m0y", "m0z", "px", "py", "pz")
_WRENCH = _NUMBERS[2:8]
_PHASES = {phase.label: phase for phase in SamplePhase}


def result_files(out: Path, scene: Scene) -> list[Path]:
    """The files `write_results` writes for ``scene`` in ``out``; `SceneError` when a whisker's
    file would be another's (a whisker named ``wrenches``)."""
    files = [out / f"{check_name(w.name, 'whisker')}.csv" for w in scene.whiskers]
    if out / WRENCHES_FILE in files:
        raise SceneError(f"whisker {Path(WRENCHES_FILE).stem!r}: its results would replace "
                         f"{WRENCHES_FILE}, the file of every whisker's wrenches; rename it")
    return [*files, out / WRENCHES_FILE, out / SUMMARY_FILE]


def _snap(result: WhiskerResult, snap: Snap) -> dict[str, Any]:
    """A jump of the path (`vibrissa.scene.snaps`): its time, kind, object and the wrenches of
    the samples before and at it."""
    def wrench(a: npt.NDArray[np.float64]) -> list[float] | None:  # null: unresolved there
        return a.tolist() if np.isfinite(a).all() else None

    return {"t": snap.t, "kind": snap.kind, "object": snap.object,
            "f0_before": wrench(result.f0_n[snap.before]),
            "m0_before": wrench(result.m0_nm[snap.before]),
            "f0_after": wrench(result.f0_n[snap.after]),
            "m0_after": wrench(result.m0_nm[snap.after])}


def write_results(out: Path, scene: Scene, results: Sequence[WhiskerResult]) -> list[Path]:
    """``out/<whisker>.csv`` per result, ``out/wrenches.csv`` and ``out/summary.json``; returns
    the files written."""
    result_files(out, scene)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    names = [obj.name for obj in scene.objects]
    for result in results:
        numbers = cells(np.column_stack([result.t, result.s1_m, result.f0_n, result.m0_nm,
                                         result.p_W_m]))
        second = cells(np.column_stack([result.second_s_m, result.second_W_m]))
        rows = (
            [r[0], SamplePhase(phase).label, *r[1:], names[obj] if obj >= 0 else "",
             "1" if refined else "0", *r2, names[obj2] if obj2 >= 0 else ""]
            for r, phase, obj, refined, r2, obj2 in zip(
                numbers, result.phase.tolist(), result.object.tolist(), result.refined.tolist(),
                second, result.second_object.tolist(), strict=True)
        )
        target = out / f"{check_name(result.name, 'whisker')}.csv"  # a file name
        write_csv(target, tuple(SCENE_COLUMNS), rows)
        written.append(target)
    wrenches = [cells(np.column_stack([r.t, r.f0_n, r.m0_nm])) for r in results]
    target = out / WRENCHES_FILE
    write_csv(target, WRENCH_COLUMNS, ([row[0], result.name, *row[1:]]
                                       for sample in zip(*wrenches, strict=True)
                                       for result, row in zip(results, sample, strict=True)))
    written.append(target)
    jumps = {r.name: snaps(r, names) for r in results}
    summary = {
        "scene_sha256": scene_digest(scene),
        "units": {"t": "s", "length": "m", "force": "N", "moment": "N m",
                  "wrench": "clamp reaction on the rod about the clamp point, in the clamp frame"},
        "whiskers": {
            r.name: {
                "episodes": [{"object": e.object, "t_first_contact": e.t_first_contact,
                              "start": e.start, "end": e.end,
                              **({"second_object": e.second_object} if e.second_object else {}),
                              "phase_changes": [{"t": t, "from": a, "to": b}
                                                for t, a, b in e.phase_changes],
                              "snap_throughs": [_snap(r, snap) for snap in jumps[r.name]
                                                if snap.kind == "snap-through"
                                                and snap.t in e.snap_throughs]}
                             for e in r.episodes],
                "snaps": [_snap(r, snap) for snap in jumps[r.name]],
                "samples_per_phase": r.counts(),
                "samples_with_two_contacts": int(np.count_nonzero(r.second_object >= 0)),
            }
            for r in results
        },
    }
    target = out / SUMMARY_FILE
    target.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    written.append(target)
    return written


def read_results(folder: str | Path, scene: Scene) -> list[WhiskerResult]:
    """The results `write_results` wrote to ``folder`` for ``scene``: one per whisker of the
    scene, in its order (other files in the folder are not read), with the episodes of
    ``summary.json``.

    Raises
    ------
    SceneError
        Naming the file (and the row and column) of a problem: no folder, a whisker of
        the scene without its CSV, a missing column, a row of the wrong length, a cell that
        is not a number, a ``t`` that is not the scene path's time (exactly: the results of
        another scene or path), an unknown phase or object, a refined flag not 0 or 1, a
        wrench that is not finite in a sample that has one (all but ``unresolved``), or a
        ``summary.json`` without the whisker's episodes.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SceneError(f"{folder}: not a folder (expected the -o DIR of vibrissa simulate)")
    results = [_read_whisker(folder / f"{whisker.name}.csv", whisker.name, scene)
               for whisker in scene.whiskers]
    episodes = _read_episodes(folder / SUMMARY_FILE, [r.name for r in results], scene)
    for result in results:
        result.episodes = episodes[result.name]
    return results


def _read_whisker(path: Path, name: str, scene: Scene) -> WhiskerResult:
    """One ``<whisker>.csv``; its rows count from 1 after the header, as in the scene's path
    file (`vibrissa.formats.scene_file.load_path`)."""
    if not path.is_file():
        raise SceneError(f"{path}: missing: the scene's whisker {name!r} has no results there")
    header, records = read_csv(path, tuple(c for c in SCENE_COLUMNS if c not in _OPTIONAL))
    body = [row for _, row in records]
    t_path = scene.path.t
    if len(body) != len(t_path):
        raise SceneError(f"{path}: {len(body)} rows, but the scene's path has {len(t_path)} "
                         f"samples (the results of another scene or path?)")
    for i, row in enumerate(body):
        if len(row) != len(header):
            raise SceneError(f"{path}: row {i + 1}: expected {len(header)} values, got {len(row)}")
    column = {c: [row[header.index(c)].strip() for row in body] if c in header else []
              for c in SCENE_COLUMNS}
    values = np.empty((len(body), len(_NUMBERS)))
    for j, key in enumerate(_NUMBERS):
        try:
            values[:, j] = [float(text) if text else math.nan for text in column[key]]
        except ValueError:
            i = next(i for i, text in enumerate(column[key]) if not _is_number(text))
            raise SceneError(f"{path}: row {i + 1}, column {key}: {column[key][i]!r} is not a "
                             f"number") from None
    wrong_t = np.flatnonzero(values[:, 0] != t_path)
    if len(wrong_t):
        i = int(wrong_t[0])
        raise SceneError(f"{path}: row {i + 1}, column t: {column['t'][i]!r} is not the path's "
                         f"time {float(t_path[i])!r} (the results of another scene or path?)")
    for i, label in enumerate(column["phase"]):
        if label not in _PHASES:
            raise SceneError(f"{path}: row {i + 1}, column phase: {label!r} is not a phase "
                             f"({', '.join(_PHASES)})")
    phase = np.array([_PHASES[label] for label in column["phase"]], dtype=np.int64)
    # What the player sends: every sample but an unresolved one has a wrench, and the wire
    # takes finite numbers only.
    no_wrench = np.argwhere((phase != SamplePhase.UNRESOLVED)[:, None] & ~np.isfinite(values[:, 2:8]))
    if len(no_wrench):
        i, key = int(no_wrench[0, 0]), _WRENCH[no_wrench[0, 1]]
        raise SceneError(f"{path}: row {i + 1}, column {key}: a {column['phase'][i]} sample "
                         f"needs a finite wrench, got {column[key][i]!r}")
    objects = {obj.name: i for i, obj in enumerate(scene.objects)}
    for i, obj in enumerate(column["object"]):
        if obj and obj not in objects:
            raise SceneError(f"{path}: row {i + 1}, column object: {obj!r} is not an object of "
                             f"the scene ({', '.join(objects) or 'it has none'})")
    touched = np.array([objects[obj] if obj else -1 for obj in column["object"]], dtype=np.int64)
    for i, flag in enumerate(column["refined"]):
        if flag not in ("0", "1"):
            raise SceneError(f"{path}: row {i + 1}, column refined: {flag!r} is not 0 or 1")
    refined = (np.array([flag == "1" for flag in column["refined"]], dtype=bool)
               if column["refined"] else np.zeros(len(body), dtype=bool))
    s1, f0, m0, p_W = (values[:, cols].copy() for cols in (1, slice(2, 5), slice(5, 8), slice(8, 11)))
    second = np.full((len(body), 4), np.nan)
    for j, key in enumerate(("s2", "p2x", "p2y", "p2z")):
        for i, text in enumerate(column[key]):
            if not _is_number(text):
                raise SceneError(f"{path}: row {i + 1}, column {key}: {text!r} is not a number")
            second[i, j] = float(text) if text else math.nan
    for i, obj in enumerate(column["object2"]):
        if obj and obj not in objects:
            raise SceneError(f"{path}: row {i + 1}, column object2: {obj!r} is not an object of "
                             f"the scene ({', '.join(objects)})")
    touched2 = np.array([objects[obj] if obj else -1 for obj in column["object2"]]
                        or np.full(len(body), -1), dtype=np.int64)
    return WhiskerResult(name, t_path, phase, s1, f0, m0, p_W, touched, refined, [],
                         second[:, 0].copy(), second[:, 1:].copy(), touched2)


def _is_number(text: str) -> bool:
    try:
        float(text or "nan")
    except ValueError:
        return False
    return True


def _one_of(value: Any, allowed: Sequence[str], key: str) -> str:
    """``value`` if it is one of ``allowed``; else a ValueError naming ``key``."""
    if value not in allowed:
        raise ValueError(f"{key} {value!r} is not one of {', '.join(allowed)}")
    return str(value)


def _read_episodes(path: Path, names: Sequence[str], scene: Scene) -> dict[str, list[Episode]]:
    """Each whisker's episodes from ``summary.json``, whose ``scene_sha256`` (when it has one:
    older files do not) must be ``scene``'s."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise SceneError(f"{path}: {exc}") from None
    written_for = doc.get("scene_sha256") if isinstance(doc, dict) else None
    if written_for is not None and written_for != scene_digest(scene):
        raise SceneError(f"{path}: the results of another scene: its scene_sha256 is not this "
                         "scene's (objects, whiskers, mu or path differ); simulate this scene")
    episodes: dict[str, list[Episode]] = {}
    for name in names:
        try:
            items: Any = doc["whiskers"][name]["episodes"]
            episodes[name] = [
                Episode(str(e["object"]), float(e["t_first_contact"]),
                        _one_of(e["end"], [str(end) for end in SweepEnd], "end"),
                        [(float(c["t"]), str(c["from"]), str(c["to"])) for c in e["phase_changes"]],
                        _one_of(e.get("start", "touch"), EPISODE_STARTS, "start"),
                        tuple(float(c["t"]) for c in e.get("snap_throughs", [])),
                        str(e.get("second_object", "")))
                for e in items]
        except (KeyError, TypeError, ValueError) as exc:
            raise SceneError(f"{path}: whiskers.{name}.episodes: not as vibrissa simulate writes "
                             f"them ({type(exc).__name__}: {exc})") from None
    return episodes
