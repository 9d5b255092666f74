"""What every node process shares: command line, parameters, topics, heartbeat, readiness.

A node's ``main`` reads ``NodeArgs``, loads its parameter dataclass with ``load_params`` and
runs inside a ``Node``::

    args = NodeArgs.parse(argv)
    params = load_params(Params, args.params_file, args.params)
    with Node.from_args(args) as node:
        wrenches = node.create_subscriber({"wrench": WhiskerWrenchArray})
        contacts = node.create_publisher("contact", ContactPointArray, wait_for=["mapper"])
        node.set_state("running")
        while not node.stop_requested:
            rx = wrenches.receive(0.1)
            ...

Heartbeat and readiness
-----------------------
A background thread publishes ``NodeStatus`` on ``/vibrissa/status`` every ``heartbeat_s``
(and at once on a state change) and listens to every node's status. A publisher created
with ``wait_for=[names]`` (or later held by ``wait_for_subscribers``) starts *gated*: what the
node publishes is encoded and buffered in order, while the thread pings the topic every
0.1 s through the same socket. A subscriber that receives a ping adds the topic to its
``seen_topics`` and the publisher's id to its ``seen_publishers`` (it never hands pings to the
application), and its node reports both in its next status. Once every named node reports the
publisher's id, the subscription path is proven up (the id, not the topic: a node respawned
on a topic its peers have seen must wait for its own path) and the thread releases the
buffer, in order, and later messages go straight out. Pings do not advance ``seq``, so they
never look like loss (see ``vibrissa.wire.transport``). With
every status, and once more at close, the thread also pings each publisher that has sent
anything: a tail of a stream that never arrived (its ``EndOfStream`` included) shows as a seq
gap at the subscribers within a heartbeat, instead of not at all.

Stopping: SIGINT/SIGTERM set ``stop_requested`` (a second SIGINT raises
``KeyboardInterrupt``); ``close()`` (or leaving the ``with`` block) reports the final state,
gives queued messages up to ``drain_s`` to leave and closes every socket. If the runtime itself
failed (its heartbeat thread), it stopped the node and leaving the ``with`` block raises
``NodeError``: the process fails instead of ending as if its work were done.
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import logging
import os
import signal
import sys
import threading
import time
import types
from collections.abc import Callable, Iterable, Mapping
from typing import Any, NoReturn

import zmq

from vibrissa.msgs import NodeStatus
from vibrissa.msgs.messages import NODE_STATES
from vibrissa.runtime.args import NodeArgs
from vibrissa.runtime.params import ParamError
from vibrissa.runtime.signals import SignalHandlers
from vibrissa.wire import (
    DEFAULT_HWM,
    STATUS_TOPIC,
    Endpoints,
    Publisher,
    Subscriber,
    node_fqn,
    resolve_topic,
)
from vibrissa.wire.security import Guard
from vibrissa.wire.transport import MessageTypes, joined_graph_note
from vibrissa.wire.waiting import wait_event

log = logging.getLogger(__name__)

PING_PERIOD_S = 0.1
EXIT_LOST_DATA = 4
"""Exit status of a node, or a launch, whose input did not arrive in full (lost or refused
messages), when nothing else failed."""

DEBUG_ENV = "VIBRISSA_DEBUG"
"""Set to 1 (``vibrissa launch --debug`` does) for the traceback of an error that ends a node."""


class NodeError(RuntimeError):
    """The node runtime failed (e.g. its heartbeat thread): leaving the ``with Node`` block
    raises it, so that the process ends with a failure, not as if its work were done."""


def run_main(main: Callable[[], int]) -> NoReturn:
    """Run a node's ``main`` as the process and exit with its status.

    An exception that ends the node is one log line, its traceback only with
    ``VIBRISSA_DEBUG=1``; the status is 2 for refused parameters (``ParamError``), 1 for any
    other error and 130 for a Ctrl-C that came before the node took over the signals.
    The process ends once its exit handlers (`atexit`, which flush the logs) ran, without the
    interpreter's teardown of numpy, numba, scipy and Open3D (0.3-0.8 s of every node's exit
    on a 2-core machine, which a Ctrl-C of a graph waited for).
    """
    try:
        code = main()
    except KeyboardInterrupt:
        code = 130
    except ParamError as exc:
        log.error("%s", exc)
        code = 2
    except Exception as exc:  # noqa: BLE001 - reported once, then the process ends
        if os.environ.get(DEBUG_ENV, "") not in ("", "0"):
            log.exception("stopped by an error")
        else:
            log.error("stopped by %s: %s (for the traceback: %s=1 or vibrissa launch --debug)",
                      type(exc).__name__, exc, DEBUG_ENV)
        code = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def configure_logging(level: int | str | None = None) -> None:
    """Log to stderr, no prefix of our own (the launcher prefixes each line with the node).

    ``level`` defaults to ``$VIBRISSA_LOG_LEVEL`` or ``INFO``.
    """
    level = level if level is not None else os.environ.get("VIBRISSA_LOG_LEVEL", "INFO")
    logging.basicConfig(stream=sys.stderr, level=level,
                        format="%(levelname)s %(name)s: %(message)s", force=True)


@dataclasses.dataclass
class _Gate:
    publisher: Publisher
    nodes: frozenset[str]
    opened: threading.Event = dataclasses.field(default_factory=threading.Event)
    next_ping: float = 0.0


class Node:
    """One node process: zmq context, topics, heartbeat, readiness gates and stop flag.

    Parameters
    ----------
    name, namespace
        The node's name and namespace; ``fqn`` is ``/namespace/name``.
    remaps
        Topic remaps ``from -> to``, applied to resolved names.
    endpoints
        Proxy endpoints; default ``Endpoints.from_env()``.
    context
        ZeroMQ context; by default the node makes its own and destroys it in ``close()``
        (closing any socket still open on it).
    heartbeat_s
        Period of ``NodeStatus`` on ``/vibrissa/status``, seconds.
    handle_signals
        Install SIGINT/SIGTERM handlers (only possible in the main thread).

    Attributes
    ----------
    counters
        The application's own counters (name -> count); ``NodeStatus.counters`` reports them
        next to the runtime's received, published, rejected, lost (and pings).
    """

    def __init__(
        self,
        name: str,
        namespace: str = "/",
        remaps: Mapping[str, str] | None = None,
        endpoints: Endpoints | None = None,
        context: zmq.Context[Any] | None = None,
        heartbeat_s: float = 0.5,
        handle_signals: bool = True,
    ) -> None:
        self.fqn = node_fqn(name, namespace)
        self.namespace = namespace
        self.remaps = dict(remaps or {})
        self.endpoints = endpoints if endpoints is not None else Endpoints.from_env()
        if endpoints is None and (note := joined_graph_note()) is not None:
            log.warning("%s: %s", self.fqn, note)
        self._own_context = context is None
        self.context: zmq.Context[Any] = zmq.Context() if context is None else context
        self.heartbeat_s = heartbeat_s
        self._state = "starting"
        self._message = ""
        self._stopped_by = ""  # the signal that stopped the node
        self._stop = threading.Event()
        self._closing = threading.Event()
        self._beat_now = threading.Event()
        self._lock = threading.Lock()  # guards the lists below against the heartbeat thread
        self._publishers: list[Publisher] = []
        self._subscribers: list[Subscriber] = []
        self._gates: list[_Gate] = []
        self._peers: dict[str, set[str]] = {}  # node -> seen_publishers from its last status
        self._peer_inputs: dict[str, set[str]] = {}  # node -> its subscribed topics, running
        self._peer_received: dict[str, int] = {}  # node -> counters["received"], last status
        self.counters: dict[str, int] = {}
        self.failure: str | None = None  # why the runtime stopped the node, if it did
        try:
            self._status_pub = Publisher(STATUS_TOPIC, NodeStatus, self.endpoints, self.context)
            self._status_sub = Subscriber({STATUS_TOPIC: NodeStatus}, self.endpoints, self.context)
        except BaseException:
            if self._own_context:
                self.context.destroy(linger=0)
            raise
        self._signals = SignalHandlers(self._on_signal)
        if handle_signals:
            self._signals.install()
        self._thread = threading.Thread(target=self._heartbeat_loop, daemon=True,
                                        name=f"vibrissa-heartbeat{self.fqn}")
        self._thread.start()

    @classmethod
    def from_args(cls, args: NodeArgs, **kwargs: Any) -> Node:
        """A node named, namespaced and remapped as on its command line."""
        return cls(args.name, args.namespace, args.remaps, **kwargs)

    # -- topics --------------------------------------------------------------------------

    def resolve(self, topic: str) -> str:
        """Fully qualified topic: namespace, then remaps."""
        return resolve_topic(topic, self.namespace, self.remaps)

    def create_publisher(
        self,
        topic: str,
        msg_type: MessageTypes,
        wait_for: Iterable[str] = (),
        hwm: int = DEFAULT_HWM,
    ) -> Publisher:
        """Direct publisher on ``resolve(topic)``; with ``wait_for`` node names it starts gated.

        Its endpoint goes out in this node's status at once, so subscribers connect to it.
        Relative node names resolve in this node's namespace, like topics.
        """
        publisher = Publisher(self.resolve(topic), msg_type, self.endpoints, self.context, hwm,
                              direct=True)
        with self._lock:
            self._publishers.append(publisher)
        self._beat_now.set()
        nodes = list(wait_for)
        if nodes:
            self._gate(publisher, nodes)
        return publisher

    def create_subscriber(
        self, topics: Mapping[str, MessageTypes | None] | None, hwm: int = DEFAULT_HWM
    ) -> Subscriber:
        """Subscriber on the resolved ``topics`` (topic -> type or tuple of types, ``None`` for
        any type), or on every topic (``topics=None``, e.g. a recorder); its counters are in
        the node's status either way."""
        resolved = None if topics is None else {
            self.resolve(topic): msg_type for topic, msg_type in topics.items()}
        subscriber = Subscriber(resolved, self.endpoints, self.context, hwm)
        with self._lock:
            self._subscribers.append(subscriber)
        return subscriber

    def wait_for_subscribers(
        self, topic: str, node_names: Iterable[str], timeout_s: float
    ) -> bool:
        """Block until the named nodes report ``topic`` in their ``seen_topics``.

        ``topic`` must be published by this node. Until then its publisher is held (messages
        buffer, in order); on timeout it stays held and is released whenever the nodes get
        ready. Returns whether they are ready (``False`` also when a stop was requested).
        """
        resolved = self.resolve(topic)
        with self._lock:
            publisher = next((p for p in self._publishers if p.topic == resolved), None)
            gate = next((g for g in self._gates if g.publisher is publisher), None)
        if publisher is None:
            raise ValueError(f"{self.fqn} has no publisher on {resolved!r}")
        if gate is None:
            gate = self._gate(publisher, list(node_names))
        deadline = time.monotonic() + timeout_s
        told: set[str] = set()
        while not gate.opened.wait(min(0.05, max(0.0, deadline - time.monotonic()))):
            if self._stop.is_set() or time.monotonic() >= deadline:
                log.warning("%s: %s not ready on %s after %.1f s (still buffering)",
                            self.fqn, sorted(gate.nodes), resolved, timeout_s)
                return False
            for node in gate.nodes - told:
                inputs = self._peer_inputs.get(node)
                if inputs is not None and resolved not in inputs and "*" not in inputs:
                    told.add(node)
                    log.warning("%s: %s runs but does not subscribe to %s (it subscribes to "
                                "%s): a remap or a namespace may be missing", self.fqn, node,
                                resolved, ", ".join(sorted(inputs)[:8]) or "nothing")
        return True

    def peer_received(self, node_names: Iterable[str]) -> dict[str, int | None]:
        """The messages each named node has taken (``received`` in its last status, 0.5 s
        apart at most), None for one not heard yet."""
        names = [resolve_topic(n, self.namespace) for n in node_names]
        return {n: self._peer_received.get(n) for n in names}

    def _gate(self, publisher: Publisher, node_names: list[str]) -> _Gate:
        nodes = frozenset(resolve_topic(n, self.namespace) for n in node_names)
        publisher.hold()
        gate = _Gate(publisher, nodes)
        with self._lock:
            self._gates.append(gate)
        return gate

    # -- state and stop ------------------------------------------------------------------

    @property
    def state(self) -> str:
        """starting | ready | running | finished | error."""
        return self._state

    def set_state(self, state: str, message: str = "") -> None:
        """Set the reported state (and message); the status goes out at once."""
        if state not in NODE_STATES:
            raise ValueError(f"state must be one of {NODE_STATES}, got {state!r}")
        self._state, self._message = state, message
        self._beat_now.set()

    @property
    def stop_requested(self) -> bool:
        """Whether a signal or ``request_stop`` asked the node to stop."""
        return self._stop.is_set()

    @property
    def stop_event(self) -> threading.Event:
        """Set when a signal or ``request_stop`` asks the node to stop (to wait on)."""
        return self._stop

    def request_stop(self) -> None:
        """Ask every loop of the node to end."""
        self._stop.set()

    def sleep(self, seconds: float) -> bool:
        """Sleep unless a stop comes first; returns ``True`` if the full time passed."""
        return not wait_event(self._stop, seconds)

    def _on_signal(self, signum: int) -> None:
        if self._stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        log.info("%s: %s, stopping", self.fqn, signal.Signals(signum).name)
        self._stopped_by = self._stopped_by or signal.Signals(signum).name
        self._stop.set()

    # -- heartbeat thread ----------------------------------------------------------------

    def status(self) -> NodeStatus:
        """The node's current ``NodeStatus``."""
        with self._lock:
            publishers, subscribers = list(self._publishers), list(self._subscribers)
        totals = {"received": 0, "published": 0, "rejected": 0, "lost": 0, "pings": 0,
                  "anomalies": 0}
        seen: set[str] = set()
        seen_pubs: set[int] = set()
        subscribes: dict[str, str] = {}
        for sub in subscribers:
            for key, value in sub.totals().items():
                totals[key] += value
            seen |= sub.seen_topics
            seen_pubs |= sub.seen_publishers
            for topic, msg_types in (sub.topics or {"*": None}).items():
                subscribes[topic] = "|".join(t.TYPE_NAME for t in msg_types) if msg_types else "*"
        totals["published"] = sum(p.published for p in publishers)
        if self.endpoints.keys is not None:
            totals["refused_peers"] = Guard.refused_in(self.context)
        totals.update(self.counters)  # one C-level copy: safe against the node's updates
        return NodeStatus(
            stamp=time.time(), node=self.fqn, state=self._state, counters=totals,
            publishes={p.topic: p.type_name for p in publishers},
            subscribes=subscribes, seen_topics=sorted(seen), message=self._message,
            endpoints={p.topic: p.endpoint for p in publishers if p.endpoint is not None},
            seen_publishers=sorted(f"{pub:016x}" for pub in seen_pubs),
        )

    def _heartbeat_loop(self) -> None:
        next_beat = 0.0
        seen = 0
        try:
            while not self._closing.is_set():
                now = time.monotonic()
                with self._lock:
                    subscribers = list(self._subscribers)
                # A newly seen publisher may open a peer's gate: report it now, not in 0.5 s.
                seen, was_seen = sum(len(sub.seen_publishers) for sub in subscribers), seen
                if now >= next_beat or self._beat_now.is_set() or seen != was_seen:
                    self._beat_now.clear()
                    self._status_pub.publish(self.status())
                    if now >= next_beat:
                        self._ping_streams()
                    next_beat = now + self.heartbeat_s
                self._service_gates(now)
                received = self._status_sub.receive(0.02)
                if received is not None and isinstance(received.msg, NodeStatus):
                    self._peers[received.msg.node] = set(received.msg.seen_publishers)
                    self._peer_received[received.msg.node] = received.msg.counters.get(
                        "received", 0)
                    if received.msg.state == "running":
                        self._peer_inputs[received.msg.node] = set(received.msg.subscribes)
            self._ping_streams()
            self._status_pub.publish(self.status())  # the final state
        except Exception as exc:  # the thread must not die silently: stop the node instead
            log.exception("%s: heartbeat thread failed", self.fqn)
            self.failure = f"heartbeat thread failed: {type(exc).__name__}: {exc}"
            self._state = "error"
            self._stop.set()

    def _ping_streams(self) -> None:
        """Ping every publisher that has sent anything (the next seq: a lost tail shows)."""
        with self._lock:
            publishers = [p for p in self._publishers if p.sent and not p.held]
        for publisher in publishers:
            publisher.ping(self.fqn)

    def _service_gates(self, now: float) -> None:
        with self._lock:
            gates = [g for g in self._gates if not g.opened.is_set()]
        for gate in gates:
            topic, pub = gate.publisher.topic, f"{gate.publisher.pub_id:016x}"
            if all(pub in self._peers.get(n, ()) for n in gate.nodes):
                sent = gate.publisher.release()
                gate.opened.set()
                log.info("%s: %s ready on %s, sent %d buffered message(s)",
                         self.fqn, sorted(gate.nodes), topic, sent)
            elif now >= gate.next_ping:
                gate.publisher.ping(self.fqn)
                gate.next_ping = now + PING_PERIOD_S

    # -- shutdown ------------------------------------------------------------------------

    def close(self, drain_s: float = 1.0) -> None:
        """Report the final state and close everything (idempotent).

        Held messages wait up to ``drain_s`` for their gate; queued ones get up to
        ``drain_s`` to leave the sockets (linger), then are discarded. A stop request (a
        signal) that comes while it waits cuts both short: the held ones are discarded, the
        queued get at most 1 s more.
        """
        if self._closing.is_set():
            return
        deadline = time.monotonic() + drain_s
        with self._lock:
            waiting = [g for g in self._gates if g.publisher.pending]
        stopped = self._stop.is_set()
        for gate in waiting:  # a signal that comes meanwhile cuts the wait short
            while not (gate.opened.wait(min(0.1, max(0.0, deadline - time.monotonic())))
                       or time.monotonic() >= deadline or (self._stop.is_set() and not stopped)):
                pass
        if self._stop.is_set() and not stopped:
            deadline = min(deadline, time.monotonic() + 1.0)
        if self._state != "error":
            self._state = "finished"
            if self._stopped_by:  # the last status says why, to the launchers of other hosts
                self._message = f"stopped by {self._stopped_by}"
        self._closing.set()
        self._thread.join(2.0)
        with self._lock:
            subscribers, publishers = list(self._subscribers), list(self._publishers)
        for sub in [*subscribers, self._status_sub]:
            sub.close()
        linger_s = max(0.0, deadline - time.monotonic())
        for pub in [*publishers, self._status_pub]:
            pub.close(linger_s)
        if self._own_context:
            Guard.stop_for(self.context)
            # Closes sockets the application made on node.context and forgot (term() would
            # hang on them), then returns once queued messages left or their linger ran out.
            self.context.destroy(linger=round(linger_s * 1000))
        self._signals.restore()

    def __enter__(self) -> Node:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: types.TracebackType | None,
    ) -> None:
        if exc is not None and not isinstance(exc, KeyboardInterrupt):
            self.set_state("error", f"{type(exc).__name__}: {exc}")
        self.close()
        if exc is None and self.failure is not None:
            raise NodeError(f"{self.fqn}: {self.failure}")
