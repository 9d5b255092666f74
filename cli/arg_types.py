"""Argparse types the commands share: a duration, a count."""

from __future__ import annotations

import argparse
import math


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
