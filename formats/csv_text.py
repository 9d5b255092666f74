"""CSV files of floats that read back exactly: a float is written as its ``repr`` (the shortest
text that parses back to the same float64), a missing value (NaN) as an empty cell; read with
the columns they must have, record by record, so that a file of any length streams."""

from __future__ import annotations

import contextlib
import csv
import math
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import ArrayLike

from vibrissa.formats.errors import SceneError
from vibrissa.formats.files import is_stream, open_text, whole_file


def cell(value: float) -> str:
    """The CSV cell of a float: its ``repr``, empty for NaN."""
    value = float(value)
    return "" if math.isnan(value) else repr(value)


def cells(values: ArrayLike) -> list[list[str]]:
    """The cells of a (rows, columns) array of floats, each as :func:`cell` gives it."""
    return [["" if v != v else repr(v) for v in row]
            for row in np.asarray(values, dtype=np.float64).tolist()]


@contextlib.contextmanager
def csv_writer(path: Path, columns: Sequence[str]) -> Iterator[Any]:
    """A ``csv.writer`` into ``path`` (UTF-8, ``\\n`` line ends) with the header ``columns``
    written; creates the folder. A file is written whole or not at all (`whole_file`); a
    stream (`is_stream`: a pipe, ``/dev/stdout``) gets the rows as they come."""
    with contextlib.ExitStack() as stack:
        target = path if is_stream(path) else stack.enter_context(whole_file(path))
        with target.open("w", newline="", encoding="utf-8") as handle:
            writer = csv.writer(handle, lineterminator="\n")
            writer.writerow(columns)
            yield writer


def write_csv(path: Path, columns: Sequence[str], rows: Iterable[Sequence[str]]) -> None:
    """A header of ``columns`` and the ``rows``, by :func:`csv_writer`."""
    with csv_writer(path, columns) as writer:
        writer.writerows(rows)


MAX_LINE_CHARS = 1 << 20
"""Characters of a CSV line at most (the csv module's fields stop at 128 Ki); only regular files
are read (`open_text`), so a line without end (``/dev/zero``) never comes."""


def csv_records(path: Path) -> Iterator[tuple[int, list[str]]]:
    """Each record of the CSV ``path`` with the file line it starts on (1 for the first); a
    UTF-8 byte order mark (as spreadsheets save) and blank lines are no part of the table.

    Raises
    ------
    SceneError
        Naming the file, and the line of bytes that are not UTF-8 (with their byte offset),
        of a field longer than the csv module takes (with its column) or of bad quoting.
    """
    record: list[str] = []  # the lines of the record being read

    def lines(handle: TextIO) -> Iterator[str]:
        for text in handle:  # a regular file (`open_text`): a line is no longer than it
            if len(text) > MAX_LINE_CHARS:
                raise SceneError(f"{path}: line {line + len(record)}: longer than "
                                 f"{MAX_LINE_CHARS} characters (not a CSV file?)")
            record.append(text)
            yield text

    line, header = 1, None
    try:
        with open_text(path) as handle:
            reader = csv.reader(lines(handle))
            for row in reader:
                if row:
                    header = header or row
                    yield line, row
                record.clear()
                line = reader.line_num + 1
    except UnicodeDecodeError:  # its position counts from a block the decoder was given
        raise SceneError(f"{path}: {_not_utf8(path)}") from None
    except csv.Error as exc:
        raise SceneError(f"{path}: line {line}{_csv_problem(exc, record, header)}") from None
    except OSError as exc:
        raise SceneError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _not_utf8(path: Path) -> str:
    """Where the first byte of ``path`` that is not UTF-8 is (a multi-byte character never
    holds a newline byte, so each line decodes alone)."""
    offset = 0
    with path.open("rb") as handle:
        for number, raw in enumerate(handle, 1):
            try:
                raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                return (f"line {number}: byte 0x{raw[exc.start]:02x} at offset "
                        f"{offset + exc.start} is not UTF-8 ({exc.reason})")
            offset += len(raw)
    return "not UTF-8"


def _csv_problem(exc: csv.Error, record: list[str], header: list[str] | None) -> str:
    """``: what is wrong`` by ``exc``; for a field over the csv module's limit, first
    ``, column NAME``: the record read again without the limit (at most the limit and a line)."""
    limit = csv.field_size_limit()
    if "field limit" not in str(exc):
        return f": {exc}"
    csv.field_size_limit(sum(map(len, record)) + 1)
    try:
        row = next(csv.reader(record), [])
    except csv.Error:
        row = []
    finally:
        csv.field_size_limit(limit)
    long = next((i for i, text in enumerate(row) if len(text) > limit), None)
    where = ""
    if long is not None:
        where = f", column {header[long].strip() if header and long < len(header) else long + 1}"
    return f"{where}: a field longer than {limit} characters (an unclosed quote?)"


def read_csv(path: Path, columns: Sequence[str]) -> tuple[list[str], Iterator[tuple[int, list[str]]]]:
    """The header (stripped) of a CSV that must have ``columns`` (more are allowed, each named
    once, and unnamed ones), and its rows after it, each with its file line, as they are read
    (:func:`csv_records`); `SceneError` names the file and what is wrong."""
    records = csv_records(path)
    first = next(records, None)
    header = [c.strip() for c in first[1]] if first else []
    missing = [name for name in columns if name not in header]
    if missing:
        raise SceneError(f"{path}: missing column(s) {', '.join(missing)} (the columns are "
                         f"{','.join(columns)})")
    # unnamed columns (a spreadsheet's trailing commas) are extra columns like any other
    repeated = sorted({name for name in header if name and header.count(name) > 1})
    if repeated:
        raise SceneError(f"{path}: column(s) {', '.join(repeated)} appear more than once")
    return header, records


def refuse_overwrite(outputs: Iterable[Path], inputs: Iterable[Path]) -> None:
    """`SceneError` when an output file would replace an input file (the same file by any
    path), or is an existing folder."""
    for out in outputs:
        if out.is_dir():
            raise SceneError(f"{out}: is a folder, not a file")
        for source in inputs:
            if out.exists() and source.exists() and out.samefile(source):
                raise SceneError(f"{out}: would overwrite the input {source}")
