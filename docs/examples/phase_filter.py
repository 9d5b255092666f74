"""Example node: forwards the contacts of one phase (tip or tangential) on a topic of its own.

Started by docs/examples/tip_map.yaml, or by hand next to a running graph:

    python docs/examples/phase_filter.py --name phase_filter --namespace /whisker0 \
        --param phase:=tangential
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from vibrissa.msgs import ContactPhase, ContactPointArray, EndOfStream
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main

log = logging.getLogger("phase_filter")


@dataclass(frozen=True)
class PhaseFilterParams:
    """The node's parameters: ``--param KEY:=VALUE``, or the launch file's ``param`` list."""

    phase: Literal["tip", "tangential"] = "tip"
    input_topic: str = "contact"  # relative names resolve in the node's namespace
    output_topic: str = "tip_contact"
    wait_for: tuple[str, ...] = ()  # nodes that must listen before anything goes out


def main(argv: Sequence[str] | None = None) -> int:
    args = NodeArgs.parse(argv, prog="phase_filter")
    configure_logging()
    params = load_params(PhaseFilterParams, args.params_file, args.params)
    wanted = ContactPhase.TIP if params.phase == "tip" else ContactPhase.TANGENTIAL
    with Node.from_args(args) as node:  # heartbeat, Ctrl-C handling, sockets closed at the end
        contacts = node.create_subscriber({params.input_topic: ContactPointArray})
        kept = node.create_publisher(params.output_topic, ContactPointArray,
                                     wait_for=params.wait_for)
        node.counters.update(kept=0, dropped=0)  # reported in the node's status
        node.set_state("running", f"keeping {params.phase} contacts")
        while not node.stop_requested:
            rx = contacts.receive(0.1)  # None after 0.1 s without a message
            if rx is None:
                continue
            if isinstance(rx.msg, EndOfStream):  # the stream ended: end ours, then stop
                kept.publish_end_of_stream(node.fqn)
                break
            # one message per tick, a row per whisker in contact (a single whisker: one row)
            keep = rx.msg.phase == wanted
            kept.publish(rx.msg.select_rows(keep))  # the same tick, its rows of that phase
            node.counters["kept"] += int(keep.sum())
            node.counters["dropped"] += int((~keep).sum())
        log.info("%s: kept %d %s contacts, dropped %d", node.fqn, node.counters["kept"],
                 params.phase, node.counters["dropped"])
    return 0


if __name__ == "__main__":
    run_main(main)  # exit status; an error at start is one line (traceback: VIBRISSA_DEBUG=1)
