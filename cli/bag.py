"""``vibrissa bag``: record, play, inspect and export MCAP bags of the node graph."""

from __future__ import annotations

import argparse
import math
import sys
import threading
from typing import Any

import zmq

from vibrissa.cli.graph import add_endpoint_flags, endpoints_from, stop_on_signals
from vibrissa.nodes import recorder
from vibrissa.runtime import Node
from vibrissa.runtime.playback import play_bag_gated
from vibrissa.wire.bag import BagReader, PlayResult, export_json, play_bag
from vibrissa.wire.transport import Endpoints


def register(subparsers: Any) -> None:
    """Add ``bag`` with its subcommands ``record``, ``play``, ``info``, ``export``."""
    bag = subparsers.add_parser("bag", help="record, play, inspect and export MCAP bags")
    sub = bag.add_subparsers(dest="bag_command", required=True, metavar="SUBCOMMAND")

    p = sub.add_parser("record", help="record topics to an MCAP bag")
    p.add_argument("topics", nargs="*", metavar="TOPIC", help="topics to record (default: all)")
    p.add_argument("-o", "--output", required=True, metavar="FILE.mcap")
    p.add_argument("--duration", type=float, default=0.0, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C/SIGTERM)")
    p.add_argument("--until-eos", action="store_true",
                   help="stop once every topic that carried EndOfStream has ended")
    p.add_argument("--eos-grace", type=float, default=1.0, metavar="S",
                   help="with --until-eos, keep recording S seconds after the last end")
    p.add_argument("--name", default="bag_recorder",
                   help="node name in the graph's status (for readiness gates)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing FILE.mcap")
    add_endpoint_flags(p)
    p.set_defaults(func=_record)

    p = sub.add_parser("play", help="publish a bag's messages with their original timing "
                       "(each with its own type, in recorded order per topic)")
    p.add_argument("bag", metavar="FILE.mcap")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--rate", type=float, default=1.0, metavar="R",
                       help="time scale, 2 = twice as fast (default 1)")
    speed.add_argument("--fast", action="store_true", help="publish as fast as possible")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics")
    p.add_argument("--wait", type=float, default=1.0, metavar="S",
                   help="seconds to let subscribers connect before the first message")
    p.add_argument("--wait-for", nargs="+", default=[], metavar="NODE",
                   help="also wait until these nodes report every played topic as received")
    p.add_argument("--wait-timeout", type=float, default=30.0, metavar="S",
                   help="give up on --wait-for after S seconds (default 30)")
    add_endpoint_flags(p)
    p.set_defaults(func=_play)

    p = sub.add_parser("info", help="summarise a bag")
    p.add_argument("bag", metavar="FILE.mcap")
    p.set_defaults(func=_info)

    p = sub.add_parser("export", help="convert to a JSON-encoded MCAP that Foxglove opens")
    p.add_argument("bag", metavar="FILE.mcap")
    p.add_argument("-o", "--output", required=True, metavar="OUT.mcap")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics")
    p.set_defaults(func=_export)


def _record(args: argparse.Namespace) -> int:
    params = recorder.RecorderParams(
        output=args.output,
        topics=tuple(args.topics),
        stop_on_eos=args.until_eos,
        eos_grace_s=args.eos_grace,
        duration_s=args.duration,
        overwrite=args.overwrite,
    )
    what = ", ".join(params.topics) if params.topics else "all topics"
    print(f"recording {what} to {params.output}", file=sys.stderr, flush=True)
    with Node(args.name, endpoints=endpoints_from(args)) as node:  # SIGINT/SIGTERM stop it
        result = recorder.run(node, params)
    print(f"{result.count} messages written to {params.output} ({result.reason}; "
          f"lost {result.lost}, rejected {result.rejected})", file=sys.stderr)
    return 0


def _play(args: argparse.Namespace) -> int:
    rate = None if args.fast else args.rate
    if rate is not None and not (rate > 0 and math.isfinite(rate)):
        print(f"vibrissa bag play: --rate must be > 0, got {rate}", file=sys.stderr)
        return 2
    endpoints = endpoints_from(args)
    with stop_on_signals() as stop:
        if args.wait_for:
            result = _play_gated(args, rate, endpoints, stop)
        else:
            context: zmq.Context[Any] = zmq.Context()
            try:
                result = play_bag(args.bag, rate=rate, topics=args.topics, wait_s=args.wait,
                                  endpoints=endpoints, context=context, stop=stop)
            finally:
                context.term()  # returns once queued messages left (linger drain_s)
    state = "interrupted" if result.interrupted else "done"
    print(f"published {result.total} messages in {result.wall_s:.3f} s ({state})",
          file=sys.stderr)
    return 130 if result.interrupted else 0


def _play_gated(args: argparse.Namespace, rate: float | None, endpoints: Endpoints,
                stop: threading.Event) -> PlayResult:
    """Play as node ``bag_player``: each publisher is held until ``--wait-for`` nodes are up."""
    with Node("bag_player", endpoints=endpoints, handle_signals=False) as node:
        node.set_state("running")
        result, _ = play_bag_gated(node, args.bag, args.wait_for, args.wait_timeout, rate=rate,
                                   topics=args.topics, stop=stop)
        return result


def _info(args: argparse.Namespace) -> int:
    print(BagReader(args.bag).info().format())
    return 0


def _export(args: argparse.Namespace) -> int:
    info = export_json(args.bag, args.output, topics=args.topics)
    print(f"wrote {info.message_count} JSON messages to {args.output}", file=sys.stderr)
    return 0
