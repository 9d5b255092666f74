"""``vibrissa keys DIR [--client NAME ...]``: CURVE key pairs for a graph and its clients."""

from __future__ import annotations

import argparse
from typing import Any

from vibrissa.wire.security import GRAPH_KEY, KEYS_ENV, create_keys


def run_keys(args: argparse.Namespace) -> int:
    """Make the graph's pair in ``args.folder`` (once) and one per ``--client``; list them."""
    written = create_keys(args.folder, tuple(args.client))
    for path in written:
        print(f"wrote {path}")
    if not written:
        print(f"{args.folder}: all keys exist already (nothing written)")
    print(f"launch with --keys {args.folder} (or {KEYS_ENV}={args.folder}); a client gets the "
          f"folder {args.folder}/clients/NAME and uses --keys with it. Keep "
          f"{GRAPH_KEY}.key_secret to the graph's own machine.")
    return 0


def register(subparsers: Any) -> None:
    """Add the ``keys`` subcommand to the ``vibrissa`` dispatcher."""
    parser = subparsers.add_parser(
        "keys",
        help="make CURVE key pairs: the graph's, and its clients'",
        description="Make the CURVE key pairs that encrypt and authenticate a graph: the "
                    f"graph's own ({GRAPH_KEY}.key, {GRAPH_KEY}.key_secret) in FOLDER, and, "
                    "for each --client NAME, a pair in FOLDER/clients/NAME whose public key "
                    "is allowed in (FOLDER/authorized). Existing keys are kept. Secret files "
                    "are readable by you alone (0600).",
    )
    parser.add_argument("folder", metavar="FOLDER", help="the key folder (created 0700)")
    parser.add_argument("--client", action="append", default=[], metavar="NAME",
                        help="also make a client's pair (repeatable)")
    parser.set_defaults(func=run_keys)
