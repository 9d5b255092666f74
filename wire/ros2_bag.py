"""Vibrissa bags to ROS 2 bags and back, without ROS: rosbag2 folders with MCAP storage, CDR.

Export (:func:`export_ros2`) writes a rosbag2 folder (``metadata.yaml``, version 8, and one
``.mcap`` file, profile ``ros2``) with the message definitions of ROS 2 Jazzy embedded, which
``ros2 bag play`` and Foxglove read:

========================== ==================================== ==============================
vibrissa                   ROS 2                                topic
========================== ==================================== ==============================
WhiskerWrenchArray         one WrenchStamped per row            ``<topic>/<whisker>`` (1)
ContactPointArray          sensor_msgs/msg/PointCloud2          the same
ContactCloud               sensor_msgs/msg/PointCloud2          the same
RobotPose                  tf2_msgs/msg/TFMessage               ``/tf``
robot description mounts   tf2_msgs/msg/TFMessage (latched)     ``/tf_static``
SurfaceMesh                visualization_msgs/msg/Marker        the same
whisker names              std_msgs/msg/String (latched)        ``/vibrissa/whiskers``
========================== ==================================== ==============================

(1) A payload of the retired single type ``vibrissa/WhiskerWrench`` (``codec.RETIRED_TYPES``:
it decodes as an array of one row) goes to ``<topic>`` itself, as it always did.

Anything else (NodeStatus, EndOfStream, ...) is skipped and counted. ``header.stamp`` is the
message's own ``stamp`` (float s -> sec, nanosec, rounded to the nearest ns;
:func:`stamp_from_ros` gives the float back exactly for stamps that are the float nearest a
whole number of ns, such as a 500 Hz clock's).

**Times.** Each ROS message's log time is its ``header.stamp``, the sensor's time, not the time
the vibrissa bag recorded it: the messages are written in stamp order (held in memory for
that), so ``ros2 bag play --clock`` publishes the stamps' clock and plays at the sensor's pace
(rate 1: a simulated path at path speed, whatever the speed of its recording). The two
messages without a stamp of their own, the whisker names and the ``/tf_static`` mounts, are
logged (and the mounts stamped) at the first stamp, so the bag spans its stamps and nothing
else; the recording's clock (log times, NodeStatus) is not carried.

**Sign of the wrench.** vibrissa's ``f0``, ``m0`` are the clamp's reaction on the rod
(docs/ARCHITECTURE.md); a WrenchStamped holds what a force/torque sensor at the clamp reads,
the load of the rod on the sensor: ``force = -f0``, ``torque = -m0`` (N, N m, about the clamp
origin, in the clamp frame ``header.frame_id``). Import negates them back.

**Points.** A PointCloud2 is dense, little-endian, one row; fields ``x``, ``y``, ``z``
(float32, m, in ``header.frame_id``), ``whisker`` (uint16, the index of the point's whisker in
the bag's list of whisker names), and for contact points ``phase`` (uint8, ``ContactPhase``)
and ``s1`` (float32, m, arc length from the clamp). The list of whisker names is every name the
bag (and the robot description) holds, sorted, as a JSON list in the one std_msgs/String on
``/vibrissa/whiskers``, latched (transient local) like ``/tf_static``.

Import (:func:`import_ros2`) reads WrenchStamped topics (one whisker each) and ``/tf`` of a
ROS 2 bag into a vibrissa bag that ``wrench_source`` mode ``replay`` plays: a
WhiskerWrenchArray of one row per sample on one topic (clamp frame = ``header.frame_id``, sign
converted back) and a RobotPose per transform ``parent -> child`` on ``/tf`` (the
reconstructor's ``map_frame``, ``robot_frame``).
"""

from __future__ import annotations

import json
import math
import os
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt
import yaml
from mcap.records import Channel as McapChannel
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.stores import ros2_jazzy as ros

from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME, clamp_frame
from vibrissa.msgs import (
    ContactCloud,
    ContactPointArray,
    RobotPose,
    SurfaceMesh,
    WhiskerWrenchArray,
    codec,
)
from vibrissa.msgs import Message as WireMessage
from vibrissa.wire.bag import BagDamage, BagReader, BagWriter, check_bag_file

if TYPE_CHECKING:
    from vibrissa.scene import Whisker

__all__ = [
    "WHISKERS_TOPIC",
    "ExportResult",
    "ImportResult",
    "export_ros2",
    "import_ros2",
    "stamp_from_ros",
    "stamp_to_ros",
]

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
ROSBAG2_VERSION: Literal[8] = 8  # the newest that rosbags writes with QoS as rosbag2 < 9 reads it too

WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
MARKER = "visualization_msgs/msg/Marker"
STRING = "std_msgs/msg/String"

TF_TOPIC = "/tf"
TF_STATIC_TOPIC = "/tf_static"
WHISKERS_TOPIC = "/vibrissa/whiskers"

# What `ros2 bag record` stores for a latched topic (/tf_static): reliable, transient local,
# keep last 1, durations 0 = "the middleware's default" (infinite).
_ZERO = QosTime(0, 0)
LATCHED_QOS = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
                  _ZERO, _ZERO, QosLiveliness.AUTOMATIC, _ZERO, False)

# Layout of one contact point in a PointCloud2 (little-endian, packed as numpy packs it).
POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("whisker", "<u2"),
                        ("phase", "u1"), ("s1", "<f4")], align=False)
CLOUD_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("whisker", "<u2")])
_POINT_FIELD_TYPES = {np.dtype("<f4"): ros.sensor_msgs__msg__PointField.FLOAT32,
                      np.dtype("<u2"): ros.sensor_msgs__msg__PointField.UINT16,
                      np.dtype("u1"): ros.sensor_msgs__msg__PointField.UINT8}

_NS = 1_000_000_000


def stamp_to_ros(stamp: float) -> tuple[int, int]:
    """A stamp in s as ROS time (sec, nanosec), the nearest ns (exactly: no float product)."""
    if not math.isfinite(stamp):
        raise ValueError(f"stamp must be finite, got {stamp}")
    total = round(Fraction(stamp) * _NS)
    sec, nanosec = divmod(total, _NS)
    return int(sec), int(nanosec)


def stamp_from_ros(sec: int, nanosec: int) -> float:
    """ROS time as s: the float nearest sec + nanosec / 1e9 (inverse of :func:`stamp_to_ros`)."""
    return float(Fraction(int(sec) * _NS + int(nanosec), _NS))


def _header(stamp: float, frame_id: str) -> Any:
    sec, nanosec = stamp_to_ros(stamp)
    return ros.std_msgs__msg__Header(
        stamp=ros.builtin_interfaces__msg__Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _vector(v: npt.NDArray[np.float64]) -> Any:
    return ros.geometry_msgs__msg__Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _wrench(stamp: float, frame_id: str, f0: npt.NDArray[np.float64],
            m0: npt.NDArray[np.float64]) -> Any:
    """The sensor's reading: the rod's load on the clamp, -f0 and -m0 (see the module doc)."""
    return ros.geometry_msgs__msg__WrenchStamped(
        header=_header(stamp, frame_id),
        wrench=ros.geometry_msgs__msg__Wrench(force=_vector(-f0), torque=_vector(-m0)))


def _cloud(stamp: float, frame_id: str, rows: npt.NDArray[Any]) -> Any:
    layout = rows.dtype.fields
    assert layout is not None  # a structured dtype
    fields = [ros.sensor_msgs__msg__PointField(
        name=name, offset=int(spec[1]), datatype=_POINT_FIELD_TYPES[spec[0]], count=1)
        for name, spec in layout.items()]
    data = np.frombuffer(rows.tobytes(), dtype=np.uint8)
    return ros.sensor_msgs__msg__PointCloud2(
        header=_header(stamp, frame_id), height=1, width=len(rows), fields=fields,
        is_bigendian=False, point_step=rows.dtype.itemsize,
        row_step=rows.dtype.itemsize * len(rows), data=data, is_dense=True)


def _points(msg: ContactPointArray, index: Mapping[str, int]) -> npt.NDArray[Any]:
    rows = np.zeros(len(msg.whisker_ids), POINT_DTYPE)
    point = msg.point
    rows["x"], rows["y"], rows["z"] = point[:, 0], point[:, 1], point[:, 2]
    rows["whisker"] = [index[n] for n in msg.whisker_ids]
    rows["phase"] = msg.phase
    rows["s1"] = msg.s1
    return rows


def _cloud_points(msg: ContactCloud, index: Mapping[str, int]) -> npt.NDArray[Any]:
    if msg.whisker_ids is None:
        dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
        rows = np.zeros(len(msg.points), dtype)
    else:
        rows = np.zeros(len(msg.points), CLOUD_DTYPE)
        rows["whisker"] = [index[n] for n in msg.whisker_ids]
    rows["x"], rows["y"], rows["z"] = msg.points[:, 0], msg.points[:, 1], msg.points[:, 2]
    return rows


def _transform(stamp: float, parent: str, child: str, p: npt.NDArray[np.float64],
               q_xyzw: npt.NDArray[np.float64]) -> Any:
    return ros.geometry_msgs__msg__TransformStamped(
        header=_header(stamp, parent), child_frame_id=child,
        transform=ros.geometry_msgs__msg__Transform(
            translation=ros.geometry_msgs__msg__Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            rotation=ros.geometry_msgs__msg__Quaternion(
                x=float(q_xyzw[0]), y=float(q_xyzw[1]), z=float(q_xyzw[2]), w=float(q_xyzw[3]))))


def _marker(msg: SurfaceMesh, marker_id: int) -> Any:
    corners = msg.vertices[msg.triangles.reshape(-1)]
    zero = ros.builtin_interfaces__msg__Duration(sec=0, nanosec=0)
    return ros.visualization_msgs__msg__Marker(
        header=_header(msg.stamp, msg.frame_id), ns="vibrissa", id=marker_id,
        type=ros.visualization_msgs__msg__Marker.TRIANGLE_LIST,
        action=ros.visualization_msgs__msg__Marker.ADD,
        pose=ros.geometry_msgs__msg__Pose(
            position=ros.geometry_msgs__msg__Point(x=0.0, y=0.0, z=0.0),
            orientation=ros.geometry_msgs__msg__Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
        scale=ros.geometry_msgs__msg__Vector3(x=1.0, y=1.0, z=1.0),
        color=ros.std_msgs__msg__ColorRGBA(r=0.55, g=0.7, b=0.9, a=0.8),
        lifetime=zero, frame_locked=False,
        points=[ros.geometry_msgs__msg__Point(x=float(x), y=float(y), z=float(z))
                for x, y, z in corners.tolist()],
        colors=[], texture_resource="",
        texture=ros.sensor_msgs__msg__CompressedImage(
            header=_header(msg.stamp, msg.frame_id), format="", data=np.zeros(0, np.uint8)),
        uv_coordinates=[], text="", mesh_resource="",
        mesh_file=ros.visualization_msgs__msg__MeshFile(filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False)


def _whisker_names(msg: WireMessage) -> Iterable[str]:
    if isinstance(msg, (WhiskerWrenchArray, ContactPointArray)):
        return msg.whisker_ids
    if isinstance(msg, ContactCloud):
        return msg.whisker_ids or []
    return []


@dataclass
class ExportResult:
    """What :func:`export_ros2` wrote: ROS messages per topic, vibrissa messages skipped per
    type, the bag's list of whisker names (the ``whisker`` index of a point cloud), and what
    of the source bag could not be read."""

    path: Path
    written: Counter[str] = field(default_factory=Counter)
    skipped: Counter[str] = field(default_factory=Counter)
    whiskers: list[str] = field(default_factory=list)
    damage: BagDamage = field(default_factory=BagDamage)

    def summary(self) -> str:
        """One line: messages and topics written, messages skipped by type."""
        skipped = ", ".join(f"{n} {t}" for t, n in sorted(self.skipped.items())) or "none"
        return (f"wrote {sum(self.written.values())} ROS 2 messages on {len(self.written)} topics "
                f"to {self.path}; skipped {sum(self.skipped.values())} ({skipped})")


class _Ros2Out:
    """A rosbag2 Writer with one connection per (topic, type), made on first use."""

    def __init__(self, writer: Writer, result: ExportResult) -> None:
        self.writer = writer
        self.result = result
        self.connections: dict[tuple[str, str], Any] = {}

    def write(self, topic: str, msgtype: str, cdr: memoryview, t_ns: int,
              latched: bool = False) -> None:
        key = (topic, msgtype)
        if key not in self.connections:
            self.connections[key] = self.writer.add_connection(
                topic, msgtype, typestore=TYPESTORE,
                offered_qos_profiles=[LATCHED_QOS] if latched else [])
        self.writer.write(self.connections[key], t_ns, cdr)
        self.result.written[topic] += 1


def export_ros2(src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
                whiskers: Sequence[Whisker] = (), robot_frame: str = ROBOT_FRAME,
                topics: Iterable[str] | None = None) -> ExportResult:
    """Write the vibrissa bag ``src`` as the rosbag2 folder ``dst`` (which must not exist).

    Parameters
    ----------
    src
        A vibrissa ``.mcap`` bag (a damaged or cut-off one as far as it reads; what does not
        read is logged as a warning and in the result's ``damage``).
    dst
        The rosbag2 folder to create.
    whiskers
        The robot description: each whisker's mount X_RC goes to ``/tf_static`` as
        ``robot_frame -> <whisker>/clamp`` at the first stamp.
    robot_frame
        The parent frame of the mounts.
    topics
        Only these topics of ``src``; all when None.

    Raises
    ------
    FileNotFoundError, ValueError
        ``src`` is no bag, ``dst`` exists, or a stamp is before 1970 (a log time cannot be).
    """
    reader = BagReader(src, topics=topics)
    out = Path(dst)
    if out.exists():
        raise ValueError(f"{out} exists; a ROS 2 bag is written to a new folder")
    names = {w.name for w in whiskers}
    for rec in reader:
        if codec.decodes_as(rec.type_name) in _NAMED:
            names.update(_whisker_names(codec.decode(rec.payload)))
    result = ExportResult(path=out, whiskers=sorted(names))
    index = {name: i for i, name in enumerate(result.whiskers)}
    converted: list[tuple[int, str, str, memoryview]] = []  # (log time = stamp ns, topic, type, CDR)
    markers: dict[str, int] = {}
    for rec in BagReader(src, topics=topics):
        if codec.decodes_as(rec.type_name) not in _EXPORTED:
            result.skipped[rec.type_name] += 1
            continue
        row_topics = rec.type_name not in codec.RETIRED_TYPES
        for topic, msgtype, ros_msg in _convert(rec.topic, codec.decode(rec.payload), index,
                                                 markers, row_topics):
            converted.append((_stamp_ns(ros_msg), topic, msgtype,
                              TYPESTORE.serialize_cdr(ros_msg, msgtype)))
    converted.sort(key=lambda m: m[0])  # stable: one stamp keeps the recorded order
    if converted and converted[0][0] < 0:
        _, topic, msgtype, _ = converted[0]
        raise ValueError(f"a {msgtype} on {topic} is stamped {converted[0][0] / _NS:g} s, before "
                         "1970: its stamp cannot be the log time of a ROS 2 bag")
    writer = Writer(out, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
    try:
        writer.open()
    except WriterError as exc:
        raise ValueError(str(exc)) from None
    ros_out = _Ros2Out(writer, result)
    try:
        t0 = converted[0][0] if converted else 0
        if result.whiskers:
            names_msg = ros.std_msgs__msg__String(data=json.dumps(result.whiskers))
            ros_out.write(WHISKERS_TOPIC, STRING, TYPESTORE.serialize_cdr(names_msg, STRING), t0,
                          True)
        if whiskers:
            stamp = stamp_from_ros(*divmod(t0, _NS))
            mounts = [_transform(stamp, robot_frame, clamp_frame(w.name), w.X_RC.translation,
                                 w.X_RC.rotation.as_quat()) for w in whiskers]
            static = ros.tf2_msgs__msg__TFMessage(transforms=mounts)
            ros_out.write(TF_STATIC_TOPIC, TF_MESSAGE, TYPESTORE.serialize_cdr(static, TF_MESSAGE),
                          t0, True)
        for t_ns, topic, msgtype, cdr in converted:
            ros_out.write(topic, msgtype, cdr, t_ns)
    finally:
        writer.close()
    result.damage = reader.report_damage("exported")
    return result


def _stamp_ns(ros_msg: Any) -> int:
    """The ROS message's stamp in ns: its header's (a TFMessage's: its first transform's)."""
    header = ros_msg.transforms[0].header if hasattr(ros_msg, "transforms") else ros_msg.header
    return int(header.stamp.sec) * _NS + int(header.stamp.nanosec)


def _convert(topic: str, msg: WireMessage, index: Mapping[str, int], markers: dict[str, int],
             row_topics: bool = True) -> Iterator[tuple[str, str, Any]]:
    """(ROS topic, ROS type, ROS message) for one vibrissa message of an exported type; a
    wrench row goes to ``<topic>/<whisker>``, or to ``topic`` without ``row_topics``."""
    if isinstance(msg, WhiskerWrenchArray):
        for name, frame_id, f0, m0 in zip(msg.whisker_ids, msg.frame_ids, msg.f0, msg.m0,
                                          strict=True):
            row_topic = f"{topic.rstrip('/')}/{name}" if row_topics else topic
            yield row_topic, WRENCH_STAMPED, _wrench(msg.stamp, frame_id, f0, m0)
    elif isinstance(msg, ContactPointArray):
        yield topic, POINT_CLOUD2, _cloud(msg.stamp, msg.frame_id, _points(msg, index))
    elif isinstance(msg, ContactCloud):
        yield topic, POINT_CLOUD2, _cloud(msg.stamp, msg.frame_id, _cloud_points(msg, index))
    elif isinstance(msg, RobotPose):
        yield TF_TOPIC, TF_MESSAGE, ros.tf2_msgs__msg__TFMessage(transforms=[_transform(
            msg.stamp, msg.frame_id, msg.child_frame_id, msg.position, msg.orientation)])
    elif isinstance(msg, SurfaceMesh):
        marker_id = markers.setdefault(topic, len(markers))
        yield topic, MARKER, _marker(msg, marker_id)


_EXPORTED = (WhiskerWrenchArray, ContactPointArray, ContactCloud, RobotPose, SurfaceMesh)
_NAMED = (WhiskerWrenchArray, ContactPointArray, ContactCloud)


@dataclass
class ImportResult:
    """What :func:`import_ros2` wrote: wrench samples per whisker, RobotPose count, and the
    /tf transforms that were not the robot's pose (parent -> child: count); what was left out
    or lost per topic, and what of the bag's MCAP files did not read (``damage``)."""

    path: Path
    wrenches: Counter[str] = field(default_factory=Counter)
    poses: int = 0
    other_transforms: Counter[str] = field(default_factory=Counter)
    refused: Counter[str] = field(default_factory=Counter)  # topic -> messages left out
    undecodable: Counter[str] = field(default_factory=Counter)  # topic -> bad payloads
    unread: Counter[str] = field(default_factory=Counter)  # topic -> listed, never read
    damage: BagDamage = field(default_factory=BagDamage)  # what of the bag's files did not read

    @property
    def lost(self) -> int:
        """Messages of the wanted topics that the bag lists but that did not come through
        (damaged records or payloads); NaN or inf samples, refused on purpose, are not."""
        return sum(self.undecodable.values()) + sum(self.unread.values())

    def summary(self) -> str:
        """One line: wrenches per whisker, poses, transforms and messages left out."""
        per = ", ".join(f"{w} {n}" for w, n in sorted(self.wrenches.items()))
        other = sum(self.other_transforms.values())
        line = (f"wrote {sum(self.wrenches.values())} wrench sample(s) ({per}) and {self.poses} "
                f"RobotPose to {self.path}; {other} other /tf transform(s) left out")
        if self.refused:
            line += "; refused by the codec (NaN, inf or a bad name): " + ", ".join(
                f"{t} {n}" for t, n in sorted(self.refused.items()))
        if self.undecodable:
            line += "; LOST, payload that does not decode: " + ", ".join(
                f"{t} {n}" for t, n in sorted(self.undecodable.items()))
        if self.unread:
            line += "; LOST, listed in the bag's metadata but not readable: " + ", ".join(
                f"{t} {n}" for t, n in sorted(self.unread.items()))
        if self.damage:
            line += f"; DAMAGED bag: {self.damage.note('imported')}"
        return line


def wrench_topics_of(src: str | os.PathLike[str]) -> list[str]:
    """The geometry_msgs/msg/WrenchStamped topics of the ROS 2 bag ``src``, sorted.

    Raises ``FileNotFoundError`` (nothing at ``src``) or ``ValueError`` (not a readable bag).
    """
    with _open_reader(src) as reader:
        return sorted({c.topic for c in reader.connections if c.msgtype == WRENCH_STAMPED})


@contextmanager
def _open_reader(src: str | os.PathLike[str]) -> Iterator[AnyReader | _DamagedMcap]:
    """The ROS 2 bag ``src`` open; `FileNotFoundError` when nothing is there, `ValueError`
    naming it when its files do not read (any error of the reader on their bytes: a damaged
    or hostile file can make it raise anything from ``KeyError`` to ``MemoryError``). An MCAP
    bag that rosbags refuses (cut off, its summary damaged) is read as far as it reads:
    `_DamagedMcap`."""
    path = Path(src)
    if not path.exists():
        raise FileNotFoundError(f"no ROS 2 bag at {path}")
    reader = AnyReader([path], default_typestore=TYPESTORE)
    try:
        reader.open()
    except Exception as exc:  # noqa: BLE001 - see above
        why = (str(exc).splitlines() or [type(exc).__name__])[0]
        damaged = _DamagedMcap.of(path, why)
        if damaged is None:
            raise ValueError(f"{path} is not a readable ROS 2 bag: {why}") from None
        yield damaged
        return
    try:
        yield reader
    finally:
        reader.close()


@dataclass(frozen=True)
class _Listed:
    """A topic as a bag's metadata.yaml lists it."""

    topic: str
    msgtype: str
    msgcount: int


class _DamagedMcap:
    """A rosbag2 folder of uncompressed MCAP files that rosbags does not open, read as
    `vibrissa.wire.bag.BagReader` reads a bag: the files' records in order up to the damage
    (complete chunks, damaged chunks skipped); the topics from metadata.yaml. The reader
    interface of ``AnyReader`` that `import_ros2` uses, and ``damage`` after `messages`."""

    def __init__(self, files: list[Path], connections: list[_Listed]) -> None:
        self.files = files
        self.connections = connections
        self.damage = BagDamage()

    @classmethod
    def of(cls, path: Path, why: str) -> _DamagedMcap | None:
        """The bag at ``path`` if its metadata.yaml reads and names uncompressed MCAP files
        that start with an MCAP header, else None; `ValueError` for a file cut inside its
        header (nothing in it can be read)."""
        try:
            info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
            if info["storage_identifier"] != "mcap" or (info.get("compression_mode") or "none").lower() != "none":
                return None
            files = [path / PurePath(name).name for name in info["relative_file_paths"]]
            connections = [_Listed(str(t["topic_metadata"]["name"]), str(t["topic_metadata"]["type"]),
                                   int(t["message_count"])) for t in info["topics_with_message_count"]]
        except Exception:  # noqa: BLE001 - metadata.yaml damaged too: the bag does not read
            return None
        for file in files:
            if not file.is_file():
                return None
            size = file.stat().st_size
            with open(file, "rb") as f:
                head = f.read(_MCAP_HEADER_AT)
            if head[:len(_MCAP_MAGIC)] != _MCAP_MAGIC[:len(head)]:
                return None
            whole = (len(head) == _MCAP_HEADER_AT and head[len(_MCAP_MAGIC)] == _MCAP_HEADER_OP
                     and size >= _MCAP_HEADER_AT + int.from_bytes(head[-8:], "little"))
            if not whole:
                raise ValueError(f"{path} is not a readable ROS 2 bag: {file.name} is cut off "
                                 f"inside its MCAP header ({size} bytes; {why})")
        return cls(files, connections)

    def messages(self, connections: Sequence[_Listed]) -> Iterator[tuple[_Listed, int, bytes]]:
        """(connection, log time ns, CDR bytes) of ``connections``' readable messages."""
        by_topic = {c.topic: c for c in connections}
        damaged_chunks = unreadable = 0
        truncated = False
        for file in self.files:
            reader = BagReader(file, topics=by_topic)
            for record in reader:
                yield by_topic[record.topic], record.log_time_ns, record.payload
            damaged_chunks += reader.damaged_chunks
            truncated = truncated or reader.truncated
            unreadable += reader.unreadable_bytes
            if reader.truncated:  # the messages of an uncompressed chunk cut off
                for topic, t_ns, payload in _cut_chunk(file, reader.unreadable_bytes):
                    if topic in by_topic:
                        yield by_topic[topic], t_ns, payload
        self.damage = BagDamage(damaged_chunks, truncated, unreadable)

    @staticmethod
    def deserialize(raw: bytes, msgtype: str) -> Any:
        return TYPESTORE.deserialize_cdr(raw, msgtype)


def _cut_chunk(file: Path, unreadable: int) -> list[tuple[str, int, bytes]]:
    """(topic, log time ns, payload) of the whole messages in the uncompressed chunk that the
    file's last ``unreadable`` bytes begin with (rosbags writes uncompressed chunks of 1 MiB:
    a cut in one loses only what follows the cut), in log-time order; none for anything else.
    The channels are those of the file's records that read."""
    channels: dict[int, str] = {}
    with open(file, "rb") as f:
        try:
            for record in StreamReader(f, emit_chunks=False, validate_crcs=False).records:
                if isinstance(record, McapChannel):
                    channels[record.id] = record.topic
        except Exception:  # noqa: BLE001 - the damage: the channels up to it are what counts
            pass
        f.seek(file.stat().st_size - unreadable)
        tail = f.read()
    # chunk: opcode, length u64, start u64, end u64, uncompressed size u64, crc u32,
    # compression (u32 length + bytes), records length u64, records
    if len(tail) < 41 or tail[0] != _MCAP_CHUNK_OP or tail[37:41] != b"\0\0\0\0":
        return []
    out: list[tuple[str, int, bytes]] = []
    at = 49
    while at + 9 <= len(tail):
        op, length = tail[at], int.from_bytes(tail[at + 1:at + 9], "little")
        body = tail[at + 9:at + 9 + length]
        if len(body) < length:
            break
        if op == _MCAP_CHANNEL_OP and len(body) >= 8:
            n = int.from_bytes(body[4:8], "little")
            channels[int.from_bytes(body[:2], "little")] = body[8:8 + n].decode(errors="replace")
        elif op == _MCAP_MESSAGE_OP and len(body) >= 22:
            topic = channels.get(int.from_bytes(body[:2], "little"))
            if topic is not None:
                out.append((topic, int.from_bytes(body[6:14], "little"), body[22:]))
        at += 9 + length
    return sorted(out, key=lambda m: m[1])


_MCAP_CHUNK_OP, _MCAP_CHANNEL_OP, _MCAP_MESSAGE_OP = 0x06, 0x04, 0x05
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_MCAP_HEADER_OP = 0x01
_MCAP_HEADER_AT = len(_MCAP_MAGIC) + 9  # the magic, the header's opcode and length


def import_ros2(src: str | os.PathLike[str], dst: str | os.PathLike[str],
                wrench_topics: Mapping[str, str], *, topic: str = "/robot/wrench",
                pose_topic: str = "/robot/pose", map_frame: str = WORLD_FRAME,
                robot_frame: str = ROBOT_FRAME) -> ImportResult:
    """Write the ROS 2 bag ``src`` as a vibrissa bag ``dst`` that ``wrench_source`` replays.

    Parameters
    ----------
    src
        A rosbag2 folder (any storage rosbags reads: mcap, sqlite3); an MCAP bag cut off or
        damaged is read as far as it reads (its complete chunks, in order), the damage in the
        result's ``damage``.
    dst
        The vibrissa ``.mcap`` bag to write (overwritten).
    wrench_topics
        ROS topic of geometry_msgs/msg/WrenchStamped -> name of its whisker. Each sample
        becomes a WhiskerWrenchArray of one row on ``topic`` in the clamp frame ``header.frame_id``
        (``<whisker>/clamp`` when empty), stamped ``header.stamp``, f0 = -force, m0 = -torque.
    topic, pose_topic
        The vibrissa topics of the wrenches and of the robot's poses.
    map_frame, robot_frame
        The /tf transform ``map_frame -> robot_frame`` (header.frame_id -> child_frame_id)
        becomes a RobotPose on ``pose_topic``; other transforms are counted and left out.

    Returns
    -------
    ImportResult
        What was written, and per topic what was not: refused by the codec, and ``lost``
        (payloads that do not decode, messages the bag's metadata lists but that were not read).

    Raises
    ------
    FileNotFoundError
        Nothing at ``src``.
    ValueError
        ``src`` is not a readable ROS 2 bag (an MCAP file cut inside its header; records of
        another storage that do not read from some point on: nothing is written then), a
        wrench topic is missing or of another type, /tf is of another type, or it has
        transforms but none ``map_frame -> robot_frame``.
    """
    path = Path(src)
    if not wrench_topics:
        raise ValueError("name at least one wrench topic")
    result = ImportResult(path=Path(dst))
    try:
        with _open_reader(path) as reader:
            found = {c.topic: c.msgtype for c in reader.connections}
            for ros_topic in wrench_topics:
                if ros_topic not in found:
                    raise ValueError(f"{path} has no topic {ros_topic} (it has: "
                                     f"{', '.join(sorted(found)) or 'none'})")
                if found[ros_topic] != WRENCH_STAMPED:
                    raise ValueError(f"{path}: topic {ros_topic} is {found[ros_topic]}, "
                                     f"expected {WRENCH_STAMPED}")
            if TF_TOPIC in found and found[TF_TOPIC] != TF_MESSAGE:
                raise ValueError(f"{path}: topic {TF_TOPIC} is {found[TF_TOPIC]}, "
                                 f"expected {TF_MESSAGE}")
            wanted = [c for c in reader.connections if c.topic in wrench_topics or c.topic == TF_TOPIC]
            listed: Counter[str] = Counter()
            for c in wanted:
                listed[c.topic] += c.msgcount
            read: Counter[str] = Counter()
            seq: Counter[str] = Counter()
            with BagWriter(dst, flush_interval_s=math.inf) as out:
                for connection, t_ns, raw in _records(reader, wanted, path, read):
                    read[connection.topic] += 1
                    try:
                        msg: Any = reader.deserialize(raw, connection.msgtype)
                    except Exception:  # noqa: BLE001 - damaged bytes: any error of the decoder
                        result.undecodable[connection.topic] += 1
                        continue
                    if connection.topic == TF_TOPIC:
                        for tf in msg.transforms:
                            if tf.header.frame_id != map_frame or tf.child_frame_id != robot_frame:
                                result.other_transforms[f"{tf.header.frame_id} -> "
                                                        f"{tf.child_frame_id}"] += 1
                                continue
                            try:
                                data = codec.encode(_robot_pose(tf))
                            except ValueError:  # NaN or inf: the codec refuses it
                                result.refused[TF_TOPIC] += 1
                                continue
                            out.write(pose_topic, data, t_ns, sequence=result.poses)
                            result.poses += 1
                        continue
                    name = wrench_topics[connection.topic]
                    try:
                        data = codec.encode(_whisker_wrench(msg, name, seq[name]))
                    except ValueError:  # NaN, inf or a bad frame name: the codec refuses it
                        result.refused[connection.topic] += 1
                        continue
                    out.write(topic, data, t_ns, sequence=seq[name])
                    seq[name] += 1
                    result.wrenches[name] += 1
            result.unread = +(listed - read)
            if isinstance(reader, _DamagedMcap):
                result.damage = reader.damage
    except _Damaged as exc:
        Path(dst).unlink(missing_ok=True)
        raise ValueError(str(exc)) from None
    if TF_TOPIC in found and result.other_transforms and not result.poses:
        Path(dst).unlink(missing_ok=True)
        raise ValueError(f"{path}: no transform {map_frame} -> {robot_frame} on {TF_TOPIC} "
                         f"(it has: {', '.join(sorted(result.other_transforms))})")
    check_bag_file(dst)
    return result


class _Damaged(Exception):
    """The bag's records cannot be read on from some point."""


def _records(reader: AnyReader | _DamagedMcap, connections: list[Any], path: Path,
             read: Counter[str]
             ) -> Iterator[tuple[Any, int, bytes]]:
    """``reader.messages(connections)``; a damaged record (any error of the reader on the
    file's bytes) ends it with `_Damaged`, naming how far it got."""
    records = reader.messages(connections=connections)
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except Exception as exc:  # noqa: BLE001 - damaged bytes: any error of the reader
            raise _Damaged(f"{path} is not a readable ROS 2 bag: a damaged record after "
                           f"{sum(read.values())} message(s): {type(exc).__name__}: "
                           f"{(str(exc).splitlines() or [''])[0]}") from None
        yield record


def _whisker_wrench(msg: Any, name: str, seq: int) -> WhiskerWrenchArray:
    w = msg.wrench
    return WhiskerWrenchArray(
        stamp=stamp_from_ros(msg.header.stamp.sec, msg.header.stamp.nanosec), seq=seq,
        whisker_ids=[name], frame_ids=[msg.header.frame_id or clamp_frame(name)],
        f0=-np.array([[w.force.x, w.force.y, w.force.z]]),
        m0=-np.array([[w.torque.x, w.torque.y, w.torque.z]]))


def _robot_pose(tf: Any) -> RobotPose:
    p, q = tf.transform.translation, tf.transform.rotation
    return RobotPose(stamp=stamp_from_ros(tf.header.stamp.sec, tf.header.stamp.nanosec),
                     frame_id=tf.header.frame_id, child_frame_id=tf.child_frame_id,
                     position=np.array([p.x, p.y, p.z]), orientation=np.array([q.x, q.y, q.z, q.w]))
