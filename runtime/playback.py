"""Bag playback through a node's gated publishers: nothing goes out before the named
downstream nodes are subscribed."""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Iterable, Mapping, Sequence

from vibrissa.runtime.node import Node
from vibrissa.wire.bag import PlayResult, play_bag
from vibrissa.wire.transport import DEFAULT_HWM, MessageTypes, Publisher

log = logging.getLogger(__name__)


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
    topic_wait_for: Mapping[str, Sequence[str]] | None = None,
) -> tuple[PlayResult, dict[str, Publisher]]:
    """Play ``path`` (``vibrissa.wire.bag.play_bag``) on publishers of ``node``.

    With ``wait_for`` node names, each topic's publisher starts held (its messages buffer, in
    order) and playback begins once every named node reports the topic (and, for a topic of
    ``topic_wait_for``, its nodes too: one that takes that topic alone), or is abandoned
    (``PlayResult.interrupted``) after ``timeout_s``; without, it begins after ``wait_s``.
    Played as fast as possible (``rate=None``) to named nodes, it keeps pace with them
    (`Intake`).
    ``stop`` (default: the node's own stop) ends it early. Returns the result and the
    publishers by topic (the node owns and closes them), e.g. to end a stream the bag does not.
    """
    publishers: dict[str, Publisher] = {}

    extra = topic_wait_for or {}

    def waits(topic: str) -> list[str]:
        return list(dict.fromkeys([*wait_for, *extra.get(topic, ())]))

    def make(topic: str, msg_type: MessageTypes, hwm: int) -> Publisher:
        publishers[topic] = node.create_publisher(topic, msg_type, wait_for=waits(topic),
                                                  hwm=hwm)
        return publishers[topic]

    def ready(made: dict[str, Publisher]) -> bool:
        return all(node.wait_for_subscribers(topic, waits(topic), timeout_s) for topic in made)

    stop = stop if stop is not None else node.stop_event
    intake = Intake(node, wait_for, timeout_s, stop) if wait_for and rate is None else None
    result = play_bag(path, rate=rate, topics=topics, wait_s=0.0 if wait_for else wait_s,
                      stop=stop, make_publisher=make,
                      ready=(lambda made: ready(made) and intake.start()) if intake is not None
                      else ready if wait_for else None,
                      pace=intake.pace if intake is not None else None)
    return result, publishers


class Intake:
    """Keeps a playback as fast as possible at most `WINDOW` messages ahead of what each of
    ``node_names`` has taken (``received`` in its status, counted from the playback's start):
    ZeroMQ's proxy drops what exceeds a subscriber's queue (`DEFAULT_HWM` messages), and a
    dropped tail, its EndOfStream with it, would leave the graph waiting for an end. A node
    that takes nothing for ``timeout_s`` is no longer waited for (logged)."""

    WINDOW = DEFAULT_HWM // 2

    def __init__(self, node: Node, node_names: Sequence[str], timeout_s: float,
                 stop: threading.Event) -> None:
        self.node = node
        self.names = list(node_names)
        self.timeout_s = timeout_s
        self.stop = stop
        self._start: dict[str, int] = {}
        self._waited: set[str] = set()

    def start(self) -> bool:
        """Note what the nodes have taken before the first message (the gates are open)."""
        taken = self.node.peer_received(self.names)
        self._start = {n: count or 0 for n, count in taken.items()}
        self._waited = set(taken)
        return True

    def pace(self, sent: int) -> bool:
        """Block until every waited node has taken ``sent`` - `WINDOW` messages; False on stop."""
        last_progress, last = time.monotonic(), dict.fromkeys(self._waited, -1)
        while not self.stop.is_set():
            behind = {}
            for name, count in self.node.peer_received(self._waited).items():
                taken = (count or 0) - self._start[name]
                if taken < sent - self.WINDOW:
                    behind[name] = taken
                    if taken != last[name]:
                        last[name], last_progress = taken, time.monotonic()
            if not behind:
                return True
            if time.monotonic() - last_progress > self.timeout_s:
                log.warning("%s: %s took nothing for %.1f s (%s of %d sent): played on "
                            "without waiting for it", self.node.fqn, sorted(behind),
                            self.timeout_s, behind, sent)
                self._waited -= set(behind)
                return True
            self.stop.wait(0.02)
        return False
