"""Recorder node: writes topics to an MCAP bag, byte for byte.

Subscribes
----------
``params.topics`` (any type each; every topic on the graph, ``/vibrissa/status`` included,
when the list is empty).

Publishes
---------
nothing but its own ``NodeStatus`` heartbeat.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from vibrissa.msgs import EndOfStream
from vibrissa.runtime import Node, NodeArgs, configure_logging, load_params, run_main
from vibrissa.runtime.params import require, require_non_negative, require_parsed, require_positive
from vibrissa.wire.bag import BagWriter
from vibrissa.wire.topics import validate_name
from vibrissa.wire.transport import Received, Subscriber

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecorderParams:
    """Parameters of the recorder node.

    Attributes
    ----------
    output
        Bag file to write (``.mcap``); its folder is created.
    topics
        Absolute topics to record; empty records every topic.
    stop_on_eos
        Stop once every topic that carried an ``EndOfStream`` has one from each of its
        publishers, and that has held for ``eos_grace_s`` (see :class:`EndOfStreamTracker`).
    eos_grace_s
        Seconds the end-of-stream condition must hold before stopping, s.
    duration_s
        Stop after this many seconds; 0 records until stopped.
    chunk_size
        Bag chunk size, bytes (a crash loses at most one chunk).
    flush_interval_s
        Flush a chunk in progress at least this often, s.
    overwrite
        Replace an existing ``output``; by default an existing file is refused.
    """

    output: str = "recording.mcap"
    topics: tuple[str, ...] = field(default_factory=tuple)
    stop_on_eos: bool = False
    eos_grace_s: float = 1.0
    duration_s: float = 0.0
    chunk_size: int = 64 * 1024
    flush_interval_s: float = 1.0
    overwrite: bool = False

    def __post_init__(self) -> None:
        require(bool(self.output), "output", self.output, "a file name")
        require(self.overwrite or not Path(self.output).exists(), "output", self.output,
                "a new file (it exists: overwrite it with overwrite: true, or "
                "`vibrissa bag record --overwrite`)")
        for topic in self.topics:
            require_parsed("topics", topic, validate_name)
        require_non_negative("eos_grace_s", self.eos_grace_s)
        require_non_negative("duration_s", self.duration_s)
        require(self.chunk_size >= 1, "chunk_size", self.chunk_size, "a size >= 1 byte")
        require_positive("flush_interval_s", self.flush_interval_s)


PARAMS = RecorderParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


class EndOfStreamTracker:
    """Decides when every stream that announced an end has ended.

    A stream is a (topic, publisher id). The condition holds when at least one
    ``EndOfStream`` has arrived and, on every topic that carried one, every publisher that
    sent anything on it has sent its ``EndOfStream``. Topics that never carry one (the status
    topic, a pose that runs forever) do not hold it up. ``eos_grace_s`` lets a downstream
    stream that is still starting up (e.g. a mesh computed after its input ended) show up
    before the recording stops.
    """

    def __init__(self, eos_grace_s: float = 1.0) -> None:
        self.eos_grace_s = eos_grace_s
        self._publishers: dict[str, set[int]] = {}
        self._ended: dict[str, set[int]] = {}
        self._since: float | None = None

    def update(self, rx: Received) -> None:
        """Note one received message."""
        self._publishers.setdefault(rx.topic, set()).add(rx.header.pub)
        if isinstance(rx.msg, EndOfStream):
            self._ended.setdefault(rx.topic, set()).add(rx.header.pub)
        self._since = None  # re-arm: check again from this message on

    def all_ended(self) -> bool:
        """True when the end-of-stream condition holds now (no grace)."""
        if not self._ended:
            return False
        return all(self._publishers[t] <= ended for t, ended in self._ended.items())

    def done(self, now_s: float) -> bool:
        """True once the condition has held for ``eos_grace_s``; ``now_s`` monotonic s."""
        if not self.all_ended():
            self._since = None
            return False
        if self._since is None:
            self._since = now_s
        return now_s - self._since >= self.eos_grace_s

    @property
    def ended_topics(self) -> list[str]:
        """Topics on which an ``EndOfStream`` has arrived."""
        return sorted(self._ended)


class BagRecorder:
    """Write received messages to a bag: the recorder's logic, without sockets.

    ``log_time`` is the receive time, kept non-decreasing so that the bag's file order is its
    log-time order (a wall clock may step back); ``sequence`` the publisher's ``seq``.
    """

    def __init__(self, writer: BagWriter, tracker: EndOfStreamTracker | None = None) -> None:
        self.writer = writer
        self.tracker = tracker
        self.count = 0
        self._last_ns = 0

    def record(self, rx: Received) -> None:
        """Append one message."""
        log_time_ns = max(int(rx.receive_time * 1e9), self._last_ns)
        self._last_ns = log_time_ns
        self.writer.write(rx.topic, rx.payload, log_time_ns, sequence=rx.header.seq)
        self.count += 1
        if self.tracker is not None:
            self.tracker.update(rx)

    def idle(self) -> None:
        """Call when nothing arrived for a while: flushes a chunk that is getting old."""
        self.writer.flush_if_due()

    def done(self, now_s: float) -> bool:
        """Whether end-of-stream says stop (always False without a tracker)."""
        return self.tracker is not None and self.tracker.done(now_s)


def subscription(topics: Iterable[str]) -> dict[str, None] | None:
    """Subscriber topic map: any type on each topic, or None for every topic."""
    topics = list(topics)
    return {t: None for t in topics} if topics else None


def subscribe(node: Node, topics: Iterable[str]) -> Subscriber:
    """The node's subscriber on ``topics`` (resolved in its namespace), or on every topic."""
    return node.create_subscriber(subscription(topics))


@dataclass
class RecordResult:
    """Outcome of :func:`record`: messages written, why it stopped, subscriber totals."""

    count: int
    reason: str
    lost: int
    rejected: int


def record(
    params: RecorderParams,
    subscriber: Subscriber,
    stop_requested: Callable[[], bool] = lambda: False,
    on_message: Callable[[Received], None] | None = None,
) -> RecordResult:
    """Record from ``subscriber`` until stopped, ``duration_s`` or end of stream.

    The bag is always closed (summary and footer written), whatever ends the loop; the
    subscriber is left open.

    Parameters
    ----------
    params
        What to record (``topics`` is the subscriber's business) and where.
    subscriber
        Source of messages, e.g. from :func:`subscribe`.
    stop_requested
        Polled every 0.1 s at most; True stops the recording.
    on_message
        Called after each message is written.
    """
    path = Path(params.output)
    path.parent.mkdir(parents=True, exist_ok=True)
    tracker = EndOfStreamTracker(params.eos_grace_s) if params.stop_on_eos else None
    t_end = time.monotonic() + params.duration_s if params.duration_s > 0 else math.inf
    with BagWriter(path, chunk_size=params.chunk_size,
                   flush_interval_s=params.flush_interval_s) as writer:
        recorder = BagRecorder(writer, tracker)
        while True:
            now = time.monotonic()
            if stop_requested():
                reason = "stopped"
                break
            if now >= t_end:
                reason = "duration"
                break
            if recorder.done(now):
                reason = "end of stream"
                break
            rx = subscriber.receive(min(0.1, max(0.0, t_end - now)))
            if rx is None:
                recorder.idle()
                continue
            recorder.record(rx)
            if on_message is not None:
                on_message(rx)
    totals = subscriber.totals()
    return RecordResult(recorder.count, reason, totals["lost"], totals["rejected"])


def run(node: Node, params: RecorderParams) -> RecordResult:
    """Record as ``node`` (state ``running`` while recording); shared with ``vibrissa bag``."""
    subscriber = subscribe(node, params.topics)
    try:
        node.set_state("running", f"recording to {params.output}")
        try:
            result = record(params, subscriber, lambda: node.stop_requested)
        except OSError as exc:  # e.g. a full disk: the bag keeps its complete chunks
            raise OSError(f"cannot write {params.output}: {exc.strerror or exc}; the bag keeps "
                          "what it holds up to its last complete chunk") from None
        log.info("%s: %d messages written to %s (%s; lost %d, rejected %d)", node.fqn,
                 result.count, params.output, result.reason, result.lost, result.rejected)
        return result
    finally:
        subscriber.close()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the recorder node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.recorder")
    configure_logging()
    params = load_params(RecorderParams, args.params_file, args.params)
    with Node.from_args(args) as node:
        run(node, params)
    return 0


if __name__ == "__main__":
    run_main(main)
