"""YAML as people write numbers, decimal as in YAML 1.2: ``1e-5`` is a float (not the string
PyYAML's YAML 1.1 rules make of an exponent without a decimal point), ``010`` is ten, and
``1:30``, ``1_000``, ``0x10`` are text (not YAML 1.1's 90, 1000 and 16). `scalar` is that rule for a
text on its own (a launch argument's value). Every YAML file vibrissa reads (launch files,
parameter files, scene files) is read with `Loader` or a subclass of it; launch and scene
files with `StrictLoader` (`load_strict`)."""

from __future__ import annotations

import re
from typing import Any

import yaml

__all__ = ["Loader", "StrictLoader", "load", "load_strict", "scalar"]

_INT_TAG, _FLOAT_TAG, _BOOL_TAG = (f"tag:yaml.org,2002:{kind}" for kind in ("int", "float", "bool"))
_INT = re.compile(r"[-+]?[0-9]+")
_FLOAT = re.compile(r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)")
_BOOL = re.compile(r"true|True|TRUE|false|False|FALSE")


def scalar(text: str) -> bool | int | float | str:
    """What ``text`` reads as, as a plain YAML 1.2 scalar: ``true``/``false``, a decimal
    integer, a float (decimal or exponent notation, ``.inf``, ``.nan``); anything else is the
    text itself, as is (also an integer of more digits than Python reads, and a float whose
    nonzero digits underflow to 0, as 1e-400: neither is the number written)."""
    if _BOOL.fullmatch(text):
        return text.lower() == "true"
    if _INT.fullmatch(text):
        try:
            return int(text)
        except ValueError:  # over sys.get_int_max_str_digits()
            return text
    if _FLOAT.fullmatch(text):
        value = float(text.replace(".", "", 1) if text[-1].isalpha() else text)
        mantissa = text.lower().partition("e")[0]
        return text if value == 0.0 and any(c in "123456789" for c in mantissa) else value
    return text


def _number(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> int | float:
    """An ``!!int`` or ``!!float`` node (also one tagged explicitly) by `scalar`'s rule."""
    text = loader.construct_scalar(node)
    value = scalar(text)
    if isinstance(value, (bool, str)) or (node.tag == _INT_TAG and not isinstance(value, int)):
        kind = "an int" if node.tag == _INT_TAG else "a float"
        raise yaml.constructor.ConstructorError(None, None, f"{text!r} is not {kind}",
                                                node.start_mark)
    return float(value) if node.tag == _FLOAT_TAG else value


class Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2's numbers (`scalar`)."""


Loader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag not in (_INT_TAG, _FLOAT_TAG)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
Loader.add_implicit_resolver(_INT_TAG, re.compile(rf"^(?:{_INT.pattern})$"), list("-+0123456789"))
Loader.add_implicit_resolver(_FLOAT_TAG, re.compile(rf"^(?:{_FLOAT.pattern})$"),
                             list("-+0123456789."))
Loader.add_constructor(_INT_TAG, _number)
Loader.add_constructor(_FLOAT_TAG, _number)


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


StrictLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != _BOOL_TAG]
    for first, resolvers in Loader.yaml_implicit_resolvers.items()
}
StrictLoader.add_implicit_resolver(_BOOL_TAG, re.compile(rf"^(?:{_BOOL.pattern})$"), list("tTfF"))
StrictLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, StrictLoader.construct_mapping
)


def load_strict(text: str) -> Any:
    """``text`` read with `StrictLoader`. Raises ``yaml.YAMLError`` (a ``MarkedYAMLError``
    says where), or ``RecursionError`` for a document nested thousands deep."""
    return yaml.load(text, Loader=StrictLoader)  # noqa: S506 - a SafeLoader subclass
