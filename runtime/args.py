"""The node command line of ARCHITECTURE.md: ``--name``, ``--namespace``, parameters, remaps."""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path

from vibrissa.wire.topics import node_fqn, resolve_topic


@dataclasses.dataclass(frozen=True)
class NodeArgs:
    """The node command line of ARCHITECTURE.md.

    ``params`` keeps the raw ``--param KEY:=VALUE`` texts; ``load_params`` parses them.
    """

    name: str
    namespace: str = "/"
    params_file: Path | None = None
    params: dict[str, str] = dataclasses.field(default_factory=dict)
    remaps: dict[str, str] = dataclasses.field(default_factory=dict)

    @property
    def fqn(self) -> str:
        """Fully qualified node name, ``/namespace/name``."""
        return node_fqn(self.name, self.namespace)

    @classmethod
    def parse(cls, argv: Sequence[str] | None = None, prog: str | None = None) -> NodeArgs:
        """Parse ``--name NAME [--namespace NS] [--params-file FILE] [--param K:=V]...
        [--remap FROM:=TO]...``; bad input exits with status 2 and a usage message."""
        parser = argparse.ArgumentParser(prog=prog, description="vibrissa node")
        parser.add_argument("--name", required=True, help="node name (one token)")
        parser.add_argument("--namespace", default="/", help="namespace, e.g. /whisker0")
        parser.add_argument("--params-file", type=Path, help="YAML mapping of parameters")
        parser.add_argument("--param", action="append", default=[], type=_param,
                            metavar="KEY:=VALUE", help="parameter override (YAML scalar)")
        parser.add_argument("--remap", action="append", default=[], type=_key_value,
                            metavar="FROM:=TO", help="topic remap")
        ns = parser.parse_args(argv)
        try:
            node_fqn(ns.name, ns.namespace)
            for source, target in ns.remap:
                resolve_topic(source, ns.namespace)
                resolve_topic(target, ns.namespace)
        except ValueError as exc:
            parser.error(str(exc))
        return cls(ns.name, ns.namespace, ns.params_file, dict(ns.param), dict(ns.remap))


def expand_home(value: str) -> str:
    """A ``NAME:=VALUE`` word's value with a leading ``~`` or ``~/`` made the home folder, as a
    shell makes it in ``NAME=~/x`` (it leaves ``NAME:=~/x`` as it is)."""
    return os.path.expanduser(value) if value == "~" or value.startswith("~/") else value


def _key_value(text: str) -> tuple[str, str]:
    key, sep, value = text.partition(":=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY:=VALUE, got {text!r}")
    return key, value


def _param(text: str) -> tuple[str, str]:
    key, value = _key_value(text)
    return key, expand_home(value)
