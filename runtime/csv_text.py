"""CSV files of floats that read back exactly: a float is written as its ``repr`` (the shortest
text that parses back to the same float64), a missing value (NaN) as an empty cell."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from pathlib import Path


def cell(value: float) -> str:
    """The CSV cell of a float: its ``repr``, empty for NaN."""
    value = float(value)
    return "" if math.isnan(value) else repr(value)


def write_csv(path: Path, columns: Sequence[str], rows: Iterable[Sequence[str]]) -> None:
    """A header of ``columns`` and the ``rows`` (UTF-8, ``\\n`` line ends); creates the folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows(rows)
