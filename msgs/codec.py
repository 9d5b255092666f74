"""The one codec of the wire: message <-> msgpack bytes, strict on decode.

A payload is a msgpack map ``{"_type": TYPE_NAME, "_v": VERSION, <field>: <value>, ...}``.
A numeric array is a map ``{"dtype": "<f8", "shape": [N, 3], "data": <raw little-endian bytes>}``
(never a list of floats). An optional field that is ``None`` is left out (a payload with
msgpack nil there decodes too). Only finite floats go on the wire: ``encode`` refuses NaN/inf with
``ValueError`` and ``decode`` with ``NonFiniteError``.

Decoded arrays are read-only views of immutable ``bytes``: the objects msgpack unpacks them
into, or the payload itself when it is ``bytes`` and read through the template of its stream
(a mutable buffer never is), so no copy is made and nothing can change them later.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import operator
import struct
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np

from vibrissa.frames import clamp_frame
from vibrissa.msgs.messages import (
    ARRAY,
    ENUM,
    FLOAT,
    INT,
    MAX_PAYLOAD_BYTES,
    MESSAGE_TYPES,
    STR,
    STR_INT_MAP,
    STR_LIST,
    STR_STR_MAP,
    ContactPoint,
    ContactPointArray,
    FieldSpec,
    Message,
    WhiskerWrench,
    WhiskerWrenchArray,
    check_shape,
    enum_member,
    enum_values_ok,
    field_specs,
)

__all__ = [
    "ArrayDtypeError",
    "ArrayShapeError",
    "DecodeError",
    "FieldTypeError",
    "MalformedPayloadError",
    "MissingFieldError",
    "NonFiniteError",
    "OversizeError",
    "UnexpectedTypeError",
    "UnknownFieldError",
    "UnknownTypeError",
    "VersionMismatchError",
    "decode",
    "encode",
    "json_schema",
    "payload_limit",
    "peek_type",
    "to_jsonable",
]


class DecodeError(ValueError):
    """A payload that does not decode; the message names the type and field."""

    def __init__(self, message: str, type_name: str = "", field: str = "") -> None:
        super().__init__(message)
        self.type_name = type_name
        self.field = field


class MalformedPayloadError(DecodeError):
    """Not a msgpack map with ``_type`` and ``_v`` (truncated, garbage, wrong layout)."""


class OversizeError(DecodeError):
    """A payload longer than its type's (or every expected type's) ``MAX_BYTES``."""


class UnknownTypeError(DecodeError):
    """``_type`` names no type in ``MESSAGE_TYPES``."""


class VersionMismatchError(DecodeError):
    """``_v`` differs from the type's ``VERSION``."""


class UnexpectedTypeError(DecodeError):
    """A known type, but not one the caller expects."""


class MissingFieldError(DecodeError):
    """A required field is absent."""


class UnknownFieldError(DecodeError):
    """A field the type does not have."""


class FieldTypeError(DecodeError):
    """A field value of the wrong type (or out of its enum / choices)."""


class ArrayDtypeError(DecodeError):
    """An array with a dtype other than the field's."""


class ArrayShapeError(DecodeError):
    """An array whose shape or byte length does not match the field."""


class NonFiniteError(DecodeError):
    """NaN or infinity in a float field or array."""


_META_KEYS = ("_type", "_v")


# -- encode --------------------------------------------------------------------------------


def encode(msg: Message) -> bytes:
    """Encode a message to msgpack bytes.

    Raises
    ------
    TypeError
        ``msg`` is not a registered message type.
    ValueError
        A float field or array holds NaN or infinity.
    """
    cls = type(msg)
    if MESSAGE_TYPES.get(getattr(cls, "TYPE_NAME", "")) is not cls:
        raise TypeError(f"encode: {cls.__name__} is not a registered message type")
    out: dict[str, Any] = {"_type": cls.TYPE_NAME, "_v": cls.VERSION}
    values = msg.__dict__
    for name, spec in field_specs(cls):
        value = values[name]
        if value is None:  # an optional field: left out
            continue
        if spec.kind == ARRAY:
            if not _all_finite(value):
                raise ValueError(f"encode: {cls.TYPE_NAME}.{name} holds a non-finite value")
            # dtype and shape were checked when the message was made
            out[name] = {"dtype": spec.dtype_str, "shape": value.shape, "data": value.tobytes()}
        elif spec.kind == FLOAT and not math.isfinite(value):
            raise ValueError(f"encode: {cls.TYPE_NAME}.{name} is {value}")
        else:
            out[name] = int(value) if spec.kind == ENUM else value
    return msgpack.packb(out)  # type: ignore[no-any-return]


def _all_finite(array: np.ndarray) -> bool:
    if array.dtype.kind != "f":
        return True
    # For the small arrays of the hot path a Python sum is faster than np.isfinite().all();
    # a finite sum proves every element finite (overflow to inf just falls to the exact test).
    if array.size <= 16 and math.isfinite(sum(array.ravel().tolist())):
        return True
    return bool(np.count_nonzero(np.isfinite(array)) == array.size)  # .all(): twice the cost


# -- decode --------------------------------------------------------------------------------


def _unpack(payload: bytes) -> dict[str, Any]:
    try:
        obj = msgpack.unpackb(payload, raw=False, use_list=True, strict_map_key=True)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise MalformedPayloadError(f"malformed payload ({len(payload)} bytes): {exc}") from exc
    if not isinstance(obj, dict):
        raise MalformedPayloadError(f"payload is a {type(obj).__name__}, expected a msgpack map")
    if not all(type(key) is str for key in obj):
        raise MalformedPayloadError("payload map has a key that is not a string")
    return obj


def peek_type(payload: bytes) -> tuple[str, int]:
    """Type name and version of a payload, without decoding its fields.

    Raises ``MalformedPayloadError`` when the payload has no readable ``_type``/``_v``.
    """
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=True)
    unpacker.feed(payload)
    found: dict[str, Any] = {}
    try:
        for _ in range(unpacker.read_map_header()):
            key = unpacker.unpack()
            if key in _META_KEYS:
                found[key] = unpacker.unpack()
                if len(found) == 2:
                    break
            else:
                unpacker.skip()
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise MalformedPayloadError(f"malformed payload ({len(payload)} bytes): {exc}") from exc
    name, version = found.get("_type"), found.get("_v")
    if not isinstance(name, str) or not isinstance(version, int) or isinstance(version, bool):
        raise MalformedPayloadError("payload has no string '_type' and integer '_v'")
    return name, version


def decode(
    payload: bytes,
    expected: type[Message] | tuple[type[Message], ...] | None = None,
) -> Message:
    """Decode and check a payload; ``expected`` restricts the accepted types.

    Raises
    ------
    DecodeError
        One of its subclasses, with a message naming the type and field; for any input, no
        other exception (a case the checks miss is a ``MalformedPayloadError`` naming it).
    """
    try:
        return _decode(payload, expected)
    except DecodeError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever the bytes, the codec's own error
        raise MalformedPayloadError(
            f"undecodable payload ({len(payload)} bytes): {type(exc).__name__}: {exc}") from exc


def payload_limit(expected: type[Message] | tuple[type[Message], ...] | None) -> int:
    """The longest payload ``decode`` reads when it expects ``expected``, bytes."""
    if expected is None:
        return MAX_PAYLOAD_BYTES
    allowed = expected if isinstance(expected, tuple) else (expected,)
    return max(t.MAX_BYTES for t in allowed)


def _decode(payload: bytes, expected: type[Message] | tuple[type[Message], ...] | None) -> Message:
    limit = payload_limit(expected)  # refused before a byte of it is read
    if len(payload) > limit:
        names = "any type" if expected is None else ", ".join(
            t.TYPE_NAME for t in (expected if isinstance(expected, tuple) else (expected,)))
        raise OversizeError(f"payload of {len(payload)} bytes, more than the {limit} bytes "
                            f"of {names}")
    if type(payload) is not bytes:  # templates read in place: only immutable bytes
        return _decode_general(payload, expected)
    templates = _TEMPLATES.get(len(payload))
    allowed = expected if isinstance(expected, tuple) or expected is None else (expected,)
    for i, template in enumerate(templates or ()):
        if allowed is None or template.cls in allowed:
            msg = _from_template(template, payload)
            if msg is not None:
                if i:  # the stream that sends most comes first
                    templates.insert(0, templates.pop(i))  # type: ignore[union-attr]
                return msg
    msg = _decode_general(payload, expected)
    if type(msg) in _TEMPLATED and len(payload) <= _MAX_TEMPLATE_BYTES:
        _learn_template(payload, msg)
    return msg


def _decode_general(payload: bytes,
                    expected: type[Message] | tuple[type[Message], ...] | None) -> Message:
    """Decode without a template: the path that finds and names what is wrong."""
    obj = _unpack(payload)
    name = obj.pop("_type", None)
    version = obj.pop("_v", None)
    if not isinstance(name, str) or not isinstance(version, int) or isinstance(version, bool):
        raise MalformedPayloadError("payload has no string '_type' and integer '_v'")
    cls = MESSAGE_TYPES.get(name)
    if cls is None:
        raise UnknownTypeError(f"unknown message type {name!r}", name)
    if expected is not None:
        allowed = expected if isinstance(expected, tuple) else (expected,)
        if cls not in allowed:
            names = ", ".join(t.TYPE_NAME for t in allowed)
            raise UnexpectedTypeError(f"got {name}, expected {names}", name)
    if len(payload) > cls.MAX_BYTES:
        raise OversizeError(f"payload of {len(payload)} bytes, more than the {cls.MAX_BYTES} "
                            f"bytes of {name}", name)
    if version != cls.VERSION:
        upgrade = _UPGRADES.get((name, version))
        if upgrade is None:
            reads = ", ".join(str(v) for v in sorted(
                {cls.VERSION} | {v for n, v in _UPGRADES if n == name}))
            raise VersionMismatchError(
                f"{name} version {version} on the wire, this build reads version {reads}", name)
        obj = upgrade(obj)
    layout = _fast_layout(cls, obj.keys())
    if layout is not None:
        fast = _decode_fast(cls, layout, obj)
        if fast is not None:
            _check_fields(fast)
            return fast
    # The general path: also the one that finds and names what is wrong.
    values: dict[str, Any] = {}
    sizes: dict[str, int] = {}
    for field_name, spec in field_specs(cls):
        if field_name not in obj:
            if field_name in _defaults(cls):
                continue  # the dataclass default applies
            raise MissingFieldError(f"{name}: missing field {field_name!r}", name, field_name)
        value = obj.pop(field_name)
        values[field_name] = (None if value is None and spec.optional
                              else _DECODERS[spec.kind](name, field_name, spec, value, sizes))
    if obj:
        extra = sorted(obj)[0]
        raise UnknownFieldError(f"{name}: unknown field {extra!r}", name, extra)
    # Every field is now checked at least as strictly as Message.__post_init__ would (dtype,
    # shape incl. shared sizes, read-only arrays, enums), so build the frozen instance
    # without running the checks twice: a third of the decode time otherwise.
    msg = object.__new__(cls)
    msg.__dict__.update(_defaults(cls))
    msg.__dict__.update(values)
    _check_fields(msg)
    return msg


def _check_fields(msg: Message) -> None:
    try:
        msg.check_fields()
    except ValueError as exc:
        raise MissingFieldError(str(exc), msg.TYPE_NAME) from None


# -- older versions -------------------------------------------------------------------------
#
# An upgrade turns the fields of an older version's payload into the current version's, before
# any of them is checked: the current version's checks then apply to them in full. It must not
# fail on any input (the payload is untrusted): what it cannot move it leaves for the checks.


def _wrench_v1(obj: dict[str, Any]) -> dict[str, Any]:
    """WhiskerWrench 1 -> 2: ``frame_id`` named the pose's frame; the wrench is in the clamp
    frame of ``whisker_id``."""
    if "frame_id" in obj:
        obj["pose_frame_id"] = obj.pop("frame_id")
    whisker = obj.get("whisker_id")
    obj["frame_id"] = clamp_frame(whisker) if isinstance(whisker, str) else whisker
    return obj


def _wrench_array_v1(obj: dict[str, Any]) -> dict[str, Any]:
    """WhiskerWrenchArray 1 -> 2: as `_wrench_v1`, one clamp frame per row."""
    if "frame_id" in obj:
        obj["pose_frame_id"] = obj.pop("frame_id")
    whiskers = obj.get("whisker_ids")
    if isinstance(whiskers, list) and all(isinstance(w, str) for w in whiskers):
        obj["frame_ids"] = [clamp_frame(w) for w in whiskers]
    else:
        obj["frame_ids"] = whiskers
    return obj


def _without_covariance(obj: dict[str, Any]) -> dict[str, Any]:
    """ContactPoint / ContactPointArray 1 -> 2: version 2 adds the optional ``covariance``;
    version 1 has none (a field of that name in a version 1 payload is refused)."""
    if "covariance" in obj:
        obj["covariance"] = "not in version 1"
    return obj


_UPGRADES: dict[tuple[str, int], Callable[[dict[str, Any]], dict[str, Any]]] = {
    (WhiskerWrench.TYPE_NAME, 1): _wrench_v1,
    (WhiskerWrenchArray.TYPE_NAME, 1): _wrench_array_v1,
    (ContactPoint.TYPE_NAME, 1): _without_covariance,
    (ContactPointArray.TYPE_NAME, 1): _without_covariance,
}
"""(type name, older version) -> its upgrade to the type's current version."""


def _defaults(cls: type[Message]) -> dict[str, Any]:
    defaults = _DEFAULTS.get(cls)
    if defaults is None:
        fields = dataclasses.fields(cls)
        defaults = {f.name: f.default for f in fields if f.default is not dataclasses.MISSING}
        _DEFAULTS[cls] = defaults
    return defaults


_DEFAULTS: dict[type, dict[str, Any]] = {}


# -- decode, fast path --------------------------------------------------------------------
#
# Types without maps (WhiskerWrench, ContactPoint, their arrays, ...), one layout per set of
# present fields (optional ones present or left out): payloads are checked field by field
# with exact-type tests, a precomputed header for fixed 1-d arrays and the shape pattern for
# the others; anything unusual (a missing or extra field, a nil, an int for a float, a wrong
# shape, a NaN, ...) returns None and the general path decodes it again and raises the
# specific error. The fast path accepts a subset of what the general path accepts and returns
# the same message, so the two cannot disagree.

_FLOAT, _INT, _ENUM, _STR, _ARRAY, _SHAPED, _STR_LIST = range(7)


@dataclasses.dataclass(frozen=True)
class _Layout:
    names: frozenset[str]
    # (name, code, check): enum -> value->member map, str -> choices, fixed 1-d array ->
    # (dtype str, shape list, byte count, dtype, struct unpacker of '<f8' data or None), other
    # array -> (dtype str, shape pattern, dtype), string list -> its length symbol or ""
    fields: tuple[tuple[str, int, Any], ...]
    left_out: tuple[str, ...]  # optional fields not in the payload: None


def _fast_layout(cls: type[Message], names: Any) -> _Layout | None:
    """The layout of payloads of ``cls`` with exactly the fields ``names`` (None: no fast
    path, e.g. a required field is missing or an unknown one is there)."""
    key = (cls, frozenset(names))
    layout = _LAYOUTS.get(key)
    if layout is None:
        layout = _make_layout(cls, key[1])
        if layout is not None:  # only valid field sets are kept: garbage cannot grow the cache
            _LAYOUTS[key] = layout
    return layout


def _make_layout(cls: type[Message], names: frozenset[str]) -> _Layout | None:
    specs = field_specs(cls)
    if not names <= {name for name, _ in specs}:
        return None
    fields: list[tuple[str, int, Any]] = []
    for name, spec in specs:
        if name not in names:
            if spec.optional:
                continue  # left out: None
            return None
        if spec.kind == FLOAT:
            fields.append((name, _FLOAT, None))
        elif spec.kind == INT:
            fields.append((name, _INT, None))
        elif spec.kind == ENUM:
            assert spec.enum is not None
            members: list[Any] = list(spec.enum)
            if issubclass(spec.enum, enum.IntFlag):  # every combination of the flags
                mask = functools.reduce(operator.or_, (int(m) for m in members), 0)
                members = [spec.enum(v) for v in range(mask + 1) if v & ~mask == 0]
            fields.append((name, _ENUM, {int(m): m for m in members}))
        elif spec.kind == STR:
            fields.append((name, _STR, frozenset(spec.choices)))
        elif spec.kind == ARRAY and spec.fixed_shape is not None and len(spec.shape) == 1:
            assert spec.dtype is not None
            size = spec.fixed_shape[0]
            floats = struct.Struct(f"<{size}d") if spec.dtype_str == "<f8" else None
            fields.append((name, _ARRAY, (spec.dtype_str, [size], size * spec.dtype.itemsize,
                                          spec.dtype, floats)))
        elif spec.kind == ARRAY:
            fields.append((name, _SHAPED, (spec.dtype_str, spec.shape, spec.dtype, spec.enum)))
        elif spec.kind == STR_LIST:
            fields.append((name, _STR_LIST, spec.length))
        else:
            return None
    return _Layout(names, tuple(fields),
                   tuple(name for name, spec in specs if spec.optional and name not in names))


_LAYOUTS: dict[tuple[type, frozenset[str]], _Layout] = {}


def _decode_fast(cls: type[Message], layout: _Layout, obj: dict[str, Any]) -> Message | None:
    values: dict[str, Any] = {}
    sizes: dict[str, int] = {}  # symbolic sizes, bound at first use
    total = 0.0  # of every float: finite proves them all finite (overflow: the general path)
    for name, code, check in layout.fields:
        value = obj[name]
        if code == _SHAPED:
            value = _shaped_array(value, check, sizes)
            if value is None or not _all_finite(value):
                return None
            if check[3] is not None and not enum_values_ok(check[3], value):
                return None
        elif code == _STR_LIST:
            if type(value) is not list or not all(type(item) is str for item in value):
                return None
            if check and sizes.setdefault(check, len(value)) != len(value):
                return None
        elif code == _ARRAY:
            dtype_str, shape, nbytes, dtype, floats = check
            if type(value) is not dict or len(value) != 3:
                return None
            data, got_shape = value.get("data"), value.get("shape")
            if (type(data) is not bytes or len(data) != nbytes or value.get("dtype") != dtype_str
                    or got_shape != shape or type(got_shape[0]) is not int):
                return None
            if floats is not None:
                total += sum(floats.unpack(data))
            elif dtype.kind == "f":
                return None
            value = np.frombuffer(data, dtype)  # read-only: bytes are immutable
        elif code == _FLOAT:
            if type(value) is not float:
                return None
            total += value
        elif code == _INT:
            if type(value) is not int:
                return None
        elif code == _ENUM:
            value = check.get(value) if type(value) is int else None
            if value is None:
                return None
        elif type(value) is not str or (check and value not in check):
            return None
        values[name] = value
    if not math.isfinite(total):
        return None
    for name in layout.left_out:
        values[name] = None
    msg = object.__new__(cls)
    msg.__dict__.update(values)
    return msg


# -- decode, template path ----------------------------------------------------------------
#
# A stream of arrays sends payloads of one layout tick after tick: the same keys, strings,
# shapes and msgpack types, only the numbers differ. After two payloads of one type and length
# in a row, the second is kept as a template of that length: where each number's bytes lie (a
# float's 8, an int's, an array's data) and the message's other values. A payload of that
# length whose every other byte is the template's is read in place: its floats checked finite,
# its ints of the template's msgpack type, its enum arrays checked, then the cross-field rules as
# on any decode. Same bytes outside the numbers, and in them numbers of the same types and
# lengths, is the same structure for the general path: the two give equal messages (fuzzed in
# tests/wire/test_codec_template.py). A nil, a negative fixint or an older version is never a
# slot, and a payload that differs goes the general way. Per-wrench types are left out: their
# streams (one per whisker) take turns, and so would their layouts.

_TEMPLATED = frozenset((WhiskerWrenchArray, ContactPointArray))
_SLOT_FLOAT, _SLOT_INT, _SLOT_ARRAY = range(3)
_BIG_DOUBLE = struct.Struct(">d")
_UINT_MARKERS, _INT_MARKERS = frozenset((0xCC, 0xCD, 0xCE, 0xCF)), frozenset((0xD0, 0xD1, 0xD2, 0xD3))
_MAX_TEMPLATE_BYTES = 1 << 16  # longer payloads (arrays of ~1 000 rows) go the general way:
# their data, not the walk through their keys, is what their decode costs
_MAX_LENGTHS = 16  # payload lengths with templates: what templates hold stays under 8 MB
_PER_LENGTH = 4  # templates of one length: streams of equal length from different sources
_RELEARN_AFTER = 64  # payloads of a length with all its templates taken that none fitted, before
# the least used is replaced: more streams of one length than templates cost a walk per 64


@dataclasses.dataclass(frozen=True)
class _Template:
    cls: type[Message]
    fixed: tuple[tuple[int, bytes], ...]  # (offset, bytes) between the slots
    # (field, kind, offset, check): float -> None; int -> (msgpack marker or None for a positive
    # fixint, byte count, signed); array -> (dtype, shape, count, enum or None)
    slots: tuple[tuple[str, int, int, Any], ...]
    values: dict[str, Any]  # the other fields' values
    copied: tuple[str, ...]  # those that are lists or maps: a copy per message


_TEMPLATES: dict[int, list[_Template]] = {}  # by payload length, the last one fitted first
_MISSES: dict[int, int] = {}  # by payload length, since its last template was made
_last_decoded: list[tuple[type, int] | None] = [None]  # (type, length) of the last payload


def _from_template(template: _Template, payload: bytes) -> Message | None:
    """The message of ``payload`` read through ``template``, or None when it does not fit."""
    for offset, want in template.fixed:
        if not payload.startswith(want, offset):
            return None
    values = dict(template.values)
    for name in template.copied:
        values[name] = type(values[name])(values[name])
    total = 0.0  # of every float: finite proves them all finite (overflow: the general path)
    for name, kind, offset, check in template.slots:
        if kind == _SLOT_FLOAT:
            value = _BIG_DOUBLE.unpack_from(payload, offset)[0]
            total += value
        elif kind == _SLOT_INT:
            marker, size, signed = check
            first = payload[offset]
            if marker is None:
                if first >= 0x80:
                    return None
                value = first
            elif first != marker:
                return None
            else:
                value = int.from_bytes(payload[offset + 1:offset + size], "big", signed=signed)
        else:
            dtype, shape, count, enum_type = check
            value = np.frombuffer(payload, dtype, count, offset)  # read-only: bytes
            if len(shape) != 1:
                value = value.reshape(shape)
            if not _all_finite(value) or (enum_type is not None
                                          and not enum_values_ok(enum_type, value)):
                return None
        values[name] = value
    if not math.isfinite(total):
        return None
    msg = object.__new__(template.cls)
    msg.__dict__.update(values)
    _check_fields(msg)
    return msg


def _learn_template(payload: bytes, msg: Message) -> None:
    """Keep ``payload`` (decoded the general way) as a template of its length when the one
    decoded that way before it had the same type and length: a stream, not a one-off (the walk
    costs about a decode)."""
    size = len(payload)
    key = (type(msg), size)
    last, _last_decoded[0] = _last_decoded[0], key
    templates = _TEMPLATES.get(size)
    if templates is not None and len(templates) >= _PER_LENGTH:
        _MISSES[size] = _MISSES.get(size, 0) + 1
        if _MISSES[size] < _RELEARN_AFTER:
            return
    if last != key:
        return
    template = _make_template(payload, msg)
    if template is None:
        return
    if templates is None:
        if len(_TEMPLATES) >= _MAX_LENGTHS:
            _TEMPLATES.clear()
            _MISSES.clear()
        templates = _TEMPLATES[size] = []
    templates.insert(0, template)
    del templates[_PER_LENGTH:]
    _MISSES[size] = 0


def _make_template(payload: bytes, msg: Message) -> _Template | None:
    """The template of a payload that decoded to ``msg`` (None: one the codec upgraded, or a
    layout without a place for its numbers)."""
    cls = type(msg)
    specs = dict(field_specs(cls))
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=True)
    unpacker.feed(payload)
    slots: list[tuple[str, int, int, Any]] = []
    spans: list[tuple[int, int]] = []
    try:
        for _ in range(unpacker.read_map_header()):
            name = unpacker.unpack()
            start = unpacker.tell()
            spec = specs.get(name)
            if name == "_v":
                if unpacker.unpack() != cls.VERSION:
                    return None
                continue
            if spec is None or getattr(msg, name) is None:  # _type, a nil: fixed bytes
                unpacker.skip()
                continue
            if spec.kind == FLOAT:
                unpacker.skip()
                if payload[start] != 0xCB:
                    return None
                slots.append((name, _SLOT_FLOAT, start + 1, None))
                spans.append((start + 1, start + 9))
            elif spec.kind == INT and spec.enum is None:
                unpacker.skip()
                size, first = unpacker.tell() - start, payload[start]
                if first < 0x80:
                    slots.append((name, _SLOT_INT, start, (None, 1, False)))
                elif first in _UINT_MARKERS or first in _INT_MARKERS:
                    slots.append((name, _SLOT_INT, start, (first, size, first in _INT_MARKERS)))
                else:
                    continue  # a negative fixint is its own marker: left in the fixed bytes
                spans.append((start, start + size))
            elif spec.kind == ARRAY:
                array = getattr(msg, name)
                for _ in range(unpacker.read_map_header()):
                    if unpacker.unpack() != "data":
                        unpacker.skip()
                        continue
                    data = unpacker.unpack()
                    offset = unpacker.tell() - len(data)
                    slots.append((name, _SLOT_ARRAY, offset,
                                  (array.dtype, array.shape, array.size, spec.enum)))
                    spans.append((offset, offset + len(data)))
            else:
                unpacker.skip()
    except (ValueError, TypeError, msgpack.UnpackException):
        return None
    fixed: list[tuple[int, bytes]] = []
    end = 0
    for start, stop in sorted(spans):
        if start > end:
            fixed.append((end, payload[end:start]))
        end = stop
    if end < len(payload):
        fixed.append((end, payload[end:]))
    in_slots = {name for name, *_ in slots}
    values = {name: value for name, value in msg.__dict__.items() if name not in in_slots}
    copied = tuple(name for name, value in values.items() if isinstance(value, (list, dict)))
    return _Template(cls, tuple(fixed), tuple(slots), values, copied)


def _shaped_array(value: Any, check: tuple[str, tuple[int | str, ...], np.dtype[Any], Any],
                  sizes: dict[str, int]) -> np.ndarray | None:
    """The array of a wire map whose shape fits the pattern (symbols bound in ``sizes``)."""
    dtype_str, pattern, dtype, _ = check
    if type(value) is not dict or len(value) != 3:
        return None
    data, shape = value.get("data"), value.get("shape")
    if (type(data) is not bytes or value.get("dtype") != dtype_str or type(shape) is not list
            or len(shape) != len(pattern)):
        return None
    count = 1
    for want, got in zip(pattern, shape, strict=True):
        if type(got) is not int or got < 0:
            return None
        if want != got and (type(want) is not str or sizes.setdefault(want, got) != got):
            return None
        count *= got
    if len(data) != count * dtype.itemsize:
        return None
    return np.frombuffer(data, dtype).reshape(shape)  # read-only: bytes are immutable


def _type_error(type_name: str, field: str, want: str, value: Any) -> FieldTypeError:
    return FieldTypeError(
        f"{type_name}.{field}: expected {want}, got {type(value).__name__}", type_name, field
    )


def _decode_float(t: str, f: str, spec: FieldSpec, value: Any, sizes: dict[str, int]) -> Any:
    if isinstance(value, bool) or not isinstance(value, (float, int)):
        raise _type_error(t, f, "float", value)
    if not math.isfinite(value):
        raise NonFiniteError(f"{t}.{f}: non-finite value {value}", t, f)
    return float(value)


def _decode_int(t: str, f: str, spec: FieldSpec, value: Any, sizes: dict[str, int]) -> Any:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _type_error(t, f, "int", value)
    if spec.enum is not None:
        try:
            return enum_member(spec.enum, value)
        except ValueError as exc:
            raise FieldTypeError(f"{t}.{f}: {exc}", t, f) from exc
    return value


def _decode_str(t: str, f: str, spec: FieldSpec, value: Any, sizes: dict[str, int]) -> Any:
    if not isinstance(value, str):
        raise _type_error(t, f, "str", value)
    if spec.choices and value not in spec.choices:
        raise FieldTypeError(f"{t}.{f}: {value!r} is not one of {spec.choices}", t, f)
    return value


def _decode_array(t: str, f: str, spec: FieldSpec, value: Any, sizes: dict[str, int]) -> Any:
    assert spec.dtype is not None
    try:
        if len(value) != 3:
            raise KeyError
        dtype, shape, data = value["dtype"], value["shape"], value["data"]
    except (TypeError, KeyError):
        raise _type_error(t, f, "array map {dtype, shape, data}", value) from None
    if dtype != spec.dtype_str:
        raise ArrayDtypeError(f"{t}.{f}: dtype {dtype!r}, expected {spec.dtype_str!r}", t, f)
    if not isinstance(data, bytes) or not isinstance(shape, list):
        raise _type_error(t, f, "array shape list[int] and bytes data", value)
    for n in shape:
        if type(n) is not int or n < 0:
            raise _type_error(t, f, "array shape list[int] and bytes data", value)
    if tuple(shape) != spec.shape:  # fixed shapes match here; symbolic ones go on
        try:
            check_shape(f"{t}.{f}", spec.shape, tuple(shape), sizes)
        except ValueError as exc:
            raise ArrayShapeError(str(exc), t, f) from exc
    if len(data) != math.prod(shape) * spec.dtype.itemsize:
        raise ArrayShapeError(
            f"{t}.{f}: {len(data)} data bytes for shape {tuple(shape)} of {dtype}", t, f
        )
    array = np.frombuffer(data, dtype=spec.dtype)  # read-only: bytes are immutable
    if len(shape) != 1:
        array = array.reshape(shape)
    if not _all_finite(array):
        raise NonFiniteError(f"{t}.{f}: non-finite value in array", t, f)
    if spec.enum is not None and not enum_values_ok(spec.enum, array):
        raise FieldTypeError(f"{t}.{f}: values that are not {spec.enum.__name__} members", t, f)
    return array


def _decode_str_list(t: str, f: str, spec: FieldSpec, value: Any, sizes: dict[str, int]) -> Any:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise _type_error(t, f, "list[str]", value)
    if spec.length:
        try:
            check_shape(f"{t}.{f}", (spec.length,), (len(value),), sizes)
        except ValueError as exc:
            raise ArrayShapeError(str(exc), t, f) from exc
    return value


def _decode_map(t: str, f: str, spec: FieldSpec, value: Any, sizes: dict[str, int]) -> Any:
    item_type = int if spec.kind == STR_INT_MAP else str
    if not isinstance(value, dict) or not all(
        isinstance(k, str) and isinstance(v, item_type) and not isinstance(v, bool)
        for k, v in value.items()
    ):
        raise _type_error(t, f, f"dict[str, {item_type.__name__}]", value)
    return value


_DECODERS: dict[str, Callable[[str, str, FieldSpec, Any, dict[str, int]], Any]] = {
    FLOAT: _decode_float,
    INT: _decode_int,
    ENUM: _decode_int,
    STR: _decode_str,
    ARRAY: _decode_array,
    STR_LIST: _decode_str_list,
    STR_INT_MAP: _decode_map,
    STR_STR_MAP: _decode_map,
}


# -- JSON (Foxglove export) ----------------------------------------------------------------


def to_jsonable(msg: Message) -> dict[str, Any]:
    """The message's fields as JSON-ready values (arrays as nested lists, enums as ints).

    The ``_type``/``_v`` keys are not included: they belong to the schema (``json_schema``).
    """
    out: dict[str, Any] = {}
    for name, spec in field_specs(type(msg)):
        value = getattr(msg, name)
        if value is None:  # an optional field left out (a wrench without a clamp pose)
            out[name] = None
        elif spec.kind == ARRAY:
            out[name] = value.tolist()
        elif spec.kind == ENUM:
            out[name] = int(value)
        elif spec.kind in (STR_LIST, STR_INT_MAP, STR_STR_MAP):
            out[name] = type(value)(value)
        else:
            out[name] = value
    return out


def json_schema(cls: type[Message]) -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of ``to_jsonable(msg)`` for a message class."""
    properties: dict[str, Any] = {}
    required: list[str] = []
    for name, spec in field_specs(cls):
        prop = _json_property(spec)
        unit = f" [{spec.unit}]" if spec.unit else ""
        prop["description"] = spec.doc + unit
        if spec.optional:
            prop = {"anyOf": [prop, {"type": "null"}], "description": prop["description"]}
        else:
            required.append(name)
        properties[name] = prop
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": cls.TYPE_NAME,
        "description": f"{(cls.__doc__ or '').strip().splitlines()[0]} (version {cls.VERSION})",
        "type": "object",
        "properties": properties,
        "required": required,
        "additionalProperties": False,
    }


def _json_property(spec: FieldSpec) -> dict[str, Any]:
    if spec.kind == FLOAT:
        return {"type": "number"}
    if spec.kind == INT:
        return {"type": "integer"}
    if spec.kind == ENUM:
        assert spec.enum is not None
        names = ", ".join(f"{m.name}={int(m.value)}" for m in spec.enum)
        return {"type": "integer", "$comment": f"{spec.enum.__name__}: {names}"}
    if spec.kind == STR:
        if spec.choices:
            return {"type": "string", "enum": list(spec.choices)}
        return {"type": "string"}
    if spec.kind == STR_LIST:
        return {"type": "array", "items": {"type": "string"}}
    if spec.kind in (STR_INT_MAP, STR_STR_MAP):
        item = "integer" if spec.kind == STR_INT_MAP else "string"
        return {"type": "object", "additionalProperties": {"type": item}}
    assert spec.kind == ARRAY and spec.dtype is not None
    schema: dict[str, Any] = {"type": "integer" if spec.dtype.kind == "i" else "number"}
    for size in reversed(spec.shape):
        schema = {"type": "array", "items": schema}
        if isinstance(size, int):
            schema.update(minItems=size, maxItems=size)
    return schema
