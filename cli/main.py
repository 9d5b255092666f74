"""Entry point of the ``vibrissa`` command: one subcommand per job."""

from __future__ import annotations

import argparse
import importlib
import sys

# Each module registers its subcommands with `register(subparsers)`; every subparser
# sets `func(args) -> int`.
_COMMAND_MODULES = ("mechanics", "launch", "bag", "topic")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vibrissa",
        description="Vibrissa-like tactile sensing: simulate, reconstruct, run the node graph.",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _COMMAND_MODULES:
        importlib.import_module(f"vibrissa.cli.{name}").register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
