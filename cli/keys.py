"""``vibrissa keys DIR [--client NAME ...] [--authorize NAME.key ...]`` and ``vibrissa keys DIR
--join graph.key --name NAME``: CURVE key pairs for a graph and its clients, on one host or
two."""

from __future__ import annotations

import argparse
from typing import Any

from vibrissa.wire.security import (
    GRAPH_KEY,
    KEYS_ENV,
    authorize_keys,
    create_keys,
    join_keys,
)


def run_keys(args: argparse.Namespace) -> int:
    """Make the graph's pair in ``args.folder`` (once), one per ``--client``, let in each
    ``--authorize`` key; or, with ``--join``, a client's folder on its own host."""
    folder = args.folder
    if args.join is not None:
        if args.name is None or args.client or args.authorize:
            raise ValueError("--join takes --name NAME, and neither --client nor --authorize")
        written = join_keys(folder, args.name, args.join)
        for path in written:
            print(f"wrote {path}")
        print(f"client folder {folder}: launch with --keys {folder}. Let it in on the graph's "
              f"host: carry the public key there (scp {folder}/{args.name}.key HOST:) and run "
              f"`vibrissa keys GRAPH_DIR --authorize {args.name}.key` (the secret "
              f"{args.name}.key_secret stays here)")
        return 0
    if args.name is not None:
        raise ValueError("--name goes with --join")
    written = create_keys(folder, tuple(args.client))
    written += authorize_keys(folder, tuple(args.authorize))
    for path in written:
        print(f"wrote {path}")
    if not written:
        print(f"{folder}: all keys exist already (nothing written)")
    print(f"launch with --keys {folder} (or {KEYS_ENV}={folder}); a client gets the folder "
          f"{folder}/clients/NAME and uses --keys with it (on another host: carry it there over "
          f"ssh, it holds NAME's secret). Or, only public keys travelling: on the client's host "
          f"`vibrissa keys DIR --join {GRAPH_KEY}.key --name NAME` with a copy of "
          f"{folder}/{GRAPH_KEY}.key, then here `vibrissa keys {folder} --authorize NAME.key`. "
          f"Keep {GRAPH_KEY}.key_secret to the graph's own machine (docs/HOSTS.md).")
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
                    "are readable by you alone (0600). A client on another host: carry "
                    "FOLDER/clients/NAME there over ssh; or make its pair there (--join, with "
                    f"a copy of the graph's public {GRAPH_KEY}.key) and let its public key in "
                    "here (--authorize): then no secret travels (docs/HOSTS.md).",
    )
    parser.add_argument("folder", metavar="FOLDER", help="the key folder (created 0700)")
    parser.add_argument("--client", action="append", default=[], metavar="NAME",
                        help="also make a client's pair (repeatable)")
    parser.add_argument("--authorize", action="append", default=[], metavar="NAME.key",
                        help="let in a client whose pair was made on its own host: copy its "
                             "public key into FOLDER/authorized (repeatable)")
    parser.add_argument("--join", metavar="GRAPH.key",
                        help="make FOLDER a client's folder on this host: the graph's public key "
                             "(a copy of its graph.key) and a new pair --name")
    parser.add_argument("--name", metavar="NAME", help="the client's name, with --join")
    parser.set_defaults(func=run_keys)
