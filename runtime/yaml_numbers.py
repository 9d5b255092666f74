"""YAML as people write numbers: ``1e-5`` is a float (YAML 1.2), not the string PyYAML's YAML
1.1 rules make of an exponent without a decimal point. Every YAML file vibrissa reads (launch
files, parameter files, scene files) is read with `Loader` or a subclass of it."""

from __future__ import annotations

import re
from typing import Any

import yaml

__all__ = ["Loader", "load"]


class Loader(yaml.SafeLoader):
    """SafeLoader that reads ``1e-5``, ``-2E3`` as floats."""


Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9]+[eE][-+]?[0-9]+$"), list("-+0123456789")
)


def load(text: str) -> Any:
    """``yaml.safe_load(text)`` with `Loader`'s numbers."""
    return yaml.load(text, Loader=Loader)  # noqa: S506 - a SafeLoader subclass
