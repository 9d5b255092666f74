"""``vibrissa sim netft [OPTIONS]``: the simulated ATI Net F/T (``nodes/netft_sim.py``) in the
foreground, for a driver or any RDT client to stream from over UDP.

Its options are the node's parameters (``NetFTSimParams``), one ``--kebab-case`` option per
field, with the node's defaults and checks: a value the node refuses is one line on stderr and
exit status 2. It is not a node of the graph: it speaks only UDP, as the hardware does.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import typing
from typing import Any

import yaml

from vibrissa.cli.graph import stop_on_signals
from vibrissa.formats import yaml_numbers
from vibrissa.nodes.netft_sim import NetFTSimParams, open_device
from vibrissa.runtime import ParamError, check_params

NETFT_DESCRIPTION = """\
Run a simulated ATI Net F/T in the foreground. It answers RDT requests (stream, stop, bias)
on UDP HOST:PORT with what a whisker's sensor reads: a scene's `vibrissa simulate` results
(--scene, --simulated, --whisker; the sensor at the whisker's X_CS), else one sweep (--surface,
--y0, --mu, --step), plus noise, bias, drift, loss and reordering. It prints the address it
listens on (--port 0: a free port) and runs until Ctrl-C or SIGTERM (exit 0). A value the
node refuses exits 2. A negative number in e-notation takes an '=': --noise-force-n=-1e-3.

It is not a node of the graph: it speaks only UDP, as the sensor does. Point a driver at it
(a launch file's netft entry with address 127.0.0.1 and this port, or by hand:
  python -m vibrissa.nodes.netft --name netft --namespace /w0 \\
      --param address:=127.0.0.1 --param port:=PORT
). Inside a launch file, run the node instead (exec netft_sim, launch/netft.yaml): the same
device and options, with its counters in its status."""

_METAVARS = {"host": "HOST", "scene": "SCENE.yaml", "simulated": "DIR", "whisker": "NAME",
             "surface": "SPEC"}


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("sim", help="simulated hardware (a force/torque sensor)")
    devices = parser.add_subparsers(dest="sim_command", required=True, metavar="DEVICE")
    netft = devices.add_parser(
        "netft", help="a simulated ATI Net F/T on UDP, fed by Step 1",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=NETFT_DESCRIPTION)
    add_param_options(netft, NetFTSimParams)
    netft.set_defaults(func=run_netft)


def add_param_options(parser: argparse.ArgumentParser, cls: type) -> None:
    """One option per field of dataclass ``cls``: ``--rate-hz X``; a tuple takes several
    values (``--bias FX FY FZ MX MY MZ``), a bool is ``--loop/--no-loop``. Not given: the
    dataclass's default. Grouped and explained by the entries of the class's ``Attributes``."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    for names, text in _attribute_docs(cls):
        group = parser.add_argument_group(", ".join(names), text)
        for name in names:
            field = fields.pop(name, None)
            if field is not None:
                _add_option(group, field, hints[name])
    if fields:  # fields the docstring does not explain
        group = parser.add_argument_group("other parameters")
        for name, field in fields.items():
            _add_option(group, field, hints[name])


def _add_option(group: Any, field: dataclasses.Field[Any], hint: Any) -> None:
    flag = "--" + field.name.replace("_", "-")
    default = field.default
    if hint is bool:
        group.add_argument(flag, dest=field.name, action=argparse.BooleanOptionalAction,
                           default=None, help=f"(default: {'yes' if default else 'no'})")
    elif typing.get_origin(hint) is tuple:
        shown = " ".join(f"{v:g}" for v in default) if isinstance(default, tuple) else default
        group.add_argument(flag, dest=field.name, nargs="+", metavar="X",
                           help=f"(default: {shown})")
    else:
        metavar = _METAVARS.get(field.name, "N" if hint is int else "X")
        group.add_argument(flag, dest=field.name, metavar=metavar,
                           help=f"(default: {default!r})" if default != "" else None)


def _attribute_docs(cls: type) -> list[tuple[list[str], str]]:
    """The entries of a numpydoc ``Attributes`` section: (names, text) in order."""
    lines = (cls.__doc__ or "").splitlines()
    try:
        start = [line.strip() for line in lines].index("Attributes") + 2
    except ValueError:
        return []
    entries: list[tuple[list[str], str]] = []
    for line in lines[start:]:
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        if indent == 4:
            entries.append(([n.strip() for n in line.split(",")], ""))
        elif indent > 4 and entries:
            names, text = entries[-1]
            entries[-1] = (names, f"{text} {line.strip().replace('``', '')}".strip())
        else:
            break
    return entries


def params_from(args: argparse.Namespace, cls: type, source: str) -> Any:
    """``cls`` from the options given (YAML values, as in a launch file); the rest default.

    Raises ``ParamError`` (one line, prefixed by ``source``) for a value ``cls`` refuses."""
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    for field in dataclasses.fields(cls):
        given = getattr(args, field.name, None) if field.init else None
        if given is None:
            continue
        if isinstance(given, list):
            values[field.name] = [_yaml(text, field.name, source) for text in given]
        elif isinstance(given, str) and hints[field.name] is not str:
            values[field.name] = _yaml(given, field.name, source)
        else:
            values[field.name] = given
    return check_params(cls, values, source)


def _yaml(text: str, name: str, source: str) -> Any:
    try:
        return yaml_numbers.load(text)
    except yaml.YAMLError:
        raise ParamError(f"{source}: parameter {name!r}: {text!r} is not a value") from None


def run_netft(args: argparse.Namespace) -> int:
    """The ``sim netft`` subcommand."""
    with stop_on_signals() as stop:
        try:
            params = params_from(args, NetFTSimParams, "vibrissa sim netft: error")
        except ParamError as exc:
            print(exc, file=sys.stderr)
            return 2
        try:
            device = open_device(params)
        except ValueError as exc:  # a whisker or results folder that does not fit the scene
            print(f"vibrissa sim netft: error: {exc}", file=sys.stderr)
            return 2
        with device:
            host, port = device.address
            source = (f"{params.whisker} of {params.scene}" if params.scene
                      else f"a sweep of {params.surface}")
            print(f"simulated Net F/T listening on udp://{host}:{port}: {source}, "
                  f"{len(device.wrench_S)} samples at {params.rate_hz:g} Hz "
                  f"({'looping' if params.loop else 'then at rest'}); Ctrl-C to stop", flush=True)
            while not stop.is_set():
                time.sleep(0.05)
            stats = device.stats
        print(f"vibrissa sim netft: stopped after {stats.made} records ({stats.dropped} dropped, "
              f"{stats.late} sent late), {stats.biases} bias requests", file=sys.stderr)
    return 0
