"""ZeroMQ transport: the XSUB/XPUB proxy, publishers and subscribers (see ARCHITECTURE.md).

A message is three frames ``[topic + b"\\0", header, payload]``; the header is msgpack
``{"pub": <uint64 publisher id>, "seq": <uint64>}`` and the payload ``vibrissa.msgs.codec.encode(msg)``.

Two paths, each message on exactly one
--------------------------------------
A publisher either connects to the proxy (the default: tools, tests, any program that speaks
the protocol) or, with ``direct=True``, binds an endpoint of its own (``Publisher.endpoint``)
that its node announces in ``NodeStatus.endpoints``; a direct publisher never sends through
the proxy. Every subscriber listens on both: on the proxy, and on every announced endpoint of
a topic it takes, which it learns from the statuses that pass its proxy socket (it subscribes
to ``/vibrissa/status`` for that). Node to node, a message thus makes one hop instead of two
through the proxy, and no message arrives twice.

Sequence numbers and loss
-------------------------
``seq`` counts, per publisher and topic, every message it sends except pings, from 0
(data messages and ``EndOfStream``). A ``Ping`` carries the ``seq`` the *next* message will
have and does not advance it. A subscriber keeps, per (topic, publisher id), the next ``seq``
it expects and adds every gap to ``lost`` (one warning per gap). Counting starts at the first
message or ping it gets from a publisher, so a ping before the data (the readiness gate, see
``vibrissa.runtime``) makes even a loss of the very first messages visible, and a ping
or ``EndOfStream`` after the data reveals a loss at the tail. Hence, once a subscriber has
seen a stream's ``EndOfStream``: ``received + lost + rejected == publisher.sent``.

Pings are never handed to the caller of ``Subscriber.receive``; they only mark the topic as
seen (``Subscriber.seen_topics``), which nodes report in their status.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import getpass
import ipaddress
import itertools
import json
import logging
import os
import socket
import stat
import tempfile
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, replace
from datetime import datetime
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar, TypeAlias

import msgpack
import zmq

from vibrissa.formats.files import read_text
from vibrissa.msgs import EndOfStream, Message, NodeStatus, Ping
from vibrissa.msgs.codec import DecodeError, decode, decodes_as, encode, payload_limit, peek_type
from vibrissa.msgs.messages import MAX_PAYLOAD_BYTES
from vibrissa.wire.inbox import PIPE_HWM, Inbox
from vibrissa.wire.security import Guard, Keys, KeysError
from vibrissa.wire.topics import STATUS_TOPIC, validate_name

__all__ = [
    "BUFFER_ENV",
    "DEFAULT_HWM",
    "DEFAULT_MAX_BUFFERED_BYTES",
    "DEFAULT_MAX_MESSAGE_BYTES",
    "DIRECT_HOST_ENV",
    "DOMAIN_ENV",
    "INSECURE_ENV",
    "MAX_PUBLISHERS",
    "MAX_SEQ_GAP",
    "SCANNED_DOMAINS",
    "Endpoints",
    "GraphRecord",
    "Header",
    "MessageTypes",
    "Proxy",
    "Publisher",
    "Received",
    "StreamEnd",
    "Subscriber",
    "TopicCounters",
    "is_loopback",
    "joined_graph_note",
    "local_address_towards",
    "register_graph",
    "running_graphs",
    "scanned_domains",
    "which_graph",
]

log = logging.getLogger(__name__)

DEFAULT_HWM = 10_000
"""Default send/receive high-water mark, messages per socket (per peer for PUB/XPUB)."""

DEFAULT_MAX_MESSAGE_BYTES = MAX_PAYLOAD_BYTES
"""Largest frame the proxy takes from a publisher, bytes: the largest payload of any type."""

DEFAULT_MAX_BUFFERED_BYTES = 256 << 20
"""What a subscriber buffers at most, bytes (plus one message of any size the proxy takes);
``VIBRISSA_MAX_BUFFERED_BYTES`` sets another default (a launch file's
``transport.max_buffered_bytes`` does, for its nodes)."""

BUFFER_ENV = "VIBRISSA_MAX_BUFFERED_BYTES"

MAX_SEQ_GAP = 1_000_000
"""Largest seq gap counted as lost messages: a publisher does not lose a million messages
between two that arrive (a subscriber's queue holds at most its hwm); a larger jump is a forged or
reset sequence, counted in ``TopicCounters.anomalies``."""

MAX_PUBLISHERS = 1024
"""Publishers (per topic and id) whose sequence a subscriber follows at once."""

MessageTypes: TypeAlias = type[Message] | tuple[type[Message], ...]
"""What a subscriber expects on a topic: one message class or a tuple of them."""

_ENV_PUB = "VIBRISSA_PUB_ENDPOINT"
_ENV_SUB = "VIBRISSA_SUB_ENDPOINT"
DOMAIN_ENV = "VIBRISSA_DOMAIN_ID"
DIRECT_HOST_ENV = "VIBRISSA_DIRECT_HOST"
"""The address of this host that its direct publishers bind (and announce), when the graph's
proxy runs on another host."""

_SNDMORE = int(zmq.SNDMORE)  # a plain int: pyzmq's flag enums cost their arithmetic at every send

INSECURE_ENV = "VIBRISSA_INSECURE"
"""``1``: sockets may bind off loopback without keys (plain text; ``vibrissa launch --insecure``)."""
_CONTROL_IDS = itertools.count()


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address as in a tcp endpoint, ``[::1]`` with brackets or without,
    or ``localhost``) is this machine's loopback."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def local_address_towards(host: str) -> str:
    """The address of this host's interface that routes to ``host`` (no packet is sent);
    ``OSError`` when there is no route or the name does not resolve."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.connect((host, 9))
        return str(probe.getsockname()[0])


def _tcp_host(endpoint: str) -> str | None:
    """``10.0.0.1`` of ``tcp://10.0.0.1:7400`` (``*`` for a wildcard); None for other schemes."""
    scheme, sep, address = endpoint.partition("://")
    return address.rpartition(":")[0] if sep and scheme == "tcp" else None


@dataclass(frozen=True)
class Endpoints:
    """Where publishers connect (``pub``, the proxy's XSUB) and subscribers (``sub``, XPUB),
    and the CURVE keys that get a process in (``None``: plain sockets, see ``security``).

    ``direct_host``: the address of this host its direct publishers bind, when the proxy runs
    on another one (None: the proxy's host). ``insecure``: sockets may bind off loopback
    without keys (else refused, `KeysError`).
    """

    pub: str
    sub: str
    keys: Keys | None = None
    direct_host: str | None = None
    insecure: bool = False

    BASE_PORT: ClassVar[int] = 7400
    MAX_DOMAIN: ClassVar[int] = (65535 - BASE_PORT - 1) // 2
    """The largest domain id whose two ports exist."""

    @classmethod
    def for_domain(cls, domain_id: int = 0, host: str = "127.0.0.1") -> Endpoints:
        """``tcp://{host}:{7400 + 2 id}`` (pub) and ``{7401 + 2 id}`` (sub): the proxy of a
        graph on this machine's loopback, or on ``host``."""
        if isinstance(domain_id, bool) or not isinstance(domain_id, int):
            raise ValueError(f"domain_id must be an int, got {type(domain_id).__name__}")
        if not 0 <= domain_id <= cls.MAX_DOMAIN:
            raise ValueError(f"domain_id {domain_id} gives no valid port")
        if not host or any(c in host for c in "/ :[]*"):
            raise ValueError(f"expected a host name or IPv4 address, got {host!r}")
        port = cls.BASE_PORT + 2 * domain_id
        return cls(f"tcp://{host}:{port}", f"tcp://{host}:{port + 1}")

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Endpoints:
        """From ``VIBRISSA_PUB_ENDPOINT``/``VIBRISSA_SUB_ENDPOINT``, else ``VIBRISSA_DOMAIN_ID``;
        keys from ``VIBRISSA_KEYS`` (``KeysError`` names a folder that cannot be used)."""
        env = os.environ if environ is None else environ
        keys = Keys.from_env(env)
        pub, sub = env.get(_ENV_PUB), env.get(_ENV_SUB)
        if bool(pub) != bool(sub):
            raise ValueError(f"set both {_ENV_PUB} and {_ENV_SUB}, or neither")
        found = (cls(pub, sub) if pub and sub
                 else cls.for_domain(cls.env_domain(env)))
        return replace(found, keys=keys, direct_host=env.get(DIRECT_HOST_ENV) or None,
                       insecure=env.get(INSECURE_ENV) == "1")

    def with_keys(self, keys: Keys | None) -> Endpoints:
        """The same endpoints, entered with ``keys``."""
        return replace(self, keys=keys)

    @classmethod
    def env_domain(cls, environ: Mapping[str, str] | None = None) -> int:
        """The domain id in ``VIBRISSA_DOMAIN_ID``, 0 when unset; ``ValueError`` names a bad one."""
        env = os.environ if environ is None else environ
        text = env.get(DOMAIN_ENV, "").strip() or "0"
        try:
            domain_id = int(text)
        except ValueError:
            raise ValueError(f"{DOMAIN_ENV}={text!r} is not an integer") from None
        if not 0 <= domain_id <= cls.MAX_DOMAIN:
            raise ValueError(f"{DOMAIN_ENV}={domain_id} is not in [0, {cls.MAX_DOMAIN}]")
        return domain_id

    @classmethod
    def domains_in_use(cls, domain_ids: Iterable[int], timeout_s: float = 0.2) -> list[int]:
        """The domains of ``domain_ids`` whose subscriber port accepts a TCP connection on
        loopback, i.e. where a graph (a launcher's proxy) is probably running."""
        found = []
        for domain_id in domain_ids:
            port = cls.BASE_PORT + 2 * domain_id + 1
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
                probe.settimeout(timeout_s)
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    found.append(domain_id)
        return found

    @classmethod
    def free(cls, host: str = "127.0.0.1") -> Endpoints:
        """Endpoints for a ``Proxy`` to bind on free ports (``Proxy.start`` reports them)."""
        return cls(f"tcp://{host}:*", f"tcp://{host}:*")

    def to_env(self) -> dict[str, str]:
        """The environment variables that hand these endpoints (and keys) to a node process."""
        return {_ENV_PUB: self.pub, _ENV_SUB: self.sub,
                **(self.keys.to_env() if self.keys is not None else {}),
                **({DIRECT_HOST_ENV: self.direct_host} if self.direct_host else {}),
                **({INSECURE_ENV: "1"} if self.insecure else {})}

    def direct_bind(self, pub_id: int) -> str | None:
        """Where a direct publisher ``pub_id`` binds, beside the proxy's XSUB: a free port on
        the same host (tcp), a socket file next to it (ipc), an inproc name; ``None`` for
        other transports (the publisher then goes through the proxy)."""
        scheme, sep, address = self.pub.partition("://")
        if not sep:
            return None
        if scheme == "tcp":
            host = self.direct_host or address.rpartition(":")[0]
            return f"tcp://{host}:*" if host else None
        if scheme in ("ipc", "inproc"):
            return f"{self.pub}-{pub_id:016x}"
        return None

    def allows_direct(self, endpoint: str) -> bool:
        """Whether ``endpoint`` is one ``direct_bind`` could have given: a port on the proxy's
        host (or this host's ``direct_host``), a socket file beside the proxy's. A subscriber
        connects to no other announced endpoint, so a forged status cannot send it to another
        host or folder. A graph whose proxy is off loopback spans hosts: a port on any host
        (with keys, a subscriber talks only to servers that prove the graph's key)."""
        scheme, sep, address = self.pub.partition("://")
        if scheme == "tcp":
            host = address.rpartition(":")[0]
            announced, _, port = endpoint.partition("://")[2].rpartition(":")
            if not (endpoint.startswith("tcp://") and port.isdigit() and announced
                    and announced != "*"):
                return False
            return (announced in (host, self.direct_host)
                    or not is_loopback(host) and announced != "0.0.0.0")
        if scheme in ("ipc", "inproc"):
            suffix = endpoint.removeprefix(f"{self.pub}-")
            return suffix != endpoint and len(suffix) == 16 and all(
                c in "0123456789abcdef" for c in suffix)
        return False

    @property
    def addresses(self) -> tuple[str, str]:
        """``(pub, sub)``, without the keys."""
        return self.pub, self.sub


GRAPHS_DIR_PREFIX = "vibrissa-graphs-"
"""Graph records: ``<temp dir>/vibrissa-graphs-<uid>/domain-<N>-<pid>.json``, one folder per
user, readable by every user (a tool names another user's graph too)."""


@dataclass(frozen=True)
class GraphRecord:
    """Who runs the graph on a domain: its launch file, when and by whom it was started (local
    time, ISO 8601) and the launcher's pid. A launcher writes it beside its proxy
    (`register_graph`); the tools read it (`running_graphs`) to say which graph they talk to."""

    domain: int
    launch_file: str
    started: str
    user: str
    pid: int

    @classmethod
    def of_this_process(cls, domain: int, launch_file: str) -> GraphRecord:
        """The record of a graph this process starts now on ``domain``."""
        try:
            user = getpass.getuser()
        except (KeyError, OSError):  # a uid without a name (a container)
            user = f"uid {os.getuid()}"
        return cls(domain, launch_file, datetime.now().astimezone().isoformat(timespec="seconds"),
                   user, os.getpid())

    def describe(self) -> str:
        """``domain 2 (launch/view.yaml, started 2026-11-28T23:59:01+00:00 by ana, pid 4242)``."""
        return (f"domain {self.domain} ({self.launch_file}, started {self.started} by "
                f"{self.user}, pid {self.pid})")


def _graphs_dir(uid: int) -> Path:
    return Path(tempfile.gettempdir()) / f"{GRAPHS_DIR_PREFIX}{uid}"


MAX_RECORD_CHARS = 4096
"""Characters of a graph record at most (a record is about 150): what a folder holds besides
records (a pipe, a huge file) is passed over, never waited for."""


def register_graph(record: GraphRecord) -> Path | None:
    """Write ``record`` for the tools of every user; its path (remove it when the graph ends),
    or None when the user's record folder cannot be used (then the graph runs unnamed)."""
    folder = _graphs_dir(os.getuid())
    try:
        folder.mkdir(mode=0o755, exist_ok=True)
        info = folder.lstat()
        if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid():
            return None  # somebody else's folder (or a link) under our name: write nothing there
        path = folder / f"domain-{record.domain}-{record.pid}.json"
        partial = path.with_suffix(".part")
        partial.write_text(json.dumps(asdict(record)))
        partial.chmod(0o644)
        partial.replace(path)
    except OSError:
        return None
    return path


def running_graphs() -> list[GraphRecord]:
    """The records of the graphs running on this machine, by domain: a record counts when its
    file and folder belong to the user it names by uid, its launcher is alive and its domain's
    port is in use. The records of the user's launchers that are gone are removed."""
    found: dict[int, GraphRecord] = {}
    for folder in Path(tempfile.gettempdir()).glob(f"{GRAPHS_DIR_PREFIX}*"):
        uid_text = folder.name.removeprefix(GRAPHS_DIR_PREFIX)
        for path in folder.glob("domain-*.json"):
            try:
                if not (uid_text.isdigit() and folder.lstat().st_uid == int(uid_text)
                        == path.lstat().st_uid):
                    continue
                record = GraphRecord(**json.loads(read_text(path, MAX_RECORD_CHARS)))
            except (OSError, ValueError, TypeError):
                continue
            if not (type(record.domain) is int and 0 <= record.domain <= Endpoints.MAX_DOMAIN
                    and type(record.pid) is int and isinstance(record.launch_file, str)
                    and isinstance(record.started, str) and isinstance(record.user, str)):
                continue
            if not _alive(record.pid):
                if int(uid_text) == os.getuid():
                    path.unlink(missing_ok=True)
                continue
            kept = found.get(record.domain)  # a launcher whose pid a new process took
            if (kept is None or kept.started < record.started) and \
                    Endpoints.domains_in_use([record.domain]):
                found[record.domain] = record
    return [found[domain] for domain in sorted(found)]


SCANNED_DOMAINS = range(32)
"""Domains probed for running graphs (besides those with a `GraphRecord`)."""


def scanned_domains(domain: int) -> list[int]:
    """The domains probed for graphs by a process on ``domain``: `SCANNED_DOMAINS` and the
    32 from its own (where a launch moves when its domain is taken)."""
    nearby = range(domain, min(domain + len(SCANNED_DOMAINS), Endpoints.MAX_DOMAIN + 1))
    return sorted({*SCANNED_DOMAINS, *nearby})


def which_graph(domain: int) -> str | None:
    """Which graph a process that joins ``domain`` by default talks to, when more than one
    runs on this machine: its record (launch file, start, user) and the others' (each with
    its domain), for a line that goes on with how to choose another; None when at most one
    runs."""
    records = {record.domain: record for record in running_graphs()}
    running = set(records) | set(Endpoints.domains_in_use(scanned_domains(domain)))
    if len(running) < 2:
        return None

    def named(d: int) -> str:
        return records[d].describe() if d in records else f"domain {d}"

    others = "; ".join(named(d) for d in sorted(running - {domain}))
    if domain not in running:
        return f"{len(running)} graphs run on this machine, none on domain {domain}: {others}"
    return (f"{len(running)} graphs run on this machine; talking to the one on {named(domain)} "
            f"(others: {others})")


def joined_graph_note(environ: Mapping[str, str] | None = None) -> str | None:
    """`which_graph` for a process whose endpoints come from the environment's domain, not
    from endpoints it was handed (a node started by hand, not by a launcher)."""
    env = os.environ if environ is None else environ
    if env.get(_ENV_PUB) or env.get(_ENV_SUB):
        return None
    note = which_graph(Endpoints.env_domain(env))
    return None if note is None else f"{note}; start it with {DOMAIN_ENV}=N for another"


def _alive(pid: int) -> bool:
    """Whether a process ``pid`` runs (of any user)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's
    except (OverflowError, ValueError):
        return False
    return True


def _remove_socket_file(endpoint: str) -> None:
    """Remove the file of a bound ``ipc://`` endpoint once its socket is closed (ZeroMQ leaves
    it behind); connections already made live on, so queued messages still leave."""
    if endpoint.startswith("ipc://"):
        try:
            os.unlink(endpoint[len("ipc://"):])
        except OSError:
            pass


def _socket(context: zmq.Context[Any], kind: int, hwm: int) -> zmq.Socket[Any]:
    """A socket with linger 0 and high-water marks ``hwm``, except a SUB's send side: it
    carries only subscriptions, which ZeroMQ drops silently beyond the mark."""
    sock = context.socket(kind)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDHWM, max(hwm, DEFAULT_HWM) if kind == zmq.SUB else hwm)
    sock.setsockopt(zmq.RCVHWM, hwm)
    return sock


def _bind(sock: zmq.Socket[Any], address: str, keys: Keys | None, insecure: bool = False
          ) -> None:
    """Bind ``sock`` as a CURVE server when there are keys; an ipc socket file only in a
    folder no other user can enter; a tcp address off loopback only with keys, unless
    ``insecure`` (`KeysError`)."""
    host = _tcp_host(address)
    if keys is None and host is not None and not is_loopback(host) and not insecure:
        raise KeysError(f"{address} is not on loopback: a graph's sockets bind off loopback "
                        "only with keys (--keys DIR; make them with `vibrissa keys DIR`), or "
                        "with --insecure for plain text that anyone on the network can read "
                        "and write")
    if keys is not None:
        keys.serve_with(sock, sock.context)
    if address.startswith("ipc://"):
        _check_private_folder(Path(address[len("ipc://"):]).parent)
    sock.bind(address)


def _connect(sock: zmq.Socket[Any], address: str, keys: Keys | None) -> None:
    if keys is not None:
        keys.connect_with(sock)
    sock.connect(address)


def _check_private_folder(folder: Path) -> None:
    """Create ``folder`` 0700, or refuse one that others may enter (their processes could
    connect to a socket file in it, whatever its mode)."""
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    info = folder.stat()
    if info.st_mode & 0o077 or info.st_uid != os.getuid():
        raise zmq.ZMQError(errno.EACCES, f"ipc folder {folder} must be yours and private (mode "
                           f"{info.st_mode & 0o777:04o}; chmod 700 it or use another folder)")


class Proxy:
    """XSUB (bound at ``endpoints.pub``) to XPUB (bound at ``endpoints.sub``) in a thread.

    Bind to ``Endpoints.free()`` for free ports; ``start()`` returns the bound endpoints.
    Stopping sends ``TERMINATE`` on an inproc control socket (``zmq.proxy_steerable``).

    A publisher that sends a frame larger than ``max_message_bytes`` is disconnected by the
    XSUB (ZeroMQ's ``MAXMSGSIZE``): nothing of it reaches a subscriber's queue, and the
    subscribers stay connected. (The limit belongs here, on the bound side: on a connecting
    SUB socket one oversized frame would cut its connection for good.)
    """

    def __init__(
        self,
        endpoints: Endpoints | None = None,
        context: zmq.Context[Any] | None = None,
        hwm: int = DEFAULT_HWM,
        max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
    ) -> None:
        self._requested = endpoints if endpoints is not None else Endpoints.from_env()
        self._context = context if context is not None else zmq.Context.instance()
        self._hwm = hwm
        self._max_message_bytes = max_message_bytes
        self._thread: threading.Thread | None = None
        self._control: zmq.Socket[Any] | None = None
        self.endpoints: Endpoints | None = None

    def start(self) -> Endpoints:
        """Bind both sockets and start forwarding; returns the actual endpoints."""
        if self._thread is not None:
            raise RuntimeError("proxy already started")
        control_address = f"inproc://vibrissa-proxy-control-{os.getpid()}-{next(_CONTROL_IDS)}"
        xsub = _socket(self._context, zmq.XSUB, self._hwm)
        xsub.setsockopt(zmq.MAXMSGSIZE, self._max_message_bytes)
        xpub = _socket(self._context, zmq.XPUB, self._hwm)
        control_in = self._context.socket(zmq.PAIR)
        control_in.setsockopt(zmq.LINGER, 0)
        keys = self._requested.keys
        try:
            _bind(xsub, self._requested.pub, keys, self._requested.insecure)
            _bind(xpub, self._requested.sub, keys, self._requested.insecure)
            control_in.bind(control_address)
            self._control = self._context.socket(zmq.PAIR)
            self._control.setsockopt(zmq.LINGER, 0)
            self._control.connect(control_address)
        except (zmq.ZMQError, KeysError):
            for sock in (xsub, xpub, control_in):
                sock.close()
            if self._control is not None:
                self._control.close()
                self._control = None
            raise
        self.endpoints = replace(self._requested, pub=xsub.getsockopt_string(zmq.LAST_ENDPOINT),
                                 sub=xpub.getsockopt_string(zmq.LAST_ENDPOINT))
        # The sockets move to the proxy thread here; thread start is the memory barrier
        # ZeroMQ asks for when a socket changes threads.
        self._thread = threading.Thread(
            target=self._run, args=(xsub, xpub, control_in), name="vibrissa-proxy", daemon=True
        )
        self._thread.start()
        log.info("proxy: publishers -> %s, subscribers -> %s%s", *self.endpoints.addresses,
                 " (CURVE)" if keys is not None else "")
        return self.endpoints

    @staticmethod
    def _run(xsub: zmq.Socket[Any], xpub: zmq.Socket[Any], control: zmq.Socket[Any]) -> None:
        try:
            zmq.proxy_steerable(xsub, xpub, None, control)
        except zmq.ContextTerminated:
            pass
        except zmq.ZMQError as exc:
            log.error("proxy stopped: %s", exc)
        finally:
            for sock in (xsub, xpub, control):
                sock.close()

    @property
    def refused(self) -> int:
        """Peers refused so far for want of an allowed key (with keys; else 0)."""
        return Guard.refused_in(self._context)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop forwarding and close the sockets (idempotent)."""
        if self._thread is None:
            return
        assert self._control is not None
        try:
            self._control.send(b"TERMINATE")
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error("proxy thread did not stop within %.1f s", timeout_s)
        finally:
            self._control.close()
            self._control = None
            self._thread = None
            if self.endpoints is not None:
                for endpoint in self.endpoints.addresses:
                    _remove_socket_file(endpoint)

    def __enter__(self) -> Proxy:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


def _check_topic(topic: str) -> bytes:
    validate_name(topic)
    if not topic.startswith("/"):
        raise ValueError(f"topic {topic!r} is relative: on the wire a topic is absolute "
                         f"(/{topic}, or in its node's namespace: /NAMESPACE/{topic})")
    return topic.encode() + b"\0"


class Publisher(contextlib.AbstractContextManager["Publisher"]):
    """Publishes messages of one type (or a few) on one (absolute) topic.

    Thread-safe: a lock serialises sends, so the node runtime's heartbeat thread can ``ping``
    and ``release`` the same socket the node publishes on. While held (``hold()``), published
    messages are encoded and buffered, in order, until ``release()`` sends them.

    Parameters
    ----------
    topic
        Fully qualified topic name, e.g. ``/whisker0/wrench``.
    msg_type
        The message class published, or a tuple of them (``EndOfStream`` is allowed in
        addition).
    hwm
        Send high-water mark, messages; beyond it ZeroMQ drops (subscribers count the loss).
    direct
        Bind an endpoint of its own (``endpoint``) instead of connecting to the proxy; the
        owner must announce it (a node does, in its ``NodeStatus``), or nobody hears it. Where
        no endpoint can be bound beside the proxy's, the publisher goes through the proxy
        (``endpoint`` is ``None``) and logs why.
    """

    def __init__(
        self,
        topic: str,
        msg_type: MessageTypes,
        endpoints: Endpoints | None = None,
        context: zmq.Context[Any] | None = None,
        hwm: int = DEFAULT_HWM,
        direct: bool = False,
    ) -> None:
        self._prefix = _check_topic(topic)
        self.topic = topic
        self.msg_types = msg_type if isinstance(msg_type, tuple) else (msg_type,)
        self.type_name = "|".join(t.TYPE_NAME for t in self.msg_types)  # for NodeStatus
        self.pub_id = int.from_bytes(os.urandom(8), "little")
        self.published = 0  # data messages accepted by publish/publish_raw (not EndOfStream)
        self.sent = 0  # messages sent with a seq: data and EndOfStream (= the next seq)
        self._lock = threading.Lock()
        self._held: deque[bytes] | None = None
        self.endpoint: str | None = None  # the bound endpoint of a direct publisher
        context = context if context is not None else zmq.Context.instance()
        endpoints = endpoints or Endpoints.from_env()
        self._socket = _socket(context, zmq.PUB, hwm)
        try:
            bind = endpoints.direct_bind(self.pub_id) if direct else None
            if bind is not None and (endpoints.keys is None or endpoints.keys.serves):
                self.endpoint = self._bind_or_none(bind, endpoints.keys, endpoints.insecure)
            if self.endpoint is None:
                _connect(self._socket, endpoints.pub, endpoints.keys)
        except zmq.ZMQError:
            self._socket.close()
            raise

    def _bind_or_none(self, address: str, keys: Keys | None, insecure: bool) -> str | None:
        try:
            _bind(self._socket, address, keys, insecure)
        except (zmq.ZMQError, KeysError) as exc:
            log.warning("%s: cannot bind %s (%s); publishing through the proxy",
                        self.topic, address, exc)
            return None
        return self._socket.getsockopt_string(zmq.LAST_ENDPOINT)

    def publish(self, msg: Message) -> None:
        """Encode and send ``msg`` (buffered while held)."""
        if not isinstance(msg, (*self.msg_types, EndOfStream)):
            raise TypeError(
                f"publisher on {self.topic} sends {self.type_name}, "
                f"got {type(msg).__name__}"
            )
        payload = encode(msg)
        with self._lock:
            if not isinstance(msg, EndOfStream):
                self.published += 1
            self._send_or_hold(payload)

    def publish_raw(self, payload: bytes) -> None:
        """Send an already encoded payload (bag replay); its type must match the publisher's."""
        name, _ = peek_type(payload)
        if name != EndOfStream.TYPE_NAME and decodes_as(name) not in self.msg_types:
            raise TypeError(
                f"publisher on {self.topic} sends {self.type_name}, payload is {name}"
            )
        with self._lock:
            if name != EndOfStream.TYPE_NAME:
                self.published += 1
            self._send_or_hold(bytes(payload))

    def publish_end_of_stream(self, source: str, stamp: float | None = None) -> None:
        """Send ``EndOfStream(count=published)``: lets subscribers see a loss at the tail."""
        with self._lock:
            count = self.published
        stamp = time.time() if stamp is None else stamp
        self.publish(EndOfStream(stamp=stamp, source=source, count=count))

    def ping(self, sender: str) -> None:
        """Send a ``Ping`` carrying the next seq; never buffered, never advances seq."""
        payload = encode(Ping(stamp=time.time(), sender=sender))
        with self._lock:
            self._send(payload, self.sent)

    def hold(self) -> None:
        """Buffer published messages from now on instead of sending them."""
        with self._lock:
            if self._held is None:
                self._held = deque()

    def release(self) -> int:
        """Send the buffered messages in order and stop buffering; returns how many."""
        with self._lock:
            held, self._held = self._held, None
            for payload in held or ():
                self._send_now(payload)
            return len(held or ())

    @property
    def held(self) -> bool:
        """Whether published messages are being buffered."""
        return self._held is not None

    @property
    def pending(self) -> int:
        """Number of buffered messages."""
        return len(self._held or ())

    def _send_or_hold(self, payload: bytes) -> None:
        if self._held is not None:
            self._held.append(payload)
        else:
            self._send_now(payload)

    def _send_now(self, payload: bytes) -> None:
        self._send(payload, self.sent)
        self.sent += 1

    def _send(self, payload: bytes, seq: int) -> None:
        header = msgpack.packb({"pub": self.pub_id, "seq": seq})
        # the three frames of send_multipart without its per-frame checks and flag-enum
        # arithmetic: 1.1 against 3.2 us from Python (warm, no subscriber)
        sock = self._socket
        sock.send(self._prefix, _SNDMORE)
        sock.send(header, _SNDMORE)
        sock.send(payload, 0, copy=len(payload) < 65536)

    def close(self, linger_s: float = 0.0) -> None:
        """Close the socket; queued messages get ``linger_s`` to leave when the context ends.

        The default, 0, discards them at once: a ``finally`` never hangs. ``Node.close`` uses
        a bounded linger for an orderly shutdown.
        """
        with self._lock:
            if self._held:
                log.warning("%s: %d held messages discarded at close", self.topic, len(self._held))
            self._socket.close(linger=max(0, round(linger_s * 1000)))
        if self.endpoint is not None:
            _remove_socket_file(self.endpoint)

    def __exit__(self, *exc_info: object) -> None:
        self.close()


@dataclass(frozen=True)
class Header:
    """Transport header of a message: publisher id and its per-topic sequence number."""

    pub: int
    seq: int


@dataclass(frozen=True)
class Received:
    """One delivered message; ``receive_time`` is wall-clock seconds (``time.time()``)."""

    topic: str
    msg: Message
    payload: bytes
    header: Header
    receive_time: float


@dataclass(frozen=True)
class StreamEnd:
    """One stream (a publisher on a topic) that ended, as a subscriber saw it: what its
    ``EndOfStream`` says was sent, what arrived, and what was lost (gaps in ``seq``, plus what
    was sent before the first message heard)."""

    topic: str
    pub: int
    source: str
    sent: int
    received: int
    lost: int
    rejected: int = 0

    def describe(self) -> str:
        """``stream of /src (pub 0123...) ended: 100 sent, 97 received, 2 lost, 1 rejected``
        (rejected: arrived, but did not decode)."""
        return (f"stream of {self.source} (pub {self.pub:016x}) ended: {self.sent} sent, "
                f"{self.received} received, {self.lost} lost"
                + (f", {self.rejected} rejected" if self.rejected else ""))


@dataclass
class TopicCounters:
    """Per-topic counts of a subscriber (messages)."""

    received: int = 0  # delivered to the caller (data and EndOfStream)
    lost: int = 0  # missing seq numbers
    rejected: int = 0  # frames that did not decode (counted, logged, never raised)
    pings: int = 0
    anomalies: int = 0  # seq jumps beyond MAX_SEQ_GAP: forged or reset, not counted as lost


class Subscriber(contextlib.AbstractContextManager["Subscriber"]):
    """Receives messages on exact topics (``topics=None``: every topic, any type).

    ``topics`` maps each fully qualified topic to the expected message class (or a tuple of
    them), or ``None`` for any registered type; ``Ping`` and ``EndOfStream`` are accepted on
    every topic.

    It listens on the proxy and, for every topic it takes other than ``/vibrissa/status``, on
    each direct publisher of that topic that a ``NodeStatus`` announces (``direct_endpoints``);
    statuses it reads only for that are neither counted nor returned.

    What it buffers is bounded: while the caller is busy elsewhere a thread takes messages off
    the sockets into a queue of at most ``max_buffered_bytes`` bytes and ``hwm`` messages
    (``wire.inbox``); what does not fit is dropped, counted in ``dropped``, and shows as lost
    on its topic.
    """

    def __init__(
        self,
        topics: Mapping[str, MessageTypes | None] | None,
        endpoints: Endpoints | None = None,
        context: zmq.Context[Any] | None = None,
        hwm: int = DEFAULT_HWM,
        max_buffered_bytes: int | None = None,
    ) -> None:
        self.max_buffered_bytes = (_buffered_bytes_from_env() if max_buffered_bytes is None
                                   else max_buffered_bytes)
        self.topics: dict[str, tuple[type[Message], ...] | None] | None = None
        self._expected: dict[str, tuple[type[Message], ...] | None] = {}
        prefixes = [b""]
        if topics is not None:
            prefixes = [_check_topic(topic) for topic in topics]
            self.topics = {topic: None if t is None else t if isinstance(t, tuple) else (t,)
                           for topic, t in topics.items()}
            for topic, types in self.topics.items():
                self._expected[topic] = None if types is None else (*types, Ping, EndOfStream)
        self.counters: dict[str, TopicCounters] = {t: TopicCounters() for t in topics or ()}
        self._seen: set[str] = set()
        self._seen_pubs: OrderedDict[int, None] = OrderedDict()  # at most MAX_PUBLISHERS
        # per (topic, publisher id), least recently heard first; at most MAX_PUBLISHERS
        self._next_seq: OrderedDict[tuple[str, int], int] = OrderedDict()
        # per stream (a publisher on a topic): [data received, lost, rejected] from its start
        self._stream_counts: dict[tuple[str, int], list[int]] = {}
        self._ended: OrderedDict[tuple[str, int], None] = OrderedDict()  # streams ended and
        # not heard from since (a repeated EndOfStream is no end of its own)
        self.ended_streams: deque[StreamEnd] = deque(maxlen=MAX_PUBLISHERS)
        # Direct publishers: discovered from statuses when any topic but the status is taken.
        self._discover = topics is None or any(t != STATUS_TOPIC for t in topics)
        self._status_wanted = topics is None or STATUS_TOPIC in topics
        status_prefix = _check_topic(STATUS_TOPIC)
        self.direct_endpoints: set[str] = set()
        self._context = context if context is not None else zmq.Context.instance()
        self._endpoints = endpoints or Endpoints.from_env()
        self._refused_endpoints: set[str] = set()  # announced, not beside the proxy
        self._direct_options_set = False  # on the socket, for the direct connections to come
        # One socket for the proxy and every direct publisher: a receive polls one socket (each
        # socket polled costs ZeroMQ a few system calls per receive).
        self._socket = sock = _socket(self._context, zmq.SUB, PIPE_HWM)
        try:
            for prefix in prefixes:
                sock.setsockopt(zmq.SUBSCRIBE, prefix)
            if self._discover and not self._status_wanted:
                sock.setsockopt(zmq.SUBSCRIBE, status_prefix)
            _connect(sock, self._endpoints.sub, self._endpoints.keys)
        except zmq.ZMQError:
            sock.close()
            raise
        try:
            self._inbox = Inbox([sock], self.max_buffered_bytes, hwm, self._payload_limit)
        except (ValueError, zmq.ZMQError):
            sock.close()
            raise

    @property
    def seen_topics(self) -> set[str]:
        """Topics on which anything (pings included) has arrived."""
        return set(self._seen)

    @property
    def seen_publishers(self) -> set[int]:
        """Ids of the publishers (the newest ``MAX_PUBLISHERS``) anything has arrived from,
        pings included: a node restarted on a topic already seen is a new id."""
        return set(self._seen_pubs.copy())

    def totals(self) -> dict[str, int]:
        """Counters summed over topics: received, lost, rejected, pings, anomalies."""
        counters = list(self.counters.values())  # one atomic copy: read by the status thread
        return {
            name: sum(getattr(c, name) for c in counters)
            for name in ("received", "lost", "rejected", "pings", "anomalies")
        }

    @property
    def queued_bytes(self) -> int:
        """Bytes received and not yet taken by ``receive``."""
        return self._inbox.queued_bytes

    @property
    def dropped(self) -> int:
        """Messages dropped because the receive queue was full (each also counts as lost on
        its topic once a later message of its stream shows the gap)."""
        return self._inbox.dropped

    def receive(self, timeout_s: float) -> Received | None:
        """Next message, or ``None`` when none arrives within ``timeout_s`` seconds.

        Pings and malformed messages are consumed here (counted, rejected ones logged) and
        never returned or raised.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            taken = self._inbox.take(deadline - time.monotonic())
            if taken is None:
                return None
            received = self._handle(*taken)
            if received is not None:
                return received

    def _connect_announced(self, status: NodeStatus) -> None:
        """Connect to the direct publishers that ``status`` announces on topics taken here."""
        for topic, endpoint in status.endpoints.items():
            if endpoint in self.direct_endpoints:
                continue
            if self.topics is not None and topic not in self.topics:
                continue
            if not self._endpoints.allows_direct(endpoint):
                if len(self._refused_endpoints) < MAX_PUBLISHERS:
                    if endpoint not in self._refused_endpoints:
                        log.warning("%s announces %s on %s: not beside the proxy (%s), ignored",
                                    status.node, endpoint, topic, self._endpoints.pub)
                    self._refused_endpoints.add(endpoint)
                continue
            self.direct_endpoints.add(endpoint)
            self._inbox.run_locked(functools.partial(self._connect_direct, endpoint,
                                                     status.node, topic))

    def _connect_direct(self, endpoint: str, node: str, topic: str) -> None:
        """Connect the subscriber's socket to ``endpoint`` too; runs with the inbox's sockets
        to itself. ZeroMQ copies a socket's options into each connection as it is made, so the
        options set here hold for the direct connections, not for the proxy's (made before);
        the socket's subscriptions, the status's included, go to every connection (a direct
        publisher sends its own topic only)."""
        if not self._direct_options_set:
            # an announced peer is not trusted with frames larger than the proxy takes
            self._socket.setsockopt(zmq.MAXMSGSIZE, DEFAULT_MAX_MESSAGE_BYTES)
            # Endpoints of nodes that are gone stay connected (what they sent last must
            # still be read); ZeroMQ retries them at most every 5 s.
            self._socket.setsockopt(zmq.RECONNECT_IVL_MAX, 5000)
            self._direct_options_set = True
        try:
            self._socket.connect(endpoint)
        except zmq.ZMQError as exc:
            log.warning("%s announces %s on %s, cannot connect: %s", node, endpoint, topic, exc)
            return
        log.debug("%s: direct from %s at %s", topic, node, endpoint)

    def _payload_limit(self, topic_frame: bytes) -> int:
        """The longest payload worth keeping on ``topic_frame`` (also called on the inbox's
        drainer thread: reads only what ``__init__`` wrote)."""
        try:
            topic = topic_frame[:-1].decode()
        except UnicodeDecodeError:
            return 0  # refused anyway
        if topic == STATUS_TOPIC and topic not in self._expected:
            return NodeStatus.MAX_BYTES  # read only to find direct publishers
        return payload_limit(self._expected.get(topic))

    def _handle(self, frames: list[bytes], cut: int = 0) -> Received | None:
        """Deliver, count or refuse one message; ``cut``: the length of a payload the inbox
        did not keep (refused here by its length alone)."""
        now = time.time()
        if len(frames) != 3 or not frames[0].endswith(b"\0"):
            self._reject("?", f"{len(frames)} frames, expected [topic\\0, header, payload]")
            return None
        raw_topic, raw_header, payload = frames
        try:
            topic = raw_topic[:-1].decode()
        except UnicodeDecodeError:
            self._reject("?", f"topic {raw_topic!r} is not UTF-8")
            return None
        if topic == STATUS_TOPIC and self._discover and not self._status_wanted:
            self._learn_from_status(payload)  # read only to find direct publishers
            return None
        counters = self.counters.get(topic)
        if counters is None:  # topics=None: counters appear with the topics
            counters = self.counters[topic] = TopicCounters()
        self._seen.add(topic)
        try:
            header = _parse_header(raw_header)
        except ValueError as exc:
            self._reject(topic, str(exc))
            return None
        self._seen_pubs[header.pub] = None
        self._seen_pubs.move_to_end(header.pub)
        if len(self._seen_pubs) > MAX_PUBLISHERS:
            self._seen_pubs.popitem(last=False)
        if cut:
            self._track(topic, counters, header, is_ping=False)  # it did use its seq
            self._reject(topic, f"payload of {cut} bytes, more than the "
                                f"{self._payload_limit(raw_topic)} taken on {topic}", header)
            return None
        try:
            msg = decode(payload, self._expected.get(topic))
        except DecodeError as exc:
            self._track(topic, counters, header, is_ping=False)  # it did use its seq
            self._reject(topic, str(exc), header)
            return None
        if self._discover and isinstance(msg, NodeStatus):
            self._connect_announced(msg)  # a status the caller takes too
        if isinstance(msg, EndOfStream) and (topic, header.pub) not in self._next_seq:
            counters.anomalies += 1  # a forged end: it would end a stream it never was
            log.warning("%s: EndOfStream from publisher %016x, never heard on this topic: "
                        "ignored", topic, header.pub)
            return None
        is_ping = isinstance(msg, Ping)
        self._track(topic, counters, header, is_ping)
        if is_ping:
            counters.pings += 1
            return None
        counters.received += 1
        if isinstance(msg, EndOfStream):
            self._end_stream(topic, counters, header, msg)
        else:
            self._stream_counts.setdefault((topic, header.pub), [0, 0, 0])[0] += 1
            self._ended.pop((topic, header.pub), None)
        return Received(topic, msg, payload, header, now)

    def _end_stream(self, topic: str, counters: TopicCounters, header: Header,
                    eos: EndOfStream) -> None:
        """Compare what the stream's end says was sent (its publisher's count from its start)
        with what arrived and what was rejected since then; messages missing from before the
        first one heard (no seq gap shows them) count as lost too. An end repeated with nothing
        heard since is an anomaly, not another end."""
        key = (topic, header.pub)
        if key in self._ended:
            counters.anomalies += 1
            log.warning("%s: EndOfStream from %s (pub %016x) again, nothing heard since its "
                        "last: ignored", topic, eos.source, header.pub)
            return
        counts = self._stream_counts.setdefault(key, [0, 0, 0])
        received, lost, rejected = counts
        self._ended[key] = None
        if len(self._ended) > MAX_PUBLISHERS:
            self._ended.popitem(last=False)
        missing = eos.count - received - lost - rejected
        if missing > 0:
            counters.lost += missing
            lost += missing
            counts[1] = lost
        elif missing < 0:
            counters.anomalies += 1  # more arrived than were sent: forged or repeated
        end = StreamEnd(topic, header.pub, eos.source, eos.count, received, lost, rejected)
        self.ended_streams.append(end)
        if lost or missing < 0:
            log.warning("%s: %s", topic, end.describe())
        else:
            log.debug("%s: %s", topic, end.describe())

    def _learn_from_status(self, payload: bytes) -> None:
        """Learn direct publishers from a status the caller does not take (one that does not
        decode is dropped unlogged: it is not the caller's)."""
        try:
            status = decode(payload, (NodeStatus,))
        except DecodeError:
            return
        if isinstance(status, NodeStatus):
            self._connect_announced(status)

    def _track(self, topic: str, counters: TopicCounters, header: Header, is_ping: bool) -> None:
        key = (topic, header.pub)
        expected = self._next_seq.get(key)
        if expected is None and len(self._next_seq) >= MAX_PUBLISHERS:
            # a flood of publisher ids (forged headers) must not grow the table: forget the
            # one heard from least recently (if it comes back, its counting starts over)
            forgotten, _ = self._next_seq.popitem(last=False)
            self._stream_counts.pop(forgotten, None)
            self._ended.pop(forgotten, None)
        elif expected is not None:
            self._next_seq.move_to_end(key)
        if expected is not None:
            gap = header.seq - expected
            if gap > MAX_SEQ_GAP or gap < -MAX_SEQ_GAP:
                counters.anomalies += 1
                log.warning("%s: publisher %016x jumped from seq %d to %d: not counted as "
                            "loss (a forged or reset sequence)", topic, header.pub, expected,
                            header.seq)
            elif gap > 0:
                counters.lost += gap
                self._stream_counts.setdefault(key, [0, 0, 0])[1] += gap
                log.warning(
                    "%s: lost %d message(s) from publisher %016x (seq %d..%d)",
                    topic, gap, header.pub, expected, header.seq - 1,
                )
            elif gap < 0 and not is_ping:
                log.warning(
                    "%s: publisher %016x seq went back from %d to %d (restarted?)",
                    topic, header.pub, expected, header.seq,
                )
            if is_ping and gap <= 0:
                return
        # A ping announces the seq of the next message; a message is followed by seq + 1.
        self._next_seq[key] = header.seq if is_ping else header.seq + 1

    def _reject(self, topic: str, reason: str, header: Header | None = None) -> None:
        """Count and log a message refused; with its ``header``, against its stream too."""
        counters = self.counters.setdefault(topic, TopicCounters())
        counters.rejected += 1
        if header is not None:
            self._stream_counts.setdefault((topic, header.pub), [0, 0, 0])[2] += 1
            self._ended.pop((topic, header.pub), None)
        log.warning("%s: rejected message: %s", topic, reason)

    def close(self) -> None:
        """Stop taking messages and close the sockets (linger 0)."""
        self._inbox.close()

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _buffered_bytes_from_env() -> int:
    text = os.environ.get(BUFFER_ENV, "").strip()
    if not text:
        return DEFAULT_MAX_BUFFERED_BYTES
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"{BUFFER_ENV}={text!r} is not an integer") from None
    if value < 1:
        raise ValueError(f"{BUFFER_ENV}={value} must be at least 1")
    return value


def _parse_header(raw: bytes) -> Header:
    try:
        header = msgpack.unpackb(raw, raw=False)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise ValueError(f"header does not unpack: {exc}") from exc
    if not isinstance(header, dict):
        raise ValueError("header is not a map")
    pub, seq = header.get("pub"), header.get("seq")
    if type(pub) is not int or type(seq) is not int or pub < 0 or seq < 0:
        raise ValueError(f"header needs non-negative int 'pub' and 'seq', got {header!r}")
    return Header(pub, seq)
