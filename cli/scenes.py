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
         mount: {position_m: [0.01, -0.02, 0.0], quaternion_xyzw: [0.17, 0, 0, 0.98]},
         sensor: {position_m: [0, 0, -0.012]}}   # optional: X_CS of its F/T sensor (identity)
    path: path.csv        # columns t,x,y,z,qx,qy,qz,qw: robot poses X_WR; relative to the scene

Output: ``DIR/<whisker>.csv`` (``SCENE_COLUMNS``, one row per path sample),
``DIR/wrenches.csv`` (``t,whisker,f0x,f0y,f0z,m0x,m0y,m0z``: every whisker's wrench at every
sample, sample by sample, the input of ``vibrissa reconstruct``) and
``DIR/summary.json`` (per whisker: contact episodes, each begun by a ``touch`` or a ``landing``
after a snap-off, phase changes, snap-throughs, samples per phase), by
`vibrissa.formats.scene_results`, which reads them back too (the wrench source's ``simulated``).

Also Step 2 of such a scene offline: ``vibrissa reconstruct WRENCHES.csv --scene SCENE.yaml -o
POINTS.csv`` (``WRENCH_COLUMNS`` in, ``POINT_COLUMNS`` out, row for row), e.g. on
``DIR/wrenches.csv``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vibrissa.cli import tables
from vibrissa.cli.arg_types import count
from vibrissa.formats.csv_text import cells, csv_writer, read_csv, refuse_overwrite
from vibrissa.formats.scene_file import SceneError, load_scene, scene_files, shown
from vibrissa.formats.scene_results import (
    SCENE_COLUMNS,
    WRENCH_COLUMNS,
    result_files,
    write_results,
)
from vibrissa.scene import (
    SamplePhase,
    Scene,
    WhiskerResult,
    clamp_inside,
    reconstruct_along,
    rod_inside_at_start,
    simulate,
)
from vibrissa.status import ContactPhase, SweepEnd
from vibrissa.units import number_text

FloatArray = NDArray[np.float64]


def print_sample_progress(whisker: str, sample: int, samples: int) -> None:
    """A worker's progress line on stderr (module level: worker processes unpickle it)."""
    print(f"  {whisker}: sample {sample} of {samples}", file=sys.stderr, flush=True)


def run_simulate(args: argparse.Namespace) -> int:
    """The ``simulate`` subcommand."""
    scene = load_scene(args.scene)
    if len(scene.path.t) < 2:  # an exploration's scene: its explore key gives only the start
        raise SceneError(f"{args.scene}: path: `vibrissa simulate` needs a path of 2 samples or "
                         "more; this scene has none but the explore start (explore it with "
                         "`vibrissa launch launch/explore.yaml scene:=...`, or add a path)")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise SceneError(f"{out}: exists and is not a folder")
    refuse_overwrite(result_files(out, scene), scene_files(args.scene))
    out.mkdir(parents=True, exist_ok=True)  # a folder that cannot be made fails before the work
    total = len(scene.whiskers)
    samples = len(scene.path.t)
    print(f"simulating {total} whisker(s) x {samples} path samples past "
          f"{len(scene.objects)} object(s)", file=sys.stderr, flush=True)

    def progress(done: int, _total: int) -> None:
        if done:
            print(f"  {done}/{total} whiskers done", file=sys.stderr, flush=True)

    results = simulate(scene, workers=args.workers, progress=progress,
                       sample_progress=print_sample_progress)
    for path in write_results(out, scene, results):
        print(f"wrote {path}")
    print(episode_summary(results, scene), file=sys.stderr)
    return 0


def episode_summary(results: Sequence[WhiskerResult], scene: Scene | None = None) -> str:
    """``12 contact episodes (7 detachment, 4 snap-off, 1 another-object), 2 of them landings
    after a snap-off; samples: 9105 none, ...``, what ``another-object`` means when an episode
    ended so, and with the ``scene`` the unresolved samples of each whisker whose clamp is
    inside an object, or whose rod starts inside one."""
    ends = Counter(episode.end for result in results for episode in result.episodes)
    samples: Counter[str] = Counter()
    for result in results:
        samples.update(result.counts())
    count = sum(ends.values())
    line = f"{count} contact episode{'s' * (count != 1)}"
    if ends:
        line += f" ({', '.join(f'{n} {end}' for end, n in ends.most_common())})"
    after = Counter(before.end for result in results
                    for before, episode in itertools.pairwise(result.episodes)
                    if episode.start == "landing")
    landings = after[SweepEnd.SNAP_OFF]
    if landings:
        line += f", {landings} of them landing{'s' * (landings != 1)} after a snap-off"
    others = sum(after.values()) - landings
    if others:
        line += f", {others} landing{'s' * (others != 1)} where one of two contacts left"
    seconds = sum(episode.start == "second-contact" for result in results
                  for episode in result.episodes)
    if seconds:
        line += (f", {seconds} with a second contact (the rod leaning on two objects: "
                 f"{sum(int(np.count_nonzero(r.second_object >= 0)) for r in results)} samples)")
    jumps = sum(len(episode.snap_throughs) for result in results for episode in result.episodes)
    if jumps:
        line += (f", {jumps} snap-through{'s' * (jumps != 1)} inside them (the contact jumped "
                 "to another branch: summary.json)")
    line += "; samples: " + ", ".join(f"{samples[phase.label]} {phase.label}"
                                      for phase in SamplePhase)
    if ends[SweepEnd.ANOTHER_OBJECT]:
        line += ("\n  another-object: a rod leaning on one object met a second; it goes on "
                 "with both contacts (a second-contact episode, the second in the CSV's s2, "
                 "p2x.. and object2) where an equilibrium with both is found, else those "
                 "samples are unresolved")
    if scene is None:
        return line
    for result, whisker in zip(results, scene.whiskers, strict=True):
        inside = clamp_inside(scene, whisker)
        held = np.flatnonzero((result.phase == SamplePhase.UNRESOLVED) & (inside >= 0))
        if len(held):
            names = sorted({scene.objects[k].name for k in inside[held]})
            line += (f"\n  {result.name}: {len(held)} sample(s) unresolved with the clamp inside "
                     f"{', '.join(names)} (from t = {result.t[held[0]]:g} s): no rod fits there")
        unresolved = (result.phase == SamplePhase.UNRESOLVED) & (inside < 0)
        first = int(np.argmin(unresolved)) if not unresolved.all() else len(unresolved)
        start = rod_inside_at_start(scene, whisker) if first else -1
        if start >= 0:
            line += (f"\n  {result.name}: {first} sample(s) unresolved from the path's start: its "
                     f"rod starts inside {scene.objects[start].name}, with no touch to follow "
                     "a contact from")
    return line


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


CLEAR_LINE = "\r\x1b[K"
"""Back to the start of a terminal's line, and the line cleared (ANSI)."""

CHUNK_ROWS = 1 << 14
"""Rows of WRENCHES.csv read, reconstructed and written at a time: the memory of ``vibrissa
reconstruct --scene`` whatever the file's length (a row gives the same bits in any batch)."""


def read_wrenches(path: Path, rows: int) -> Iterator[tuple[
        int, list[str], FloatArray, list[str], FloatArray, FloatArray]]:
    """WRENCHES.csv, ``rows`` rows at a time: the number of the first (1 after the header),
    the t texts, t (s), whisker names, f0 (N) and m0 (N m) in clamp frames. `SceneError`
    names the file and the column (here) or the row (as the rows are read). An empty wrench
    cell is a missing value (Step 2 flags it ``non_finite_input``)."""
    header, records = read_csv(path, WRENCH_COLUMNS)
    return _wrench_chunks(path, header, records, rows)


def _wrench_chunks(path: Path, header: list[str], records: Iterator[tuple[int, list[str]]],
                   rows: int) -> Iterator[tuple[int, list[str], FloatArray, list[str], FloatArray,
                                                FloatArray]]:
    at = {name: header.index(name) for name in WRENCH_COLUMNS}
    first = 1
    while chunk := list(itertools.islice(records, rows)):
        t_text, names = [], []
        values = np.empty((len(chunk), 7))
        for k, (line, row) in enumerate(chunk):
            i = first + k
            if len(row) != len(header):
                raise SceneError(f"{path.name}: {_row_name(i, line)}: expected {len(header)} "
                                 f"values, got {len(row)}")
            t_text.append(row[at["t"]].strip())
            names.append(row[at["whisker"]].strip())
            for j, name in enumerate(("t", *WRENCH_COLUMNS[2:])):
                text = row[at[name]].strip()
                try:
                    values[k, j] = number_text(text) if text else math.nan
                except ValueError:
                    raise SceneError(f"{path.name}: {_row_name(i, line)}, column {name}: "
                                     f"{shown(text)} is not a number") from None
            if not math.isfinite(values[k, 0]):
                raise SceneError(f"{path.name}: {_row_name(i, line)}: t must be a finite number")
        yield first, t_text, values[:, 0], names, values[:, 1:4], values[:, 4:7]
        first += len(chunk)


def _row_name(row: int, line: int) -> str:
    """``row N``, the Nth data row (POINTS.csv's row N), and its file line where blank lines
    make them differ."""
    return f"row {row}" if line == row + 1 else f"row {row} (line {line})"


def run_reconstruct(args: argparse.Namespace) -> int:
    """``vibrissa reconstruct WRENCHES.csv --scene SCENE.yaml -o POINTS.csv``, streamed
    (`CHUNK_ROWS` at a time; on a terminal, the rows done so far on one updating line: about
    75 000 rows/s on 2 cores, a minute of 8 whiskers at 1 kHz in 6-7 s); POINTS.csv is written
    whole or not at all."""
    scene = load_scene(args.scene)
    source, output = Path(args.input), Path(args.output)
    refuse_overwrite([output], [source, *scene_files(args.scene)])
    chunks = read_wrenches(source, CHUNK_ROWS)
    known = [w.name for w in scene.whiskers]
    known_names = set(known)
    rows = found = 0
    counts: Counter[str] = Counter()
    phase_label = {phase.value: phase.label for phase in ContactPhase}
    tty, start = sys.stderr.isatty(), time.perf_counter()
    with csv_writer(output, tuple(POINT_COLUMNS)) as writer:
        for first, t_text, t, names, f0, m0 in chunks:
            for k, name in enumerate(names):
                if name not in known_names:
                    raise SceneError(f"{source.name}: row {first + k}: whisker {name!r} is not "
                                     f"in {Path(args.scene).name} ({', '.join(known)})")
            rec = reconstruct_along(scene, t, names, f0, m0)
            status = [tables.status_name(code) if ok else "no_pose"
                      for code, ok in zip(rec.status.tolist(), rec.pose_ok.tolist(), strict=True)]
            point_s1 = cells(np.column_stack([rec.point_m, rec.s1_m]))
            writer.writerows([t_text[i], names[i], *point_s1[i], phase_label[phase], status[i]]
                             for i, phase in enumerate(rec.phase.tolist()))
            rows += len(t)
            found += int(np.sum(np.isfinite(rec.point_m[:, 0])))
            counts.update(name for name in status if name not in ("ok", "axial_load"))
            if tty:
                print(f"\rreconstruct: {rows} rows, {found} with a contact, "
                      f"{time.perf_counter() - start:.0f} s", end="", file=sys.stderr, flush=True)
    line = f"{CLEAR_LINE if tty else ''}reconstruct: {rows} rows, {found} with a contact"
    if counts:
        line += f", {sum(counts.values())} without (" + ", ".join(
            f"{name}: {n}" for name, n in sorted(counts.items())) + ")"
    print(f"{line} -> {args.output}", file=sys.stderr)
    return 0


def register(subparsers: Any) -> None:
    """Add the ``simulate`` subcommand to the ``vibrissa`` dispatcher."""
    columns = "\n".join(f"  {name} [{unit}]: {meaning}"
                        for name, (unit, meaning) in SCENE_COLUMNS.items())
    parser = subparsers.add_parser(
        "simulate",
        help="Step 1 of a robot's whiskers along its path past objects (SCENE.yaml, SI)",
        description=(__doc__.split("\n\nAlso Step 2")[0].replace("``", "").replace("::\n", ":\n")
                     + f"\n\nColumns of DIR/<whisker>.csv:\n{columns}"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("scene", metavar="SCENE.yaml")
    parser.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--workers", type=count, default=None, metavar="N",
                        help="processes for the whiskers (default: all cores)")
    parser.set_defaults(func=run_simulate)
