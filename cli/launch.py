"""``vibrissa launch FILE.yaml [name:=value ...]``: the command line of the launch system
(``vibrissa.launch``): it parses the arguments and calls the launcher."""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from typing import Any

from vibrissa.cli.arg_types import Parser, folder, seconds
from vibrissa.cli.graph import domain_id
from vibrissa.cli.main import parse_command_line
from vibrissa.launch.description import (
    LaunchDescription,
    LaunchFileError,
    check_node_params,
    load_launch_file,
    node_params,
    parse_arg_overrides,
)
from vibrissa.launch.launcher import DEFAULT_GRACE_S, Launcher, node_command, resolve_launch_file
from vibrissa.runtime.node import DEBUG_ENV
from vibrissa.wire.security import KEYS_ENV, Keys, KeysError
from vibrissa.wire.transport import DOMAIN_ENV


def run_launch(args: argparse.Namespace) -> int:
    """The ``launch`` subcommand (``func`` of its parser).

    Parameters
    ----------
    args : argparse.Namespace
        ``file``, ``overrides``, ``grace``, ``show_args``, ``dry_run``.

    Returns
    -------
    int
        Exit status; 2 for an invalid launch file or argument.
    """
    path = resolve_launch_file(args.file)
    try:
        overrides = parse_arg_overrides(args.overrides)
        description = load_launch_file(path, overrides)
        check_node_params(description)
    except LaunchFileError as exc:
        print(f"vibrissa launch: error: {exc}", file=sys.stderr)
        return 2
    file_keys = description.transport.keys if description.transport else None
    try:  # --keys, else the file's, else VIBRISSA_KEYS (the launcher reads that one itself)
        keys = Keys.load(args.keys or file_keys) if args.keys or file_keys else None
    except KeysError as exc:
        print(f"vibrissa launch: error: {exc}", file=sys.stderr)
        return 2
    if args.show_args:
        _print_args(description)
        return 0
    if args.dry_run:
        for spec in description.nodes:
            params = "<params-file>" if spec.params else None
            print(f"[{spec.name}] " + shlex.join(node_command(spec, params)))
            for key, value in node_params(spec).items():
                print(f"[{spec.name}]   param {key}: {value!r}")
        return 0
    return Launcher(description, grace_s=args.grace, domain=args.domain, debug=args.debug,
                    keys=keys, insecure=args.insecure).run()


def _print_args(description: LaunchDescription) -> None:
    if not description.args:
        print(f"{description.source}: no arguments")
        return
    print(f"Arguments of {description.source} (pass as NAME:=VALUE):")
    for arg in description.args:
        default = "(required)" if arg.default is None else f"default: {arg.default!r}"
        print(f"  {arg.name}: {arg.description or '-'}  [{default}]")


def register(subparsers: Any) -> None:
    """Add the ``launch`` subcommand to the ``vibrissa`` dispatcher.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.
    """
    parser = subparsers.add_parser(
        "launch",
        help="run a node graph from a YAML launch file",
        description="Run a node graph from a YAML launch file (ROS 2 style). Arguments "
                    "declared in the file are set with NAME:=VALUE.",
    )
    parser.add_argument("file", help="launch file path, or the name of a packaged launch file")
    parser.add_argument("overrides", nargs="*", metavar="NAME:=VALUE",
                        help="launch argument values (before or after the flags)")
    parser.add_argument("--domain", type=domain_id, metavar="N",
                        help=f"run the graph on domain N (default: ${DOMAIN_ENV}, else 0, "
                             "else the next free one); the tools take the same --domain")
    parser.add_argument("--insecure", action="store_true",
                        help="let a graph off loopback (transport bind or proxy_host) run "
                             "without keys: plain text anyone on the network can read and write")
    parser.add_argument("--keys", metavar="DIR", type=folder,
                        help="encrypt and authenticate every socket with the CURVE keys of DIR "
                             f"(`vibrissa keys DIR`; default: ${KEYS_ENV}, else the file's "
                             "transport.keys, else none)")
    parser.add_argument("--debug", action="store_true",
                        help=f"nodes print the traceback of an error at start ({DEBUG_ENV}=1)")
    parser.add_argument("--grace", type=seconds, default=DEFAULT_GRACE_S, metavar="SECONDS",
                        help="wait after SIGINT, then after SIGTERM, before escalating "
                             f"(default {DEFAULT_GRACE_S:g})")
    parser.add_argument("--show-args", action="store_true",
                        help="list the launch file's arguments and exit")
    parser.add_argument("--dry-run", action="store_true",
                        help="validate and print the node commands without starting anything")
    parser.set_defaults(func=run_launch, overrides_anywhere=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``vibrissa launch`` alone (same as ``vibrissa launch ...``)."""
    parser = Parser(prog="vibrissa")
    register(parser.add_subparsers(dest="command", required=True))
    args = parse_command_line(parser, ["launch", *(sys.argv[1:] if argv is None else argv)])
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
