"""The live view's state stays bounded: invented names and a long run's cloud (LiveView, the
Foxglove bridge's logic, logging to an MCAP file that the test reads back)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from vibrissa.frames import Transform
from vibrissa.msgs import ContactPointArray, NodeStatus, WhiskerWrenchArray
from vibrissa.nodes import foxglove_bridge
from vibrissa.nodes.foxglove_bridge import FoxgloveBridgeParams, LiveView
from vibrissa.wire import STATUS_TOPIC

fg = pytest.importorskip("foxglove")
mcap_reader = pytest.importorskip("mcap.reader")


def test_invented_names_and_a_long_cloud_keep_the_view_bounded(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(foxglove_bridge, "MAX_NAMES", 8)
    counters: dict[str, int] = {}
    context = fg.Context()
    writer = fg.open_mcap(str(tmp_path / "view.mcap"), allow_overwrite=True, context=context)
    try:
        view = LiveView(fg, FoxgloveBridgeParams(max_cloud_points=50), [], counters, context)
        for k in range(20):  # 20 whiskers: 8 get a wrench channel, 12 are refused
            view.handle("/robot/wrench", WhiskerWrenchArray(
                stamp=0.0, seq=0, whisker_ids=[f"w{k}"], frame_ids=[f"w{k}/clamp"],
                f0=[[1.0, 0.0, 0.0]], m0=[[0.0, 0.0, 0.0]]), 0.0)
        for k in range(20):  # 20 nodes' statuses: 8 kept
            view.handle(STATUS_TOPIC, NodeStatus(stamp=0.0, node=f"/n{k}", state="running", counters={}, publishes={},
                subscribes={}, seen_topics=[]), 0.0)
        for k in range(30):  # 30 ticks of 3 points: the cloud shows the newest 50
            view.handle("/robot/contact", ContactPointArray(
                stamp=0.0, seq=k, frame_id="world", whisker_ids=["w0", "w1", "w2"],
                point=np.full((3, 3), float(k)), s1=[0.5] * 3, phase=[1] * 3,
                force=[[0.0, 0.0, 1.0]] * 3, status=[0] * 3), 0.0)
        view.tick(1.0)
    finally:
        writer.close()
    assert counters["wrenches"] == 20 and counters["statuses"] == 20
    assert counters["refused_names"] == 12 + 12
    assert counters["contacts"] == 90 and counters["cloud_aged_out"] == 40
    with (tmp_path / "view.mcap").open("rb") as handle:
        reader = mcap_reader.make_reader(handle)
        topics = {channel.topic for channel in reader.get_summary().channels.values()}
    assert {t for t in topics if t.startswith("/whiskers/")} == {
        f"/whiskers/w{k}/wrench" for k in range(8)}


def test_a_client_sees_the_robot_descriptions_wrench_channels_before_any_wrench() -> None:
    """foxglove-sdk takes a subscription to a channel made while a client is connected only
    after advertising it: a fast client can be refused. The channels of the described whiskers
    exist before the server starts, so a client gets them at connect and can subscribe."""
    websockets = pytest.importorskip("websockets.sync.client")
    context = fg.Context()
    mounts = [(f"w{k}", Transform()) for k in range(3)]
    view = LiveView(fg, FoxgloveBridgeParams(), mounts, {}, context)
    server = fg.start_server(port=0, context=context)
    try:
        with websockets.connect(f"ws://127.0.0.1:{server.port}",
                                subprotocols=["foxglove.sdk.v1"]) as ws:
            advertised: dict[str, int] = {}
            while len(advertised) < 8:  # 5 fixed channels and 3 wrench channels
                op = json.loads(ws.recv(timeout=5.0))
                if op["op"] == "advertise":
                    advertised.update({c["topic"]: c["id"] for c in op["channels"]})
            assert {t for t in advertised if t.startswith("/whiskers/")} == {
                "/whiskers/w0/wrench", "/whiskers/w1/wrench", "/whiskers/w2/wrench"}
            channel = view._wrench["w1"]
            assert not channel.has_sinks()
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 7, "channelId": advertised["/whiskers/w1/wrench"]}]}))
            deadline = time.monotonic() + 60.0
            while not channel.has_sinks():  # until the server has taken the subscription
                assert time.monotonic() < deadline, "the server never took the subscription"
                time.sleep(0.01)
            view.handle("/robot/wrench", WhiskerWrenchArray(
                stamp=1.5, seq=4, whisker_ids=["w1"], frame_ids=["w1/clamp"], f0=[[1.0, 0.0, 0.0]],
                m0=[[0.0, 2.0, 0.0]]), 10.0)
            frame = ws.recv(timeout=5.0)
            while isinstance(frame, str):  # skip control messages
                frame = ws.recv(timeout=5.0)
    finally:
        server.stop()
    assert frame[0] == 0x01 and int.from_bytes(frame[1:5], "little") == 7
    wrench = json.loads(frame[13:])
    assert wrench["frame_id"] == "w1/clamp" and wrench["seq"] == 4
    assert wrench["m0"] == {"x": 0.0, "y": 2.0, "z": 0.0}
