"""The localizer node's loop (nodes/localizer.py) without sockets: contacts in another frame or
not finite are refused and counted (logged once), poses of other frames or not finite ignored
and counted, the good messages go out in order in frame ``map``, and both outputs end with
``EndOfStream`` once the input ended."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from tests.nodes.test_scene_results import FakePublisher
from vibrissa.msgs import ContactPointArray, EndOfStream, RobotPose
from vibrissa.nodes.localizer import LocalizerParams, run
from vibrissa.wire.transport import Header, Received


@dataclass
class Subscriber:
    queue: list[tuple[str, Any]]

    def receive(self, timeout_s: float) -> Received | None:
        if not self.queue:
            return None
        topic, msg = self.queue.pop(0)
        return Received(topic, msg, b"", Header(1, 0), 0.0)


@dataclass
class FakeNode:
    queue: list[tuple[str, Any]]
    fqn: str = "/localizer"
    stop_requested: bool = False
    counters: dict[str, int] = field(default_factory=dict)
    publishers: dict[str, FakePublisher] = field(default_factory=dict)

    def create_subscriber(self, topics: dict[str, Any], **kwargs: Any) -> Subscriber:
        return Subscriber(self.queue)

    def create_publisher(self, topic: str, *args: Any, **kwargs: Any) -> FakePublisher:
        return self.publishers.setdefault(topic, FakePublisher(topic))

    def resolve(self, topic: str) -> str:
        return topic if topic.startswith("/") else "/" + topic

    def set_state(self, state: str, detail: str = "") -> None:
        pass


def contact(stamp: float, seq: int, frame: str = "odom", x: float = 0.05) -> ContactPointArray:
    return ContactPointArray(stamp=stamp, seq=seq, frame_id=frame, whisker_ids=["w"],
                             point=[[x, 0.0, 0.02]], s1=[0.03], phase=[2],
                             force=[[-0.01, 0.0, 0.0]], status=[0])


def pose(stamp: float, frame: str = "odom", x: float = 0.0) -> RobotPose:
    return RobotPose(stamp=stamp, frame_id=frame, child_frame_id="base_link",
                     position=[x, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize("drift", [0.0, 0.02])
def test_bad_input_is_refused_and_counted_and_the_rest_goes_out_in_map(
        drift: float, caplog: pytest.LogCaptureFixture) -> None:
    queue: list[tuple[str, Any]] = []
    for k in range(100):
        queue.append(("/pose", pose(0.01 * k, x=0.001 * k)))
        queue.append(("/contact_odom", contact(0.01 * k, k)))
    queue += [("/contact_odom", contact(1.5, 100, frame="world")),
              ("/contact_odom", contact(1.6, 101, x=float("nan"))),
              ("/pose", pose(1.7, frame="map")),
              ("/pose", pose(1.8, x=float("inf"))),
              ("/pose", EndOfStream(stamp=2.0, source="/robot/wrench_source", count=100)),
              ("/contact_odom", EndOfStream(stamp=2.0, source="/robot/reconstructor",
                                            count=102))]
    node = FakeNode(queue)
    with caplog.at_level(logging.WARNING):
        run(node, LocalizerParams(drift_per_m=drift))  # type: ignore[arg-type]
    assert node.counters["refused"] == 2 and node.counters["ignored_poses"] == 2
    assert node.counters["placed"] == 100
    assert sum("contacts refused" in r.getMessage() for r in caplog.records) == 1
    out = node.publishers["contact"].sent
    assert out[-1] == "EOS" and node.publishers["map_odom"].sent[-1] == "EOS"
    assert [m.seq for m in out[:-1]] == list(range(100))
    assert {m.frame_id for m in out[:-1]} == {"map"}
    np.testing.assert_array_equal([m.point[0] for m in out[:-1]],
                                  [[0.05, 0.0, 0.02]] * 100)  # nothing to register against
