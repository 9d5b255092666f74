"""Argparse types the commands share: a duration, a count, a folder; and their parser."""

from __future__ import annotations

import argparse
import math
import re

_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` (and its subparsers) that takes ``-1e3`` as a value, as it takes
    ``-1000`` and ``-0.5`` (``--y0 -1e3``; argparse's own pattern has no exponent)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._negative_number_matcher = _NEGATIVE_NUMBER


def seconds(text: str) -> float:
    """Argparse type: a duration in seconds, finite and >= 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def count(text: str) -> int:
    """Argparse type: a count of things, an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def folder(text: str) -> str:
    """Argparse type: a folder's name, not empty (an empty ``--keys ''`` is a mistake, not
    "no keys")."""
    if not text:
        raise argparse.ArgumentTypeError("expected a folder, got an empty name")
    return text
