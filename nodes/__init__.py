"""vibrissa nodes: one process per module, plus the shared runtime (``runtime``)."""

from vibrissa.nodes.runtime import Node, NodeArgs, configure_logging, load_params

__all__ = ["Node", "NodeArgs", "configure_logging", "load_params"]
