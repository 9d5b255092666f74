"""YAML as people write numbers: ``1e-5`` is a float (YAML 1.2), not the string PyYAML's YAML
1.1 rules make of an exponent without a decimal point. Every YAML file vibrissa reads (launch
files, parameter files, scene files) is read with `Loader` or a subclass of it; launch and
scene files with `StrictLoader` (`load_strict`)."""

from __future__ import annotations

import re
from typing import Any

import yaml

__all__ = ["Loader", "StrictLoader", "load", "load_strict"]


class Loader(yaml.SafeLoader):
    """SafeLoader that reads ``1e-5``, ``-2E3`` as floats."""


Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9]+[eE][-+]?[0-9]+$"), list("-+0123456789")
)


def load(text: str) -> Any:
    """``yaml.safe_load(text)`` with `Loader`'s numbers."""
    return yaml.load(text, Loader=Loader)  # noqa: S506 - a SafeLoader subclass


class StrictLoader(Loader):
    """`Loader` with YAML 1.2 booleans, duplicate keys and aliases rejected.

    Only ``true``/``false`` are booleans, so ``respawn: yes`` is reported as a wrong type
    instead of silently meaning true, and a name ``on`` stays the text it looks like; a
    repeated key is an error instead of last-one-wins. An alias (``*name``) is refused where it
    stands: a few hundred bytes of nested aliases expand to 10^9 values (a "billion laughs")
    once anything walks them, and a recursive one never ends.
    """

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):  # type: ignore[no-untyped-call]
            event = self.peek_event()  # type: ignore[no-untyped-call]
            raise yaml.composer.ComposerError(
                None, None, f"aliases (*{event.anchor}) are not allowed", event.start_mark)
        return super().compose_node(parent, index)  # type: ignore[no-untyped-call]

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            try:
                duplicate = key in seen
            except TypeError:  # unhashable key: let the base class report it
                break
            if duplicate:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


_BOOL_TAG = "tag:yaml.org,2002:bool"
StrictLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != _BOOL_TAG]
    for first, resolvers in Loader.yaml_implicit_resolvers.items()
}
StrictLoader.add_implicit_resolver(
    _BOOL_TAG, re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF")
)
StrictLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, StrictLoader.construct_mapping
)


def load_strict(text: str) -> Any:
    """``text`` read with `StrictLoader`. Raises ``yaml.YAMLError`` (a ``MarkedYAMLError``
    says where), or ``RecursionError`` for a document nested thousands deep."""
    return yaml.load(text, Loader=StrictLoader)  # noqa: S506 - a SafeLoader subclass
