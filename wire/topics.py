"""ROS 2-style topic names: validation, namespace resolution and remapping."""

from __future__ import annotations

import re
from collections.abc import Mapping

STATUS_TOPIC = "/vibrissa/status"

_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def validate_token(name: str, what: str = "node name") -> None:
    """Raise ``ValueError`` naming ``name`` unless it is one token ``[A-Za-z_][A-Za-z0-9_]*``."""
    if not isinstance(name, str) or not _TOKEN.fullmatch(name):
        raise ValueError(f"invalid {what} {name!r}: must match [A-Za-z_][A-Za-z0-9_]*")


def validate_name(name: str, what: str = "topic name") -> None:
    """Raise ``ValueError`` naming ``name`` unless it is a valid ROS 2-style name.

    A name is ``/``-separated tokens ``[A-Za-z_][A-Za-z0-9_]*``, optionally with a leading
    ``/`` (absolute); no empty tokens, no trailing ``/`` (except the root namespace ``/``).
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"invalid {what} {name!r}: empty")
    if name == "/":
        return
    if name.startswith("~"):
        raise ValueError(f"invalid {what} {name!r}: private names '~' are not supported")
    body = name[1:] if name.startswith("/") else name
    for token in body.split("/"):
        if not _TOKEN.fullmatch(token):
            raise ValueError(
                f"invalid {what} {name!r}: token {token!r} must match [A-Za-z_][A-Za-z0-9_]*"
            )


def validate_namespace(namespace: str) -> None:
    """Raise ``ValueError`` unless ``namespace`` is absolute and valid (``/`` or ``/a/b``)."""
    validate_name(namespace, "namespace")
    if not namespace.startswith("/"):
        raise ValueError(f"invalid namespace {namespace!r}: must start with '/'")


def _expand(name: str, namespace: str) -> str:
    validate_name(name)
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}"


def resolve_topic(
    name: str, namespace: str = "/", remaps: Mapping[str, str] | None = None
) -> str:
    """Fully qualified name of topic ``name`` for a node in ``namespace``.

    An absolute name is kept, a relative one is prefixed with ``namespace``. Then the first
    remap ``from -> to`` whose resolved ``from`` equals the result replaces it with the
    resolved ``to`` (both sides of a remap resolve in ``namespace`` too, as in ROS 2).

    Raises
    ------
    ValueError
        ``name``, ``namespace`` or a remap side is not a valid name; the message names it.
    """
    validate_namespace(namespace)
    resolved = _expand(name, namespace)
    for source, target in (remaps or {}).items():
        if _expand(source, namespace) == resolved:
            return _expand(target, namespace)
    return resolved


def node_fqn(name: str, namespace: str = "/") -> str:
    """Fully qualified node name: ``/ns/name``; ``name`` is one token."""
    validate_namespace(namespace)
    validate_token(name)
    return _expand(name, namespace)
