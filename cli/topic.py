"""``vibrissa topic``: list the graph's topics, echo a topic, measure its rate."""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple, TextIO

import numpy as np

from vibrissa.cli.arg_types import count, seconds
from vibrissa.cli.graph import (
    add_endpoint_flags,
    domain_of,
    endpoints_from,
    graph_note,
    nothing_heard,
    stop_on_signals,
    where,
)
from vibrissa.msgs import EndOfStream, Message, NodeStatus
from vibrissa.msgs.codec import to_jsonable
from vibrissa.wire.topics import STATUS_TOPIC, validate_name
from vibrissa.wire.transport import Endpoints, Received, Subscriber, running_graphs

_ARRAY_ITEMS_SHOWN = 12  # longer arrays are summarised in the YAML-ish echo


def register(subparsers: Any) -> None:
    """Add ``topic`` with its subcommands ``list``, ``echo``, ``hz``."""
    topic = subparsers.add_parser("topic", help="inspect the topics of the running graph")
    sub = topic.add_subparsers(dest="topic_command", required=True, metavar="SUBCOMMAND")

    p = sub.add_parser("list", help="topics with their type, publishers and subscribers")
    p.add_argument("--listen", type=float, default=1.5, metavar="S",
                   help="seconds to listen for status heartbeats and traffic (default 1.5)")
    add_endpoint_flags(p)
    p.set_defaults(func=_list)

    p = sub.add_parser("echo", help="print the messages on a topic")
    p.add_argument("topic", metavar="TOPIC")
    p.add_argument("--count", "-n", type=count, default=0, metavar="N",
                   help="exit after N messages, N >= 1 (default: until Ctrl-C)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument("--timeout", type=seconds, default=0.0, metavar="S",
                   help="exit with status 1 after S seconds without a message")
    add_endpoint_flags(p)
    p.set_defaults(func=_echo)

    p = sub.add_parser("hz", help="rate of a topic: period statistics and lost messages")
    p.add_argument("topic", metavar="TOPIC")
    p.add_argument("--window", "-w", type=int, default=100, metavar="N",
                   help="periods in the statistics window (default 100)")
    p.add_argument("--duration", type=float, default=0.0, metavar="S",
                   help="exit after S seconds (default: until Ctrl-C)")
    p.add_argument("--interval", type=float, default=1.0, metavar="S",
                   help="seconds between reports (default 1)")
    add_endpoint_flags(p)
    p.set_defaults(func=_hz)


# -- list ------------------------------------------------------------------------------------


@dataclass
class TopicEntry:
    """What ``topic list`` knows about one topic."""

    types: set[str] = field(default_factory=set)
    publishers: set[str] = field(default_factory=set)
    subscribers: set[str] = field(default_factory=set)
    messages: int = 0


def survey(endpoints: Endpoints, listen_s: float, context: Any = None) -> dict[str, TopicEntry]:
    """Listen for ``listen_s`` seconds: topics from NodeStatus heartbeats plus traffic seen.

    A publisher seen only on the wire (no status, e.g. a bag player) is listed by its
    publisher id as ``pub:<hex>``.
    """
    topics: dict[str, TopicEntry] = {}
    named_ids: set[int] = set()
    wire_ids: dict[str, set[int]] = {}
    with Subscriber(None, endpoints=endpoints, context=context) as sub:
        deadline = time.monotonic() + listen_s
        while (remaining := deadline - time.monotonic()) > 0:
            rx = sub.receive(remaining)
            if rx is None:
                break
            entry = topics.setdefault(rx.topic, TopicEntry())
            entry.messages += 1
            if not isinstance(rx.msg, EndOfStream):
                entry.types.add(rx.msg.TYPE_NAME)
            wire_ids.setdefault(rx.topic, set()).add(rx.header.pub)
            if isinstance(rx.msg, NodeStatus) and rx.topic == STATUS_TOPIC:
                named_ids.add(rx.header.pub)
                entry.publishers.add(rx.msg.node)
                for t, type_name in rx.msg.publishes.items():
                    e = topics.setdefault(t, TopicEntry())
                    e.publishers.add(rx.msg.node)
                    e.types.update(type_name.split("|"))  # a publisher of several types
                for t, type_name in rx.msg.subscribes.items():
                    e = topics.setdefault(t, TopicEntry())
                    e.subscribers.add(rx.msg.node)
                    if type_name != "*":
                        e.types.update(type_name.split("|"))
        for t in sub.seen_topics:  # pinged but silent topics
            topics.setdefault(t, TopicEntry())
    for t, ids in wire_ids.items():
        entry = topics[t]
        if not entry.publishers or t == STATUS_TOPIC:
            # nodes that report status name themselves; anything else by its wire id
            entry.publishers.update(f"pub:{i:016x}" for i in ids - named_ids)
    return topics


def _say_which_graph(tool: str, args: argparse.Namespace) -> None:
    """`graph_note` on stderr, when more than one graph runs and none was named."""
    note = graph_note(args)
    if note is not None:
        print(f"vibrissa topic {tool}: {note}", file=sys.stderr, flush=True)


def _list(args: argparse.Namespace) -> int:
    endpoints = endpoints_from(args)
    _say_which_graph("list", args)
    topics = survey(endpoints, args.listen)
    if not topics:
        print(f"vibrissa topic list: {nothing_heard(args, endpoints)}", file=sys.stderr)
        return 1
    rows = [("TOPIC", "TYPE", "PUBLISHERS", "SUBSCRIBERS")]
    for name in sorted(topics):
        e = topics[name]
        rows.append((name, ",".join(sorted(e.types)) or "?", ",".join(sorted(e.publishers)) or "-",
                     ",".join(sorted(e.subscribers)) or "-"))
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    for r in rows:
        print(f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:<{widths[2]}}  {r[3]}")
    return 0


# -- echo ------------------------------------------------------------------------------------


def _yaml_value(value: Any) -> str:
    if isinstance(value, np.ndarray):
        if value.size <= _ARRAY_ITEMS_SHOWN:
            return json.dumps(value.tolist())
        head = ", ".join(f"{x:g}" for x in value.ravel()[:6].tolist())
        return f"<array {value.dtype.str} shape {list(value.shape)}: [{head}, ...]>"
    if isinstance(value, (dict, list, str, float, int, bool)) or value is None:
        return json.dumps(value)
    return repr(value)


def format_message(topic: str, msg: Message, as_json: bool) -> str:
    """One message as a JSON line, or as a YAML-ish block ending with ``---``."""
    if as_json:
        return json.dumps({"topic": topic, "type": msg.TYPE_NAME, "msg": to_jsonable(msg)},
                          allow_nan=False)
    lines = [f"# {topic} [{msg.TYPE_NAME}]"]
    for name in to_jsonable(msg):
        lines.append(f"{name}: {_yaml_value(getattr(msg, name))}")
    lines.append("---")
    return "\n".join(lines)


class EchoResult(NamedTuple):
    """How ``echo`` ended: messages printed, and whether its timeout ended it."""

    printed: int
    timed_out: bool


SILENCE_HINT_S = 3.0
"""After this long with nothing received, ``echo`` and ``hz`` say once why that may be, s."""

SilenceHint = Callable[[], str]
"""What ``echo`` and ``hz`` say on stderr when nothing came: one line, found while they wait
(it may take a second; it is dropped if a message came meanwhile)."""


def _hint_unless_heard(sub: Subscriber, on_silence: SilenceHint, err: TextIO
                       ) -> Received | None:
    """Find the silence hint; print it unless a message arrived while it was found, which is
    returned instead (a hint then would contradict the message that follows it)."""
    text = on_silence()
    rx = sub.receive(0.1)  # a message the proxy was forwarding as the hint was found
    if rx is None:
        print(text, file=err, flush=True)
    return rx


def echo(
    endpoints: Endpoints, topic: str, *, count: int = 0, as_json: bool = False,
    timeout_s: float = 0.0, stop: threading.Event | None = None, out: TextIO | None = None,
    context: Any = None, on_silence: SilenceHint | None = None, err: TextIO | None = None,
    on_late: SilenceHint | None = None,
) -> EchoResult:
    """Print messages on ``topic``.

    Stops after ``count`` messages (0: no limit), after ``timeout_s`` s without a message
    (0: never) or when ``stop`` is set; prints what ``on_silence`` finds on ``err`` (default
    stderr) once when nothing has come `SILENCE_HINT_S` after the start, or at the timeout
    (unless a message came while it was found), and what ``on_late`` says before the first
    message that comes after that hint.
    """
    validate_name(topic)
    out = out if out is not None else sys.stdout
    err = err if err is not None else sys.stderr
    stop = stop if stop is not None else threading.Event()
    printed = 0
    with Subscriber({topic: None}, endpoints=endpoints, context=context) as sub:
        last = start = time.monotonic()
        hinted = on_silence is None
        late = False
        while not stop.is_set() and (count <= 0 or printed < count):
            rx = sub.receive(0.1)
            if rx is None and not (hinted or printed) and (
                    time.monotonic() - start > SILENCE_HINT_S
                    or (timeout_s > 0 and time.monotonic() - last > timeout_s)):
                hinted = True
                assert on_silence is not None
                rx = _hint_unless_heard(sub, on_silence, err)
                late = rx is None  # the hint went out: a message now would belie it
            if rx is None:
                if timeout_s > 0 and time.monotonic() - last > timeout_s:
                    return EchoResult(printed, timed_out=True)
                continue
            if late and on_late is not None:
                print(on_late(), file=err, flush=True)
            late = False
            last = time.monotonic()
            print(format_message(rx.topic, rx.msg, as_json), file=out, flush=True)
            printed += 1
    return EchoResult(printed, timed_out=False)


def _silence_hint(tool: str, args: argparse.Namespace, endpoints: Endpoints) -> SilenceHint:
    """The line that says why nothing came (`_why_silent`)."""
    return lambda: (f"vibrissa topic {tool}: nothing on {args.topic} yet: "
                    f"{_why_silent(args, endpoints)}")


def _came_after_all(args: argparse.Namespace, endpoints: Endpoints) -> str:
    """What ``echo`` says when a message follows its silence hint: the graph it came from, when
    a launcher recorded it (it may have started since)."""
    records = [] if args.pub or args.sub else running_graphs()
    source = next((r.describe() for r in records if r.domain == domain_of(args)),
                  where(args, endpoints))
    return f"vibrissa topic echo: a message on {args.topic} came after all, from {source}"


def _why_silent(args: argparse.Namespace, endpoints: Endpoints) -> str:
    """A graph whose statuses come through is reachable: then either no node publishes the
    topic (the topics they do publish follow) or its publishers have sent nothing yet; a
    graph heard not at all is ``nothing_heard``'s case (keys, another domain)."""
    topics = survey(endpoints, 1.0)
    if not topics:
        return nothing_heard(args, endpoints)
    publishers = sorted(topics[args.topic].publishers) if args.topic in topics else []
    if publishers:
        return f"its publishers ({', '.join(publishers)}) have sent nothing on it yet"
    published = sorted(t for t, e in topics.items() if e.publishers and t != STATUS_TOPIC)
    return (f"no node of the graph on {where(args, endpoints)} publishes it (published: "
            f"{', '.join(published) or 'nothing but statuses'})")


def _echo(args: argparse.Namespace) -> int:
    endpoints = endpoints_from(args)
    _say_which_graph("echo", args)
    with stop_on_signals() as stop:
        result = echo(endpoints, args.topic, count=args.count, as_json=args.json,
                      timeout_s=args.timeout, stop=stop,
                      on_silence=_silence_hint("echo", args, endpoints),
                      on_late=lambda: _came_after_all(args, endpoints))
    if result.timed_out:
        print(f"vibrissa topic echo: no message on {args.topic} for {args.timeout:g} s "
              f"({result.printed} printed)", file=sys.stderr)
        return 1
    return 1 if args.count > 0 and result.printed < args.count else 0


# -- hz --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RateStats:
    """Rate of a topic over the last ``window`` periods (s) plus counts since start."""

    rate_hz: float
    min_s: float
    max_s: float
    std_s: float
    window: int
    received: int
    lost: int

    def format(self) -> str:
        """``ros2 topic hz``-style report."""
        return (f"average rate: {self.rate_hz:.3f} Hz\n"
                f"  min: {self.min_s:.6f} s  max: {self.max_s:.6f} s  "
                f"std dev: {self.std_s:.6f} s  window: {self.window}\n"
                f"  received: {self.received}  lost: {self.lost}")


class RateMeter:
    """Period statistics over a sliding window of receive times."""

    def __init__(self, window: int = 100) -> None:
        if window < 1:
            raise ValueError(f"window must be >= 1 period, got {window}")
        self._times: deque[float] = deque(maxlen=window + 1)
        self.received = 0

    def add(self, t_s: float) -> None:
        """Note one message received at ``t_s`` (s, any clock)."""
        self._times.append(t_s)
        self.received += 1

    def stats(self, lost: int = 0) -> RateStats | None:
        """Statistics of the window, or None before two messages arrived."""
        if len(self._times) < 2:
            return None
        periods = np.diff(np.asarray(self._times))
        mean = float(periods.mean())
        return RateStats(
            rate_hz=1.0 / mean if mean > 0 else math.inf,
            min_s=float(periods.min()), max_s=float(periods.max()), std_s=float(periods.std()),
            window=len(periods), received=self.received, lost=lost,
        )


def hz(
    endpoints: Endpoints, topic: str, *, window: int = 100, duration_s: float = 0.0,
    interval_s: float = 1.0, stop: threading.Event | None = None, out: TextIO | None = None,
    context: Any = None, on_silence: SilenceHint | None = None, err: TextIO | None = None,
) -> RateStats | None:
    """Report the rate of ``topic`` every ``interval_s`` s; returns the last statistics.

    ``EndOfStream`` is not counted as a sample; lost messages come from ``seq`` gaps. Prints
    what ``on_silence`` finds on ``err`` (default stderr) once, at the first report
    `SILENCE_HINT_S` after the start (or at the end) with nothing received, unless a message
    came while it was found.
    """
    validate_name(topic)
    out = out if out is not None else sys.stdout
    err = err if err is not None else sys.stderr
    stop = stop if stop is not None else threading.Event()
    meter = RateMeter(window)
    last: RateStats | None = None
    t_end = time.monotonic() + duration_s if duration_s > 0 else math.inf
    with Subscriber({topic: None}, endpoints=endpoints, context=context) as sub:
        start = time.monotonic()
        next_report = start + interval_s
        heard = False
        hinted = on_silence is None

        def take(rx: Received | None) -> None:
            nonlocal heard
            heard = heard or rx is not None
            if rx is not None and not isinstance(rx.msg, EndOfStream):
                meter.add(rx.receive_time)

        while not stop.is_set() and (now := time.monotonic()) < t_end:
            take(sub.receive(max(0.0, min(next_report, t_end) - now)))
            if time.monotonic() >= next_report:
                next_report += interval_s
                last = meter.stats(sub.counters[topic].lost) or last
                print(last.format() if last else "no new messages", file=out, flush=True)
                if not (heard or hinted) and time.monotonic() - start >= SILENCE_HINT_S:
                    hinted = True
                    assert on_silence is not None
                    take(_hint_unless_heard(sub, on_silence, err))
        if not (heard or hinted):
            assert on_silence is not None
            take(_hint_unless_heard(sub, on_silence, err))
        return meter.stats(sub.counters[topic].lost) or last


def _hz(args: argparse.Namespace) -> int:
    endpoints = endpoints_from(args)
    _say_which_graph("hz", args)
    with stop_on_signals() as stop:
        stats = hz(endpoints, args.topic, window=args.window, duration_s=args.duration,
                   interval_s=args.interval, stop=stop,
                   on_silence=_silence_hint("hz", args, endpoints))
    return 0 if stats is not None else 1
