"""The node runtime: what every node process shares (command line, parameters, logging,
topics, heartbeat, readiness, stop).

A node's ``main`` reads ``NodeArgs``, loads its parameter dataclass with ``load_params`` and
runs inside a ``Node`` (see ``vibrissa.runtime.node``).

These names are imported on first use (PEP 562): a command that only writes CSV files through
``vibrissa.runtime.csv_text`` does not load ZeroMQ and the node machinery (0.1 s of start-up).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from vibrissa.runtime.args import NodeArgs
    from vibrissa.runtime.node import Node, configure_logging, run_main
    from vibrissa.runtime.params import ParamError, check_params, load_params

_MODULE_OF = {"Node": "node", "NodeArgs": "args", "ParamError": "params", "check_params": "params",
              "configure_logging": "node", "load_params": "params", "run_main": "node"}

__all__ = ["Node", "NodeArgs", "ParamError", "check_params", "configure_logging", "load_params",
           "run_main"]


def __getattr__(name: str) -> Any:
    if name not in _MODULE_OF:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"vibrissa.runtime.{_MODULE_OF[name]}"), name)
