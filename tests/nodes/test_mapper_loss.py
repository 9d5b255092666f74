"""A real mapper process on loopback: a stream that lost a message on the way, or points past
the map's bounds, are named in the report and its status counters, and the mapper's exit
status says so unless the loss is allowed."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from vibrissa.msgs import ContactPhase, ContactPointArray, ContactStatus, NodeStatus
from vibrissa.wire import STATUS_TOPIC, Endpoints, Publisher, Subscriber

TOPIC = "/w/contact"


def contact(i: int, frame_id: str = "world") -> ContactPointArray:
    return ContactPointArray(stamp=0.0, seq=i, whisker_ids=["w"], frame_id=frame_id,
                             point=[[0.01 * (i % 4), 0.01 * (i // 4), 0.5 + 0.001 * i]], s1=[0.5],
                             phase=[ContactPhase.TIP], force=[[0.0, 0.0, 1.0]],
                             status=[ContactStatus.OK])


def run_mapper(tmp_path: Path, endpoints: Endpoints, params: list[str],
               send: Callable[[Publisher], None]) -> tuple[int, str, dict[str, int]]:
    """A mapper process on TOPIC with ``params`` (``KEY:=VALUE``): once it hears the topic,
    ``send`` publishes, then the stream ends; the exit status, the output and the counters of
    its last ``NodeStatus``."""
    words = [w for p in [f"topics:=[{TOPIC}]", f"out_dir:={tmp_path}", "plot:=false", *params]
             for w in ("--param", p)]
    mapper = subprocess.Popen(
        [sys.executable, "-m", "vibrissa.nodes.mapper", "--name", "mapper", *words],
        env={**os.environ, **endpoints.to_env()}, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    try:
        with Publisher(TOPIC, ContactPointArray, endpoints) as pub, \
                Subscriber({STATUS_TOPIC: NodeStatus}, endpoints) as statuses:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:  # ping until the mapper hears the topic
                pub.ping("/test")
                rx = statuses.receive(0.1)
                if rx is not None and rx.msg.node == "/mapper" and TOPIC in rx.msg.seen_topics:
                    break
            else:
                pytest.fail("the mapper never heard the topic")
            send(pub)
            pub.publish_end_of_stream("/test")
            counters: dict[str, int] = {}
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:  # statuses until the final one, sent on exit
                rx = statuses.receive(0.5)
                if rx is None and mapper.poll() is not None:
                    break
                if rx is not None and rx.msg.node == "/mapper":
                    counters = rx.msg.counters
        out, _ = mapper.communicate(timeout=120)
    finally:
        if mapper.poll() is None:
            mapper.kill()
            mapper.communicate()
    return mapper.returncode, out, counters


@pytest.mark.parametrize("allow_loss", [False, True])
def test_a_lost_contact_is_reported_and_fails_the_mapper(
    tmp_path: Path, endpoints: Endpoints, allow_loss: bool
) -> None:
    def send(pub: Publisher) -> None:
        for i in range(12):
            if i == 5:  # sent, and lost on the way: its seq is used, it never arrives
                pub.sent += 1
                pub.published += 1
                continue
            pub.publish(contact(i))

    rc, out, _ = run_mapper(tmp_path, endpoints, [f"allow_loss:={str(allow_loss).lower()}"], send)
    assert rc == (0 if allow_loss else 4), out
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
    """max_points 8 and max_frames 2: a flood of points and of frames keeps the mapper's
    memory bounded; what does not fit is counted per bound, logged, reported, exit 4."""
    def send(pub: Publisher) -> None:
        for i in range(6):  # frames world and a: 6 points
            pub.publish(contact(i, "world" if i < 4 else "a"))
        for i in range(6, 9):  # a third frame: dropped (max_frames)
            pub.publish(contact(i, f"f{i}"))
        for i in range(9, 14):  # 2 more fit (8 in all), then 3 dropped (max_points)
            pub.publish(contact(i))

    rc, out, counters = run_mapper(tmp_path, endpoints, ["max_points:=8", "max_frames:=2"], send)
    assert rc == 4, out
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["n_points"] == 8 and report["lost"] == 0
    assert report["dropped_points"] == {"max_frames": 3, "max_points": 3}
    assert (counters["max_frames"], counters["max_points"], counters["bad_covariance"]) == (3, 3, 0)
    assert sorted(f["frame_id"] for f in report["frames"]) == ["a", "world"]
    text = (tmp_path / "report.txt").read_text()
    assert "DROPPED: 3 contact point(s) beyond max_frames" in text
    assert "DROPPED: 3 contact point(s) beyond max_points" in text
    assert "dropped beyond the map's bounds" in out and "dropped so far" in out


def test_points_the_map_cannot_use_are_dropped_counted_and_the_map_still_written(
    tmp_path: Path, endpoints: Endpoints
) -> None:
    """A point at 1e300 m (its plot and its page overflowed) and a contact force of zero or
    2e303 N (no normal: the surface fit asserted): counted per reason, reported, exit 4, and
    the map of the usable points written; a covariance of -1e-2 I is counted, the point kept."""
    def send(pub: Publisher) -> None:
        for i in range(7):
            pub.publish(contact(i))
        pub.publish(dataclasses.replace(contact(7), covariance=[-1e-2 * np.eye(3)]))
        pub.publish(dataclasses.replace(contact(8), point=[[1e300, 0.0, 0.5]]))
        for i, force in ((9, [0.0, 0.0, 0.0]), (10, [0.0, 2e303, 2e303])):
            pub.publish(dataclasses.replace(contact(i), force=[force]))

    rc, out, counters = run_mapper(tmp_path, endpoints, [], send)
    assert rc == 4 and "Traceback" not in out, out
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["n_points"] == 8
    assert report["dropped_points"] == {"out_of_range": 1, "no_force_direction": 2}
    assert report["bad_covariance"] == 1
    assert {k: counters.get(k) for k in ("out_of_range", "no_force_direction",
                                         "bad_covariance")} == {
        "out_of_range": 1, "no_force_direction": 2, "bad_covariance": 1}
    text = (tmp_path / "report.txt").read_text()
    assert "DROPPED: 1 contact point(s) with a coordinate beyond 1e+07 m" in text
    assert "DROPPED: 2 contact point(s) with a contact force of zero or over 1e+12 N" in text
    assert "BAD COVARIANCE: 1 contact point(s) with a covariance that is not symmetric" in text
