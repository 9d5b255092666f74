"""``vibrissa launch FILE.yaml [name:=value ...]``: run a node graph from a YAML launch file.

The launcher starts the XSUB/XPUB proxy in its own process on the ports of a domain (as ROS 2's
``ROS_DOMAIN_ID``: ``--domain``, the file's ``transport``, else ``VIBRISSA_DOMAIN_ID``, default 0,
or the next free domain when another graph holds that one), so that ``vibrissa topic`` and
``vibrissa bag`` find the graph without flags and two graphs never share a proxy. Then it starts
every node in file order as a child in its own process group, with the proxy's endpoints in its
environment
(``Endpoints.to_env()``) and its parameters in a temporary YAML file. Each line a child writes is
echoed with a ``[name] `` prefix. Nodes that fail are respawned per their policy; a failed
``required`` node, a node with ``on_exit: shutdown`` finishing, Ctrl-C or SIGTERM shut the graph
down: SIGINT to every running node at once (in reverse start order, consumers first), as ROS 2's
launch does, so the graph stops in the time of its slowest node, not in the sum of them; then
each, in reverse start order, has its grace period, SIGTERM, a grace period, SIGKILL.

Nodes die with their launcher: each child asks the kernel for a SIGTERM when the launcher
dies (``PR_SET_PDEATHSIG``), so a SIGKILLed launcher leaves no node behind; a node busy
computing that does not end by itself is ended `vibrissa.runtime.signals.ORPHAN_GRACE_S` later
by an alarm. The temporary parameter folder of a launcher that died is removed by the next
launch.

The launcher listens to the nodes' statuses: the summary gives, per node, what it published
and received (all its starts together) and what it lost or refused, and names every node whose
input did not arrive in full.

A ``required`` node that ends while the others still run fails the graph (or is respawned)
whatever its exit status, unless it is ``finite`` (its work ends by itself, as a simulated
source's) and exits 0.

With keys (``--keys``, the file's ``transport.keys``, else ``VIBRISSA_KEYS``) the proxy and
every node speak CURVE (``vibrissa.wire.security``); the summary counts the peers refused.

Exit status: 0 when every node ended with 0 (or was stopped by the launcher after an
``on_exit: shutdown``); 1 when a node failed for good (the last line names it); 2 for an
invalid launch file or argument (nothing is started); ``EXIT_LOST_DATA`` (4) when nothing
failed but a node without ``allow_loss`` lost or refused input; 128 + signal number after
Ctrl-C/SIGTERM.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import IO

import yaml

from vibrissa.launch.description import (
    LaunchDescription,
    NodeSpec,
    TransportSpec,
    node_module,
    node_params,
    resolve_launch_file,
)
from vibrissa.msgs import NodeStatus
from vibrissa.runtime.node import DEBUG_ENV, EXIT_LOST_DATA
from vibrissa.runtime.signals import SignalHandlers
from vibrissa.runtime.traffic import Traffic
from vibrissa.wire.security import Keys, KeysError
from vibrissa.wire.topics import STATUS_TOPIC
from vibrissa.wire.transport import (
    BUFFER_ENV,
    DOMAIN_ENV,
    Endpoints,
    GraphRecord,
    Proxy,
    Subscriber,
    is_loopback,
    local_address_towards,
    register_graph,
)

__all__ = [
    "DEFAULT_GRACE_S",
    "Launcher",
    "RUN_MODULE",
    "NodeOutcome",
    "die_with_parent",
    "node_command",
    "resolve_launch_file",
]

DEFAULT_GRACE_S = 5.0
RUN_MODULE = ("import runpy, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
              "signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT]); "
              "runpy.run_module(sys.argv.pop(1), run_name='__main__', alter_sys=True)")
"""How a package node starts: ``python -c RUN_MODULE MODULE ...`` runs MODULE as ``python -m``
would, except that a SIGINT before the node takes over its signals (its imports take a second
or two) ends the process at once and quietly, instead of in a KeyboardInterrupt traceback. The
launcher starts it with SIGINT blocked (`package_node_start`), so that one sent while the
interpreter itself still starts (on a loaded machine, longer than a second) waits until then."""
PEER_SILENT_S = 2.0
"""A node of another host not heard for this long when one of them times out went with it."""
DOMAIN_TRIES = 32
"""Domains tried from the preferred one when it is taken and no domain was asked for."""
_POLL_S = 0.02
_READER_JOIN_S = 2.0
_LOG_PREFIX = "[launch] "


@dataclass
class NodeOutcome:
    """How one node's run went, for the summary and the exit status."""

    name: str
    starts: int = 0
    respawns: int = 0
    returncode: int | None = None
    failed: bool = False
    stopped_by_launcher: bool = False
    lost_data: bool = False  # it exited EXIT_LOST_DATA: done, its input incomplete
    note: str = ""

    def describe(self) -> str:
        """Human-readable result, e.g. ``exit 0``, ``killed by SIGKILL``."""
        if self.note:
            return self.note
        text = _describe_returncode(self.returncode)
        return f"stopped by launcher ({text})" if self.stopped_by_launcher else text


ANSWERS = (2, 3, EXIT_LOST_DATA)
"""Exit statuses that are a node's answer, not a crash: 2 refused input or parameters, 3
nothing to do (a mapper without points), `EXIT_LOST_DATA` done with incomplete input. A new
start would only repeat them (or wait for streams that ended), so they are never respawned."""


def _crashed(rc: int | None, early: bool) -> bool:
    """Whether an exit is a crash, which a respawn may mend: any status but 0 and `ANSWERS`
    (killed by a signal, an error, not started), or a required node's exit 0 while the graph
    runs."""
    return early or rc not in (0, *ANSWERS)


def _what_happened(rc: int | None) -> str:
    """``exited with code 3`` / ``was killed by SIGKILL``, for log lines."""
    text = _describe_returncode(rc)
    return text.replace("exit ", "exited with code ", 1) if rc is not None and rc >= 0 else (
        f"was {text}")


def _describe_returncode(rc: int | None) -> str:
    if rc is None:
        return "not started"
    if rc >= 0:
        return f"exit {rc}"
    try:
        return f"killed by {signal.Signals(-rc).name}"
    except ValueError:
        return f"killed by signal {-rc}"


@dataclass
class _Running:
    """Runtime state of one node."""

    spec: NodeSpec
    outcome: NodeOutcome
    proc: subprocess.Popen[bytes] | None = None
    readers: list[threading.Thread] = field(default_factory=list)
    state: str = "pending"  # pending | running | waiting (respawn) | done
    respawn_at: float = 0.0
    heard_at: float | None = None  # monotonic time of the current start's first status
    ended_at: float | None = None  # monotonic time it was last seen done


@dataclass
class _Peer:
    """A node of the graph that this launch did not start (another host's, a tool), as its
    statuses tell."""

    heard_at: float  # monotonic time of its last status
    state: str
    gone: bool = False
    message: str = ""  # of its last status


def node_command(spec: NodeSpec, params_file: str | None, python: str = sys.executable
                 ) -> list[str]:
    """The argv that starts ``spec``, following the node command line of ARCHITECTURE.md.

    Parameters
    ----------
    spec : NodeSpec
        The node.
    params_file : str or None
        Its parameters file, if it has parameters.
    python : str
        Interpreter for ``pkg``/``exec`` nodes.

    Returns
    -------
    list of str
        ``python -c RUN_MODULE <the node's module>`` (or ``cmd``) ``--name N --namespace NS
        [--params-file F] [--remap FROM:=TO]... [args...]``.
    """
    if spec.cmd is not None:
        argv = list(spec.cmd)
    else:
        assert spec.executable is not None  # exactly one of cmd and executable
        argv = [python, "-c", RUN_MODULE, node_module(spec.pkg, spec.executable)]
    argv += ["--name", spec.name, "--namespace", spec.namespace]
    if params_file is not None:
        argv += ["--params-file", params_file]
    for remap in spec.remaps:
        argv += ["--remap", f"{remap.source}:={remap.target}"]
    argv += list(spec.args)
    return argv


class _Output:
    """Line-prefixed, lock-protected writing to the launcher's stdout and stderr."""

    def __init__(self, stdout: IO[str], stderr: IO[str]) -> None:
        self.stdout = stdout
        self.stderr = stderr
        self.lock = threading.Lock()

    def write(self, stream: IO[str], text: str) -> None:
        with self.lock:
            try:
                stream.write(text)
                stream.flush()
            except (OSError, ValueError):
                pass  # a closed or broken output must not kill the launcher

    def log(self, message: str) -> None:
        self.write(self.stderr, f"{_LOG_PREFIX}{message}\n")

    def pump(self, pipe: IO[bytes], stream: IO[str], prefix: str) -> None:
        """Copy ``pipe`` to ``stream`` line by line with ``prefix`` (reader-thread body)."""
        with pipe:
            for raw in iter(lambda: pipe.readline(65536), b""):
                line = raw.decode("utf-8", errors="replace")
                if not line.endswith("\n"):
                    line += "\n"
                self.write(stream, prefix + line)


class Launcher:
    """Runs a `LaunchDescription`: proxy, nodes, respawns, ordered shutdown.

    Parameters
    ----------
    description : LaunchDescription
        The validated launch file.
    grace_s : float
        Seconds to wait after SIGINT, and again after SIGTERM, before escalating.
    stdout, stderr : text streams, optional
        Where prefixed child output and the launcher's own log go (default: sys streams).
    python : str
        Interpreter for ``pkg``/``exec`` nodes.
    domain : int, optional
        The graph's domain (``--domain``), over the launch file's; it must be free.
    debug : bool
        Nodes log the traceback of an error that ends them (``VIBRISSA_DEBUG=1``).
    keys : Keys, optional
        CURVE keys (``--keys``), over the launch file's and ``VIBRISSA_KEYS``.
    insecure : bool
        A graph off loopback may run without keys (``--insecure``): plain text.
    """

    def __init__(
        self,
        description: LaunchDescription,
        *,
        grace_s: float = DEFAULT_GRACE_S,
        stdout: IO[str] | None = None,
        stderr: IO[str] | None = None,
        python: str = sys.executable,
        domain: int | None = None,
        debug: bool = False,
        keys: Keys | None = None,
        insecure: bool = False,
    ) -> None:
        self.description = description
        self.domain = domain
        self.keys = keys
        self.insecure = insecure
        self.exit_status = 1  # of a launch that could not join its graph
        self.refused_peers = 0
        self.debug = debug
        self.grace_s = grace_s
        self.out = _Output(stdout or sys.stdout, stderr or sys.stderr)
        self.python = python
        self.nodes = [_Running(spec, NodeOutcome(spec.name)) for spec in description.nodes]
        self._signals: list[int] = []
        self._shutting_down = False
        self._failure: str | None = None
        self._signals_at_shutdown = 0
        self._env: dict[str, str] = {}
        self._params_dir: str | None = None
        self._statuses: Subscriber | None = None
        self._stranded: list[str] = []  # nodes whose input can no longer arrive, and why
        self._reach = ""  # how tools reach a graph that moved off its preferred domain
        self.traffic = Traffic()
        self._spans_hosts = False
        self._joined_at: float | None = None  # when this launch joined a graph over hosts
        self._peers: dict[str, _Peer] = {}  # nodes of other hosts, by name

    # -- the run -------------------------------------------------------------------------------

    def run(self) -> int:
        """Start everything, supervise until the graph ends, shut down, summarise.

        Returns
        -------
        int
            The exit status (see the module docstring).
        """
        with SignalHandlers(self._signals.append):
            started = self._join_graph()
            if started is None:
                return self.exit_status
            proxy, endpoints, domain_env = started
            record = None
            if domain_env and is_loopback(endpoints.sub.partition("://")[2].rpartition(":")[0]):
                # on a domain of loopback: the tools of every user can name the graph
                record = register_graph(GraphRecord.of_this_process(
                    int(domain_env[DOMAIN_ENV]), os.path.abspath(self.description.source)))
            self._statuses = Subscriber({STATUS_TOPIC: NodeStatus}, endpoints)
            transport = self.description.transport or TransportSpec()
            self._env = {"PYTHONUNBUFFERED": "1", **endpoints.to_env(), **domain_env,
                         **({DEBUG_ENV: "1"} if self.debug else {}),
                         **({BUFFER_ENV: str(transport.max_buffered_bytes)}
                            if transport.max_buffered_bytes is not None else {})}
            remove_orphaned_params_dirs()
            self._params_dir = tempfile.mkdtemp(prefix=f"{PARAMS_DIR_PREFIX}{os.getpid()}-")
            try:
                self._supervise()
            finally:
                self._shutdown()
                self._collect_statuses(0.3)  # the nodes' final statuses
                self._await_peers()
                self._statuses.close()
                self._statuses = None
                if proxy is not None:
                    self.refused_peers = proxy.refused
                    with contextlib.suppress(Exception):
                        proxy.stop()
                if record is not None:
                    record.unlink(missing_ok=True)
                shutil.rmtree(self._params_dir, ignore_errors=True)
        return self._finish()

    def _join_graph(self) -> tuple[Proxy | None, Endpoints, dict[str, str]] | None:
        """Join the graph: start its proxy here (`_start_proxy`), or, with ``proxy_host``, join
        the proxy of another host. Returns the proxy (None: another host's), the endpoints for
        the nodes and the domain variable, or ``None`` after logging why not (``exit_status``
        says how the launch ends)."""
        spec = self.description.transport or TransportSpec()
        try:
            keys = self.keys or (Keys.load(spec.keys) if spec.keys else Keys.from_env())
        except KeysError as exc:
            self.out.log(f"cannot use the keys: {exc}")
            return None
        if spec.bind is not None:  # ZeroMQ binds addresses, not names
            try:
                spec = replace(spec, bind=socket.gethostbyname(spec.bind))
            except OSError as exc:
                self.out.log(f"cannot bind {spec.bind}: {exc}")
                return None
        host = spec.bind or spec.proxy_host
        self._spans_hosts = host is not None
        self._joined_at = time.monotonic() if self._spans_hosts else None
        if host is not None and not is_loopback(host) and keys is None:
            if not self.insecure:
                self.out.log(f"refused: this graph reaches {host}, off loopback, without keys. "
                             "Give the same keys on every host (--keys DIR, made with `vibrissa "
                             "keys DIR`; docs/HOSTS.md), or --insecure to send plain text")
                self.exit_status = 2
                return None
            self.out.log(f"INSECURE (--insecure): the graph's traffic with {host} is plain text; "
                         "anyone on that network can read it and publish into it")
        if spec.proxy_host is None:
            return self._start_proxy(spec, keys)
        domain = self.domain if self.domain is not None else spec.domain
        try:
            domain = Endpoints.env_domain() if domain is None else domain
            direct_host = spec.direct_host or local_address_towards(spec.proxy_host)
        except (ValueError, OSError) as exc:
            self.out.log(f"cannot join the graph at {spec.proxy_host}: {exc}")
            return None
        endpoints = replace(Endpoints.for_domain(domain, spec.proxy_host), keys=keys,
                            direct_host=direct_host, insecure=self.insecure)
        secured = "plain text" if keys is None else f"CURVE with the keys of {keys.folder}"
        self.out.log(f"joining the graph whose proxy runs on {spec.proxy_host} (domain {domain}: "
                     f"publishers -> {endpoints.pub}, subscribers -> {endpoints.sub}; this "
                     f"host's direct publishers on {direct_host}; {secured}; tools: --graph "
                     f"{spec.proxy_host}:{domain})")
        self._reach = f" the graph on {spec.proxy_host}:{domain}"
        return None, endpoints, {DOMAIN_ENV: str(domain)}

    def _start_proxy(self, spec: TransportSpec, keys: Keys | None
                     ) -> tuple[Proxy, Endpoints, dict[str, str]] | None:
        """Bind the graph's proxy: the launch file's endpoints, else the domain of ``domain``
        or of the file (taken or fail), else the environment's domain (default 0) or, when
        that is taken by another graph, the next free one (not at ``bind``: the other hosts
        join the domain they are told); on loopback or at ``bind``."""
        secured = "" if keys is None else f"; CURVE with the keys of {keys.folder}"
        if spec.pub_endpoint is not None and spec.sub_endpoint is not None:
            proxy = Proxy(Endpoints(spec.pub_endpoint, spec.sub_endpoint, keys,
                                    insecure=self.insecure),
                          max_message_bytes=spec.max_message_bytes)
            try:
                endpoints = proxy.start()
            except Exception as exc:  # noqa: BLE001 - any failure to bind ends the launch
                self.out.log(f"cannot start the proxy: {exc}")
                return None
            self.out.log(f"proxy: publishers -> {endpoints.pub}, subscribers -> {endpoints.sub} "
                         f"(tools: --pub {endpoints.pub} --sub {endpoints.sub}{secured})")
            return proxy, endpoints, {}
        fixed = self.domain if self.domain is not None else spec.domain
        if fixed is not None:
            candidates = [fixed]
        else:
            try:
                preferred = Endpoints.env_domain()
            except ValueError as exc:
                self.out.log(f"cannot choose a domain: {exc}")
                return None
            # a graph over hosts stays on its domain: the other hosts join the one they are told
            candidates = [preferred] if spec.bind is not None else list(
                range(preferred, min(preferred + DOMAIN_TRIES, Endpoints.MAX_DOMAIN + 1)))
        for domain in candidates:
            proxy = Proxy(replace(Endpoints.for_domain(domain, spec.bind or "127.0.0.1"),
                                  keys=keys, direct_host=spec.direct_host,
                                  insecure=self.insecure),
                          max_message_bytes=spec.max_message_bytes)
            try:
                endpoints = proxy.start()
            except Exception as exc:  # noqa: BLE001 - any failure to bind ends the launch
                if getattr(exc, "errno", None) == errno.EADDRINUSE:
                    continue
                self.out.log(f"cannot start the proxy on domain {domain}: {exc}")
                return None
            if domain != candidates[0]:
                self.out.log(f"domain {candidates[0]} is in use by another graph; this graph "
                             f"runs on domain {domain}")
                self._reach = f" domain {domain} (tools: --domain {domain} or {DOMAIN_ENV}={domain})"
            tools = ("tools find it without flags" if domain == 0 and DOMAIN_ENV not in os.environ
                     else f"tools: --domain {domain} or {DOMAIN_ENV}={domain}")
            if spec.bind is not None:
                tools = f"tools: --graph {spec.bind}:{domain}"
                self._reach = f" the graph on {spec.bind}:{domain}"
            self.out.log(f"proxy: publishers -> {endpoints.pub}, subscribers -> {endpoints.sub} "
                         f"(domain {domain}; {tools}{secured})")
            return proxy, endpoints, {DOMAIN_ENV: str(domain)}
        taken = (f"domain {candidates[0]} is in use" if len(candidates) == 1
                 else f"domains {candidates[0]}-{candidates[-1]} are all in use")
        self.out.log(f"cannot start the proxy: {taken} (another graph has bound its ports); "
                     "choose a free one with --domain N")
        return None

    def _supervise(self) -> None:
        for node in self.nodes:
            if self._check_signals() or self._shutting_down:
                return
            self._start(node)
            self._poll_exits()
        while not self._shutting_down:
            if self._check_signals():
                return
            self._poll_exits()
            now = time.monotonic()
            for node in self.nodes:
                if node.state == "waiting" and now >= node.respawn_at and not self._shutting_down:
                    node.outcome.respawns += 1
                    self._start(node)
            if all(node.state == "done" for node in self.nodes):
                return
            self._collect_statuses(_POLL_S)
            self._end_stranded()
            self._check_peers()

    def _check_peers(self) -> None:
        """In a graph over several hosts: a node not of this launch (another host's, a tool) not
        heard for ``peer_timeout_s`` (its host or the link down) is gone, said once; ``on_peer_lost``
        says whether this launch ends (failed) or runs on, and the others silent for
        `PEER_SILENT_S` then are gone with it. One heard again is back. No other host heard
        at all within ``peer_timeout_s`` is said once (how to join is usually what is wrong)."""
        if not self._spans_hosts:
            return
        spec = self.description.transport or TransportSpec()
        now = time.monotonic()
        if not self._peers and self._joined_at is not None \
                and now - self._joined_at > spec.peer_timeout_s:
            self._joined_at = None  # said once
            where = spec.bind or spec.proxy_host
            self.out.log(f"no node of another host heard for {spec.peer_timeout_s:g} s: is the "
                         f"other host's launch running, with the graph at {where} on the same "
                         "domain, and keys this graph allows (a refused key is counted where "
                         "it was refused)?")
        silent = {name: now - peer.heard_at for name, peer in self._peers.items()
                  if not peer.gone and peer.state not in ("finished", "error")}
        if not any(quiet > spec.peer_timeout_s for quiet in silent.values()):
            return
        # with one gone, so are those that went silent with it (statuses come every 0.5 s)
        gone = sorted(name for name, quiet in silent.items()
                      if quiet > min(spec.peer_timeout_s, PEER_SILENT_S))
        for name in gone:
            self._peers[name].gone = True
        what = (f"node(s) {', '.join(gone)} (not this launch's) not heard for "
                f"{spec.peer_timeout_s:g} s (their host, their launch or the link is down)")
        if spec.on_peer_lost == "continue":
            self.out.log(f"{what}; marked gone, running on (on_peer_lost: continue)")
            return
        self._failure = what
        self.out.log(f"{what}; shutting down (on_peer_lost: shutdown)")
        self._shutting_down = True

    def _end_stranded(self) -> None:
        """Shut the graph down when a running node waits for input that can no longer arrive:
        every node publishing a topic it takes is done, and one of them ended before this
        start of the node was heard (its EndOfStream went out before the node listened) or
        crashed (no EndOfStream went out)."""
        for node in self.nodes:
            if node.state != "running" or node.heard_at is None:
                continue
            inputs = self.traffic.subscribes(node.spec.fqn)
            producers = [other for other in self.nodes if other is not node
                         and self.traffic.publishes(other.spec.fqn) & inputs]
            if not producers or any(other.state != "done" for other in producers):
                continue
            heard = node.heard_at
            early = {other.spec.name: "ended before it listened" for other in producers
                     if other.ended_at is not None and other.ended_at < heard}
            crashed = {other.spec.name: _what_happened(other.outcome.returncode)
                       for other in producers if _crashed(other.outcome.returncode, False)}
            gone = {**crashed, **early}
            if not gone:
                continue
            sent = sum((self.traffic.of(p.spec.fqn) or {}).get("published", 0) for p in producers)
            got = (self.traffic.of(node.spec.fqn) or {}).get("received", 0)
            why = ", ".join(f"'{name}' {what}" for name, what in gone.items())
            self._stranded.append(f"'{node.spec.name}' waits for input that can no longer "
                                  f"arrive ({why}): its inputs' publishers sent {sent} "
                                  f"message(s); it received {got} on all its topics")
            self.out.log(f"{self._stranded[-1]}; shutting down")
            self._shutting_down = True
            return

    def _check_signals(self) -> bool:
        if not self._signals:
            return False
        self.out.log(f"received {signal.Signals(self._signals[0]).name}; shutting down")
        self._shutting_down = True
        return True

    def _start(self, node: _Running) -> None:
        spec = node.spec
        params_file = None
        if spec.params:
            assert self._params_dir is not None
            params_file = os.path.join(self._params_dir, f"{spec.name}.params.yaml")
            with open(params_file, "w", encoding="utf-8") as fh:
                yaml.safe_dump(node_params(spec), fh, sort_keys=False)
        argv = node_command(spec, params_file, self.python)
        env = {**os.environ, **self._env, **dict(spec.env)}
        node.outcome.starts += 1
        try:
            proc = subprocess.Popen(
                argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                env=env, start_new_session=True,  # own process group: signalled as a whole
                preexec_fn=package_node_start(os.getpid()) if spec.cmd is None
                else die_with_parent(os.getpid()),
            )
        except OSError as exc:
            node.proc = None
            self._on_exit(node, None, f"could not start: {exc}")
            return
        node.proc = proc
        node.state = "running"
        node.heard_at = None
        prefix = f"[{spec.name}] "
        node.readers = []
        for pipe, stream in ((proc.stdout, self.out.stdout), (proc.stderr, self.out.stderr)):
            assert pipe is not None
            reader = threading.Thread(target=self.out.pump, args=(pipe, stream, prefix),
                                      name=f"launch-{spec.name}", daemon=True)
            reader.start()
            node.readers.append(reader)
        what = "respawned" if node.outcome.starts > 1 else "started"
        self.out.log(f"{what} '{spec.name}' (pid {proc.pid})")

    def _poll_exits(self) -> None:
        for node in self.nodes:
            if node.state == "running" and _has_exited(node.proc):
                rc = self._reap(node)
                self._on_exit(node, rc, "")

    def _reap(self, node: _Running) -> int:
        """Collect an exited node: kill what is left of its process group, drain its output."""
        proc = node.proc
        assert proc is not None
        # The leader is a zombie until waited for, so its pid (= the group id) cannot have
        # been reused yet: killing the group is safe and takes any orphaned children with it.
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        rc = proc.wait()
        for reader in node.readers:
            reader.join(_READER_JOIN_S)
        node.state = "done"
        node.outcome.returncode = rc
        return rc

    def _on_exit(self, node: _Running, rc: int | None, note: str) -> None:
        spec, outcome = node.spec, node.outcome
        outcome.returncode = rc
        node.state = "done"
        node.ended_at = time.monotonic()
        if self._shutting_down:
            return
        early = (rc == 0 and spec.required and not spec.finite and spec.on_exit != "shutdown"
                 and any(other.state != "done" for other in self.nodes if other is not node))
        if (rc == 0 and not early) or rc == EXIT_LOST_DATA:
            outcome.lost_data = rc == EXIT_LOST_DATA
            self.out.log(f"'{spec.name}' finished (exit {rc}"
                         f"{': its input did not arrive in full' if outcome.lost_data else ''})")
            if spec.on_exit == "shutdown":
                self.out.log(f"'{spec.name}' has on_exit: shutdown; shutting down")
                self._shutting_down = True
            return
        # A required node that ends while the graph runs on left it without a part it needs,
        # whatever its exit status, unless its work ends by itself (finite: true).
        what = note or ("ended (exit 0) while the graph still runs (a node whose work ends "
                        "by itself is marked finite: true)" if early else _what_happened(rc))
        if (spec.respawn and _crashed(rc, early)
                and (spec.respawn_max is None or outcome.respawns < spec.respawn_max)):
            node.state = "waiting"
            node.respawn_at = time.monotonic() + spec.respawn_delay
            cap = f"/{spec.respawn_max}" if spec.respawn_max is not None else ""
            self.out.log(f"'{spec.name}' {what}; respawn {outcome.respawns + 1}{cap} "
                         f"in {spec.respawn_delay:g} s")
            return
        outcome.failed = True
        outcome.note = note
        exhausted = ("" if not spec.respawn else " (respawn limit reached)" if _crashed(rc, early)
                     else f" (not respawned: exit {rc} is the node's answer)")
        if spec.required or spec.on_exit == "shutdown":
            why = "required node" if spec.required else "node with on_exit: shutdown"
            self._failure = f"{why} '{spec.name}' {what}{exhausted}"
            self.out.log(f"{self._failure}; shutting down")
            self._shutting_down = True
        else:
            self.out.log(f"'{spec.name}' {what}{exhausted}; not required, continuing")

    # -- shutdown ------------------------------------------------------------------------------

    def _shutdown(self) -> None:
        """Stop every node still running: SIGINT to all, then each in reverse start order."""
        self._shutting_down = True
        self._signals_at_shutdown = len(self._signals)
        for node in reversed(self.nodes):
            if node.state == "running" and node.proc is not None and not _has_exited(node.proc):
                node.outcome.stopped_by_launcher = True
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(node.proc.pid, signal.SIGINT)
        for node in reversed(self.nodes):
            if node.state == "pending":
                node.outcome.note = "not started"
            elif node.state == "waiting":
                last = _describe_returncode(node.outcome.returncode)
                node.outcome.note = f"respawn cancelled after {last}"
            elif node.state == "running":
                self._stop(node)
            node.state = "done"

    def _stop(self, node: _Running) -> None:
        proc = node.proc
        assert proc is not None
        if not _has_exited(proc):
            node.outcome.stopped_by_launcher = True
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
                if len(self._signals) > self._signals_at_shutdown:
                    sig = signal.SIGKILL  # a second Ctrl-C: no more waiting
                if sig != signal.SIGINT:  # SIGINT went to every node at once (_shutdown)
                    with contextlib.suppress(ProcessLookupError, PermissionError):
                        os.killpg(proc.pid, sig)
                if sig == signal.SIGKILL or self._wait(proc, self.grace_s):
                    break
                self.out.log(f"'{node.spec.name}' still running {self.grace_s:g} s after "
                             f"{sig.name}; escalating")
        self._reap(node)

    def _wait(self, proc: subprocess.Popen[bytes], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if _has_exited(proc):
                return True
            if len(self._signals) > self._signals_at_shutdown:
                return False
            time.sleep(_POLL_S)
        return _has_exited(proc)

    def _collect_statuses(self, timeout_s: float = 0.0) -> None:
        """Take the statuses that arrived (waiting up to ``timeout_s`` for the first)."""
        if self._statuses is None:
            return
        rx = self._statuses.receive(timeout_s)
        while rx is not None:
            if isinstance(rx.msg, NodeStatus):
                self.traffic.add(rx.msg)
                own = False
                for node in self.nodes:
                    if node.spec.fqn == rx.msg.node:
                        own = True
                        if node.state == "running":
                            node.heard_at = node.heard_at or time.monotonic()
                if not own and self._spans_hosts:
                    self._heard_peer(rx.msg)
            rx = self._statuses.receive(0.0)

    def _await_peers(self) -> None:
        """Before the summary of a graph over several hosts: the final statuses of the other
        hosts' nodes (their counts), for up to ``peer_timeout_s``; not after Ctrl-C."""
        if not self._peers or self._signals:
            return
        spec = self.description.transport or TransportSpec()
        deadline = time.monotonic() + spec.peer_timeout_s
        while time.monotonic() < deadline and any(
                not peer.gone and peer.state not in ("finished", "error")
                for peer in self._peers.values()):
            self._collect_statuses(_POLL_S)
            if self._signals:
                return

    def _heard_peer(self, status: NodeStatus) -> None:
        peer = self._peers.get(status.node)
        if peer is None:
            self._peers[status.node] = _Peer(time.monotonic(), status.state,
                                             message=status.message)
            return
        if peer.gone:
            self.out.log(f"node {status.node} (not this launch's) is heard again")
        if status.state in ("finished", "error") and peer.state != status.state:
            why = f" ({status.message})" if status.message else ""
            self.out.log(f"node {status.node} (not this launch's): {status.state}{why}")
        peer.heard_at, peer.state, peer.gone = time.monotonic(), status.state, False
        peer.message = status.message

    def _finish(self) -> int:
        outcomes = [node.outcome for node in self.nodes]
        width = max(len(o.name) for o in outcomes)
        result_width = max(len(o.describe()) for o in outcomes)
        self.out.log(f"summary:{self._reach}")
        shortfalls: list[tuple[bool, str]] = []
        refused_peers = self.refused_peers
        for node, o in zip(self.nodes, outcomes, strict=True):
            moved = self.traffic.of(node.spec.fqn)
            flow = ""
            if moved is not None:
                flow = f"  published {moved['published']}  received {moved['received']}"
                flow += "".join(f"  {key} {moved[key]}" for key in ("lost", "rejected",
                                                                      "anomalies") if moved[key])
                if moved["lost"] or moved["rejected"]:
                    allowed = " (allow_loss)" if node.spec.allow_loss else ""
                    shortfalls.append((node.spec.allow_loss, f"'{o.name}' lost {moved['lost']} "
                                       f"and refused {moved['rejected']} input message(s)"
                                       f"{allowed}"))
                refused_peers += moved["refused_peers"]
            self.out.log(f"  {o.name:<{width}}  {o.describe():<{result_width}}  "
                         f"starts {o.starts}  respawns {o.respawns}{flow}")
        if self._peers:
            self.out.log("  the graph's other nodes (not this launch's):")
        for name, peer in sorted(self._peers.items()):
            moved = self.traffic.of(name) or {}
            flow = "".join(f"  {key} {moved[key]}" for key in ("published", "received", "lost",
                                                                "rejected") if key in moved)
            state = ("gone (not heard at the end)" if peer.gone else
                     f"{peer.state} ({peer.message})" if peer.message.startswith("stopped by")
                     else peer.state)
            self.out.log(f"  {name:<{width}}  {state}{flow}")
        if refused_peers:
            self.out.log(f"refused {refused_peers} connection(s) without an allowed key "
                         f"({self.refused_peers} at the proxy)")
        if shortfalls:
            self.out.log("data did not arrive in full: " + "; ".join(t for _, t in shortfalls))
        if self._failure is not None:
            self.out.log(f"launch failed: {self._failure}")
            return 1
        failed = [o for o in outcomes if o.failed]
        if failed:
            names = ", ".join(f"'{o.name}' ({o.describe()})" for o in failed)
            self.out.log(f"launch failed: node {names}")
            return 1
        if self._stranded:
            self.out.log("data did not arrive in full: " + "; ".join(self._stranded))
            return EXIT_LOST_DATA
        if self._signals:
            return 128 + self._signals[0]
        lossy = [node.spec.name for node in self.nodes
                 if node.outcome.lost_data and not node.spec.allow_loss]
        if lossy:
            self.out.log(f"node(s) {', '.join(lossy)} ended with exit {EXIT_LOST_DATA}: their "
                         f"input did not arrive in full")
        if lossy or not all(allowed for allowed, _ in shortfalls):
            self.out.log("launch finished, but data were lost (allow_loss: true on the node "
                         "accepts that)")
            return EXIT_LOST_DATA
        self.out.log("launch finished")
        return 0


PARAMS_DIR_PREFIX = "vibrissa-launch-"
"""Temporary parameter folders: ``vibrissa-launch-<launcher pid>-<random>`` in the temp dir."""

_PR_SET_PDEATHSIG = 1
_LIBC = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith("linux") else None


def package_node_start(launcher_pid: int) -> Callable[[], None]:
    """What a package node's process runs between fork and exec: SIGINT blocked until
    `RUN_MODULE` sets its default action and unblocks it, and `die_with_parent`."""
    with_parent = die_with_parent(launcher_pid)

    def start() -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT])
        if with_parent is not None:
            with_parent()
    return start


def die_with_parent(launcher_pid: int) -> Callable[[], None] | None:
    """What a child runs between fork and exec: a SIGTERM to it when the launcher (any parent,
    ``launcher_pid``) dies (Linux; elsewhere nothing). If it is already gone, it ends at once."""
    if _LIBC is None:
        return None
    libc = _LIBC

    def set_parent_death_signal() -> None:
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        if os.getppid() != launcher_pid:  # the launcher died before the prctl took effect
            os._exit(1)
    return set_parent_death_signal


def remove_orphaned_params_dirs(temp_dir: str | None = None) -> list[str]:
    """Remove the parameter folders of launchers that are gone (killed before they could
    clean up); returns what was removed. Folders of running launchers and of other users are
    left alone."""
    removed = []
    base = temp_dir or tempfile.gettempdir()
    for entry in os.scandir(base):
        name = entry.name
        if not name.startswith(PARAMS_DIR_PREFIX) or not entry.is_dir(follow_symlinks=False):
            continue
        pid_text = name[len(PARAMS_DIR_PREFIX):].partition("-")[0]
        if not pid_text.isdigit() or entry.stat(follow_symlinks=False).st_uid != os.getuid():
            continue
        try:
            os.kill(int(pid_text), 0)
            continue  # its launcher still runs
        except (ProcessLookupError, PermissionError):
            pass  # gone (a process of another user has its pid now)
        shutil.rmtree(entry.path, ignore_errors=True)
        removed.append(entry.path)
    return removed


def _has_exited(proc: subprocess.Popen[bytes] | None) -> bool:
    """Whether ``proc`` has exited, without reaping it (its pid stays reserved)."""
    if proc is None or proc.returncode is not None:
        return True
    try:
        info = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
    except ChildProcessError:
        return True
    return info is not None
