"""Entry point of the ``vibrissa`` command: one subcommand per job."""

from __future__ import annotations

import argparse
import atexit
import gc
import importlib
import os
import signal
import sys
from collections.abc import Sequence

from vibrissa.cli.arg_types import Parser

EXIT_FAILED, EXIT_USAGE = 1, 2
"""Exit statuses of every command: 1 the work failed; 2 the command line or an input was
refused (a missing file, a file of the wrong kind, a bad value), as argparse's own errors."""

# Each module registers its subcommands with `register(subparsers)`; every subparser
# sets `func(args) -> int`. A command imports only its own module (start-up time).
_COMMAND_MODULES = ("mechanics", "scenes", "launch", "bag", "topic", "keys", "sensor", "sim")
_MODULE_OF = {"sweep": "mechanics", "reconstruct": "mechanics", "study": "mechanics",
              "simulate": "scenes", "launch": "launch", "bag": "bag", "topic": "topic",
              "keys": "keys", "sensor": "sensor", "sim": "sim"}


def parse_command_line(parser: argparse.ArgumentParser, argv: Sequence[str]) -> argparse.Namespace:
    """``parser.parse_args``, except that a command with ``overrides_anywhere`` also takes its
    ``NAME:=VALUE`` overrides after its flags (``launch demo --dry-run out:=x``)."""
    args, extras = parser.parse_known_args(argv)
    if extras:
        anywhere = getattr(args, "overrides_anywhere", False)
        if not anywhere or not all(":=" in e for e in extras):
            flag = next((e for e in extras if e.startswith("--") and ":=" not in e), None)
            hint = (f" (a launch argument is NAME:=VALUE: {flag[2:].split('=')[0]}:=...)"
                    if anywhere and flag else "")
            _chosen(parser, args).error(f"unrecognized arguments: {' '.join(extras)}{hint}")
        args.overrides = [*args.overrides, *extras]
    return args


def _chosen(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The parser of the (sub)command that ``args`` ran (``topic hz``), whose usage an error
    in its arguments shows."""
    for action in parser._actions:  # argparse keeps its subparsers nowhere public
        if isinstance(action, argparse._SubParsersAction):
            chosen = action.choices.get(getattr(args, action.dest or "", None) or "")
            if isinstance(chosen, argparse.ArgumentParser):
                return _chosen(chosen, args)
    return parser


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``vibrissa`` parser: with a known ``command``, only that command's module is
    imported; else every command's (``--help``, a misspelt command)."""
    parser = Parser(
        prog="vibrissa",
        description="Vibrissa-like tactile sensing: simulate, reconstruct, run the node graph.",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    modules = (_MODULE_OF[command],) if command in _MODULE_OF else _COMMAND_MODULES
    for name in modules:
        importlib.import_module(f"vibrissa.cli.{name}").register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status.

    An error that escapes a command is one line on stderr and status 2 for a refused input
    (OSError, ValueError: a missing file, a file of the wrong kind), else 1 (its traceback with
    ``VIBRISSA_DEBUG=1``); output cut off by its reader (``| head``) ends the command quietly
    with status 141 (128 + SIGPIPE), as a shell tool that the pipe kills.

    As the process's own command (``argv`` None) it freezes the objects at exit
    (``gc.freeze``): the interpreter's collections at shutdown would walk numba's 1e5 objects
    for 0.3-0.4 s to free memory that the ending process returns anyway, and SIGTERM ends it
    as Ctrl-C does (`_terminated`).
    """
    if argv is None:
        atexit.register(gc.freeze)
        signal.signal(signal.SIGTERM, _terminated)
    argv = sys.argv[1:] if argv is None else argv
    command = argv[0] if argv and not argv[0].startswith("-") else None
    try:  # the command's module loads here (0.1-0.3 s): Ctrl-C meanwhile ends quietly too
        args = parse_command_line(build_parser(command), argv)
    except KeyboardInterrupt:
        return 128 + signal.SIGINT
    command = " ".join(filter(None, (args.command, getattr(args, f"{args.command}_command", ""))))
    try:
        return int(args.func(args))
    except BrokenPipeError:
        # Nobody reads stdout any more: point it at /dev/null so that the interpreter's
        # final flush does not fail again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except KeyboardInterrupt:
        return 128 + signal.SIGINT
    except Exception as exc:  # noqa: BLE001 - one line for the user, the traceback on demand
        stopped = _stop_status(exc)
        if stopped is not None:
            return stopped
        from vibrissa.runtime.node import DEBUG_ENV  # the node runtime (ZeroMQ) only here

        if os.environ.get(DEBUG_ENV, "") not in ("", "0"):
            raise
        if isinstance(exc, (OSError, ValueError)):  # a missing file, a file of the wrong kind
            print(f"vibrissa {command}: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
        print(f"vibrissa {command}: error: {type(exc).__name__}: {exc} (for the "
              f"traceback: {DEBUG_ENV}=1)", file=sys.stderr)
        return EXIT_FAILED


def _stop_status(exc: BaseException) -> int | None:
    """The status of a SIGTERM or Ctrl-C that ``exc`` wraps (raised inside a compiled kernel's
    call back into Python, it comes out as a SystemError caused by it), else None."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        if isinstance(cause, SystemExit) and isinstance(cause.code, int):
            return cause.code
        if isinstance(cause, KeyboardInterrupt):
            return 128 + signal.SIGINT
        cause = cause.__cause__ or cause.__context__
    return None


def _terminated(signum: int, _frame: object) -> None:
    """SIGTERM (``kill``, ``timeout``) unwinds the command as Ctrl-C does, so that what it was
    writing is removed (`vibrissa.formats.files.whole_file`); status 128 + 15."""
    raise SystemExit(128 + signum)


if __name__ == "__main__":
    sys.exit(main())
