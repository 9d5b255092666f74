"""ZeroMQ CURVE for a graph: key folders, encrypted and authenticated sockets, the guard.

A key folder (``vibrissa keys DIR``) holds::

    graph.key, graph.key_secret   the graph's pair: every bound socket (the proxy, direct
                                  publishers) serves with it, every member connects with it
    authorized/NAME.key           public keys of further clients allowed in
    clients/NAME/                 what a client NAME needs: graph.key, NAME.key, NAME.key_secret

A process whose folder holds ``graph.key_secret`` is a member of the graph (it may bind);
a client folder holds exactly one other secret, its own, and connects only. As ssh asks of its
keys, everything that decides who is let in (the folder, ``authorized/``, every key file) must
be the user's own and writable by nobody else, and secret files readable by the user alone
(0600): a folder another local user made or may write is refused, since they could put their
own key in it.

With keys, every socket speaks CURVE (encrypted, each peer proves its key). A bound socket asks
the process's `Guard` (ZeroMQ's ZAP handler, RFC 27) about each client key: allowed are the
graph's own and ``authorized/*.key``. ``ZAP_ENFORCE_DOMAIN`` makes a server refuse everyone
when no guard answers, so a stopped guard never opens the door. The guard also counts every
failed handshake (a plain-text peer, a wrong server key, a key not allowed) from the sockets'
monitors: ZAP alone never hears of a peer that does not speak CURVE.

pyzmq writes and reads the certificate files (``zmq.auth``); its ``ThreadAuthenticator`` is not
used because it neither counts refusals nor watches the monitors, which this one thread does.
"""

from __future__ import annotations

import logging
import os
import queue
import shutil
import stat
import tempfile
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import zmq
import zmq.auth
from zmq.utils.monitor import parse_monitor_message

__all__ = ["GRAPH_KEY", "KEYS_ENV", "Guard", "Keys", "KeysError", "authorize_keys", "create_keys",
           "join_keys"]

log = logging.getLogger(__name__)

KEYS_ENV = "VIBRISSA_KEYS"
"""Environment variable naming the key folder of a process (unset: no CURVE)."""

GRAPH_KEY = "graph"
ZAP_DOMAIN = "vibrissa"
_ZAP_ENDPOINT = "inproc://zeromq.zap.01"
_FAILED_HANDSHAKE = (zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
                     | zmq.EVENT_HANDSHAKE_FAILED_AUTH)
_LOG_EVERY_S = 10.0  # a refused peer retries ~10 times a second: one log line per interval


class KeysError(ValueError):
    """A key folder or file that cannot be used; the message names it and says why."""


@dataclass(frozen=True)
class Keys:
    """The CURVE keys of one process (z85-encoded, 40 bytes each).

    ``server_public`` is the graph's public key, which every client checks its server against;
    ``secret`` of a member is the graph's secret (``serves``); ``allowed`` are the client keys
    a bound socket lets in.
    """

    folder: Path
    name: str
    public: bytes
    secret: bytes = field(repr=False)  # never in a log line or a traceback
    server_public: bytes
    allowed: frozenset[bytes]

    @property
    def serves(self) -> bool:
        """Whether this process holds the graph's secret, i.e. may bind sockets."""
        return self.name == GRAPH_KEY

    @classmethod
    def load(cls, folder: str | os.PathLike[str]) -> Keys:
        """The keys of a folder made by `create_keys` (the graph's or a client's)."""
        if not os.fspath(folder):
            raise KeysError("the key folder is an empty name (leave it out for a graph "
                            "without keys)")
        root = Path(folder).absolute()  # handed to children, whatever their working folder
        if not root.is_dir():
            raise KeysError(f"key folder {root} does not exist (make one: vibrissa keys {root})")
        _check_own(root)
        secrets = sorted(root.glob("*.key_secret"))
        if (root / f"{GRAPH_KEY}.key_secret").exists():
            name = GRAPH_KEY
        elif len(secrets) == 1:
            name = secrets[0].name.removesuffix(".key_secret")
        else:
            found = ", ".join(p.name for p in secrets) or "none"
            raise KeysError(f"key folder {root}: expected {GRAPH_KEY}.key_secret or exactly one "
                            f"client's NAME.key_secret, found {found}")
        public, secret = _read_pair(root / f"{name}.key_secret")
        server_public, _ = _read_key(root / f"{GRAPH_KEY}.key")
        allowed = {server_public}
        authorized = root / "authorized"
        if authorized.is_dir():
            _check_own(authorized)
            allowed |= {_read_key(path)[0] for path in sorted(authorized.glob("*.key"))}
        return cls(root, name, public, secret, server_public, frozenset(allowed))

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Keys | None:
        """The keys of the folder in ``VIBRISSA_KEYS``; ``None`` when it is unset or empty."""
        folder = (os.environ if environ is None else environ).get(KEYS_ENV, "")
        return cls.load(folder) if folder else None

    def to_env(self) -> dict[str, str]:
        """The environment variable that hands these keys to a child process."""
        return {KEYS_ENV: str(self.folder)}

    def connect_with(self, sock: zmq.Socket[Any]) -> None:
        """Make ``sock`` a CURVE client of the graph (before it connects)."""
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_serverkey = self.server_public

    def serve_with(self, sock: zmq.Socket[Any], context: zmq.Context[Any]) -> None:
        """Make ``sock`` a CURVE server guarded by the context's `Guard` (before it binds)."""
        if not self.serves:
            raise KeysError(f"client keys {self.folder} cannot bind a socket of the graph")
        Guard.of(context, self).watch(sock)
        sock.curve_server = True
        sock.curve_secretkey = self.secret
        sock.setsockopt_string(zmq.ZAP_DOMAIN, ZAP_DOMAIN)
        sock.setsockopt(zmq.ZAP_ENFORCE_DOMAIN, 1)


def _check_own(path: Path) -> None:
    """`KeysError` unless ``path`` is the user's own and nobody else may write it (a key put
    there by another user would let them in)."""
    try:
        st = path.stat()
    except OSError as exc:
        raise KeysError(f"cannot read {path}: {exc.strerror or exc}") from None
    if st.st_uid != os.geteuid():
        raise KeysError(f"{path} belongs to user id {st.st_uid}, not to you ({os.geteuid()}): "
                        f"keys must be yours and private")
    if st.st_mode & 0o022:
        raise KeysError(f"{path} may be written by others (mode {stat.S_IMODE(st.st_mode):04o}), "
                        f"who could let themselves in: chmod go-w {path}")


def _read_key(path: Path) -> tuple[bytes, bytes | None]:
    _check_own(path)
    try:
        public, secret = zmq.auth.load_certificate(path)
    except (OSError, ValueError) as exc:
        raise KeysError(f"cannot read key {path}: {exc}") from None
    for key in (public, secret):
        if key is not None and len(key) != 40:
            raise KeysError(f"key {path} is not a 40-character z85 CURVE key")
    return public, secret


def _read_pair(path: Path) -> tuple[bytes, bytes]:
    mode = path.stat().st_mode
    if mode & 0o077:
        raise KeysError(f"secret key {path} is accessible by others (mode "
                        f"{stat.S_IMODE(mode):04o}): chmod 600 {path}")
    public, secret = _read_key(path)
    if secret is None:
        raise KeysError(f"{path} holds no secret key")
    return public, secret


def create_keys(folder: str | os.PathLike[str], clients: tuple[str, ...] = ()) -> list[Path]:
    """Make the graph's key pair in ``folder`` (0700) unless it is there, and a pair for each
    client not there yet; returns the files written. Secrets are 0600 from the start: each
    pair is made in a private temporary folder and moved in."""
    root = Path(folder)
    if not os.fspath(folder):
        raise KeysError("the key folder is an empty name")
    for name in clients:
        _client_name(name)
    root.mkdir(mode=0o700, parents=True, exist_ok=True)
    for made in (root, root / "authorized", root / "clients"):
        if made.exists():
            _check_own(made)  # before anything is written into it
    written: list[Path] = []
    if not (root / f"{GRAPH_KEY}.key_secret").exists():
        written += _new_pair(root, GRAPH_KEY)
    for name in clients:
        home = root / "clients" / name
        if home.exists():
            continue
        home.parent.mkdir(mode=0o700, exist_ok=True)
        home.mkdir(mode=0o700)
        written += _new_pair(home, name)
        shutil.copy(root / f"{GRAPH_KEY}.key", home / f"{GRAPH_KEY}.key")
        (root / "authorized").mkdir(mode=0o700, exist_ok=True)
        shutil.copy(home / f"{name}.key", root / "authorized" / f"{name}.key")
        written += [home / f"{GRAPH_KEY}.key", root / "authorized" / f"{name}.key"]
    return written


def _client_name(name: str) -> None:
    if not name.isidentifier():
        raise KeysError(f"client name {name!r}: use letters, digits and _")
    if name == GRAPH_KEY:
        raise KeysError(f"{GRAPH_KEY!r} is the graph's own key, not a client's")


def _public_key_file(path: Path) -> bytes:
    """The public key of a ``NAME.key`` file; `KeysError` for a secret file or no key."""
    public, secret = _read_key(path)
    if secret is not None:
        raise KeysError(f"{path} holds a secret key: give the public NAME.key (the secret "
                        "never leaves its host)")
    return public


def join_keys(folder: str | os.PathLike[str], name: str, graph_key: str | os.PathLike[str]
              ) -> list[Path]:
    """Make a client's folder on the client's own host: the graph's public key (a copy of
    ``graph_key``, the graph's ``graph.key``) and a new pair ``name``, whose public key
    ``NAME.key`` the graph's host then lets in (`authorize_keys`). Returns the files written."""
    _client_name(name)
    server_public = _public_key_file(Path(graph_key))
    root = Path(folder)
    if not os.fspath(folder):
        raise KeysError("the key folder is an empty name")
    root.mkdir(mode=0o700, parents=True, exist_ok=True)
    _check_own(root)
    if (root / f"{GRAPH_KEY}.key_secret").exists() or any(
            p.name != f"{name}.key_secret" for p in root.glob("*.key_secret")):
        raise KeysError(f"{root} holds another secret key already: a client folder holds its "
                        "own pair only; choose a new folder")
    written: list[Path] = []
    existing = root / f"{GRAPH_KEY}.key"
    if existing.exists() and _public_key_file(existing) != server_public:
        raise KeysError(f"{existing} is another graph's key")
    if not existing.exists():
        shutil.copy(graph_key, existing)
        os.chmod(existing, 0o644)
        written.append(existing)
    if not (root / f"{name}.key_secret").exists():
        written += _new_pair(root, name)
    return written


def authorize_keys(folder: str | os.PathLike[str], public_keys: tuple[str, ...]) -> list[Path]:
    """Let clients into the graph of ``folder``: copy each public ``NAME.key`` (made on the
    client's host by `join_keys`) into ``folder/authorized``. Returns the files written."""
    root = Path(folder)
    if not (root / f"{GRAPH_KEY}.key_secret").exists():
        raise KeysError(f"{root} is not a graph's key folder (no {GRAPH_KEY}.key_secret; make "
                        f"one with `vibrissa keys {root}`)")
    _check_own(root)
    authorized = root / "authorized"
    authorized.mkdir(mode=0o700, exist_ok=True)
    _check_own(authorized)
    written = []
    for key in map(Path, public_keys):
        _public_key_file(key)
        name = key.name.removesuffix(".key")
        if not key.name.endswith(".key"):
            raise KeysError(f"{key}: expected a public key file NAME.key")
        _client_name(name)
        target = authorized / key.name
        shutil.copy(key, target)
        os.chmod(target, 0o644)
        written.append(target)
    return written


def _new_pair(folder: Path, name: str) -> list[Path]:
    with tempfile.TemporaryDirectory(dir=folder) as private:  # 0700 by tempfile
        public, secret = zmq.auth.create_certificates(private, name)
        os.chmod(secret, 0o600)
        os.chmod(public, 0o644)
        moved = [folder / Path(public).name, folder / Path(secret).name]
        os.replace(public, moved[0])
        os.replace(secret, moved[1])
    return moved


class Guard:
    """The ZAP handler of one context, in a thread, and the counter of refused peers.

    ``refused`` counts the connections a watched (bound) socket accepted whose handshake failed
    (ZeroMQ's handshake-failed events): a plain-text peer, a wrong server key, a key not
    allowed, a peer that leaves before its greeting (a reset); each once. Connections the
    kernel refuses before ZeroMQ accepts them (beyond the listen backlog, ``ZMQ_BACKLOG``,
    100, while a flood is not yet accepted) never reach the socket and are not counted.
    Refusals are logged at most once per 10 s, with the count since the last line.
    """

    _guards: ClassVar[dict[int, Guard]] = {}
    _lock: ClassVar[threading.Lock] = threading.Lock()

    def __init__(self, context: zmq.Context[Any], allowed: frozenset[bytes]) -> None:
        self._context = context
        self._allowed = allowed
        self.refused = 0
        self._monitors: queue.SimpleQueue[zmq.Socket[Any]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._last_log = -_LOG_EVERY_S
        self._logged = 0  # refusals counted in log lines so far
        zap = context.socket(zmq.REP)
        zap.setsockopt(zmq.LINGER, 0)
        zap.bind(_ZAP_ENDPOINT)
        self._thread = threading.Thread(target=self._run, args=(zap,), name="vibrissa-zap",
                                        daemon=True)
        self._thread.start()

    @classmethod
    def of(cls, context: zmq.Context[Any], keys: Keys) -> Guard:
        """The running guard of ``context``, started with ``keys.allowed`` if there is none."""
        with cls._lock:
            guard = cls._guards.get(id(context))
            if guard is None or not guard._thread.is_alive():
                guard = cls._guards[id(context)] = cls(context, keys.allowed)
            elif guard._allowed != keys.allowed:
                raise KeysError("one context serves with one set of allowed keys")
            return guard

    @classmethod
    def stop_for(cls, context: zmq.Context[Any]) -> int:
        """Stop the guard of ``context`` (before the context ends); returns its refusals."""
        with cls._lock:
            guard = cls._guards.pop(id(context), None)
        if guard is None:
            return 0
        guard._stop.set()
        guard._thread.join(1.0)
        return guard.refused

    @classmethod
    def refused_in(cls, context: zmq.Context[Any]) -> int:
        """Peers refused so far by the guard of ``context`` (0 without one)."""
        guard = cls._guards.get(id(context))
        return 0 if guard is None else guard.refused

    def watch(self, sock: zmq.Socket[Any]) -> None:
        """Count the failed handshakes of ``sock`` (call before it binds)."""
        self._monitors.put(sock.get_monitor_socket(_FAILED_HANDSHAKE))

    def _run(self, zap: zmq.Socket[Any]) -> None:
        poller = zmq.Poller()
        poller.register(zap, zmq.POLLIN)
        monitors: list[zmq.Socket[Any]] = []
        try:
            while not self._stop.is_set():
                while not self._monitors.empty():
                    monitor = self._monitors.get()
                    monitors.append(monitor)
                    poller.register(monitor, zmq.POLLIN)
                for sock, _ in poller.poll(100):
                    if sock is zap:
                        zap.send_multipart(self._answer(zap.recv_multipart()))
                    else:
                        self._on_event(sock, poller, monitors)
        except zmq.ZMQError as exc:  # the context ended under it (destroy)
            log.debug("guard stopped: %s", exc)
        finally:
            for sock in (zap, *monitors):
                sock.close(linger=0)

    def _answer(self, request: list[bytes]) -> list[bytes]:
        """The ZAP reply (RFC 27): 200 for an allowed CURVE key, 400 for anything else."""
        if len(request) < 6:
            return [b"1.0", b"", b"500", b"malformed ZAP request", b"", b""]
        version, request_id, _domain, _address, _identity, mechanism = request[:6]
        credentials = request[6:]
        if mechanism == b"CURVE" and len(credentials) == 1 and len(credentials[0]) == 32:
            key = zmq.utils.z85.encode(credentials[0])
            if key in self._allowed:
                return [version, request_id, b"200", b"OK", key, b""]
        return [version, request_id, b"400", b"key not allowed", b"", b""]

    def _on_event(self, monitor: zmq.Socket[Any], poller: zmq.Poller,
                  monitors: list[zmq.Socket[Any]]) -> None:
        event = parse_monitor_message(monitor.recv_multipart())
        if event["event"] == zmq.EVENT_MONITOR_STOPPED:
            poller.unregister(monitor)
            monitors.remove(monitor)
            monitor.close(linger=0)
            return
        self.refused += 1
        now = time.monotonic()
        if now - self._last_log >= _LOG_EVERY_S:
            self._last_log = now
            log.warning("refused %d peer(s) without an allowed key on %s since the last line "
                        "(%d so far)", self.refused - self._logged,
                        event["endpoint"].decode(errors="replace"), self.refused)
            self._logged = self.refused
