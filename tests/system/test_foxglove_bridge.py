"""The live view with real processes (launch/view.yaml): a WebSocket client speaking Foxglove's
WebSocket protocol subscribes to every channel the bridge advertises while the robot demo
runs, and decodes a message of each."""

from __future__ import annotations

import asyncio
import base64
import json
import re
import struct
import time
from pathlib import Path
from typing import Any

import pytest

from tests.system.test_system_pipeline import LAUNCH, Launch, entries
from vibrissa.formats.scene_file import load_robot

websockets = pytest.importorskip("websockets")
pytest.importorskip("foxglove")

SCENE = LAUNCH / "robot" / "scene.yaml"
# foxglove-sdk 0.30 serves the protocol as "foxglove.sdk.v1" (the same ops and binary frames as
# "foxglove.websocket.v1", which it refuses with HTTP 400); a client offers both, as the app does.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # opcode of a binary message frame: u8 op, u32 subscription, u64 ns, payload
RECEIVE_S = 240.0
STATUS_ERROR = 2  # the level of a status op that says a request failed (e.g. "Unknown channel ID")


def proto_fields(buf: bytes) -> list[tuple[int, int, int | bytes]]:
    """The top-level fields (number, wire type, value) of a protobuf message; ValueError when
    ``buf`` is not well-formed protobuf."""

    def varint(i: int) -> tuple[int, int]:
        value = shift = 0
        while True:
            if i >= len(buf) or shift > 63:
                raise ValueError("truncated varint")
            byte = buf[i]
            value |= (byte & 0x7F) << shift
            i, shift = i + 1, shift + 7
            if not byte & 0x80:
                return value, i

    fields: list[tuple[int, int, int | bytes]] = []
    i = 0
    while i < len(buf):
        key, i = varint(i)
        number, wire = key >> 3, key & 7
        value: int | bytes
        if wire == 0:
            value, i = varint(i)
        elif wire in (1, 5):
            size = 8 if wire == 1 else 4
            value, i = buf[i:i + size], i + size
        elif wire == 2:
            size, i = varint(i)
            value, i = buf[i:i + size], i + size
        else:
            raise ValueError(f"wire type {wire}")
        if number == 0 or i > len(buf):
            raise ValueError("bad field or truncated")
        fields.append((number, wire, value))
    return fields


def decode(channel: dict[str, Any], payload: bytes) -> Any:
    """A message of ``channel`` decoded: JSON parsed, protobuf walked into its fields."""
    if channel["encoding"] == "json":
        return json.loads(payload)
    assert channel["encoding"] == "protobuf", channel
    assert channel["schemaEncoding"] == "protobuf", channel
    proto_fields(base64.b64decode(channel["schema"]))  # a FileDescriptorSet
    return proto_fields(payload)


HEALTH_NODES = {"/robot/reconstructor", "/foxglove_bridge"}
"""A /health table that lists either has heard the graph beyond its source (one with only the
wrench source's status came first in a CI run)."""


async def _watch(url: str, wanted: set[str], timeout: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """Subscribe to every advertised channel until each of ``wanted`` and every advertised
    channel has a message; the server info and each topic's first decoded message (of
    ``/health``, the first that lists one of `HEALTH_NODES`; of ``/meshes``, the first with an
    entity)."""
    channels: dict[int, dict[str, Any]] = {}
    subscriptions: dict[int, dict[str, Any]] = {}
    first: dict[str, Any] = {}
    info: dict[str, Any] = {}
    deadline = time.monotonic() + timeout
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        while True:
            missing = sorted((wanted | {c["topic"] for c in channels.values()}) - first.keys())
            if not missing:
                break
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                pytest.fail(f"no message within {timeout} s on {missing}")
            try:
                frame = await asyncio.wait_for(ws.recv(), remaining)
            except TimeoutError:
                pytest.fail(f"no message within {timeout} s on {missing}")
            except websockets.ConnectionClosed as exc:
                pytest.fail(f"the bridge closed ({exc}) with no message yet on {missing}")
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] == "serverInfo":
                    info = op
                elif op["op"] == "status" and op.get("level") == STATUS_ERROR:
                    pytest.fail(f"the bridge refused the client: {op.get('message')}")
                elif op["op"] == "advertise":
                    new = [c for c in op["channels"] if c["id"] not in channels]
                    channels.update({c["id"]: c for c in new})
                    subs = [{"id": len(subscriptions) + k, "channelId": c["id"]}
                            for k, c in enumerate(new)]
                    subscriptions.update({s["id"]: channels[s["channelId"]] for s in subs})
                    if subs:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                continue
            assert frame[0] == MESSAGE_DATA, frame[:1]
            sub_id, stamp_ns = struct.unpack_from("<IQ", frame, 1)
            channel = subscriptions[sub_id]
            payload = frame[13:]
            assert payload, channel["topic"]
            assert stamp_ns > 0
            message = decode(channel, payload)
            if channel["topic"] == "/health" and not HEALTH_NODES & {
                    n["node"] for n in message["nodes"]}:
                continue  # the bridge's first tables may come before these nodes' statuses
            if channel["topic"] == "/meshes" and not any(n == 2 for n, _, _ in message):
                continue  # a deletion: the mapper's first updates may have no known triangles
            first.setdefault(channel["topic"], message)
    return info, first


def _strings(fields: list[tuple[int, int, int | bytes]]) -> bytes:
    return b"\0".join(v for _, w, v in fields if w == 2 and isinstance(v, bytes))


def test_a_websocket_client_receives_every_channel_of_the_live_view(tmp_path: Path) -> None:
    whiskers = [w.name for w in load_robot(SCENE)]
    wanted = {"/contacts", "/tf", "/meshes", "/map/cloud", "/health",
              *(f"/whiskers/{w}/wrench" for w in whiskers)}
    # the bridge ends 10 s after the map: time for a client on a loaded machine to see every
    # channel (with 3 s, CI's client once saw the connection close first); the path plays in
    # real time (500 samples/s, 3.4 s), as a robot streams: as fast as possible, a loaded
    # client once got no message at all of one whisker's wrench channel
    launch = Launch(tmp_path, entries("view.yaml"), f"out:={tmp_path / 'out'}",
                    f"scene:={SCENE}", "port:=0", "hold:=10", "rate:=500")
    try:
        port = int(launch.wait_line(r"serving the graph to Foxglove on ws://127\.0\.0\.1:(\d+)",
                                    30).group(1))
        info, first = asyncio.run(_watch(f"ws://127.0.0.1:{port}", wanted, RECEIVE_S))
        rc = launch.wait(60)
    finally:
        launch.kill()
    assert rc == 0, launch.text()
    assert info.get("op") == "serverInfo"
    # JSON channels: the wrench of every whisker, the health table of the graph's nodes
    for whisker in whiskers:
        wrench = first[f"/whiskers/{whisker}/wrench"]
        assert set(wrench["f0"]) == set(wrench["m0"]) == {"x", "y", "z"}
        assert wrench["frame_id"] == f"{whisker}/clamp"
    nodes = {n["node"] for n in first["/health"]["nodes"]}
    assert HEALTH_NODES & nodes, nodes
    assert {"received", "published", "lost", "received_hz"} <= set(first["/health"]["nodes"][0])
    # foxglove.PointCloud: frame_id (2), point_stride (4, fixed32) 16 bytes (x, y, z, whisker),
    # data (6) whole points
    cloud = dict((n, v) for n, _, v in first["/contacts"])
    assert cloud[2] == b"world" and cloud[4] == struct.pack("<I", 16)
    assert isinstance(cloud[6], bytes) and len(cloud[6]) % 16 == 0
    # foxglove.FrameTransforms: the robot's pose or the mounts, parent and child named
    transforms = [proto_fields(v) for _, _, v in first["/tf"] if isinstance(v, bytes)]
    assert transforms and all(b"base_link" in _strings(t) for t in transforms)
    # foxglove.SceneUpdate: an entity (2) with a triangle list, of the known or unknown part
    entities = [proto_fields(v) for n, _, v in first["/meshes"] if n == 2 and isinstance(v, bytes)]
    assert entities and re.search(rb"\bmesh(_unknown)?/world\b", _strings(entities[0]))


def test_the_layout_is_json_and_shows_channels_the_bridge_serves() -> None:
    layout = json.loads((LAUNCH / "foxglove_layout.json").read_text())
    assert layout["version"] == 1 and layout["content"]["type"] == "split"
    text = json.dumps(layout)
    served = ["/contacts", "/map/cloud", "/meshes", "/health", "/whiskers/w00/wrench.f0.x",
              "/whiskers/w01/wrench.m0.z"]
    assert all(f'"{topic}' in text for topic in served)
