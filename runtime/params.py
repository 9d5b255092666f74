"""A node's parameters: one frozen dataclass, loaded strictly from YAML and ``--param`` texts."""

from __future__ import annotations

import dataclasses
import difflib
import enum
import math
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from vibrissa.formats import yaml_numbers
from vibrissa.units import finite_number

# Not msgspec.convert: for a dataclass it ignores unknown keys (strictness is the point here),
# takes a ``field(init=False)`` (the nodes' derived ``rod``) for a required key, and gives the
# key path of a wrong value only inside its message text, which would have to be re-parsed.
P = TypeVar("P")
T = TypeVar("T")


class ParamError(ValueError):
    """A parameter value that a node refuses; the message names the source, key and value."""


def load_params(
    cls: type[P],
    params_file: str | Path | None = None,
    overrides: Mapping[str, object] | None = None,
) -> P:
    """Load frozen dataclass ``cls`` strictly: defaults, then ``params_file``, then ``overrides``.

    The file is a flat YAML mapping ``name: value``. An override given as text (from
    ``--param k:=v``) is parsed as YAML, except for a text parameter (`takes_text`), which
    takes the text as is. Ints are accepted for floats; nested dataclasses load from mappings.

    Raises
    ------
    ParamError
        Unknown key (naming the file and key), wrong type (naming key, expected and actual
        type), a value the dataclass refuses, a missing required parameter, or a file that is
        not a mapping.
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"load_params needs a dataclass type, got {cls!r}")
    values: dict[str, Any] = {}
    sources = [str(params_file)] if params_file is not None else []
    sources += ["--param"] if overrides else []
    source = " and ".join(sources) or "defaults"
    if params_file is not None:
        try:
            data = yaml_numbers.load(Path(params_file).read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise ParamError(f"{params_file}: cannot read parameters: {exc}") from exc
        if not isinstance(data, dict):
            kind = type(data).__name__
            raise ParamError(f"{params_file}: expected a mapping of parameters, got a {kind}")
        values.update(_typed_values(cls, data, str(params_file), from_text=False))
    if overrides:
        values.update(_typed_values(cls, overrides, "--param", from_text=True))
    return _build(cls, values, source)


def did_you_mean(word: str, known: Iterable[str]) -> str:
    """``": did you mean 'pose_delay'?"`` for the known name closest to a mistyped ``word``
    (`difflib.get_close_matches`), or an empty text when none is close."""
    close = difflib.get_close_matches(word, list(known), n=1)
    return f": did you mean {close[0]!r}?" if close else ""


def takes_text(hint: Any) -> bool:
    """Whether a parameter of type ``hint`` takes a text as is: ``str`` or ``Path`` (with
    ``None`` too, ``null`` is read as YAML: None)."""
    return hint in (str, Path)


def require(ok: bool, name: str, value: object, rule: str) -> None:
    """A dataclass's own check: ``ValueError`` ``parameter NAME must be RULE, got VALUE``."""
    if not ok:
        raise ValueError(f"parameter {name!r} must be {rule}, got {value!r}")


def require_positive(name: str, value: float) -> None:
    """``value`` is a finite number > 0 (``require``)."""
    require(math.isfinite(value) and value > 0, name, value, "a finite number > 0")


def require_non_negative(name: str, value: float) -> None:
    """``value`` is a finite number >= 0 (``require``)."""
    require(math.isfinite(value) and value >= 0, name, value, "a finite number >= 0")


def require_parsed(name: str, value: object, parse: Callable[[Any], T]) -> T:
    """``parse(value)`` succeeds (a spec such as a surface, a bag file): its result; its error
    is named."""
    try:
        return parse(value)
    except (ValueError, OSError) as exc:
        raise ValueError(f"parameter {name!r}: {exc}") from None


def check_params(cls: type[P], data: Mapping[str, object], source: str) -> P:
    """``cls`` from already typed values (e.g. a launch file's ``param`` list), as a node
    would load them; ``source`` prefixes every error (``demo.yaml: node 'mapper'``).

    Raises
    ------
    ParamError
        As ``load_params``.
    """
    return _build(cls, _typed_values(cls, data, source, from_text=False), source)


def _build(cls: type[P], values: Mapping[str, Any], source: str) -> P:
    missing = [
        f.name for f in dataclasses.fields(cls)  # type: ignore[arg-type]
        if f.init and f.name not in values
        and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ParamError(f"{source}: missing required parameter(s) {missing} of {cls.__name__}")
    try:
        return cls(**values)
    except ValueError as exc:  # the dataclass's own checks (__post_init__)
        raise ParamError(f"{source}: {exc}") from None


def _typed_values(cls: type, data: Mapping[Any, object], source: str, from_text: bool,
                  prefix: str = "") -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls) if f.init}
    out: dict[str, Any] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if key not in known:
            raise ParamError(
                f"{source}: unknown parameter {name!r} for {cls.__name__}"
                f"{did_you_mean(str(key), known)} (known: {', '.join(sorted(known))})"
            )
        hint = hints[key]
        if from_text and isinstance(value, str) and not takes_text(hint):
            try:
                value = yaml_numbers.load(value)
            except yaml.YAMLError as exc:
                raise ParamError(f"{source}: parameter {name!r}: {value!r} is not YAML") from exc
        out[key] = _check(value, hint, name, source)
    return out


def _check(value: object, hint: Any, name: str, source: str) -> Any:
    """``value`` converted to type ``hint``, or ``ParamError`` naming the parameter."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for option in args:
            if option is type(None):
                continue
            try:
                return _check(value, option, name, source)
            except ValueError:
                pass
    elif origin is typing.Literal:
        if value in args:
            return value
    elif origin in (list, tuple) and isinstance(value, (list, tuple)):
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            if len(args) == len(value):
                return tuple(_check(v, a, f"{name}[{i}]", source)
                             for i, (v, a) in enumerate(zip(value, args, strict=True)))
        else:
            item = args[0] if args else Any
            items = [_check(v, item, f"{name}[{i}]", source) for i, v in enumerate(value)]
            return tuple(items) if origin is tuple else items
    elif origin is dict and isinstance(value, dict):
        key_type, item_type = args if args else (Any, Any)
        return {_check(k, key_type, name, source): _check(v, item_type, f"{name}.{k}", source)
                for k, v in value.items()}
    elif isinstance(hint, type) and dataclasses.is_dataclass(hint) and isinstance(value, dict):
        return hint(**_typed_values(hint, value, source, from_text=False, prefix=f"{name}."))
    elif (hint is float and isinstance(value, (int, float)) and not isinstance(value, bool)
          and not (isinstance(value, int) and not finite_number(value))):  # 400 digits: no float
        return float(value)
    elif hint is Path and isinstance(value, str):
        return Path(value)
    elif isinstance(hint, type) and issubclass(hint, enum.Enum):
        try:
            return hint(value) if not isinstance(value, str) else hint[value]
        except (KeyError, ValueError):
            pass
    elif hint is int and isinstance(value, bool):
        pass
    elif isinstance(hint, type) and origin is None and isinstance(value, hint):
        return value
    expected = getattr(hint, "__name__", None) if origin is None else None
    if origin is typing.Literal:
        expected = "one of " + ", ".join(map(repr, args))
    shown = repr(value)
    raise ParamError(
        f"{source}: parameter {name!r} expects {expected or hint}, "
        f"got {type(value).__name__} ({shown if len(shown) <= 60 else shown[:57] + '...'})"
    )
