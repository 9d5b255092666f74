"""The live map in the view (a real bridge process, a Foxglove WebSocket client): each of the
mapper's updates of a frame's map, known and unknown part, replaces that part's entity in the
scene; the parts are two entities drawn apart; an update with no triangles deletes its part."""

from __future__ import annotations

import json
import struct
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from tests.system.test_foxglove_bridge import MESSAGE_DATA, SUBPROTOCOLS, proto_fields
from tests.system.test_foxglove_keys import DEADLINE_S, bridge_process
from vibrissa.msgs import SurfaceMesh
from vibrissa.wire.transport import Endpoints, Proxy, Publisher

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets.sync.client")

KNOWN, UNKNOWN = "mesh/world", "mesh_unknown/world"
RESEND_S = 0.5  # a message published before the bridge's subscription reached it is gone


def grid_mesh(n_triangles: int, n_points: int, z_m: float) -> SurfaceMesh:
    """A strip of ``n_triangles`` triangles at height ``z_m`` (none: an empty mesh), fitted to
    ``n_points`` points."""
    x = np.arange(n_triangles + 2, dtype=np.float64) * 0.001 if n_triangles else np.zeros(0)
    vertices = np.column_stack([x, np.arange(len(x)) % 2 * 0.001, np.full(len(x), z_m)])
    triangles = np.array([[k, k + 1, k + 2] for k in range(n_triangles)],
                         dtype=np.int32).reshape(-1, 3)
    return SurfaceMesh(stamp=time.time(), frame_id="world", vertices=vertices,
                       triangles=triangles, method="live test", n_points=n_points)


def entity_of(buf: bytes) -> dict[str, Any]:
    """A foxglove.SceneEntity's id (3), metadata (6: key 1, value 2), and of its triangle list
    (12) the vertex count (points, 2) and the colour (3: r, g, b, a doubles)."""
    fields = proto_fields(buf)
    [entity_id] = [v for n, _, v in fields if n == 3]
    pairs = [dict((k, v) for k, _, v in proto_fields(pair))
             for n, _, pair in fields if n == 6 and isinstance(pair, bytes)]
    metadata = {pair[1].decode(): pair[2].decode() for pair in pairs}
    [triangles] = [proto_fields(v) for n, _, v in fields if n == 12 and isinstance(v, bytes)]
    [colour] = [dict((k, v) for k, _, v in proto_fields(v)) for n, _, v in triangles
                if n == 3 and isinstance(v, bytes)]
    rgba = tuple(struct.unpack("<d", colour[k])[0] if k in colour else 0.0 for k in (1, 2, 3, 4))
    assert isinstance(entity_id, bytes)
    return {"id": entity_id.decode(), "n_points": metadata["n_points"],
            "part": metadata.get("part", ""), "vertices": sum(n == 2 for n, _, _ in triangles),
            "rgba": rgba}


class MeshClient:
    """A Foxglove WebSocket client of the bridge's ``/meshes``: every entity and deletion it
    received, in order (``events``: ``("entity", {...})`` or ``("delete", id)``)."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.events: list[tuple[str, Any]] = []
        self._subscribed = False

    def until(self, done: Callable[[], bool], publish: Callable[[], None] | None = None,
              what: str = "") -> None:
        """Receive until ``done()``, calling ``publish`` every RESEND_S (if given)."""
        deadline = time.monotonic() + DEADLINE_S
        sent = -float("inf")
        while not done():
            assert time.monotonic() < deadline, (
                f"not within {DEADLINE_S} s: {what}; the last events: {self.events[-6:]}")
            if publish is not None and time.monotonic() - sent > RESEND_S:
                publish()
                sent = time.monotonic()
            try:
                frame = self.ws.recv(timeout=RESEND_S)
            except TimeoutError:
                continue
            self._take(frame)

    def _take(self, frame: str | bytes) -> None:
        if isinstance(frame, str):
            op = json.loads(frame)
            meshes = [c for c in op.get("channels", ()) if c["topic"] == "/meshes"]
            if op["op"] == "advertise" and meshes and not self._subscribed:
                self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": 1, "channelId": meshes[0]["id"]}]}))
                self._subscribed = True
            return
        assert frame[0] == MESSAGE_DATA
        for n, _, v in proto_fields(frame[13:]):  # SceneUpdate: deletions (1), entities (2)
            assert isinstance(v, bytes)
            if n == 1:
                self.events.append(("delete", dict((k, x) for k, _, x in proto_fields(v))[3]
                                    .decode()))
            elif n == 2:
                self.events.append(("entity", entity_of(v)))

    def entities(self, since: int = 0) -> list[dict[str, Any]]:
        return [e for kind, e in self.events[since:] if kind == "entity"]

    def has(self, entity_id: str, n_points: str, since: int = 0) -> bool:
        return any(e["id"] == entity_id and e["n_points"] == n_points
                   for e in self.entities(since))


def test_each_map_update_replaces_its_parts_entity_in_the_scene() -> None:
    with Proxy(Endpoints.free()) as proxy:
        assert proxy.endpoints is not None
        with (bridge_process(proxy.endpoints) as (url, _),
              Publisher("/surface_mesh", SurfaceMesh, proxy.endpoints) as known,
              Publisher("/surface_mesh_unknown", SurfaceMesh, proxy.endpoints) as unknown,
              websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws):
            client = MeshClient(ws)

            def update(n_known: int, n_unknown: int, n_points: int) -> Callable[[], None]:
                def publish() -> None:
                    known.publish(grid_mesh(n_known, n_points, 0.01))
                    unknown.publish(grid_mesh(n_unknown, n_points, 0.02))
                return publish

            # update 1, then update 2 (more points, the surface grown) of both parts
            client.until(lambda: client.has(KNOWN, "100") and client.has(UNKNOWN, "100"),
                         update(2, 5, 100), "update 1")
            first = {e["id"]: e for e in client.entities()}
            second_from = len(client.events)
            client.until(lambda: (client.has(KNOWN, "200", second_from)
                                  and client.has(UNKNOWN, "200", second_from)),
                         update(6, 3, 200), "update 2")
            # then, with nothing published, the bridge's state for late clients: update 2 only
            settled = len(client.events)
            client.until(lambda: all(sum(e["id"] == i for e in client.entities(settled)) >= 2
                                     for i in (KNOWN, UNKNOWN)), None, "the state again")
            second = {e["id"]: e for e in client.entities(second_from)}
            assert {e["n_points"] for e in client.entities(settled)} == {"200"}
            # two entities, each part its own, drawn apart: known opaque-ish blue, unknown
            # translucent grey; each update's vertices replace the previous ones
            assert set(first) == set(second) == {KNOWN, UNKNOWN}
            assert (first[KNOWN]["vertices"], second[KNOWN]["vertices"]) == (4, 8)
            assert (first[UNKNOWN]["vertices"], second[UNKNOWN]["vertices"]) == (7, 5)
            assert {e["part"] for e in second.values()} == {"known", "unknown"}
            assert second[KNOWN]["part"] == "known"
            r, g, b, a = second[UNKNOWN]["rgba"]
            assert r == g == b and a < 0.5 < second[KNOWN]["rgba"][3]
            assert second[KNOWN]["rgba"][2] > second[KNOWN]["rgba"][0]  # blue

            # an update with no unknown triangles: that part leaves the scene, the known stays
            cleared_from = len(client.events)
            client.until(lambda: ("delete", UNKNOWN) in client.events[cleared_from:],
                         update(7, 0, 300), "the unknown part deleted")
            deleted_at = client.events.index(("delete", UNKNOWN), cleared_from)
            client.until(lambda: sum(e["id"] == KNOWN for e in client.entities(deleted_at)) >= 3,
                         None, "the state after the deletion")
            assert all(e["id"] == KNOWN for e in client.entities(deleted_at))
            assert ("delete", KNOWN) not in client.events
