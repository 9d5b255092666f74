"""What the graph tools share (``topic``, ``bag``): where the graph is, how to stop."""

from __future__ import annotations

import argparse
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from vibrissa.cli.arg_types import folder
from vibrissa.runtime.signals import SignalHandlers
from vibrissa.wire.security import KEYS_ENV, Keys
from vibrissa.wire.topics import validate_name
from vibrissa.wire.transport import (
    DOMAIN_ENV,
    Endpoints,
    running_graphs,
    scanned_domains,
    which_graph,
)


def add_endpoint_flags(parser: argparse.ArgumentParser) -> None:
    """``--domain``, ``--graph``, ``--pub``/``--sub`` and ``--keys``, over
    ``VIBRISSA_DOMAIN_ID`` (default 0) and ``VIBRISSA_KEYS``."""
    parser.add_argument("--domain", type=domain_id, metavar="N",
                        help=f"the graph's domain (default: ${DOMAIN_ENV}, else 0; "
                             "`vibrissa launch` prints it)")
    parser.add_argument("--graph", type=graph_address, metavar="HOST[:DOMAIN]",
                        help="a graph whose proxy runs on another host (launched there with "
                             "bind:=HOST), on DOMAIN (default: --domain, else as for --domain)")
    parser.add_argument("--pub", metavar="ENDPOINT",
                        help="proxy endpoint publishers connect to (XSUB), over --domain")
    parser.add_argument("--sub", metavar="ENDPOINT",
                        help="proxy endpoint subscribers connect to (XPUB), over --domain")
    parser.add_argument("--keys", metavar="DIR", type=folder,
                        help=f"CURVE keys of a graph launched with keys (default: ${KEYS_ENV})")


def domain_id(text: str) -> int:
    """Argparse type: a domain id in [0, ``Endpoints.MAX_DOMAIN``]."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer domain id, got {text!r}") from None
    if not 0 <= value <= Endpoints.MAX_DOMAIN:
        raise argparse.ArgumentTypeError(f"domain id must be in [0, {Endpoints.MAX_DOMAIN}], "
                                         f"got {value}")
    return value


class Names(argparse.Action):
    """A list option: ``--opt A,B``, ``--opt A --opt B`` or ``--opt A B``. A word after it
    that is no name (``is_name``: a path, say) is a positional argument it took: it is kept
    in ``spilled`` on the namespace for `take_spilled`, so ``--topics /a FILE`` still names
    FILE."""

    def __init__(self, option_strings: list[str], dest: str, *, is_name: Callable[[str], bool],
                 **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs="+", **kwargs)
        self.is_name = is_name

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        items = list(getattr(namespace, self.dest, None) or [])
        spilled = list(getattr(namespace, "spilled", []))
        names: list[str] = []
        for k, word in enumerate(values):
            parts = [part.strip() for part in word.split(",")]
            if not all(self.is_name(part) for part in parts if part):
                spilled.extend(values[k:])  # the positional arguments after the option
                break
            if not all(parts):
                parser.error(f"argument {option_string}: expected NAME[,NAME...], got {word!r}")
            names.extend(parts)
        if not names:
            parser.error(f"argument {option_string}: expected a name, got {values[0]!r} (a path? "
                         "put it before the option or after --)")
        setattr(namespace, self.dest, items + names)
        namespace.spilled = spilled


def take_spilled(args: argparse.Namespace, required: str, *optional: str) -> str | None:
    """Fill the positional arguments ``required`` and ``optional`` (in order) that are empty
    with the words a `Names` option took; what is wrong if one is left over or ``required``
    is still empty."""
    spilled = list(getattr(args, "spilled", []))
    for dest in (required, *optional):
        if getattr(args, dest) is None and spilled:
            setattr(args, dest, spilled.pop(0))
    if spilled:
        return f"unrecognized arguments: {' '.join(spilled)}"
    if getattr(args, required) is None:
        return f"the following arguments are required: {required}{AFTER_NAMES}"
    return None


AFTER_NAMES = ("; a word after --topics or --wait-for that could be a name is read as one "
               "(a path without a dot, say): put it before the option, or after --")


def is_graph_name(word: str) -> bool:
    """Whether ``word`` is a topic or node name (``/robot/pose``, ``/probe``,
    ``reconstructor``); a path with a dot (``robot.mcap``) is none."""
    try:
        validate_name(word)
    except ValueError:
        return False
    return True


def graph_address(text: str) -> tuple[str, int | None]:
    """Argparse type: ``HOST[:DOMAIN]``."""
    host, colon, domain = text.partition(":")
    if colon and not domain:
        raise argparse.ArgumentTypeError(f"expected HOST[:DOMAIN], got {text!r}")
    try:
        Endpoints.for_domain(0, host)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None
    return host, domain_id(domain) if colon else None


def endpoints_from(args: argparse.Namespace) -> Endpoints:
    """``--pub``/``--sub`` where given, else ``--graph``, else ``--domain``, else the
    environment.

    Raises ``ValueError`` for a bad ``VIBRISSA_DOMAIN_ID`` (or only one of the endpoint
    variables) and ``KeysError`` for a key folder that cannot be used.
    """
    keys = Keys.load(args.keys) if args.keys else Keys.from_env()
    graph = getattr(args, "graph", None)
    if graph is not None:
        base = Endpoints.for_domain(domain_of(args), graph[0])
    elif args.domain is not None:
        base = Endpoints.for_domain(args.domain)
    else:
        base = Endpoints.from_env()
    return Endpoints(args.pub or base.pub, args.sub or base.sub, keys)


def domain_of(args: argparse.Namespace) -> int:
    """The domain a tool looks at: ``--graph``'s, else ``--domain``, else the environment's."""
    graph = getattr(args, "graph", None)
    if graph is not None and graph[1] is not None:
        return int(graph[1])
    return args.domain if args.domain is not None else Endpoints.env_domain()


def where(args: argparse.Namespace, endpoints: Endpoints) -> str:
    """The graph a tool looked at, for messages: ``domain 0 (tcp://...)``."""
    if args.pub or args.sub:
        return f"--pub {endpoints.pub} --sub {endpoints.sub}"
    return f"domain {domain_of(args)} ({endpoints.sub})"


def graph_note(args: argparse.Namespace) -> str | None:
    """`which_graph` for a tool run without ``--domain`` (or ``--graph``, ``--pub/--sub``);
    None when the graph was named."""
    if args.domain is not None or getattr(args, "graph", None) is not None or args.pub \
            or args.sub:
        return None
    note = which_graph(domain_of(args))
    return None if note is None else f"{note}; pass --domain N (or {DOMAIN_ENV}=N) for another"


def nothing_heard(args: argparse.Namespace, endpoints: Endpoints) -> str:
    """What to tell a user whose tool heard no graph: where it looked, and where graphs run
    (domains 0-31 and the 32 from the tool's own, where a launch moves when its is taken)."""
    domain = domain_of(args)
    running = Endpoints.domains_in_use(scanned_domains(domain))
    here = where(args, endpoints)
    if not (args.pub or args.sub) and domain in running:
        if endpoints.keys is None:
            return (f"a graph runs on {here} but let nothing through: it was probably launched "
                    f"with keys; pass --keys DIR (or {KEYS_ENV}=DIR) with a folder it allows")
        return (f"a graph runs on {here} but let nothing through: it does not allow the keys "
                f"of {endpoints.keys.folder} (is it a client folder of that graph's "
                "`vibrissa keys FOLDER --client NAME`?), or it runs without keys")
    text = f"no running graph heard on {here}"
    records = {record.domain: record for record in running_graphs()}
    others = [d for d in sorted({*running, *records})
              if Endpoints.for_domain(d).sub != endpoints.sub]
    if others:
        listed = ", ".join(str(d) for d in others)
        text += f"; graphs are running on domain {listed}: pass --domain N (or {DOMAIN_ENV}=N)"
        text += "".join(f"; {records[d].describe()}" for d in others if d in records)
    else:
        text += ("; start one (`vibrissa launch demo`), or point at yours with --domain N "
                 f"({DOMAIN_ENV}=N) or --pub/--sub")
    return text


def no_graph(args: argparse.Namespace, endpoints: Endpoints) -> str | None:
    """`nothing_heard` when no graph runs on the tool's domain (nothing listens on its proxy's
    port, so nobody received what it published); None when one does, or when ``--pub/--sub``
    name the proxy."""
    if args.pub or args.sub or Endpoints.domains_in_use([domain_of(args)]):
        return None
    return nothing_heard(args, endpoints)


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event set by SIGINT/SIGTERM while inside; restores the previous handlers."""
    stop = threading.Event()
    with SignalHandlers(lambda signum: stop.set()):
        yield stop
