"""The recorder node: end-of-stream logic without sockets, then as a real process."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import yaml

from vibrissa.msgs import EndOfStream, NodeStatus, WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.nodes.recorder import EndOfStreamTracker
from vibrissa.wire import STATUS_TOPIC, Endpoints, Header, Publisher, Received, Subscriber
from vibrissa.wire.bag import BagReader

TIMEOUT_S = 20.0


def wrench(i: int) -> WhiskerWrenchArray:
    return WhiskerWrenchArray(
        stamp=0.01 * i, seq=i, whisker_ids=["w0"], frame_ids=["w0/clamp"],
        pose_frame_id="world", clamp_position=[[0.0, 0.0, 0.1]],
        clamp_orientation=[[0.0, 0.0, 0.0, 1.0]], f0=[[0.0, 0.01 * i, 0.0]], m0=[[0.0, 0.0, 0.0]],
    )


def rx(topic: str, pub: int, msg: Any) -> Received:
    return Received(topic, msg, encode(msg), Header(pub, 0), 0.0)


@contextmanager
def recorder(params: Path, endpoints: Endpoints, *args: str) -> Iterator[subprocess.Popen[str]]:
    """The recorder node as a process named ``rec``; killed if still running at the end."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "vibrissa.nodes.recorder", "--name", "rec", "--params-file",
         str(params), *args], env={**os.environ, **endpoints.to_env()}, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def seen(pub: Publisher, status: Subscriber, node: str) -> NodeStatus:
    """The readiness handshake: ping until ``node`` reports ``pub``'s topic; its status."""
    deadline = time.monotonic() + TIMEOUT_S
    while True:
        assert time.monotonic() < deadline, f"{node} never reported {pub.topic}"
        pub.ping("/test")
        got = status.receive(0.1)
        if got is not None and isinstance(got.msg, NodeStatus) and got.msg.node == node \
                and pub.topic in got.msg.seen_topics:
            return got.msg


def test_end_of_stream_waits_for_every_publisher_and_grace() -> None:
    eos = EndOfStream(stamp=0.0, source="/a", count=1)
    tracker = EndOfStreamTracker(eos_grace_s=0.5)
    tracker.update(rx("/w", 1, wrench(0)))
    tracker.update(rx("/w", 2, wrench(0)))
    tracker.update(rx("/pose", 3, wrench(0)))  # never ends: does not hold the stop up
    assert not tracker.done(0.0)
    tracker.update(rx("/w", 1, eos))
    assert not tracker.all_ended()  # publisher 2 still going
    tracker.update(rx("/w", 2, eos))
    assert tracker.all_ended() and not tracker.done(10.0)
    assert tracker.done(10.5)
    tracker.update(rx("/c", 4, wrench(1)))  # new data re-arms the grace; /c has no end yet
    assert tracker.all_ended() and not tracker.done(10.6)
    tracker.update(rx("/c", 4, eos))
    assert tracker.ended_topics == ["/c", "/w"]


def test_recorder_node_process_stops_on_end_of_stream(tmp_path: Path,
                                                      endpoints: Endpoints) -> None:
    out = tmp_path / "bags" / "run.mcap"
    params = tmp_path / "rec.yaml"
    params.write_text(yaml.safe_dump({"output": str(out), "topics": ["wrench"],
                                      "stop_on_eos": True, "eos_grace_s": 0.2}))
    with recorder(params, endpoints, "--namespace", "/w0") as proc, \
            Publisher("/w0/wrench", WhiskerWrenchArray, endpoints) as pub, \
            Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as status:
        seen(pub, status, "/w0/rec")
        sent = []
        for i in range(50):
            pub.publish(wrench(i))
            sent.append(encode(wrench(i)))
        pub.publish_end_of_stream("/test")
        _, err = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == 0, err
    records = list(BagReader(out))
    assert [r.payload for r in records[:-1]] == sent
    assert records[-1].type_name == EndOfStream.TYPE_NAME


def test_recording_every_topic_reports_its_counters(tmp_path: Path, endpoints: Endpoints) -> None:
    # The record-all subscriber is the node's own: its received/lost/rejected reach the status.
    out = tmp_path / "all.mcap"
    params = tmp_path / "rec.yaml"
    params.write_text(yaml.safe_dump({"output": str(out), "stop_on_eos": True, "eos_grace_s": 0.2}))
    with recorder(params, endpoints) as proc, \
            Publisher("/w9/wrench", WhiskerWrenchArray, endpoints) as pub, \
            Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as status:
        last = seen(pub, status, "/rec")
        deadline = time.monotonic() + TIMEOUT_S
        for i in range(40):
            pub.publish(wrench(i))
        pub.publish_end_of_stream("/test")
        while proc.poll() is None or (last is not None and last.state != "finished"):
            assert time.monotonic() < deadline, "recorder did not finish"
            got = status.receive(0.1)
            if got is not None and isinstance(got.msg, NodeStatus) and got.msg.node == "/rec":
                last = got.msg
            elif got is None and proc.poll() is not None:
                break
        _, err = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == 0, err
    assert last is not None and last.counters["received"] >= 41, last
    assert last.counters["lost"] == 0 and last.counters["rejected"] == 0
    assert sum(1 for r in BagReader(out) if r.topic == "/w9/wrench") == 41
