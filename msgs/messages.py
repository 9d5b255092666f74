"""Message types on the wire: one frozen dataclass per type, SI units, frames in the field docs.

Every field carries its wire spec in ``dataclasses.field(metadata=...)`` (kind, unit, shape,
doc); the codec and ``json_schema`` read it from there, so a field is described once.
Arrays held by a message are always read-only numpy arrays of the field's dtype: writeable
inputs are copied on construction, so a message cannot change after it is made.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

import numpy as np
import numpy.typing as npt

from vibrissa.status import SNAP_KINDS, ContactPhase, ContactStatus

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int32]

FLOAT64 = np.dtype("<f8")
INT32 = np.dtype("<i4")

# Field kinds of the wire spec.
FLOAT = "float"
INT = "int"
STR = "str"
ARRAY = "array"
STR_LIST = "str_list"
STR_INT_MAP = "str_int_map"
STR_STR_MAP = "str_str_map"

NODE_STATES = ("starting", "ready", "running", "finished", "error")


@dataclass(frozen=True)
class FieldSpec:
    """Wire description of one message field.

    ``shape`` entries are ints or a symbol such as ``"N"`` that must take the same value in
    every field of one message that uses it; ``length`` does the same for a string list.
    """

    kind: str
    doc: str
    unit: str = ""
    dtype: np.dtype[Any] | None = None
    shape: tuple[int | str, ...] = ()
    enum: type[enum.IntEnum] | type[enum.IntFlag] | None = None
    choices: tuple[str, ...] = ()
    length: str = ""
    optional: bool = False

    @functools.cached_property
    def dtype_str(self) -> str:
        """``dtype.str`` of an array field, e.g. ``"<f8"`` (cached: numpy rebuilds it per call)."""
        return self.dtype.str if self.dtype is not None else ""

    @functools.cached_property
    def fixed_shape(self) -> tuple[int, ...] | None:
        """``shape`` of an array field when it has no symbolic size, else ``None``."""
        if self.kind != ARRAY or not all(isinstance(n, int) for n in self.shape):
            return None
        return tuple(int(n) for n in self.shape)

    @functools.cached_property
    def exact_type(self) -> type | None:
        """The type a value must have to be stored as it is (no coercion, no copy).

        ``None`` for kinds that are always copied (lists, maps) or may be absent (optional).
        """
        if self.optional:
            return None
        if self.kind == ARRAY:
            return np.ndarray
        if self.kind == STR:
            return str if not self.choices else None
        return {FLOAT: float, INT: int}.get(self.kind)

    def accepts_as_is(self, value: Any, sizes: dict[str, int]) -> bool:
        """Whether ``value`` already is what construction would make of it.

        Exact Python types, and read-only arrays of the field's dtype and shape (symbolic sizes
        bound in ``sizes``) that are not of an enum: the checks of ``_coerce`` hold for them, so
        the fast path of construction skips it (an enum array's values are checked there).
        """
        exact = self.exact_type
        if exact is None or type(value) is not exact:
            return False
        if isinstance(value, np.ndarray):
            if value.flags.writeable or value.dtype != self.dtype or self.enum is not None:
                return False
            if self.fixed_shape is not None:
                return bool(value.shape == self.fixed_shape)
            try:
                check_shape("", self.shape, value.shape, sizes)
            except ValueError:
                return False  # _coerce names the mismatch
        return True


def enum_values_ok(enum_type: type[enum.IntEnum] | type[enum.IntFlag], values: Any) -> bool:
    """Whether every value (an int or an int array) is a member of ``enum_type``: a defined
    value of an IntEnum, or a combination of defined bits of an IntFlag (no others)."""
    array = np.asarray(values)
    flags, mask, members = _enum_values(enum_type)
    if array.size <= 64:  # a tick's rows: Python's ints cost less than numpy's calls
        items = array.ravel().tolist()
        if flags:
            if array.dtype.kind in "iu" and not mask & (mask + 1):  # bits 0..k, all defined
                return not items or (min(items) >= 0 and max(items) <= mask)
            return all(type(v) is int and v >= 0 and not v & ~mask for v in items)
        return members.issuperset(items)
    if flags:
        return bool(np.all(array >= 0) and not np.any(array & ~mask))
    return bool(np.all(np.isin(array, list(members))))


@functools.cache
def _enum_values(enum_type: type[enum.IntEnum] | type[enum.IntFlag]
                 ) -> tuple[bool, int, frozenset[int]]:
    """Whether ``enum_type`` is an IntFlag, the mask of its bits, the values of its members."""
    if issubclass(enum_type, enum.IntFlag):
        return True, functools.reduce(lambda a, b: a | int(b), enum_type, 0), frozenset()
    return False, 0, frozenset(int(m) for m in enum_type)


def enum_member(enum_type: type[enum.IntEnum] | type[enum.IntFlag], value: int) -> Any:
    """``enum_type(value)``; ``ValueError`` for a value that is not a member (``enum_values_ok``:
    an IntFlag refuses undefined bits, which Python's own conversion keeps)."""
    if not enum_values_ok(enum_type, value):
        raise ValueError(f"{value} is not a valid {enum_type.__name__}")
    return enum_type(value)


def _spec(**kwargs: Any) -> Any:
    return field(metadata={"spec": FieldSpec(**kwargs)})


def _optional(**kwargs: Any) -> Any:
    return field(default=None, metadata={"spec": FieldSpec(optional=True, **kwargs)})


def _number(unit: str, doc: str) -> Any:
    return _spec(kind=FLOAT, unit=unit, doc=doc)


def _count(doc: str) -> Any:
    return _spec(kind=INT, doc=doc)


def _text(doc: str, choices: tuple[str, ...] = ()) -> Any:
    return _spec(kind=STR, doc=doc, choices=choices)


def _array(
    shape: tuple[int | str, ...], unit: str, doc: str, dtype: np.dtype[Any] = FLOAT64,
    enum: type[enum.IntEnum] | type[enum.IntFlag] | None = None,
) -> Any:
    return _spec(kind=ARRAY, shape=shape, unit=unit, doc=doc, dtype=dtype, enum=enum)


def _stamp() -> Any:
    return _number("s", "time of the data, seconds (Unix epoch, or the simulation/bag clock)")


def _frame_id(doc: str = "frame the geometry is expressed in, normally 'world'") -> Any:
    return _text(doc)


def field_specs(cls: type) -> tuple[tuple[str, FieldSpec], ...]:
    """(name, spec) of every field of message class ``cls``, in declaration order."""
    specs = cls.__dict__.get("_FIELD_SPECS")
    if specs is None:
        specs = tuple((f.name, f.metadata["spec"]) for f in dataclasses.fields(cls))
        cls._FIELD_SPECS = specs  # type: ignore[attr-defined]
    return specs  # type: ignore[no-any-return]


def _field_names(cls: type) -> frozenset[str]:
    names = cls.__dict__.get("_FIELD_NAMES")
    if names is None:
        names = frozenset(name for name, _ in field_specs(cls))
        cls._FIELD_NAMES = names  # type: ignore[attr-defined]
    return names  # type: ignore[no-any-return]


MAX_PAYLOAD_BYTES = 64 << 20
"""The largest payload of any type (a cloud of 2.8 M points), bytes."""


class Message:
    """Base of every wire message: construction-time checks and array-aware equality.

    ``MAX_BYTES`` bounds an encoded payload of the type: decode refuses a longer one before
    reading it, so a flood of oversized frames costs a receiver a length check each.
    """

    TYPE_NAME: ClassVar[str]
    VERSION: ClassVar[int]
    MAX_BYTES: ClassVar[int] = 64 << 10  # one sample: a few hundred bytes and its names

    def __post_init__(self) -> None:
        sizes: dict[str, int] = {}
        values = self.__dict__
        for name, spec in field_specs(type(self)):
            value = values[name]
            if (value is None and spec.optional) or spec.accepts_as_is(value, sizes):
                continue
            object.__setattr__(self, name, _coerce(type(self), name, spec, value, sizes))
        self.check_fields()

    def check_fields(self) -> None:
        """Rules across fields (``ValueError``); the codec runs them on decode too."""

    @classmethod
    def unchecked(cls, **values: Any) -> Self:
        """A message of ``values`` (every field, by name) taken as they are, without the checks
        of construction or ``check_fields``.

        Only for values that already are what construction would make of them: read-only
        arrays of the field's dtype and shape, sizes that agree, enum members, lists of str
        of their own. The codec's decode builds its checked fields with it, and code that
        builds its own output from what it made (Step 2's points) may too; anything from
        outside (the wire, a file, a caller) goes through the constructor. ``encode`` still
        refuses non-finite values.
        """
        if values.keys() != _field_names(cls):
            raise TypeError(f"{cls.__name__}.unchecked takes every field by name: "
                            f"{', '.join(sorted(_field_names(cls)))}")
        msg = object.__new__(cls)
        msg.__dict__.update(values)
        return msg

    def select_rows(self, keep: npt.ArrayLike) -> Self:
        """This message with only the rows ``keep`` (a bool mask (N,) or row indices) of every
        field sized by ``N``; the other fields as they are."""
        rows = np.asarray(keep)
        if rows.dtype == np.bool_:
            rows = np.flatnonzero(rows)
        values: dict[str, Any] = {}
        for name, spec in field_specs(type(self)):
            value = getattr(self, name)
            if value is not None and spec.kind == ARRAY and spec.shape[:1] == ("N",):
                value = value[rows]
            elif value is not None and spec.kind == STR_LIST and spec.length == "N":
                value = [value[i] for i in rows.tolist()]
            values[name] = value
        return type(self)(**values)

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for name, _ in field_specs(type(self)):
            a, b = getattr(self, name), getattr(other, name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
                    return False
                if a.shape != b.shape or not np.array_equal(a, b):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # type: ignore[assignment]  # holds arrays


def _coerce(cls: type, name: str, spec: FieldSpec, value: Any, sizes: dict[str, int]) -> Any:
    where = f"{cls.__name__}.{name}"
    if spec.kind == ARRAY:
        assert spec.dtype is not None
        read_only = isinstance(value, np.ndarray) and not value.flags.writeable
        if read_only and value.dtype == spec.dtype:
            array = value
        else:
            array = np.array(value, dtype=spec.dtype, copy=True)
            array.flags.writeable = False
        check_shape(where, spec.shape, array.shape, sizes)
        if spec.enum is not None and not enum_values_ok(spec.enum, array):
            raise ValueError(f"{where} holds values that are not {spec.enum.__name__} members")
        return array
    if spec.kind == FLOAT:
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise TypeError(f"{where} expects a float, got {type(value).__name__}")
        return float(value)
    if spec.kind == INT:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise TypeError(f"{where} expects an int, got {type(value).__name__}")
        return int(value)
    if spec.kind == STR:
        if not isinstance(value, str):
            raise TypeError(f"{where} expects a str, got {type(value).__name__}")
        if spec.choices and value not in spec.choices:
            raise ValueError(f"{where} must be one of {spec.choices}, got {value!r}")
        return value
    if spec.kind == STR_LIST:
        items = list(value)
        if not all(isinstance(item, str) for item in items):
            raise TypeError(f"{where} expects a list of str")
        if spec.length:
            check_shape(where, (spec.length,), (len(items),), sizes)
        return items
    if spec.kind in (STR_INT_MAP, STR_STR_MAP):
        if not isinstance(value, Mapping):
            raise TypeError(f"{where} expects a dict, got {type(value).__name__}")
        item_type = int if spec.kind == STR_INT_MAP else str
        out = dict(value)
        for key, item in out.items():
            if not (isinstance(key, str) and isinstance(item, item_type)) or isinstance(item, bool):
                raise TypeError(f"{where} expects dict[str, {item_type.__name__}]")
        return out
    raise AssertionError(f"unknown field kind {spec.kind!r}")


def check_shape(
    where: str, expected: tuple[int | str, ...], actual: tuple[int, ...], sizes: dict[str, int]
) -> None:
    """Raise ``ValueError`` naming ``where`` unless ``actual`` matches ``expected``.

    Symbolic sizes (``"N"``) are bound in ``sizes`` at first use and must agree afterwards.
    """
    if len(expected) == len(actual):
        for want, got in zip(expected, actual, strict=True):
            if want != got and (type(want) is not str or sizes.setdefault(want, got) != got):
                break
        else:
            return
    want_text = "(" + ", ".join(f"{w}={sizes[w]}" if w in sizes else str(w) for w in expected)
    raise ValueError(f"{where} expects shape {want_text.rstrip(', ')}), got {actual}")


@dataclass(frozen=True, eq=False)
class WhiskerWrenchArray(Message):
    """The base wrench of each whisker of one tick, in its clamp frame; a single whisker's
    sample is a batch of one row.

    Row i of every field belongs to whisker ``whisker_ids[i]``, measured in the clamp frame
    ``frame_ids[i]``; all rows share ``stamp``. A sensor measures in its own frame and does not
    know where it is: the clamp poses come from the robot's pose stream and the robot
    description (``vibrissa.frame_buffer``). A source that knows them (a simulation, a
    motion-capture rig) may send them along as X_PC in ``pose_frame_id``: all three pose fields
    or none. Version 1 (poses in ``frame_id``) decodes as version 2 with ``pose_frame_id`` =
    that frame and the clamp frames ``<whisker>/clamp``.
    """

    TYPE_NAME: ClassVar[str] = "vibrissa/WhiskerWrenchArray"
    MAX_BYTES: ClassVar[int] = 1 << 20  # some 5 000 whiskers
    VERSION: ClassVar[int] = 2

    stamp: float = _stamp()
    seq: int = _count("the source's tick counter")
    whisker_ids: list[str] = _spec(kind=STR_LIST, length="N", doc="whisker of each row")
    frame_ids: list[str] = _spec(
        kind=STR_LIST, length="N", doc="clamp frame C each row is measured in, e.g. 'w0/clamp'")
    f0: FloatArray = _array(("N", 3), "N", "force of the clamp on the rod, expressed in its C")
    m0: FloatArray = _array(
        ("N", 3), "N m", "moment of the clamp on the rod about C's origin, expressed in its C"
    )
    pose_frame_id: str | None = _optional(
        kind=STR, doc="frame P of the clamp poses, e.g. 'world'; omitted without poses")
    clamp_position: FloatArray | None = _optional(
        kind=ARRAY, shape=("N", 3), unit="m", dtype=FLOAT64,
        doc="p_PC: each clamp frame C's origin in P, or omitted")
    clamp_orientation: FloatArray | None = _optional(
        kind=ARRAY, shape=("N", 4), dtype=FLOAT64,
        doc="R_PC: unit quaternion (x, y, z, w) of each C in P, z = rod axis, or omitted")

    def check_fields(self) -> None:
        _check_pose_fields(self)

    @property
    def has_pose(self) -> bool:
        """Whether the clamp poses came with the tick."""
        return self.pose_frame_id is not None


def _check_pose_fields(msg: WhiskerWrenchArray) -> None:
    present = [name for name in _POSE_FIELDS if getattr(msg, name) is not None]
    if present and len(present) != len(_POSE_FIELDS):
        missing = [name for name in _POSE_FIELDS if name not in present]
        raise ValueError(f"{type(msg).__name__}: the clamp pose needs {', '.join(_POSE_FIELDS)} "
                         f"together; {', '.join(missing)} missing")


_POSE_FIELDS = ("pose_frame_id", "clamp_position", "clamp_orientation")


@dataclass(frozen=True, eq=False)
class ContactPointArray(Message):
    """Contacts reconstructed from one WhiskerWrenchArray: only rows with a consistent contact
    (a single whisker's contact is a batch of one row), and which of the tick's other
    whiskers were free."""

    TYPE_NAME: ClassVar[str] = "vibrissa/ContactPointArray"
    MAX_BYTES: ClassVar[int] = 1 << 20  # some 6 000 whiskers with covariances
    VERSION: ClassVar[int] = 3

    stamp: float = _stamp()
    seq: int = _count("seq of the WhiskerWrenchArray these contacts were reconstructed from")
    frame_id: str = _frame_id()
    whisker_ids: list[str] = _spec(kind=STR_LIST, length="N", doc="which whisker touched, per row")
    point: FloatArray = _array(("N", 3), "m", "contact point on the rod, in frame_id")
    s1: FloatArray = _array(("N",), "m", "arc length of the contact along the rod from the clamp")
    phase: IntArray = _array(
        ("N",), "", "ContactPhase: 0 none, 1 tip, 2 tangential", dtype=INT32, enum=ContactPhase)
    force: FloatArray = _array(("N", 3), "N", "contact force on the rod, in frame_id")
    status: IntArray = _array(("N",), "", "ContactStatus bit flags; 0 = OK", dtype=INT32,
                              enum=ContactStatus)
    covariance: FloatArray | None = _optional(
        kind=ARRAY, shape=("N", 3, 3), unit="m^2", dtype=FLOAT64,
        doc="covariance of each point from the wrench noise, in frame_id; omitted without a "
        "noise model (version 1 has none)")
    free_ids: list[str] | None = _optional(
        kind=STR_LIST, doc="the tick's whiskers found free (a zero wrench, or below the contact "
        "detector's threshold); a whisker in neither list touched something that gives no "
        "single contact, or could not be placed; omitted by a producer that does not tell "
        "(versions 1 and 2 have none)")


@dataclass(frozen=True, eq=False)
class ContactCloud(Message):
    """Accumulated contact points; N = 0 is allowed."""

    TYPE_NAME: ClassVar[str] = "vibrissa/ContactCloud"
    VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = MAX_PAYLOAD_BYTES

    stamp: float = _stamp()
    frame_id: str = _frame_id()
    points: FloatArray = _array(("N", 3), "m", "contact points, in frame_id")
    normals: FloatArray = _array(
        ("N", 3), "", "surface normals at the points, in frame_id: unit, or zero when unknown"
    )
    whisker_ids: list[str] | None = _optional(
        kind=STR_LIST, length="N", doc="whisker of each point, or omitted"
    )


@dataclass(frozen=True, eq=False)
class SurfaceMesh(Message):
    """Triangle mesh of a surface fitted to a contact cloud."""

    TYPE_NAME: ClassVar[str] = "vibrissa/SurfaceMesh"
    VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = MAX_PAYLOAD_BYTES

    stamp: float = _stamp()
    frame_id: str = _frame_id()
    vertices: FloatArray = _array(("N", 3), "m", "mesh vertices, in frame_id")
    triangles: IntArray = _array(("M", 3), "", "vertex indices of each triangle", dtype=INT32)
    method: str = _text("surface fitting method")
    n_points: int = _count("number of cloud points the surface was fitted to")
    cloud_to_surface_max: float | None = _optional(
        kind=FLOAT, unit="m", doc="max distance cloud -> true surface, None when unknown"
    )
    cloud_to_surface_mean: float | None = _optional(
        kind=FLOAT, unit="m", doc="mean distance cloud -> true surface, None when unknown"
    )
    mesh_to_surface_max: float | None = _optional(
        kind=FLOAT, unit="m", doc="max distance mesh -> true surface, None when unknown"
    )
    mesh_to_surface_mean: float | None = _optional(
        kind=FLOAT, unit="m", doc="mean distance mesh -> true surface, None when unknown"
    )


@dataclass(frozen=True, eq=False)
class SweepProposal(Message):
    """Where to sweep next: a section of an object's estimated surface whose touch would cut
    its uncertainty most (``vibrissa.next_sweep``)."""

    TYPE_NAME: ClassVar[str] = "vibrissa/SweepProposal"
    VERSION: ClassVar[int] = 1

    stamp: float = _stamp()
    frame_id: str = _frame_id()
    object: str = _text("the object's name in the mapper's report")
    rank: int = _count("1 for the first proposal, 2 for the next (given the first), ...")
    axis: FloatArray = _array((3,), "", "unit normal of the section's plane, in frame_id")
    offset: float = _number("m", "the plane's offset along axis (a paper trail's y0)")
    line: FloatArray = _array(("N", 3), "m", "the section of the estimated surface, in order")
    std_on_line: float = _number("m", "largest predicted position std on the section")
    std_max_before: float = _number(
        "m", "largest predicted position std of the reachable surface before this proposal")
    std_max_after: float = _number(
        "m", "the same after this proposal (and the ones before it) were touched")


PATH_MODES = ("append", "replace")


@dataclass(frozen=True, eq=False)
class PathSegment(Message):
    """A path command for the robot base: waypoints X_WR of ``base_link`` in the world frame,
    driven in order from where the robot stands (or will stand, after the segments queued
    before), position linear and orientation slerp between them, each leg at ``speed_mps`` and
    ``turn_rate_rps`` at most (``vibrissa.paths.waypoint_samples``). Checked by the receiver
    (``vibrissa.paths.check_segment``), not on decode: a bad command is a counted rejection."""

    TYPE_NAME: ClassVar[str] = "vibrissa/PathSegment"
    VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 1 << 20  # some 15 000 waypoints

    stamp: float = _stamp()
    frame_id: str = _frame_id("frame W of the waypoints: the robot's map frame, 'world'")
    segment_id: int = _count("the commander's number of the segment (>= 0), for the log")
    mode: str = _text("'append': after the queued segments; 'replace': instead of them, "
                      "from where the robot is", choices=PATH_MODES)
    position: FloatArray = _array(("N", 3), "m", "p_WR: base_link's origin at each waypoint")
    orientation: FloatArray = _array(("N", 4), "", "R_WR at each waypoint: unit quaternion "
                                     "(x, y, z, w)")
    speed_mps: float = _number("m/s", "largest speed of base_link's origin (> 0)")
    turn_rate_rps: float = _number("rad/s", "largest turn rate of base_link (> 0)")


@dataclass(frozen=True, eq=False)
class SnapEvent(Message):
    """A jump of a whisker's equilibrium path between two samples of a simulated stream
    (`vibrissa.scene.snaps`): the wrench changes by more than a step of the continuation
    allows. Stamped as the wrench sample it is told at (``after``); wrenches in the clamp frame
    ``frame_id`` as the whisker's `WhiskerWrenchArray` rows, without noise, each pair left out
    where its sample is unresolved (Step 1 found no equilibrium there: the whisker's stream has
    no row for it)."""

    TYPE_NAME: ClassVar[str] = "vibrissa/SnapEvent"
    VERSION: ClassVar[int] = 1

    stamp: float = _stamp()
    whisker_id: str = _text("the whisker")
    frame_id: str = _frame_id("the whisker's clamp frame C, as its wrench rows")
    kind: str = _text("'snap-off', 'snap-through' (to another branch inside a contact) or "
                      "'landing' (on the sample after a snap-off)", choices=SNAP_KINDS)
    object: str = _text("the scene object of the contact")
    f0_before: FloatArray | None = _optional(
        kind=ARRAY, shape=(3,), unit="N", dtype=FLOAT64,
        doc="clamp force on the rod at the sample before, in C; omitted: unresolved there")
    m0_before: FloatArray | None = _optional(
        kind=ARRAY, shape=(3,), unit="N m", dtype=FLOAT64,
        doc="clamp moment about the clamp point at the sample before, in C; omitted: "
            "unresolved there")
    f0_after: FloatArray | None = _optional(
        kind=ARRAY, shape=(3,), unit="N", dtype=FLOAT64,
        doc="clamp force at the sample told, in C; omitted: unresolved there (a snap-off "
            "that no landing follows)")
    m0_after: FloatArray | None = _optional(
        kind=ARRAY, shape=(3,), unit="N m", dtype=FLOAT64,
        doc="clamp moment at the sample told, in C; omitted: unresolved there")


SENSOR_COMMANDS = ("bias",)


@dataclass(frozen=True, eq=False)
class SensorCommand(Message):
    """A request to a sensor driver on its command topic (``vibrissa sensor bias NAME``)."""

    TYPE_NAME: ClassVar[str] = "vibrissa/SensorCommand"
    VERSION: ClassVar[int] = 1

    stamp: float = _stamp()
    command: str = _text("'bias': tare the sensor, if its rod is free", choices=SENSOR_COMMANDS)
    sender: str = _text("who asks (a node or a tool), for the driver's log")


@dataclass(frozen=True, eq=False)
class RobotPose(Message):
    """Pose X_PC of frame child_frame_id (C) in frame_id (P)."""

    TYPE_NAME: ClassVar[str] = "vibrissa/RobotPose"
    VERSION: ClassVar[int] = 1

    stamp: float = _stamp()
    frame_id: str = _frame_id("parent frame P")
    child_frame_id: str = _text("child frame C")
    position: FloatArray = _array((3,), "m", "p_PC: C's origin in P")
    orientation: FloatArray = _array((4,), "", "R_PC as unit quaternion (x, y, z, w)")


@dataclass(frozen=True, eq=False)
class NodeStatus(Message):
    """Heartbeat of a node on /vibrissa/status (every 0.5 s)."""

    TYPE_NAME: ClassVar[str] = "vibrissa/NodeStatus"
    MAX_BYTES: ClassVar[int] = 1 << 20  # thousands of topics
    VERSION: ClassVar[int] = 2

    stamp: float = _stamp()
    node: str = _text("fully qualified node name, e.g. /whisker0/reconstruct")
    state: str = _text("starting | ready | running | finished | error", choices=NODE_STATES)
    counters: dict[str, int] = _spec(
        kind=STR_INT_MAP, doc="message counters: at least received, published, rejected, lost"
    )
    publishes: dict[str, str] = _spec(kind=STR_STR_MAP, doc="topic -> type name published")
    subscribes: dict[str, str] = _spec(
        kind=STR_STR_MAP, doc="topic -> type name subscribed ('*' for any type)"
    )
    seen_topics: list[str] = _spec(
        kind=STR_LIST, doc="topics on which the node has received anything, pings included"
    )
    message: str = field(default="", metadata={"spec": FieldSpec(kind=STR, doc="free text")})
    endpoints: dict[str, str] = field(default_factory=dict, metadata={"spec": FieldSpec(
        kind=STR_STR_MAP,
        doc="topic -> endpoint its direct publisher binds; subscribers connect there",
    )})
    seen_publishers: list[str] = field(default_factory=list, metadata={"spec": FieldSpec(
        kind=STR_LIST,
        doc="publisher ids (16 hex digits) the node has received anything from, pings included",
    )})


@dataclass(frozen=True, eq=False)
class EndOfStream(Message):
    """Last message of a source on a topic."""

    TYPE_NAME: ClassVar[str] = "vibrissa/EndOfStream"
    VERSION: ClassVar[int] = 1

    stamp: float = _stamp()
    source: str = _text("fully qualified name of the node that published the stream")
    count: int = _count("number of data messages the source published on this topic before")


@dataclass(frozen=True, eq=False)
class Ping(Message):
    """Readiness probe; subscribers note the topic as seen and never hand it to the node."""

    TYPE_NAME: ClassVar[str] = "vibrissa/Ping"
    VERSION: ClassVar[int] = 1

    stamp: float = _stamp()
    sender: str = _text("fully qualified name of the pinging node")


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.TYPE_NAME: cls
    for cls in (
        WhiskerWrenchArray,
        ContactPointArray,
        ContactCloud,
        SurfaceMesh,
        SweepProposal,
        PathSegment,
        SnapEvent,
        SensorCommand,
        RobotPose,
        NodeStatus,
        EndOfStream,
        Ping,
    )
}
