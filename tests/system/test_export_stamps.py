"""A demo recorded by the real graph (launch/record_demo.yaml: the recorder node writes the
MCAP bag) and exported to ROS 2: read back with rosbags, each message's log time is its header
stamp, and the simulated stream's stamps start at the launch's ``epoch`` (given, or by default
the time the launch started), while the vibrissa bag keeps the recorder's clock."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from rosbags.highlevel import AnyReader

from tests.system.test_system_pipeline import STEP, Y0, Launch, entries, node, set_param
from vibrissa.cli.main import main as vibrissa_main
from vibrissa.msgs import WhiskerWrenchArray, codec
from vibrissa.wire.bag import BagReader
from vibrissa.wire.ros2_bag import WHISKERS_TOPIC, stamp_to_ros

EPOCH = 1_767_225_600.25  # 2026-01-01T00:00:00.25Z


def _ns(stamp: float) -> int:
    sec, nanosec = stamp_to_ros(stamp)
    return sec * 1_000_000_000 + nanosec


def ros2_times(folder: Path) -> tuple[list[tuple[str, int, int]], list[int]]:
    """(topic, log time ns, header stamp ns) of every stamped message of a ROS 2 bag, read
    with rosbags, and the log times of its unstamped ones (the whisker names)."""
    stamped: list[tuple[str, int, int]] = []
    unstamped: list[int] = []
    with AnyReader([folder]) as reader:
        for connection, t_ns, raw in reader.messages():
            msg: Any = reader.deserialize(raw, connection.msgtype)
            if connection.topic == WHISKERS_TOPIC:
                unstamped.append(t_ns)
                continue
            for header in [tf.header for tf in msg.transforms] if hasattr(msg, "transforms") \
                    else [msg.header]:
                stamped.append((connection.topic, t_ns,
                                header.stamp.sec * 1_000_000_000 + header.stamp.nanosec))
    return stamped, unstamped


@pytest.mark.parametrize("epoch", [None, EPOCH], ids=["default", "given"])
def test_a_recorded_demo_exports_at_its_stamps_from_the_epoch(tmp_path: Path,
                                                              epoch: float | None) -> None:
    launch_entries = entries("record_demo.yaml")
    set_param(node(launch_entries, "wrench_source"), "y0", Y0)  # two coarse sweeps
    out = tmp_path / "out"
    words = [f"out:={out}", f"step:={STEP}", *([] if epoch is None else [f"epoch:={epoch!r}"])]
    before = time.time()
    launch = Launch(tmp_path, launch_entries, *words)
    rc = launch.wait()
    after = time.time()
    assert rc == 0, launch.text()
    recorded = [(r.log_time_ns, codec.decode(r.payload)) for r in BagReader(out / "wrench.mcap")]
    wrenches = [(t_ns, m) for t_ns, m in recorded if isinstance(m, WhiskerWrenchArray)]
    assert len(wrenches) > 100
    first = wrenches[0][1].stamp
    if epoch is None:  # the launch's start: before the first sample was recorded
        assert before <= first <= wrenches[0][0] / 1e9
    else:
        assert first == epoch
    assert f"stamps from the epoch {first:.6f} s" in launch.text()  # stated in the log
    stamps = [m.stamp for _, m in wrenches]
    assert stamps == sorted(stamps) and stamps[-1] - first < after - before
    # the recording itself is on the recorder's clock, as before
    assert all(before * 1e9 <= t_ns <= after * 1e9 for t_ns, _ in recorded)

    ros2 = tmp_path / "ros2"
    assert vibrissa_main(["bag", "export", "--format", "ros2", str(out / "wrench.mcap"),
                          str(ros2)]) == 0
    stamped, unstamped = ros2_times(ros2)
    assert len(stamped) == sum(len(m.whisker_ids) for _, m in wrenches)
    assert {topic for topic, _, _ in stamped} == {"/whisker0/wrench/whisker0"}
    assert all(t_ns == stamp_ns for _, t_ns, stamp_ns in stamped)  # log time = header stamp
    assert sorted(stamp_ns for *_, stamp_ns in stamped) == [_ns(s) for s in stamps]
    assert unstamped == [_ns(first)]  # the whisker names at the first stamp: no other clock
    with AnyReader([ros2]) as reader:
        assert (reader.start_time, reader.end_time) == (_ns(first), _ns(stamps[-1]) + 1)
