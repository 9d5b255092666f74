"""CSV and JSON tables of sweeps and reconstructions, shared by the mechanics commands.

Floats are written with ``repr`` (full precision, round-trips exactly); a missing value is an
empty cell. Units are the paper's (eq. 1): lengths in L, forces in EI/L^2, moments in EI/L.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vibrissa.formats.csv_text import cell, cells, csv_records, write_csv
from vibrissa.formats.scene_file import SceneError, shown
from vibrissa.reconstruct import Reconstruction
from vibrissa.status import ContactPhase, ContactStatus
from vibrissa.sweep import STATE_NAMES, Sweep
from vibrissa.units import number_text

SWEEP_COLUMNS = (
    "x0", "y0", "phase", "s1", "psi",
    "f0x", "f0y", "f0z", "m0x", "m0y", "m0z",
    "px", "py", "pz", "fn", "ft",
    "state", "nx", "ny", "nz", "refined",
)
WRENCH_COLUMNS = ("x0", "y0", "f0x", "f0y", "f0z", "m0x", "m0y", "m0z")
RECONSTRUCTION_COLUMNS = ("x0", "y0", "rx", "ry", "rz", "s1", "phase", "status")
"""Without the optional z0 (after y0, when the input has it) and err (last, with --surface)."""

COLUMNS: dict[str, tuple[str, str]] = {
    "x0": ("L", "clamp position P0, x (the trail runs along -x)"),
    "y0": ("L", "clamp position P0, y (the trail's offset)"),
    "z0": ("L", "clamp position P0, z (reconstruct: carried from the input when it has it)"),
    "phase": ("-", "tip or tangential contact"),
    "s1": ("L", "arc length from the clamp to the contact"),
    "psi": ("rad", "angle of the bending plane E_psi about the clamp axis (eq. 20)"),
    "f0x": ("EI/L^2", "clamp reaction force on the rod, x (f0 + F = 0)"),
    "f0y": ("EI/L^2", "clamp reaction force on the rod, y"),
    "f0z": ("EI/L^2", "clamp reaction force on the rod, z"),
    "m0x": ("EI/L", "clamp reaction moment on the rod about P0, x (m0 + r x F = 0)"),
    "m0y": ("EI/L", "clamp reaction moment, y"),
    "m0z": ("EI/L", "clamp reaction moment, z (0: no twist)"),
    "px": ("L", "simulated contact point P1, x"),
    "py": ("L", "simulated contact point P1, y"),
    "pz": ("L", "simulated contact point P1, z"),
    "fn": ("EI/L^2", "normal component of the contact force F on the rod"),
    "ft": ("EI/L^2", "tangential (friction) component of F"),
    "state": ("-", "slide or stick"),
    "nx": ("-", "outward unit normal of the object at P1, x"),
    "ny": ("-", "outward unit normal, y"),
    "nz": ("-", "outward unit normal, z"),
    "refined": ("-", "1: reached by sub-steps or as part of a longer step (positions before "
                     "it may be missing), 0: one plain step"),
    "rx": ("L", "reconstructed contact point, x (empty without a contact)"),
    "ry": ("L", "reconstructed contact point, y"),
    "rz": ("L", "reconstructed contact point, z"),
    "status": ("-", "ok, or why there is no contact (vibrissa.ContactStatus names)"),
    "err": ("L", "|signed distance| of the reconstructed point to --surface"),
}
"""Every CSV column: (unit, meaning). Units are the paper's (eq. 1): L is the rod length, EI its
bending stiffness."""


def columns_help(names: Iterable[str]) -> str:
    """The ``--help`` text of CSV columns: ``name [unit]: meaning`` per line."""
    return "\n".join(f"  {name} [{COLUMNS[name][0]}]: {COLUMNS[name][1]}" for name in names)
UNITS = {
    "length": "L (rod length)",
    "force": "EI/L^2",
    "moment": "EI/L",
    "note": "dimensionless per eq. 1; f0, m0: clamp reaction on the rod, moment about P0, "
    "in the clamp frame (z = rod axis at the clamp)",
}


class TableError(ValueError):
    """A table that cannot be read: names the file and what is wrong."""


@dataclass(frozen=True)
class WrenchTable:
    """Clamp positions and support reactions read from a CSV.

    Attributes
    ----------
    p0 : ndarray, shape (N, 3)
        Clamp positions (x0, y0, z0), units of L.
    f0, m0 : ndarray, shape (N, 3)
        Clamp reactions on the rod, EI/L^2 and EI/L.
    has_z0 : bool
        Whether the file had a z0 column (else z0 = 0).
    """

    p0: NDArray[np.float64]
    f0: NDArray[np.float64]
    m0: NDArray[np.float64]
    has_z0: bool = False


def write_sweep_csv(path: Path, sweep: Sweep) -> None:
    """One row per equilibrium of ``sweep`` with :data:`SWEEP_COLUMNS`."""
    n = sweep.n_steps
    numbers = cells(np.column_stack([
        sweep.x0[:n], np.full(n, sweep.y0), sweep.s1[:n], sweep.psi[:n], sweep.f0[:n],
        sweep.m0[:n], sweep.contact[:n], sweep.fn[:n], sweep.ft[:n], sweep.normal[:n]]))
    rows = (
        [*r[:2], ContactPhase(phase).label, *r[2:15], STATE_NAMES[state], *r[15:18],
         "1" if refined else "0"]
        for r, phase, state, refined in zip(numbers, sweep.phase[:n].tolist(),
                                            sweep.state[:n].tolist(),
                                            sweep.refined[:n].tolist(), strict=True)
    )
    write_csv(path, SWEEP_COLUMNS, rows)


def sweep_summary(sweep: Sweep, surface_spec: str) -> dict[str, Any]:
    """The JSON sidecar of a sweep CSV: how it ended, phase changes, inputs and units."""
    summary = sweep.summary()
    summary["y0"], summary["mu"] = sweep.y0, float(sweep.trail.mu)
    return {"surface": surface_spec, **summary, "units": UNITS}


def write_json(path: Path, data: Any) -> None:
    """Pretty JSON; numpy scalars become Python numbers, NaN becomes null."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_plain(data), indent=2, allow_nan=False) + "\n")


def _plain(data: Any) -> Any:
    if isinstance(data, dict):
        return {str(key): _plain(value) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [_plain(value) for value in data]
    if isinstance(data, np.ndarray):
        return _plain(data.tolist())
    if isinstance(data, (np.integer, bool)):
        return data if isinstance(data, bool) else int(data)
    if isinstance(data, (float, np.floating)):
        value = float(data)
        return None if not math.isfinite(value) else value
    return data


def read_wrench_csv(path: Path) -> WrenchTable:
    """Read x0, y0, [z0,] f0x..m0z from a CSV (e.g. written by ``vibrissa sweep``); rows
    count from 1 after the header, as in the scene's files.

    Raises
    ------
    TableError
        Naming the file and the missing column or the bad cell (row, column, text).
    """
    try:
        records = [row for _, row in csv_records(path)]  # a BOM, blank lines: no rows
    except SceneError as exc:
        raise TableError(str(exc)) from None
    header = records[0] if records else None
    rows = records[1:]
    if header is None:
        expected = ", ".join(WRENCH_COLUMNS)
        raise TableError(f"{path}: empty file, expected a header with columns {expected}")
    header = [name.strip() for name in header]
    missing = [name for name in WRENCH_COLUMNS if name not in header]
    if missing:
        raise TableError(f"{path}: missing column {', '.join(repr(m) for m in missing)}")
    wanted = [*WRENCH_COLUMNS, "z0"] if "z0" in header else list(WRENCH_COLUMNS)
    index = {name: header.index(name) for name in wanted}
    values = {name: np.empty(len(rows)) for name in wanted}
    for r, row in enumerate(rows):
        if len(row) != len(header):  # a cut-off or mangled row is not a missing value
            raise TableError(f"{path}: row {r + 1}: expected {len(header)} values, got "
                             f"{len(row)}")
        for name, c in index.items():
            text = row[c].strip()
            try:
                # An empty cell is a missing value: Step 2 flags it (non_finite_input).
                values[name][r] = number_text(text) if text else np.nan
            except ValueError:
                raise TableError(
                    f"{path}: row {r + 1}, column {name!r}: {shown(text)} is not a number"
                ) from None
    z0 = values["z0"] if "z0" in values else np.zeros(len(rows))
    return WrenchTable(
        p0=np.column_stack([values["x0"], values["y0"], z0]),
        f0=np.column_stack([values["f0x"], values["f0y"], values["f0z"]]),
        m0=np.column_stack([values["m0x"], values["m0y"], values["m0z"]]),
        has_z0="z0" in values,
    )


@functools.lru_cache(maxsize=1024)  # a few codes recur over millions of rows
def status_name(status: int) -> str:
    """``ok``, or the lower-case flag names of a :class:`ContactStatus` joined by ``|``."""
    if status == 0:
        return "ok"
    names = [flag.name.lower() for flag in ContactStatus if flag and flag & status and flag.name]
    return "|".join(names)


def write_reconstruction_csv(
    path: Path, table: WrenchTable, rec: Reconstruction, error: NDArray[np.float64] | None = None
) -> None:
    """Columns x0, y0 (z0 when ``table`` has it) of the input row, then rx, ry, rz, s1, phase,
    status (and err if given); no contact: empty rx..s1."""
    position = ["x0", "y0", *(["z0"] if table.has_z0 else [])]
    columns = [*position, *RECONSTRUCTION_COLUMNS[2:], *(["err"] if error is not None else [])]
    rows = (
        [
            *map(cell, table.p0[i, :len(position)]),
            *map(cell, rec.point[i]), cell(rec.s1[i]), ContactPhase(rec.phase[i]).label,
            status_name(int(rec.status[i])),
            *([cell(error[i])] if error is not None else []),
        ]
        for i in range(len(rec.status))
    )
    write_csv(path, columns, rows)
