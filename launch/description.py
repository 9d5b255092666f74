"""The YAML launch format: strict parsing into frozen dataclasses, substitutions, arguments.

The format follows ROS 2's YAML launch files where it fits::

    launch:
      - arg: {name: mu, default: "0.2", description: "friction coefficient"}
      - transport: {domain: 3}            # optional; default: VIBRISSA_DOMAIN_ID, else 0
                                          # keys: DIR  encrypts and authenticates (CURVE)
      - node:
          pkg: vibrissa                   # runs `python -m` the module pkg registers for exec
          exec: reconstructor             # ... or `cmd: [prog, arg, ...]` instead of pkg/exec
          name: reconstructor
          namespace: /whisker0
          param: [{name: mu, value: "$(var mu)"}]
          remap: [{from: wrench, to: /whisker0/wrench}]
          env: [{name: FOO, value: bar}]
          respawn: true
          respawn_delay: 0.2
          respawn_max: 5
          required: true
          finite: false                   # true: its work ends by itself (exit 0 is success)
          allow_loss: false               # true: input lost or refused is not a failure
          on_exit: shutdown
          if: "$(equals $(var mode) live)" # or unless: ...; a node whose condition fails is
                                          # left out (its entry is still checked)
          ready_before: [wrench_source]   # these nodes of the launch wait for this one too
      - include:
          file: robot.yaml                # a path (relative: to this file's folder), else a
                                          # packaged launch file
          arg: [{name: out, value: "$(var out)"}]

An included file's arguments take, in order, the include's ``arg`` value, the including file's
value of the same name (its own arguments and what it was given, as ROS 2's launch
configurations), its default. Its nodes, transport and arguments join the launch as if written
in place; ``NAME:=VALUE`` on the command line may name an argument of any file of the launch.

Substitutions inside strings: ``$(var NAME)``, ``$(env NAME)``, ``$(env NAME default)``,
``$(equals A B)`` and ``$(not-equals A B)`` (``true`` or ``false``), ``$(if C A B)`` (A when C
is ``true``, B when ``false``; A and B one word each), ``$(dirname)`` (the launch
file's directory), ``$(python)`` (the interpreter running the launch, for ``cmd`` nodes
written in Python) and ``$(launch_time)`` (when the launch file was read, s since the Unix
epoch, one value for the whole file: the default ``epoch`` of a simulated source); they nest,
innermost first, and a value is never read again as one. Every error is a `LaunchFileError`
whose message names the file and the key path, e.g.
``demo.yaml: launch[2].node.respawn: expected bool``.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import os
import shlex
import stat
import sys
import time
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

import yaml

from vibrissa.formats import yaml_numbers
from vibrissa.runtime.args import expand_home
from vibrissa.runtime.params import ParamError, check_params, did_you_mean, takes_text
from vibrissa.units import finite_number
from vibrissa.wire.topics import node_fqn, validate_name, validate_namespace, validate_token
from vibrissa.wire.transport import DEFAULT_MAX_MESSAGE_BYTES, Endpoints

__all__ = [
    "ON_EXIT_ACTIONS",
    "LaunchArg",
    "LaunchDescription",
    "LaunchFileError",
    "NodeSpec",
    "Param",
    "Remap",
    "TransportSpec",
    "check_node_params",
    "load_launch_file",
    "node_params",
    "parse_arg_overrides",
    "parse_launch",
    "resolve_launch_file",
]

ON_EXIT_ACTIONS = ("shutdown",)


class LaunchFileError(ValueError):
    """A launch file or a command-line argument override is invalid.

    Parameters
    ----------
    source : str
        The launch file as given (path or packaged name).
    key_path : str
        Where in the file, e.g. ``launch[2].node.respawn``; empty for whole-file errors.
    message : str
        What is wrong.
    """

    def __init__(self, source: str, key_path: str, message: str) -> None:
        self.source = source
        self.key_path = key_path
        self.message = message
        where = f"{source}: {key_path}" if key_path else source
        super().__init__(f"{where}: {message}")


@dataclass(frozen=True)
class LaunchArg:
    """A declared launch argument (``- arg: {name, default, description}``)."""

    name: str
    default: str | None = None
    description: str = ""


@dataclass(frozen=True)
class Param:
    """One node parameter; ``value`` is any YAML value (scalar, list, mapping). ``text``: the
    value's text when it was one string with substitutions (``value`` is what it reads as,
    `yaml_numbers.scalar`); a text parameter of the node takes it as is (`node_params`)."""

    name: str
    value: Any
    text: str | None = None


@dataclass(frozen=True)
class Remap:
    """A topic remap ``source:=target`` (``{from: source, to: target}`` in YAML)."""

    source: str
    target: str


@dataclass(frozen=True)
class TransportSpec:
    """Where the launcher's proxy binds.

    Either a ``domain`` id (its loopback ports, ``Endpoints.for_domain``; the launch fails when
    another graph holds them), or explicit ``pub_endpoint`` (XSUB, publishers connect) and
    ``sub_endpoint`` (XPUB, subscribers connect), or neither: the domain of
    ``VIBRISSA_DOMAIN_ID`` (default 0), or the next free one (``vibrissa.launch.launcher``).
    ``keys``: a key folder (``vibrissa keys``); every socket of the graph then speaks CURVE.
    ``max_message_bytes``: the largest frame the proxy takes from a publisher.
    ``max_buffered_bytes``: what each subscriber of a node buffers at most (its default is
    ``DEFAULT_MAX_BUFFERED_BYTES``).

    A graph over several hosts: one launch holds the proxy on the ports of its domain at
    ``bind`` (an address of this host the others reach), the others join it with
    ``proxy_host`` (that address) and no proxy of their own. ``direct_host``: the address this
    host's direct publishers bind and announce (default: ``bind``, or the address of the
    interface that routes to ``proxy_host``). Off loopback, keys are required (or
    ``--insecure``). A node of another host not heard for ``peer_timeout_s`` is gone:
    ``on_peer_lost`` ``shutdown`` ends this launch (failed), ``continue`` keeps it running.
    """

    domain: int | None = None
    pub_endpoint: str | None = None
    sub_endpoint: str | None = None
    keys: str | None = None
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES
    max_buffered_bytes: int | None = None
    bind: str | None = None
    proxy_host: str | None = None
    direct_host: str | None = None
    peer_timeout_s: float = 10.0
    on_peer_lost: str = "shutdown"


NODE_ENTRY_POINTS = "vibrissa.nodes"


def node_module(pkg: str, executable: str) -> str:
    """The module that runs node ``executable`` of the installed package ``pkg``: the entry
    point of that name in the group ``vibrissa.nodes`` that ``pkg`` registers (as ROS finds a
    package's executables in its index). Raises ``ValueError`` naming the known nodes."""
    known = []
    for entry in importlib.metadata.entry_points(group=NODE_ENTRY_POINTS):
        if entry.dist is not None and entry.dist.name == pkg:
            if entry.name == executable:
                return entry.value
            known.append(entry.name)
    if not known:
        raise ValueError(f"no installed package {pkg!r} registers nodes ({NODE_ENTRY_POINTS!r} "
                         "entry points)")
    raise ValueError(f"package {pkg!r} has no node {executable!r}{did_you_mean(executable, known)} "
                     f"(known: {', '.join(sorted(known))})")


@dataclass(frozen=True)
class NodeSpec:
    """One ``- node:`` entry, substitutions resolved.

    Exactly one of ``executable`` (run as ``python -m`` its module, :func:`node_module`) and ``cmd``
    (an arbitrary argv) is set. The node command line (``--name``, ``--namespace``,
    ``--params-file``, ``--remap``) and then ``args`` are appended to either.
    """

    name: str
    namespace: str = "/"
    pkg: str = "vibrissa"
    executable: str | None = None
    cmd: tuple[str, ...] | None = None
    args: tuple[str, ...] = ()
    params: tuple[Param, ...] = ()
    remaps: tuple[Remap, ...] = ()
    env: tuple[tuple[str, str], ...] = ()
    respawn: bool = False
    respawn_delay: float = 0.0
    respawn_max: int | None = None
    required: bool = False
    finite: bool = False
    allow_loss: bool = False
    on_exit: str | None = None

    @property
    def fqn(self) -> str:
        """Fully qualified node name, e.g. ``/whisker0/reconstructor``."""
        return node_fqn(self.name, self.namespace)


@dataclass(frozen=True)
class LaunchDescription:
    """A parsed launch file with what it includes: declared arguments, their resolved values,
    transport, nodes."""

    source: str
    args: tuple[LaunchArg, ...] = ()
    arg_values: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    transport: TransportSpec | None = None
    nodes: tuple[NodeSpec, ...] = ()


def node_params(spec: NodeSpec) -> dict[str, Any]:
    """The parameters ``spec``'s node is given, in declaration order: for a ``pkg``/``exec``
    node whose ``PARAMS`` type a parameter as text (``str``, ``Path``), a value that was one
    string with substitutions is that text as is (``out:=2026`` is ``"2026"``), else what it
    reads as. ValueError names a node that no package registers."""
    hints: dict[str, Any] = {}
    if spec.executable is not None and any(p.text is not None for p in spec.params):
        params_class = getattr(importlib.import_module(node_module(spec.pkg, spec.executable)),
                               "PARAMS", None)
        hints = typing.get_type_hints(params_class) if params_class is not None else {}
    return {p.name: p.text if p.text is not None and takes_text(hints.get(p.name)) else p.value
            for p in spec.params}


def check_node_params(description: LaunchDescription) -> None:
    """Check every ``pkg``/``exec`` node's parameters with its own parameter dataclass (the
    ``PARAMS`` of the node's module) before anything starts: types, ranges and specs such as
    surfaces and bag files, exactly as the node will load them. A ``cmd`` node, or a module
    without ``PARAMS``, checks its own.

    Raises
    ------
    LaunchFileError
        One line naming the file, the node, the parameter and the value, e.g.
        ``demo.yaml: node 'wrench_source': parameter 'mu' expects float, got str ('abc')``.
    """
    for spec in description.nodes:
        if spec.executable is None:
            continue
        where = f"node '{spec.name}'"
        try:
            module = importlib.import_module(node_module(spec.pkg, spec.executable))
        except ValueError as exc:
            raise LaunchFileError(description.source, where, str(exc)) from None
        params_class = getattr(module, "PARAMS", None)
        if params_class is not None:
            try:
                check_params(params_class, node_params(spec), where)
            except ParamError as exc:
                raise LaunchFileError(description.source, "", str(exc)) from None


# ---------------------------------------------------------------------------------------------
# YAML loading


def _load_yaml(text: str, source: str) -> Any:
    try:
        return yaml_numbers.load_strict(text)
    except RecursionError:
        raise LaunchFileError(source, "", "nested too deeply") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        what = exc.problem or exc.context or "invalid YAML"
        raise LaunchFileError(source, where, what) from None
    except yaml.YAMLError as exc:
        raise LaunchFileError(source, "", f"invalid YAML: {exc}") from None


# ---------------------------------------------------------------------------------------------
# Parsing helpers


MAX_LAUNCH_FILE_BYTES = 16 << 20
"""A launch file is a few kB; a larger one is not a launch file."""

MAX_RESPAWN_DELAY_S = 3600.0
"""A respawn waits at most an hour: a longer delay is a typo (1e300 s would hang the launch)."""


def _folder_name(value: str) -> None:
    if not value:
        raise ValueError("an empty folder name (leave the key out for a graph without keys)")


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class _Parser:
    """Walks the document, tracking the key path for error messages."""

    def __init__(self, source: str, dirname: str, env: Mapping[str, str]) -> None:
        self.source = source
        self.dirname = dirname
        self.env = env
        self.launch_time = time.time()
        self.args: dict[str, str] = {}

    def error(self, path: str, message: str) -> LaunchFileError:
        return LaunchFileError(self.source, path, message)

    # -- substitutions -------------------------------------------------------------------------

    def substitute(self, text: str, path: str) -> str:
        """Resolve the substitutions of ``text``, innermost first; a value is not re-read."""
        return self._resolve(text, 0, path, inside=False)[0]

    def _resolve(self, text: str, start: int, path: str, inside: bool) -> tuple[str, int]:
        """``text`` from ``start`` resolved up to the end, or (``inside`` a substitution) up
        to its closing parenthesis; returns the text and the index after what was read."""
        out: list[str] = []
        i = start
        while i < len(text):
            if text.startswith("$(", i):
                body, i = self._resolve(text, i + 2, path, inside=True)
                out.append(self._evaluate(body, path))
            elif inside and text[i] == ")":
                return "".join(out), i + 1
            elif inside and text[i] == "(":
                break
            else:
                out.append(text[i])
                i += 1
        if inside:
            raise self.error(path, f"unterminated substitution in {_show(text)}")
        return "".join(out), i

    def _evaluate(self, body: str, path: str) -> str:
        """The value of one substitution ``$(body)``, its inner ones already resolved."""
        words = body.split()
        kind, rest = (words[0], words[1:]) if words else ("", [])
        if kind == "var" and len(rest) == 1:
            if rest[0] not in self.args:
                known = ", ".join(sorted(self.args)) or "none"
                raise self.error(path, f"unknown launch argument in $(var {rest[0]})"
                                 f"{did_you_mean(rest[0], self.args)} (known: {known})")
            return self.args[rest[0]]
        if kind == "env" and len(rest) >= 1:
            value = self.env.get(rest[0])
            if value is not None:
                return value
            if len(rest) > 1:
                return " ".join(rest[1:])
            raise self.error(
                path, f"environment variable {rest[0]!r} is not set and has no default"
            )
        if kind in ("equals", "not-equals") and len(rest) == 2:
            return "true" if (rest[0] == rest[1]) == (kind == "equals") else "false"
        if kind == "if" and len(rest) == 3:
            if rest[0] not in ("true", "false"):
                raise self.error(path, f"$(if C A B) needs C true or false, got {_show(rest[0])}")
            return rest[1] if rest[0] == "true" else rest[2]
        if kind == "dirname" and not rest:
            return self.dirname
        if kind == "python" and not rest:
            return sys.executable
        if kind == "launch_time" and not rest:
            return repr(self.launch_time)
        raise self.error(
            path,
            f"bad substitution {_show('$(' + body + ')')}; expected $(var NAME), $(env NAME), "
            "$(env NAME default), $(equals A B), $(not-equals A B), $(if C A B), $(dirname), "
            "$(python) or $(launch_time)",
        )

    def retyped(self, value: Any, path: str) -> Any:
        """Substitute inside a string and read the result as a plain YAML 1.2 scalar
        (`yaml_numbers.scalar`: true/false, a decimal int, a float, else the text as is).

        This is how ``respawn: $(var respawn)`` or ``value: $(var mu)`` get their types, as in
        ROS 2; a string without substitutions keeps the type YAML gave it.
        """
        if not isinstance(value, str) or "$(" not in value:
            return value
        return yaml_numbers.scalar(self.substitute(value, path))

    # -- typed leaves ----------------------------------------------------------------------------

    def mapping(self, value: Any, path: str, required: Sequence[str], optional: Sequence[str]
                ) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.error(path, f"expected a mapping, got {_show(value)}")
        for key in value:
            if key not in required and key not in optional:
                allowed = ", ".join([*required, *optional])
                raise self.error(f"{path}.{key}", f"unknown key"
                                 f"{did_you_mean(str(key), [*required, *optional])} "
                                 f"(allowed: {allowed})")
        for key in required:
            if key not in value:
                raise self.error(f"{path}.{key}", "missing required key")
        return value

    def list_of(self, value: Any, path: str) -> list[Any]:
        if not isinstance(value, list):
            raise self.error(path, f"expected a list, got {_show(value)}")
        return value

    def string(self, value: Any, path: str, check: Callable[[str], None] | None = None) -> str:
        """A string, passing ``check`` if given (a name rule of the wire, raising ValueError)."""
        value = self.retyped(value, path)
        if not isinstance(value, str):
            raise self.error(path, f"expected str, got {_show(value)}")
        if check is not None:
            try:
                check(value)
            except ValueError as exc:
                raise self.error(path, str(exc)) from None
        return value

    def text(self, value: Any, path: str) -> str:
        """A string-valued field that also accepts a number (``value: 3`` for an env var)."""
        value = self.retyped(value, path)
        if isinstance(value, bool):
            return "true" if value else "false"
        if isinstance(value, (int, float, str)):
            return str(value)
        raise self.error(path, f"expected str, got {_show(value)}")

    def boolean(self, value: Any, path: str) -> bool:
        value = self.retyped(value, path)
        if not isinstance(value, bool):
            raise self.error(path, f"expected bool, got {_show(value)}")
        return value

    def number(self, value: Any, path: str, minimum: float = 0.0,
               maximum: float | None = None) -> float:
        value = self.retyped(value, path)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(path, f"expected a number, got {_show(value)}")
        if not (finite_number(value) and value >= minimum):
            raise self.error(path, f"expected a finite number >= {minimum:g}, got {_show(value)}")
        if maximum is not None and value > maximum:
            raise self.error(path, f"expected at most {maximum:g}, got {_show(value)}")
        return float(value)

    def integer(self, value: Any, path: str, minimum: int, maximum: int | None = None) -> int:
        value = self.retyped(value, path)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(path, f"expected int, got {_show(value)}")
        if value < minimum or (maximum is not None and value > maximum):
            bound = f"in [{minimum}, {maximum}]" if maximum is not None else f">= {minimum}"
            raise self.error(path, f"expected an int {bound}, got {_show(value)}")
        return value

    def param_value(self, text: str, path: str) -> Any:
        """What a parameter's substituted text reads as: a YAML flow list of scalars when it is
        in brackets (``y0:=[-0.2, 0, 0.2]``), else a plain scalar (`yaml_numbers.scalar`)."""
        if not (text.startswith("[") and text.endswith("]")):
            return yaml_numbers.scalar(text)
        try:
            items = yaml_numbers.load_strict(text)
        except yaml.YAMLError:
            items = None
        if not isinstance(items, list) or any(isinstance(v, (list, dict)) for v in items):
            raise self.error(path, f"expected a list of scalars like [1, 2], got {_show(text)}")
        return items

    def deep(self, value: Any, path: str) -> Any:
        """Substitute recursively inside a parameter value (lists, mappings, strings)."""
        if isinstance(value, list):
            return [self.deep(v, f"{path}[{i}]") for i, v in enumerate(value)]
        if isinstance(value, dict):
            for key in value:
                if not isinstance(key, str):
                    raise self.error(path, f"expected str keys, got {_show(key)}")
            return {k: self.deep(v, f"{path}.{k}") for k, v in value.items()}
        return self.retyped(value, path)

    # -- entries -------------------------------------------------------------------------------

    def arg(self, value: Any, path: str) -> LaunchArg:
        body = self.mapping(value, path, ("name",), ("default", "description"))
        name = self.string(body["name"], f"{path}.name", partial(validate_token, what="argument name"))
        default = None
        if "default" in body:
            default = self.text(body["default"], f"{path}.default")
        description = self.text(body.get("description", ""), f"{path}.description")
        return LaunchArg(name=name, default=default, description=description)

    def transport(self, value: Any, path: str) -> TransportSpec:
        body = self.mapping(value, path, (), ("domain", "pub_endpoint", "sub_endpoint", "keys",
                                              "max_message_bytes", "max_buffered_bytes", "bind",
                                              "proxy_host", "direct_host", "peer_timeout_s",
                                              "on_peer_lost"))
        hosts = {key: self.host(body[key], f"{path}.{key}") for key in
                 ("bind", "proxy_host", "direct_host") if key in body}
        hosts = {key: host for key, host in hosts.items() if host}  # an empty argument: unset
        if hosts.get("direct_host") == "0.0.0.0" or (hosts.get("bind") == "0.0.0.0"
                                                    and "direct_host" not in hosts):
            raise self.error(path, "0.0.0.0 binds every interface but is no address the other "
                                   "hosts can reach: give direct_host, this host's address they "
                                   "reach (direct publishers announce it)")
        if "bind" in hosts and "proxy_host" in hosts:
            raise self.error(path, "give bind (this host holds the proxy) or proxy_host (another "
                                   "host does), not both")
        if hosts.keys() & {"bind", "proxy_host"} and "pub_endpoint" in body:
            raise self.error(path, "give bind or proxy_host (with a domain) or "
                                   "pub_endpoint/sub_endpoint, not both")
        on_peer_lost = self.string(body.get("on_peer_lost", "shutdown"), f"{path}.on_peer_lost")
        if on_peer_lost not in ("shutdown", "continue"):
            raise self.error(f"{path}.on_peer_lost",
                             f"expected shutdown or continue, got {on_peer_lost!r}")
        common = TransportSpec(
            bind=hosts.get("bind"), proxy_host=hosts.get("proxy_host"),
            direct_host=hosts.get("direct_host"),
            peer_timeout_s=self.number(body.get("peer_timeout_s", 10.0), f"{path}.peer_timeout_s",
                                       0.5),
            on_peer_lost=on_peer_lost,
            keys=self.string(body["keys"], f"{path}.keys", _folder_name) if "keys" in body else None,
            max_message_bytes=self.integer(body.get("max_message_bytes",
                                                    DEFAULT_MAX_MESSAGE_BYTES),
                                           f"{path}.max_message_bytes", 1024),
            max_buffered_bytes=self.integer(body["max_buffered_bytes"],
                                            f"{path}.max_buffered_bytes", 1 << 20)
            if "max_buffered_bytes" in body else None,
        )
        if "domain" in body:
            if "pub_endpoint" in body or "sub_endpoint" in body:
                raise self.error(path, "give either domain or pub_endpoint/sub_endpoint, not both")
            return replace(common, domain=self.integer(body["domain"], f"{path}.domain", 0,
                                                       Endpoints.MAX_DOMAIN))
        if ("pub_endpoint" in body) != ("sub_endpoint" in body):
            missing = "sub_endpoint" if "pub_endpoint" in body else "pub_endpoint"
            raise self.error(f"{path}.{missing}", "missing (give both endpoints or neither)")
        if "pub_endpoint" in body:
            pub = self.string(body["pub_endpoint"], f"{path}.pub_endpoint")
            sub = self.string(body["sub_endpoint"], f"{path}.sub_endpoint")
            for key, endpoint in (("pub_endpoint", pub), ("sub_endpoint", sub)):
                if "://" not in endpoint:
                    raise self.error(
                        f"{path}.{key}", f"expected a ZeroMQ endpoint like tcp://HOST:PORT, "
                        f"got {endpoint!r}"
                    )
            return replace(common, pub_endpoint=pub, sub_endpoint=sub)
        return common

    def host(self, value: Any, path: str) -> str:
        """A host name or IPv4 address (``Endpoints.for_domain``), or empty."""
        text = self.text(value, path)
        if text:
            try:
                Endpoints.for_domain(0, text)
            except ValueError as exc:
                raise self.error(path, str(exc)) from None
        return text

    def included(self, value: Any, path: str) -> bool:
        """Whether a node entry takes part: its ``if`` is true, or its ``unless`` false."""
        if not isinstance(value, dict):
            return True
        if "if" in value and "unless" in value:
            raise self.error(path, "give 'if' or 'unless', not both")
        if "if" in value:
            return self.boolean(value["if"], f"{path}.if")
        if "unless" in value:
            return not self.boolean(value["unless"], f"{path}.unless")
        return True

    def ready_before(self, value: Any, path: str) -> list[str]:
        """A node entry's ``ready_before``: names of the launch's nodes (``name`` or full name)
        that hold their output until this node hears it."""
        items = self.list_of(value.get("ready_before", []), f"{path}.ready_before")
        return [self.string(v, f"{path}.ready_before[{i}]", check=validate_name)
                for i, v in enumerate(items)]

    def include(self, value: Any, path: str) -> tuple[str, dict[str, str]]:
        """An ``include`` entry: the file it names (`resolve_launch_file` from this file's
        folder) and the arguments it gives."""
        body = self.mapping(value, path, ("file",), ("arg", "if", "unless"))
        name = self.string(body["file"], f"{path}.file")
        if not name:
            raise self.error(f"{path}.file", "an empty file name")
        args: dict[str, str] = {}
        for i, entry in enumerate(self.list_of(body.get("arg", []), f"{path}.arg")):
            where = f"{path}.arg[{i}]"
            item = self.mapping(entry, where, ("name", "value"), ())
            aname = self.string(item["name"], f"{where}.name",
                                partial(validate_token, what="argument name"))
            if aname in args:
                raise self.error(f"{where}.name", f"argument {aname!r} given twice")
            args[aname] = self.text(item["value"], f"{where}.value")
        return resolve_launch_file(name, self.dirname), args

    def node(self, value: Any, path: str) -> NodeSpec:
        keys = ("pkg", "exec", "cmd", "args", "name", "namespace", "param", "remap", "env",
                "respawn", "respawn_delay", "respawn_max", "required", "finite", "allow_loss",
                "on_exit", "if", "unless", "ready_before")
        body = self.mapping(value, path, (), keys)
        has_exec, has_cmd = "exec" in body, "cmd" in body
        if has_exec == has_cmd:
            raise self.error(path, "expected exactly one of 'exec' (with optional 'pkg') or "
                             "'cmd'")
        executable: str | None = None
        cmd: tuple[str, ...] | None = None
        pkg = "vibrissa"
        if has_cmd:
            if "pkg" in body:
                raise self.error(f"{path}.pkg", "not allowed together with 'cmd'")
            items = self.list_of(body["cmd"], f"{path}.cmd")
            if not items:
                raise self.error(f"{path}.cmd", "expected a non-empty list")
            cmd = tuple(self.text(v, f"{path}.cmd[{i}]") for i, v in enumerate(items))
        else:
            executable = self.string(body["exec"], f"{path}.exec")
            if "pkg" in body:
                pkg = self.string(body["pkg"], f"{path}.pkg")
            try:
                node_module(pkg, executable)
            except ValueError as exc:
                raise self.error(f"{path}.exec", str(exc)) from None
        if "name" in body:
            name = self.string(body["name"], f"{path}.name", check=validate_token)
        elif executable is not None:
            name = executable
        else:
            raise self.error(f"{path}.name", "missing required key (needed with 'cmd')")
        namespace = "/"
        if "namespace" in body:
            namespace = self.string(body["namespace"], f"{path}.namespace")
            if not namespace.startswith("/"):
                namespace = "/" + namespace
            if namespace != "/":
                namespace = namespace.rstrip("/")
            try:
                validate_namespace(namespace)
            except ValueError as exc:
                raise self.error(f"{path}.namespace", str(exc)) from None

        args: tuple[str, ...] = ()
        if "args" in body:
            raw = self.retyped(body["args"], f"{path}.args")
            if isinstance(raw, str):
                args = tuple(shlex.split(raw))
            else:
                items = self.list_of(raw, f"{path}.args")
                args = tuple(self.text(v, f"{path}.args[{i}]") for i, v in enumerate(items))

        params: list[Param] = []
        for i, entry in enumerate(self.list_of(body.get("param", []), f"{path}.param")):
            where = f"{path}.param[{i}]"
            item = self.mapping(entry, where, ("name", "value"), ())
            pname = self.string(item["name"], f"{where}.name")
            if not pname or any(c.isspace() for c in pname):
                raise self.error(f"{where}.name", f"invalid parameter name {pname!r}")
            if any(p.name == pname for p in params):
                raise self.error(f"{where}.name", f"duplicate parameter {pname!r}")
            value = item["value"]
            if isinstance(value, str) and "$(" in value:
                text = self.substitute(value, f"{where}.value")
                params.append(Param(pname, self.param_value(text, f"{where}.value"), text))
            else:
                params.append(Param(pname, self.deep(value, f"{where}.value")))

        remaps: list[Remap] = []
        for i, entry in enumerate(self.list_of(body.get("remap", []), f"{path}.remap")):
            where = f"{path}.remap[{i}]"
            item = self.mapping(entry, where, ("from", "to"), ())
            remaps.append(Remap(self.string(item["from"], f"{where}.from", check=validate_name),
                                self.string(item["to"], f"{where}.to", check=validate_name)))

        env: list[tuple[str, str]] = []
        for i, entry in enumerate(self.list_of(body.get("env", []), f"{path}.env")):
            where = f"{path}.env[{i}]"
            item = self.mapping(entry, where, ("name", "value"), ())
            ename = self.string(item["name"], f"{where}.name",
                                partial(validate_token, what="environment variable"))
            env.append((ename, self.text(item["value"], f"{where}.value")))

        respawn = self.boolean(body.get("respawn", False), f"{path}.respawn")
        respawn_delay = self.number(body.get("respawn_delay", 0.0), f"{path}.respawn_delay",
                                    maximum=MAX_RESPAWN_DELAY_S)
        respawn_max = None
        if "respawn_max" in body:
            respawn_max = self.integer(body["respawn_max"], f"{path}.respawn_max", 0)
        for key in ("respawn_delay", "respawn_max"):
            if key in body and not respawn:
                raise self.error(f"{path}.{key}", "has no effect without 'respawn: true'")
        required = self.boolean(body.get("required", False), f"{path}.required")
        finite = self.boolean(body.get("finite", False), f"{path}.finite")
        allow_loss = self.boolean(body.get("allow_loss", False), f"{path}.allow_loss")
        on_exit = None
        if "on_exit" in body:
            on_exit = self.string(body["on_exit"], f"{path}.on_exit")
            if on_exit not in ON_EXIT_ACTIONS:
                raise self.error(f"{path}.on_exit",
                                 f"expected one of {', '.join(ON_EXIT_ACTIONS)}, got {on_exit!r}")
        return NodeSpec(
            name=name, namespace=namespace, pkg=pkg, executable=executable, cmd=cmd, args=args,
            params=tuple(params), remaps=tuple(remaps), env=tuple(env), respawn=respawn,
            respawn_delay=respawn_delay, respawn_max=respawn_max, required=required,
            finite=finite, allow_loss=allow_loss, on_exit=on_exit,
        )


# ---------------------------------------------------------------------------------------------
# Public entry points


def parse_arg_overrides(items: Sequence[str], source: str = "command line") -> dict[str, str]:
    """Parse ``NAME:=VALUE`` words from the command line.

    Parameters
    ----------
    items : sequence of str
        The words, e.g. ``["mu:=0.3", "out:=out/run1"]``.
    source : str
        Named in error messages.

    Returns
    -------
    dict of str to str
        Argument name to value; an argument given twice is an error.
    """
    overrides: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep:
            raise LaunchFileError(source, "", f"bad argument {item!r}: expected NAME:=VALUE")
        try:
            validate_token(name, "argument name")
        except ValueError as exc:
            raise LaunchFileError(source, "", f"bad argument {item!r}: {exc}") from None
        if name in overrides:
            raise LaunchFileError(source, "", f"argument {name!r} given twice ({name}:="
                                  f"{overrides[name]}, {item})")
        overrides[name] = expand_home(value)
    return overrides


@dataclass
class _Launch:
    """What the files of one launch declare, gathered while they are read."""

    environ: Mapping[str, str]
    args: list[LaunchArg] = field(default_factory=list)
    values: dict[str, str] = field(default_factory=dict)
    transport: TransportSpec | None = None
    nodes: list[NodeSpec] = field(default_factory=list)
    ready: list[tuple[NodeSpec, list[str], str, str]] = field(default_factory=list)
    """Each ``ready_before``: the node, the names it lists, its file and key path."""


def _parse_file(document: Any, source: str, dirname: str, context: Mapping[str, str],
                files: tuple[str, ...], out: _Launch) -> set[str]:
    """Read one file of a launch into ``out``, its includes first where they stand; its
    arguments take their values from ``context`` else their defaults. ``files``: the real
    paths of the files including it (a cycle is an error). Returns the names it declares."""
    p = _Parser(source, dirname, out.environ)
    if document is None:
        raise p.error("", "empty file; expected a mapping with a 'launch' list")
    body = p.mapping(document, "", ("launch",), ())
    entries = p.list_of(body["launch"], "launch")

    kinds = ("arg", "include", "node", "transport")
    shapes: list[tuple[str, str, Any]] = []
    for i, entry in enumerate(entries):
        path = f"launch[{i}]"
        if not isinstance(entry, dict) or len(entry) != 1:
            raise p.error(path, f"expected a mapping with one key ({', '.join(kinds)}), "
                          f"got {_show(entry)}")
        ((kind, value),) = entry.items()
        if kind not in kinds:
            raise p.error(f"{path}.{kind}", f"unknown entry{did_you_mean(str(kind), kinds)} "
                          f"(allowed: {', '.join(kinds)})")
        shapes.append((f"{path}.{kind}", kind, value))

    # Arguments first, in order: a default may use $(var ...) of an earlier argument.
    declared: list[LaunchArg] = []
    for path, kind, value in shapes:
        if kind != "arg":
            continue
        arg = p.arg(value, path)
        if any(a.name == arg.name for a in declared):
            raise p.error(f"{path}.name", f"duplicate argument {arg.name!r}")
        declared.append(arg)
        if arg.name in context:
            p.args[arg.name] = context[arg.name]
        elif arg.default is not None:
            p.args[arg.name] = arg.default
        else:
            raise p.error(path, f"argument {arg.name!r} has no default; give it on the command "
                          f"line as {arg.name}:=VALUE")
    for arg in declared:
        if all(a.name != arg.name for a in out.args):
            out.args.append(arg)
            out.values[arg.name] = p.args[arg.name]

    for path, kind, value in shapes:
        if kind == "transport":
            if out.transport is not None:
                raise p.error(path, "only one transport entry is allowed")
            out.transport = p.transport(value, path)
        elif kind == "include":
            file, given = p.include(value, path)
            if p.included(value, path):
                _include(p, path, file, {**context, **p.args, **given}, given, files, out)
        elif kind == "node":
            node = p.node(value, path)  # checked even when left out
            ready_before = p.ready_before(value, path)
            if not p.included(value, path):
                continue
            if any(n.name == node.name for n in out.nodes):
                raise p.error(f"{path}.name", f"duplicate node name {node.name!r} (node names "
                              "label the output and must be unique in a launch)")
            out.nodes.append(node)
            if ready_before:
                out.ready.append((node, ready_before, source, f"{path}.ready_before"))
    return {a.name for a in declared}


def _include(p: _Parser, path: str, file: str, context: Mapping[str, str],
             given: Mapping[str, str], files: tuple[str, ...], out: _Launch) -> None:
    """Read the file an ``include`` entry (at ``path`` of ``p``'s file) names into ``out``."""
    real = os.path.realpath(file)
    if real in files:
        chain = " -> ".join(Path(f).name for f in (*files[files.index(real):], real))
        raise p.error(f"{path}.file", f"include cycle: {chain}")
    if not os.path.isfile(file):
        raise p.error(f"{path}.file", f"no launch file {file!r} (a path, relative to "
                      f"{p.dirname}, or a packaged launch file)")
    try:
        declared = _parse_file(_read_document(file), file, str(Path(file).resolve().parent),
                               context, (*files, real), out)
    except LaunchFileError as exc:  # where in the including file, too
        raise LaunchFileError(exc.source, exc.key_path,
                              f"{exc.message} (included by {p.source}: {path})") from None
    for name in given:
        if name not in declared:
            raise p.error(f"{path}.arg", f"{Path(file).name} has no argument {name!r}"
                          f"{did_you_mean(name, declared)} (its arguments: "
                          f"{', '.join(sorted(declared)) or 'none'})")


def _wait_also_for(spec: NodeSpec, fqn: str) -> NodeSpec:
    """``spec`` with node ``fqn`` added to its ``wait_for`` parameter. ValueError when its
    parameter dataclass has no ``wait_for``, or its value is not a list."""
    if spec.executable is not None:
        params_class = getattr(importlib.import_module(node_module(spec.pkg, spec.executable)),
                               "PARAMS", None)
        if params_class is not None and all(
                f.name != "wait_for" for f in dataclasses.fields(params_class)):
            raise ValueError(f"node {spec.name!r} ({spec.executable}) has no 'wait_for' "
                             "parameter: it cannot wait for another node")
    params = list(spec.params)
    index = next((i for i, p in enumerate(params) if p.name == "wait_for"), None)
    if index is None:
        params.append(Param("wait_for", [fqn]))
    else:
        waits = params[index].value
        if not isinstance(waits, list):
            raise ValueError(f"node {spec.name!r}: its 'wait_for' is {_show(waits)}, not a list")
        if fqn not in waits:
            params[index] = Param("wait_for", [*waits, fqn])
    return replace(spec, params=tuple(params))


def parse_launch(
    document: Any,
    source: str,
    overrides: Mapping[str, str] | None = None,
    *,
    dirname: str | None = None,
    environ: Mapping[str, str] | None = None,
) -> LaunchDescription:
    """Validate a loaded launch document, read its includes and resolve its substitutions.

    Parameters
    ----------
    document : Any
        The YAML document, ``{"launch": [...]}``.
    source : str
        The file name used in error messages.
    overrides : mapping of str to str, optional
        Launch argument values from the command line; a name that no file of the launch
        declares is an error.
    dirname : str, optional
        Value of ``$(dirname)`` (and the folder of relative includes); defaults to the
        directory of ``source``.
    environ : mapping of str to str, optional
        Environment for ``$(env ...)``; defaults to `os.environ`.

    Returns
    -------
    LaunchDescription
        Arguments, nodes and transport of the file and of what it includes, in file order;
        each node a ``ready_before`` names waits for that node too (its ``wait_for``).

    Raises
    ------
    LaunchFileError
        Naming the file and the key path of the first problem.
    """
    overrides = dict(overrides or {})
    if dirname is None:
        dirname = str(Path(source).resolve().parent)
    out = _Launch(os.environ if environ is None else environ)
    _parse_file(document, source, dirname, overrides, (os.path.realpath(source),), out)
    known = [a.name for a in out.args]
    unknown = sorted(set(overrides) - set(known))
    if unknown:
        hint = did_you_mean(unknown[0], known) if len(unknown) == 1 else ""
        raise LaunchFileError(source, "", f"unknown launch argument "
                              f"{', '.join(map(repr, unknown))}{hint} "
                              f"(known: {', '.join(known) or 'none'})")
    if not out.nodes:
        raise LaunchFileError(source, "launch", "no node entries")
    nodes = out.nodes
    for consumer, targets, where, path in out.ready:
        for j, target in enumerate(targets):
            index = next((i for i, n in enumerate(nodes) if target in (n.name, n.fqn)), None)
            if index is None:
                raise LaunchFileError(where, f"{path}[{j}]", f"no node {target!r} in the launch"
                                      f"{did_you_mean(target, [n.name for n in nodes])}")
            try:
                nodes[index] = _wait_also_for(nodes[index], consumer.fqn)
            except ValueError as exc:
                raise LaunchFileError(where, f"{path}[{j}]", str(exc)) from None
    return LaunchDescription(source=source, args=tuple(out.args),
                             arg_values=MappingProxyType(out.values), transport=out.transport,
                             nodes=tuple(nodes))


def resolve_launch_file(name: str, folder: str | None = None) -> str:
    """Find a launch file: a path (relative to ``folder``, default the working directory),
    else a file shipped in the `vibrissa.launch` package.

    Parameters
    ----------
    name : str
        ``path/to/file.yaml``, or ``demo``/``demo.yaml`` for a packaged file.
    folder : str, optional
        Where a relative path starts (an including file's folder).

    Returns
    -------
    str
        A readable path (the path of ``name`` itself when nothing better is found, so that
        the error names what the user typed).
    """
    path = name if folder is None else os.path.join(folder, name)
    if os.path.exists(path) or os.sep in name:
        return path
    package = resources.files("vibrissa.launch")
    for candidate in (name, f"{name}.yaml"):
        entry = package / candidate
        if entry.is_file():
            return str(entry)
    return path


def load_launch_file(
    path: str | os.PathLike[str],
    overrides: Mapping[str, str] | None = None,
    *,
    environ: Mapping[str, str] | None = None,
) -> LaunchDescription:
    """Read and validate a launch file.

    Parameters
    ----------
    path : str or path-like
        The YAML launch file.
    overrides : mapping of str to str, optional
        Launch argument values (``name:=value`` from the command line).
    environ : mapping of str to str, optional
        Environment for ``$(env ...)``; defaults to `os.environ`.

    Returns
    -------
    LaunchDescription

    Raises
    ------
    LaunchFileError
        The file cannot be read, is not valid YAML, or does not validate.
    """
    source = os.fspath(path)
    return parse_launch(_read_document(source), source, overrides, environ=environ)


def _read_document(source: str) -> Any:
    """The YAML document of launch file ``source``; LaunchFileError when it cannot be read."""
    try:
        if not stat.S_ISREG(os.stat(source).st_mode):  # a device or a pipe: read without end
            raise LaunchFileError(source, "", "not a regular file")
        if os.stat(source).st_size > MAX_LAUNCH_FILE_BYTES:
            raise LaunchFileError(source, "", f"larger than {MAX_LAUNCH_FILE_BYTES} bytes")
        data = Path(source).read_bytes()
    except OSError as exc:
        raise LaunchFileError(source, "", f"cannot read: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise LaunchFileError(source, f"line {line}, column {column}",
                              f"not UTF-8 text (byte 0x{data[exc.start]:02x})") from None
    return _load_yaml(text, source)
