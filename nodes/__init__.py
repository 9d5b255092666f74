"""vibrissa nodes: one process per module (``python -m vibrissa.nodes.<name>``)."""
