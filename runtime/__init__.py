"""The node runtime: what every node process shares (command line, parameters, logging,
topics, heartbeat, readiness, stop).

A node's ``main`` reads ``NodeArgs``, loads its parameter dataclass with ``load_params`` and
runs inside a ``Node`` (see ``vibrissa.runtime.node``).
"""

from vibrissa.runtime.args import NodeArgs
from vibrissa.runtime.node import Node, configure_logging, run_main
from vibrissa.runtime.params import ParamError, check_params, load_params

__all__ = ["Node", "NodeArgs", "ParamError", "check_params", "configure_logging", "load_params",
           "run_main"]
