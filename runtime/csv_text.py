"""CSV files of floats that read back exactly: a float is written as its ``repr`` (the shortest
text that parses back to the same float64), a missing value (NaN) as an empty cell; read with
the columns they must have."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from vibrissa.runtime.scene_file import SceneError


def cell(value: float) -> str:
    """The CSV cell of a float: its ``repr``, empty for NaN."""
    value = float(value)
    return "" if math.isnan(value) else repr(value)


def cells(values: ArrayLike) -> list[list[str]]:
    """The cells of a (rows, columns) array of floats, each as :func:`cell` gives it."""
    return [["" if v != v else repr(v) for v in row]
            for row in np.asarray(values, dtype=np.float64).tolist()]


def write_csv(path: Path, columns: Sequence[str], rows: Iterable[Sequence[str]]) -> None:
    """A header of ``columns`` and the ``rows`` (UTF-8, ``\\n`` line ends); creates the folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows(rows)


def read_csv(path: Path, columns: Sequence[str]) -> tuple[list[str], list[list[str]]]:
    """The header (stripped) and the rows of a CSV that must have ``columns`` (more are
    allowed, each named once, and unnamed ones); `SceneError` names the file and what is
    wrong. A UTF-8 byte order mark (as spreadsheets save) and blank lines are no part of the
    table."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            rows = [row for row in csv.reader(handle) if row]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise SceneError(f"{path}: {exc}") from None
    header = [c.strip() for c in rows[0]] if rows else []
    missing = [name for name in columns if name not in header]
    if missing:
        raise SceneError(f"{path}: missing column(s) {', '.join(missing)} (the columns are "
                         f"{','.join(columns)})")
    # unnamed columns (a spreadsheet's trailing commas) are extra columns like any other
    repeated = sorted({name for name in header if name and header.count(name) > 1})
    if repeated:
        raise SceneError(f"{path}: column(s) {', '.join(repeated)} appear more than once")
    return header, rows[1:]


def refuse_overwrite(outputs: Iterable[Path], inputs: Iterable[Path]) -> None:
    """`SceneError` when an output file would replace an input file (the same file by any
    path), or is an existing folder."""
    for out in outputs:
        if out.is_dir():
            raise SceneError(f"{out}: is a folder, not a file")
        for source in inputs:
            if out.exists() and source.exists() and out.samefile(source):
                raise SceneError(f"{out}: would overwrite the input {source}")
