"""A real mapper process on loopback: a stream that lost a message on the way is named in the
report, and the mapper's exit status says so unless the loss is allowed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vibrissa.msgs import ContactPhase, ContactPoint, ContactStatus, NodeStatus
from vibrissa.wire import STATUS_TOPIC, Endpoints, Publisher, Subscriber

TOPIC = "/w/contact"


def contact(i: int, frame_id: str = "world") -> ContactPoint:
    return ContactPoint(stamp=0.0, seq=i, whisker_id="w", frame_id=frame_id,
                        point=[0.01 * (i % 4), 0.01 * (i // 4), 0.5 + 0.001 * i], s1=0.5,
                        phase=ContactPhase.TIP, force=[0.0, 0.0, 1.0], status=ContactStatus.OK)


def until_heard(pub: Publisher, statuses: Subscriber) -> None:
    """Ping on TOPIC until the mapper's status says it hears it."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        pub.ping("/test")
        rx = statuses.receive(0.1)
        if rx is not None and rx.msg.node == "/mapper" and TOPIC in rx.msg.seen_topics:
            return
    pytest.fail("the mapper never heard the topic")


@pytest.mark.parametrize("allow_loss", [False, True])
def test_a_lost_contact_is_reported_and_fails_the_mapper(
    tmp_path: Path, endpoints: Endpoints, allow_loss: bool
) -> None:
    env = {**os.environ, **endpoints.to_env()}
    mapper = subprocess.Popen(
        [sys.executable, "-m", "vibrissa.nodes.mapper", "--name", "mapper",
         "--param", f"topics:=[{TOPIC}]", "--param", f"out_dir:={tmp_path}",
         "--param", "plot:=false", "--param", f"allow_loss:={str(allow_loss).lower()}"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        with Publisher(TOPIC, ContactPoint, endpoints) as pub, \
                Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses:
            until_heard(pub, statuses)
            for i in range(12):
                if i == 5:  # sent, and lost on the way: its seq is used, it never arrives
                    pub.sent += 1
                    pub.published += 1
                    continue
                pub.publish(contact(i))
            pub.publish_end_of_stream("/test")
        out, _ = mapper.communicate(timeout=120)
    finally:
        if mapper.poll() is None:
            mapper.kill()
            mapper.communicate()
    assert mapper.returncode == (0 if allow_loss else 4), out
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["n_points"] == 11 and report["lost"] == 1
    [stream] = report["streams"]
    assert (stream["topic"], stream["source"], stream["sent"], stream["received"],
            stream["lost"]) == (TOPIC, "/test", 12, 11, 1)
    text = (tmp_path / "report.txt").read_text()
    assert "LOST: 1 contact message(s) never arrived" in text
    assert f"input {TOPIC} from /test: 12 sent, 11 received, 1 lost" in text
    assert "lost on the way to the map" in out


def test_points_beyond_the_maps_bounds_are_dropped_counted_and_fail_the_mapper(
    tmp_path: Path, endpoints: Endpoints
) -> None:
    """A real mapper with max_points 8 and max_frames 2: a flood of points and of frames keeps
    its memory bounded; what does not fit is counted per bound, logged, reported, exit 4."""
    env = {**os.environ, **endpoints.to_env()}
    mapper = subprocess.Popen(
        [sys.executable, "-m", "vibrissa.nodes.mapper", "--name", "mapper",
         "--param", f"topics:=[{TOPIC}]", "--param", f"out_dir:={tmp_path}",
         "--param", "plot:=false", "--param", "max_points:=8", "--param", "max_frames:=2"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        with Publisher(TOPIC, ContactPoint, endpoints) as pub, \
                Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses:
            until_heard(pub, statuses)
            for i in range(6):  # frames world and a: 6 points
                pub.publish(contact(i, "world" if i < 4 else "a"))
            for i in range(6, 9):  # a third frame: dropped (max_frames)
                pub.publish(contact(i, f"f{i}"))
            for i in range(9, 14):  # 2 more fit (8 in all), then 3 dropped (max_points)
                pub.publish(contact(i))
            pub.publish_end_of_stream("/test")
        out, _ = mapper.communicate(timeout=120)
    finally:
        if mapper.poll() is None:
            mapper.kill()
            mapper.communicate()
    assert mapper.returncode == 4, out
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["n_points"] == 8 and report["lost"] == 0
    assert report["dropped_points"] == {"max_frames": 3, "max_points": 3}
    assert sorted(f["frame_id"] for f in report["frames"]) == ["a", "world"]
    text = (tmp_path / "report.txt").read_text()
    assert "DROPPED: 3 contact point(s) beyond max_frames" in text
    assert "DROPPED: 3 contact point(s) beyond max_points" in text
    assert "dropped beyond the map's bounds" in out and "dropped so far" in out
