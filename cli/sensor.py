"""``vibrissa sensor bias NAME``: ask a running force/torque driver (``nodes/netft.py``) to tare
its sensor. The driver does it only while its rod is free; this command prints whether it did."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from vibrissa.cli.graph import add_endpoint_flags, endpoints_from, where
from vibrissa.msgs import NodeStatus, SensorCommand
from vibrissa.wire.topics import STATUS_TOPIC, resolve_topic
from vibrissa.wire.transport import Publisher, Subscriber


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("sensor", help="commands to a force/torque sensor driver")
    commands = parser.add_subparsers(dest="sensor_command", required=True, metavar="COMMAND")
    bias = commands.add_parser(
        "bias", help="tare the sensor (only done while its rod is free)",
        description="Publish a bias request on NAME's command topic and wait for the driver's "
                    "answer in its status. Exit 0 biased, 1 refused (the driver logs why), "
                    "3 no driver answered.")
    bias.add_argument("name", metavar="NAME",
                      help="the driver's namespace or node name, e.g. /w0 (topic NAME/sensor_command)")
    bias.add_argument("--topic", default="sensor_command", help="command topic, relative to NAME")
    bias.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the answer")
    add_endpoint_flags(bias)
    bias.set_defaults(func=run_bias)


def run_bias(args: argparse.Namespace) -> int:
    endpoints = endpoints_from(args)
    namespace = args.name if args.name.startswith("/") else f"/{args.name}"
    topic = resolve_topic(args.topic, namespace)
    with Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as status, \
            Publisher(topic, SensorCommand, endpoints) as publisher:
        first: dict[str, dict[str, int]] = {}  # driver -> its counters before the request
        deadline = time.monotonic() + args.timeout
        next_send = 0.0
        while time.monotonic() < deadline:
            if first and time.monotonic() >= next_send:  # again until it answers (slow joiners)
                publisher.publish(SensorCommand(stamp=time.time(), command="bias",
                                                sender="vibrissa sensor bias"))
                next_send = time.monotonic() + 0.25
            rx = status.receive(0.05)
            if rx is None or not isinstance(rx.msg, NodeStatus) or topic not in rx.msg.subscribes:
                continue
            counters = rx.msg.counters
            before = first.setdefault(rx.msg.node, dict(counters))
            if counters.get("biases", 0) > before.get("biases", 0):
                print(f"{rx.msg.node}: sensor biased")
                return 0
            if counters.get("bias_refused", 0) > before.get("bias_refused", 0):
                print(f"{rx.msg.node}: bias refused: the rod is not free (the driver's log says "
                      "why)", file=sys.stderr)
                return 1
    print(f"vibrissa sensor bias: no driver answered on {topic} within {args.timeout:g} s "
          f"({where(args, endpoints)})", file=sys.stderr)
    return 3
