"""Bag playback through a node's gated publishers: nothing goes out before the named
downstream nodes are subscribed."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterable, Sequence

from vibrissa.runtime.node import Node
from vibrissa.wire.bag import PlayResult, play_bag
from vibrissa.wire.transport import MessageTypes, Publisher


def play_bag_gated(
    node: Node,
    path: str | os.PathLike[str],
    wait_for: Sequence[str],
    timeout_s: float,
    *,
    rate: float | None = 1.0,
    topics: Iterable[str] | None = None,
    wait_s: float = 0.5,
    stop: threading.Event | None = None,
) -> tuple[PlayResult, dict[str, Publisher]]:
    """Play ``path`` (``vibrissa.wire.bag.play_bag``) on publishers of ``node``.

    With ``wait_for`` node names, each topic's publisher starts held (its messages buffer, in
    order) and playback begins once every named node reports the topic, or is abandoned
    (``PlayResult.interrupted``) after ``timeout_s``; without, it begins after ``wait_s``.
    ``stop`` (default: the node's own stop) ends it early. Returns the result and the
    publishers by topic (the node owns and closes them), e.g. to end a stream the bag does not.
    """
    publishers: dict[str, Publisher] = {}

    def make(topic: str, msg_type: MessageTypes, hwm: int) -> Publisher:
        publishers[topic] = node.create_publisher(topic, msg_type, wait_for=wait_for, hwm=hwm)
        return publishers[topic]

    def ready(made: dict[str, Publisher]) -> bool:
        return all(node.wait_for_subscribers(topic, wait_for, timeout_s) for topic in made)

    result = play_bag(path, rate=rate, topics=topics, wait_s=0.0 if wait_for else wait_s,
                      stop=stop if stop is not None else node.stop_event,
                      make_publisher=make, ready=ready if wait_for else None)
    return result, publishers
