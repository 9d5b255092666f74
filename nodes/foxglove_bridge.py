"""Foxglove bridge node: serves the running graph to the Foxglove app over its WebSocket protocol.

Needs the optional extra ``view`` (``pip install 'vibrissa[view]'``, the ``foxglove-sdk``
package); without it the node exits at start with one line naming the extra. It serves
``ws://host:port`` (default ``ws://127.0.0.1:8765``, loopback unless ``host`` says otherwise;
``port`` 0 takes a free port) and logs the address; ``launch/foxglove_layout.json`` is a layout
for it.

Subscribes
----------
``wrench_topics`` (default ``[/robot/wrench]``) : WhiskerWrenchArray
``contact_topics`` (default ``[/robot/contact]``) : ContactPointArray
``pose_topic`` (default ``/robot/pose``) : RobotPose
``cloud_topic`` (default ``/contact_cloud``) : ContactCloud, the mapper's
``mesh_topic`` (default ``/surface_mesh``) : SurfaceMesh, the mapper's map of a frame, its
    known part; its ``EndOfStream`` starts the ``hold_s`` countdown
``unknown_mesh_topic`` (default ``/surface_mesh_unknown``) : SurfaceMesh, the unknown part of
    the mapper's map of a frame (its triangles whose std is above the mapper's limit)
``/vibrissa/status`` : NodeStatus of every node

Serves (Foxglove channels)
--------------------------
``/whiskers/<whisker>/wrench`` : JSON ``{stamp, seq, frame_id, f0: {x, y, z}, m0: {x, y, z}}``
    Every wrench row as it arrives (N, N m, in the whisker's clamp frame), one channel per
    whisker: those of the robot description's whiskers from the start, any other's when it
    first appears.
``/contacts`` : foxglove.PointCloud
    Every contact point so far in ``map_frame`` (fields x, y, z float32 m; ``whisker``
    float32, the whisker's index in order of appearance, for the colour), growing every
    ``period_s``.
``/tf`` : foxglove.FrameTransforms
    Each RobotPose (``world`` -> ``base_link``), and every ``REPUBLISH_S`` the mounts of the
    robot description ``robot`` (``base_link`` -> ``<whisker>/clamp``, X_RC).
``/map/cloud`` : foxglove.PointCloud
    The mapper's cloud (x, y, z, nx, ny, nz float32: points and contact normals).
``/meshes`` : foxglove.SceneUpdate
    Two entities per mesh frame, each a TriangleListPrimitive: the known part
    (``mesh/<frame_id>``, blue) and the unknown part (``mesh_unknown/<frame_id>``, grey and
    translucent). Each SurfaceMesh replaces its part's entity, so the surface grows with the
    mapper's updates; one with no triangles deletes it.
``/health`` : JSON ``{stamp, nodes: [{node, state, received, published, lost, rejected,
    received_hz, published_hz, message}]}``
    Every node's last status, the rates from its last two statuses.

Clients that connect late see the state: the cloud, the mounts, the map cloud and the meshes
go out again every ``REPUBLISH_S``. Every Foxglove message is stamped with the bridge's wall
clock at arrival (one clock for the 3D panel's frame lookups and the plots); the graph's own
stamp is the JSON's ``stamp``. Contacts in a frame other than ``map_frame`` are counted
(``other_frame``), not shown. Counters in the node's status: ``wrenches`` (rows),
``contacts`` (points), ``other_frame``, ``poses``, ``meshes`` (both parts), ``bad_meshes`` (a
triangle indexing past the vertices: counted, not shown), ``clouds``, ``statuses``. Undecodable input is
rejected by the transport (``rejected``); input the bridge misses (it is a viewer, a launch
gives it ``allow_loss``) is counted as ``lost``.

Foxglove's WebSocket protocol has no authentication: any local user who reaches the port sees
every channel. So on a graph with keys (``VIBRISSA_KEYS``) the bridge refuses to start (exit 2)
unless ``allow_unauthenticated_view`` is true, and then says so in a warning: the keys protect
the graph's sockets, not the view. The view speaks the subprotocol ``foxglove.sdk.v1`` only
(`SUBPROTOCOL`: foxglove-sdk's server takes no other); a client that offers only
``foxglove.websocket.v1`` (an older Foxglove app) is refused with HTTP 400. Clients refused at
the handshake (another subprotocol, not a WebSocket) are counted (``refused_clients``) and
logged at most once per ``REFUSED_LOG_S``, with that hint.

With ``hold_s`` >= 0 the node ends (exit 0) ``hold_s`` seconds after the mapper's
``EndOfStream`` on ``mesh_topic``, so a launch that ends on it (``on_exit: shutdown``,
``launch/view.yaml``) shows the final map for that long; otherwise it serves until stopped.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from vibrissa.formats.scene_file import load_robot
from vibrissa.frames import ROBOT_FRAME, WORLD_FRAME, Transform, clamp_frame
from vibrissa.msgs import (
    ContactCloud,
    ContactPointArray,
    EndOfStream,
    Message,
    NodeStatus,
    RobotPose,
    SurfaceMesh,
    WhiskerWrenchArray,
    codec,
)
from vibrissa.runtime import Node, NodeArgs, ParamError, configure_logging, load_params, run_main
from vibrissa.runtime.params import require, require_parsed, require_positive
from vibrissa.wire.bag import BagReader
from vibrissa.wire.security import KEYS_ENV, Keys
from vibrissa.wire.topics import STATUS_TOPIC, resolve_topic, validate_name

if TYPE_CHECKING:
    from foxglove import Channel
    from foxglove.channels import FrameTransformsChannel, PointCloudChannel, SceneUpdateChannel
    from foxglove.messages import FrameTransform, PointCloud, SceneUpdate

log = logging.getLogger(__name__)

EXTRA = "view"
"""The optional extra that installs what the node needs (``pip install 'vibrissa[view]'``)."""

SUBPROTOCOL = "foxglove.sdk.v1"
"""The WebSocket subprotocol the view accepts, the only one foxglove-sdk's server takes (it has
no setting for another): a client that offers only ``foxglove.websocket.v1`` (the same
protocol under its older name: older Foxglove apps, ws-protocol clients) is refused with HTTP
400 at the handshake."""

REFUSED_HINT = (f"the view speaks the WebSocket subprotocol {SUBPROTOCOL} only: a client that "
                "offers only foxglove.websocket.v1 (an older Foxglove app) is refused")
"""Said when the view starts and with each line about refused clients."""

REPUBLISH_S = 1.0
"""Period of the state sent again for clients that connect late (mounts, cloud, map), s."""

MAX_NAMES = 4096
"""The most frames, nodes and whiskers the bridge keeps state for; more are counted
(``refused_names``) and not shown."""

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class FoxgloveBridgeParams:
    """Parameters of the Foxglove bridge (``--param KEY:=VALUE`` or the launch file).

    host, port
        Where the WebSocket server listens; port 0: a free port (logged).
    wrench_topics, contact_topics, pose_topic, cloud_topic, mesh_topic, unknown_mesh_topic
        The graph's topics to show (see the module docstring).
    robot
        Robot description (a scene file) for the mount frames; empty: no mounts.
    map_frame, robot_frame
        The frame of the contact cloud, and the robot's body frame (parent of the mounts).
    period_s
        How often the growing cloud and the health table go out, s.
    hold_s
        Seconds to serve on after the mapper's end of stream, then exit 0; negative: serve
        until stopped.
    max_cloud_points
        The live contact cloud shows the newest this many points; the older ones leave the
        view (counted: ``cloud_aged_out``), so that a long run keeps the memory and each
        cloud message bounded.
    allow_unauthenticated_view
        Serve a graph that has keys although Foxglove clients are not authenticated (anyone
        on the machine who reaches ``host:port`` sees the graph); false: refuse to start.
    """

    host: str = "127.0.0.1"
    port: int = 8765
    wrench_topics: tuple[str, ...] = ("/robot/wrench",)
    contact_topics: tuple[str, ...] = ("/robot/contact",)
    pose_topic: str = "/robot/pose"
    cloud_topic: str = "/contact_cloud"
    mesh_topic: str = "/surface_mesh"
    unknown_mesh_topic: str = "/surface_mesh_unknown"
    robot: str = ""
    map_frame: str = WORLD_FRAME
    robot_frame: str = ROBOT_FRAME
    period_s: float = 0.2
    hold_s: float = -1.0
    max_cloud_points: int = 1_000_000
    allow_unauthenticated_view: bool = False

    def __post_init__(self) -> None:
        require(bool(self.host), "host", self.host, "a host name or address")
        require(0 <= self.port <= 65535, "port", self.port, "a port in [0, 65535] (0: any free)")
        for topic in (*self.wrench_topics, *self.contact_topics, self.pose_topic,
                      self.cloud_topic, self.mesh_topic, self.unknown_mesh_topic):
            require_parsed("topics", topic, validate_name)
        require(self.unknown_mesh_topic != self.mesh_topic, "unknown_mesh_topic",
                self.unknown_mesh_topic, "a topic other than mesh_topic")
        if self.robot:
            require_parsed("robot", self.robot, load_robot)
        for key in ("map_frame", "robot_frame"):
            require(bool(getattr(self, key)), key, getattr(self, key), "a frame name")
        require_positive("period_s", self.period_s)
        require(self.max_cloud_points >= 1, "max_cloud_points", self.max_cloud_points,
                "a count >= 1")


PARAMS = FoxgloveBridgeParams
"""The node's parameter dataclass: the launcher checks a launch file's values with it."""


REFUSED_LOG_S = 10.0
"""Seconds between two log lines about refused clients (a client retrying in a loop)."""


class RefusedClients(logging.Filter):
    """Counts the Foxglove server's refused handshakes into ``counters["refused_clients"]`` and
    lets one log line through per `REFUSED_LOG_S`, with the count since the last."""

    def __init__(self, counters: dict[str, int], clock: Any = time.monotonic) -> None:
        super().__init__()
        self._counters = counters
        self._clock = clock
        self._last = -math.inf
        self._logged = 0
        counters.setdefault("refused_clients", 0)

    def filter(self, record: logging.LogRecord) -> bool:
        if "handshake failed" not in record.getMessage():
            return True
        self._counters["refused_clients"] += 1
        if self._clock() - self._last < REFUSED_LOG_S:
            return False
        self._last = self._clock()
        refused = self._counters["refused_clients"]
        record.msg, record.args = ("refused %d client(s) at the handshake (%d so far; the last: "
                                   "%s; %s)", (refused - self._logged, refused,
                                               record.getMessage(), REFUSED_HINT))
        record.levelno, record.levelname = logging.WARNING, "WARNING"
        self._logged = refused
        return True


def refuse_keyed_graph(params: FoxgloveBridgeParams, environ: Mapping[str, str]) -> None:
    """`ParamError` if the graph has keys (``VIBRISSA_KEYS``) and the view would serve it to
    unauthenticated clients without ``allow_unauthenticated_view``."""
    if environ.get(KEYS_ENV) and not params.allow_unauthenticated_view:
        raise ParamError("the graph has keys, but Foxglove clients are not authenticated: any "
                         "local user could watch it; set allow_unauthenticated_view:=true to "
                         "serve it anyway")


def import_foxglove() -> ModuleType:
    """The ``foxglove`` package (foxglove-sdk), or an ImportError that names the extra."""
    try:
        import foxglove
        import foxglove.channels
        import foxglove.messages
    except ImportError as exc:
        raise ImportError(f"the Foxglove bridge needs the optional extra '{EXTRA}': "
                          f"pip install 'vibrissa[{EXTRA}]' ({exc})") from None
    return foxglove


_VEC3_SCHEMA = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
WRENCH_SCHEMA: dict[str, Any] = {
    "title": "vibrissa.WhiskerWrenchRow",
    "description": "One whisker's base wrench: f0 (N) and m0 (N m) in its clamp frame",
    "type": "object",
    "properties": {"stamp": {"type": "number"}, "seq": {"type": "integer"},
                   "frame_id": {"type": "string"}, "f0": _VEC3_SCHEMA, "m0": _VEC3_SCHEMA},
}
HEALTH_SCHEMA: dict[str, Any] = {
    "title": "vibrissa.GraphHealth",
    "description": "Every node's last status: counters and rates (messages per second)",
    "type": "object",
    "properties": {"stamp": {"type": "number"}, "nodes": {"type": "array", "items": {
        "type": "object", "properties": {
            "node": {"type": "string"}, "state": {"type": "string"},
            "message": {"type": "string"},
            **{k: {"type": "integer"} for k in ("received", "published", "lost", "rejected")},
            **{k: {"type": "number"} for k in ("received_hz", "published_hz")}}}}},
}


MESH_PARTS: dict[bool, tuple[str, tuple[float, float, float, float]]] = {
    True: ("mesh", (0.35, 0.6, 0.9, 0.8)),
    False: ("mesh_unknown", (0.6, 0.6, 0.6, 0.25)),
}
"""Each part of a frame's map (known: True), as a scene entity: the prefix of its id
(``<prefix>/<frame_id>``) and its colour (r, g, b, a)."""


def _vec3(v: FloatArray) -> dict[str, float]:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


class LiveView:
    """The graph's messages as Foxglove messages on Foxglove channels (no sockets of the graph:
    ``handle`` takes decoded messages, ``tick`` sends what goes out periodically).

    Parameters
    ----------
    fg : module
        The ``foxglove`` package; its channels log to every sink of its context (the server).
    params : FoxgloveBridgeParams
    mounts : sequence of (whisker name, X_RC)
        The robot description's mounts in ``params.robot_frame``.
    counters : dict
        Where the counts go (the node's status counters).
    context : foxglove.Context, optional
        The channels' context (its sinks); the SDK's global one by default.
    unknown_mesh_topic : str, optional
        The topic (fully qualified) whose SurfaceMesh are the unknown part of a map (those of
        any other topic are the known part); by default ``params.unknown_mesh_topic`` in the
        root namespace (a bag's topics).
    """

    def __init__(self, fg: ModuleType, params: FoxgloveBridgeParams,
                 mounts: Sequence[tuple[str, Transform]], counters: dict[str, int],
                 context: Any = None, unknown_mesh_topic: str | None = None) -> None:
        self.fg, self.params, self.counters, self._context = fg, params, counters, context
        self._unknown_mesh_topic = (resolve_topic(params.unknown_mesh_topic)
                                    if unknown_mesh_topic is None else unknown_mesh_topic)
        for key in ("wrenches", "contacts", "other_frame", "poses", "meshes", "bad_meshes",
                    "clouds", "statuses", "refused_names", "cloud_aged_out"):
            counters.setdefault(key, 0)
        self._wrench: dict[str, Channel] = {}
        self._contacts: PointCloudChannel = fg.channels.PointCloudChannel("/contacts",
                                                                          context=context)
        self._tf: FrameTransformsChannel = fg.channels.FrameTransformsChannel("/tf",
                                                                              context=context)
        self._map_cloud: PointCloudChannel = fg.channels.PointCloudChannel("/map/cloud",
                                                                           context=context)
        self._meshes: SceneUpdateChannel = fg.channels.SceneUpdateChannel("/meshes",
                                                                          context=context)
        self._health: Channel = fg.Channel("/health", schema=HEALTH_SCHEMA, context=context)
        self._mounts = [(params.robot_frame, clamp_frame(name), X_RC) for name, X_RC in mounts]
        for name, _ in mounts:  # before any client connects: see _wrench_channel
            self._wrench_channel(name)
        self._whisker_index: dict[str, int] = {}
        self._points: list[npt.NDArray[np.float32]] = []  # (n, 4) rows: x, y, z, whisker
        self._cloud_rows = 0
        self._cloud_sent_rows = 0  # an empty cloud does not go out
        self._cloud_msg: PointCloud | None = None
        self._map_cloud_msgs: dict[str, PointCloud] = {}
        self._mesh_msgs: dict[str, SceneUpdate] = {}  # by entity id
        self._nodes: dict[str, dict[str, Any]] = {}
        self._health_dirty = False
        self._next_republish = 0.0

    # -- input ---------------------------------------------------------------------------------

    def handle(self, topic: str, msg: Message, now: float) -> None:
        """Turn one message of the graph, received at ``now`` (s, wall clock), into output."""
        if isinstance(msg, WhiskerWrenchArray):
            self._on_wrench(msg, now)
        elif isinstance(msg, ContactPointArray):
            self._on_contacts(msg.frame_id, msg.whisker_ids, msg.point)
        elif isinstance(msg, RobotPose):
            self.counters["poses"] += 1
            self._log(self._tf, self.fg.messages.FrameTransforms(transforms=[self._transform(
                msg.frame_id, msg.child_frame_id, msg.position, msg.orientation, now)]), now)
        elif isinstance(msg, ContactCloud):
            self.counters["clouds"] += 1
            if not self._room(self._map_cloud_msgs, msg.frame_id):
                return
            self._map_cloud_msgs[msg.frame_id] = self._map_cloud_msg(msg, now)
            self._log(self._map_cloud, self._map_cloud_msgs[msg.frame_id], now)
        elif isinstance(msg, SurfaceMesh):
            self._on_mesh(msg, topic != self._unknown_mesh_topic, now)
        elif isinstance(msg, NodeStatus) and topic == STATUS_TOPIC:
            self._on_status(msg)

    def _on_wrench(self, msg: WhiskerWrenchArray, now: float) -> None:
        for whisker, frame_id, f0, m0 in zip(msg.whisker_ids, msg.frame_ids, msg.f0, msg.m0,
                                             strict=True):
            channel = self._wrench_channel(whisker)
            if channel is not None:
                self._log(channel, {"stamp": msg.stamp, "seq": msg.seq, "frame_id": frame_id,
                                    "f0": _vec3(f0), "m0": _vec3(m0)}, now)
        self.counters["wrenches"] += len(msg.whisker_ids)

    def _wrench_channel(self, whisker: str) -> Channel | None:
        """The wrench channel of ``whisker``, made on first use (None: no room for it).

        foxglove-sdk (0.30) advertises a channel made while a client is connected before it
        takes subscriptions to it: a client that answers within that moment is refused
        ("Unknown channel ID", 7 of 2 000 channels in a stress test) and never gets the
        channel's messages. So the channels of the robot description's whiskers are made with
        the view, before the server starts; only those of other whiskers come on first sight."""
        channel = self._wrench.get(whisker)
        if channel is None and self._room(self._wrench, whisker):
            channel = self._wrench[whisker] = self.fg.Channel(
                f"/whiskers/{whisker}/wrench", schema=WRENCH_SCHEMA, context=self._context)
        return channel

    def _log(self, channel: Any, msg: Any, now: float) -> None:
        """Log on ``channel`` at ``now`` (s): the wall clock live, the bag's time offline."""
        channel.log(msg, log_time=int(round(now * 1e9)))

    def _on_contacts(self, frame_id: str, whiskers: Sequence[str], points: FloatArray) -> None:
        if frame_id != self.params.map_frame:
            self.counters["other_frame"] += len(whiskers)
            return
        rows = np.empty((len(whiskers), 4), dtype=np.float32)
        rows[:, :3] = points
        rows[:, 3] = [self._whisker_index.setdefault(w, len(self._whisker_index))
                      if self._room(self._whisker_index, w) else -1 for w in whiskers]
        self._points.append(rows)
        self._cloud_rows += len(rows)
        self.counters["contacts"] += len(rows)

    def _on_mesh(self, msg: SurfaceMesh, known: bool, now: float) -> None:
        """Replace the entity of ``msg``'s part (``known``) of its frame's map; a mesh with no
        triangles deletes it (and it goes out no more with the state)."""
        if len(msg.triangles) and (msg.triangles.min() < 0
                                   or msg.triangles.max() >= len(msg.vertices)):
            self.counters["bad_meshes"] += 1
            return
        self.counters["meshes"] += 1
        prefix, (r, g, b, a) = MESH_PARTS[known]
        entity_id = f"{prefix}/{msg.frame_id}"
        if not self._room(self._mesh_msgs, entity_id):
            return
        m = self.fg.messages
        stamp = m.Timestamp.from_epoch_secs(now)
        if not len(msg.triangles):
            self._mesh_msgs.pop(entity_id, None)
            self._log(self._meshes, m.SceneUpdate(deletions=[m.SceneEntityDeletion(
                timestamp=stamp, type=m.SceneEntityDeletionType.MatchingId, id=entity_id)]), now)
            return
        triangles = m.TriangleListPrimitive(
            points=[m.Point3(x=float(x), y=float(y), z=float(z)) for x, y, z in msg.vertices],
            indices=msg.triangles.reshape(-1).tolist(), color=m.Color(r=r, g=g, b=b, a=a))
        entity = m.SceneEntity(
            timestamp=stamp, frame_id=msg.frame_id, id=entity_id, triangles=[triangles],
            metadata=[m.KeyValuePair(key="part", value="known" if known else "unknown"),
                      m.KeyValuePair(key="method", value=msg.method),
                      m.KeyValuePair(key="n_points", value=str(msg.n_points))])
        self._mesh_msgs[entity_id] = m.SceneUpdate(entities=[entity])
        self._log(self._meshes, self._mesh_msgs[entity_id], now)

    def _on_status(self, msg: NodeStatus) -> None:
        self.counters["statuses"] += 1
        if not self._room(self._nodes, msg.node):
            return
        counts = {k: int(msg.counters.get(k, 0))
                  for k in ("received", "published", "lost", "rejected")}
        before = self._nodes.get(msg.node)
        rates = {"received_hz": 0.0, "published_hz": 0.0}
        if before is not None and msg.stamp > before["_stamp"]:
            dt = msg.stamp - before["_stamp"]
            rates = {f"{k}_hz": max(0.0, counts[k] - before[k]) / dt
                     for k in ("received", "published")}
        self._nodes[msg.node] = {"node": msg.node, "state": msg.state, "message": msg.message,
                                 **counts, **rates, "_stamp": msg.stamp}
        self._health_dirty = True

    def _room(self, table: Mapping[str, Any], name: str) -> bool:
        """Whether ``table`` (per frame, node or whisker name) has ``name`` or room for it: it
        holds at most MAX_NAMES, so that invented names cannot grow it (counted:
        ``refused_names``)."""
        if name in table or len(table) < MAX_NAMES:
            return True
        self.counters["refused_names"] += 1
        return False

    # -- output --------------------------------------------------------------------------------

    def tick(self, now: float) -> None:
        """Send the grown cloud and the health table; every REPUBLISH_S, the state again."""
        republish = now >= self._next_republish
        if republish:
            self._next_republish = now + REPUBLISH_S
        if self._cloud_rows != self._cloud_sent_rows:
            self._cloud_msg = self._contact_cloud_msg(now)
            self._cloud_sent_rows = self._cloud_rows
            self._log(self._contacts, self._cloud_msg, now)
        elif republish and self._cloud_msg is not None:
            self._log(self._contacts, self._cloud_msg, now)
        if self._health_dirty or republish:
            self._health_dirty = False
            nodes = [{k: v for k, v in entry.items() if not k.startswith("_")}
                     for _, entry in sorted(self._nodes.items())]
            self._log(self._health, {"stamp": now, "nodes": nodes}, now)
        if not republish:
            return
        if self._mounts:
            self._log(self._tf, self.fg.messages.FrameTransforms(transforms=[
                self._transform(parent, child, X.translation, X.quaternion_xyzw, now)
                for parent, child, X in self._mounts]), now)
        for cloud in self._map_cloud_msgs.values():
            self._log(self._map_cloud, cloud, now)
        for update in self._mesh_msgs.values():
            self._log(self._meshes, update, now)

    def _transform(self, parent: str, child: str, p: FloatArray, q_xyzw: FloatArray,
                   now: float) -> FrameTransform:
        m = self.fg.messages
        return m.FrameTransform(
            timestamp=m.Timestamp.from_epoch_secs(now), parent_frame_id=parent,
            child_frame_id=child, translation=m.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            rotation=m.Quaternion(x=float(q_xyzw[0]), y=float(q_xyzw[1]), z=float(q_xyzw[2]),
                                  w=float(q_xyzw[3])))

    def _contact_cloud_msg(self, now: float) -> PointCloud:
        if len(self._points) > 1:
            self._points = [np.concatenate(self._points)]
        if self._points and len(self._points[0]) > self.params.max_cloud_points:
            self.counters["cloud_aged_out"] += len(self._points[0]) - self.params.max_cloud_points
            self._points = [self._points[0][-self.params.max_cloud_points:]]
        data = self._points[0] if self._points else np.empty((0, 4), dtype=np.float32)
        return self._point_cloud(self.params.map_frame, ("x", "y", "z", "whisker"), data, now)

    def _map_cloud_msg(self, msg: ContactCloud, now: float) -> PointCloud:
        data = np.hstack([msg.points, msg.normals]).astype(np.float32)
        return self._point_cloud(msg.frame_id, ("x", "y", "z", "nx", "ny", "nz"), data, now)

    def _point_cloud(self, frame_id: str, names: Sequence[str], data: npt.NDArray[np.float32],
                     now: float) -> PointCloud:
        """A foxglove.PointCloud of float32 rows (n, len(names)), fields in that order."""
        m = self.fg.messages
        float32 = m.PackedElementFieldNumericType.Float32
        fields = [m.PackedElementField(name=name, offset=4 * i, type=float32)
                  for i, name in enumerate(names)]
        return m.PointCloud(
            timestamp=m.Timestamp.from_epoch_secs(now), frame_id=frame_id,
            pose=m.Pose(position=m.Vector3(x=0.0, y=0.0, z=0.0),
                        orientation=m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
            point_stride=4 * len(names), fields=fields,
            data=np.ascontiguousarray(data, dtype="<f4").tobytes())


def run(node: Node, params: FoxgloveBridgeParams, fg: ModuleType) -> None:
    """Serve until stopped, or ``hold_s`` after the mapper's end of stream."""
    mounts = ([(w.name, w.X_RC) for w in load_robot(params.robot)] if params.robot else [])
    types: dict[str, Any] = {topic: WhiskerWrenchArray for topic in params.wrench_topics}
    types.update({topic: ContactPointArray for topic in params.contact_topics})
    types.update({params.pose_topic: RobotPose, params.cloud_topic: ContactCloud,
                  params.mesh_topic: SurfaceMesh, params.unknown_mesh_topic: SurfaceMesh,
                  STATUS_TOPIC: NodeStatus})
    inputs = node.create_subscriber(types)
    mesh_topic = node.resolve(params.mesh_topic)
    # its channels before any client
    view = LiveView(fg, params, mounts, node.counters,
                    unknown_mesh_topic=node.resolve(params.unknown_mesh_topic))
    server = fg.start_server(name=f"vibrissa {node.fqn}", host=params.host, port=params.port)
    try:
        url = f"ws://{params.host}:{server.port}"
        log.info("%s: serving the graph to Foxglove on %s (Foxglove app: Open connection -> "
                 "Foxglove WebSocket -> %s; layout: launch/foxglove_layout.json; %s)",
                 node.fqn, url, url, REFUSED_HINT)
        node.set_state("running", f"serving {url}")
        end_at = float("inf")
        next_tick = 0.0
        while not node.stop_requested and time.monotonic() < end_at:
            rx = inputs.receive(min(0.1, params.period_s))
            now = time.time()
            if rx is not None:
                if isinstance(rx.msg, EndOfStream):
                    if rx.topic == mesh_topic and params.hold_s >= 0 and end_at == float("inf"):
                        log.info("%s: the map is complete; serving %g s more", node.fqn,
                                 params.hold_s)
                        end_at = time.monotonic() + params.hold_s
                else:
                    view.handle(rx.topic, rx.msg, now)
            if time.monotonic() >= next_tick:
                next_tick = time.monotonic() + params.period_s
                view.tick(now)
    finally:
        server.stop()
    log.info("%s: served %d wrench rows, %d contacts, %d poses, %d meshes; refused %d "
             "client(s) at the handshake", node.fqn, node.counters["wrenches"],
             node.counters["contacts"], node.counters["poses"], node.counters["meshes"],
             node.counters.get("refused_clients", 0))


def export_bag(bag: str | os.PathLike[str], output: str | os.PathLike[str],
               params: FoxgloveBridgeParams | None = None,
               topics: Iterable[str] | None = None) -> dict[str, int]:
    """The live view of a recorded bag, as a file: an MCAP of the same Foxglove channels and
    schemas (PointCloud, FrameTransforms, SceneUpdate, the wrench series), each message at its
    bag log time; the cloud and the health table every ``params.period_s`` of bag time; only
    ``topics`` of the bag when given. Needs the extra ``view``. Returns the view's counters, with ``damaged_chunks`` and
    ``unreadable_bytes`` of the bag (a damaged bag is also logged as a warning)."""
    fg = import_foxglove()
    params = params or FoxgloveBridgeParams()
    mounts = ([(w.name, w.X_RC) for w in load_robot(params.robot)] if params.robot else [])
    counters: dict[str, int] = {}
    context = fg.Context()
    reader = BagReader(bag, topics)  # a path that is no bag fails here, before the output is made
    writer = fg.open_mcap(os.fspath(output), allow_overwrite=True, context=context)
    try:
        view = LiveView(fg, params, mounts, counters, context)
        next_tick = -math.inf
        now = 0.0
        for record in reader:
            msg = codec.decode(record.payload)
            now = record.log_time_ns * 1e-9
            if not isinstance(msg, EndOfStream):
                view.handle(record.topic, msg, now)
            if now >= next_tick:
                next_tick = now + params.period_s
                view.tick(now)
        view.tick(now + params.period_s)  # the last of the cloud and the health table
    finally:
        writer.close()
    damage = reader.report_damage("exported")
    counters["damaged_chunks"] = damage.damaged_chunks
    counters["unreadable_bytes"] = damage.unreadable_bytes
    return counters


def main(argv: Sequence[str] | None = None) -> int:
    """Run the Foxglove bridge node (see ARCHITECTURE.md for the command line)."""
    args = NodeArgs.parse(argv, prog="python -m vibrissa.nodes.foxglove_bridge")
    configure_logging()
    params = load_params(FoxgloveBridgeParams, args.params_file, args.params)
    refuse_keyed_graph(params, os.environ)
    fg = import_foxglove()
    with Node.from_args(args) as node:
        if params.allow_unauthenticated_view and Keys.from_env() is not None:
            log.warning("%s: serving a graph with keys to unauthenticated Foxglove clients on "
                        "%s:%d (allow_unauthenticated_view)", node.fqn, params.host, params.port)
        logging.getLogger("foxglove.websocket.server").addFilter(RefusedClients(node.counters))
        run(node, params, fg)
    return 0


if __name__ == "__main__":
    run_main(main)
