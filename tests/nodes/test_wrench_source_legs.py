"""The wrench source's legs (socket-free): ``passes`` N legs forth and back in one stream that
ends, ``loop`` one simulated cycle played again and again until stopped, stamps and ``seq``
running on, and a loop refused where a cycle would not repeat exactly."""

from __future__ import annotations

import dataclasses
import itertools
import logging
from pathlib import Path

import numpy as np
import pytest

from tests.nodes.test_scene_results import FakeNode, FakePublisher
from tests.nodes.test_scene_results import write_scene as write_scene_with_a_buried_whisker
from vibrissa.formats.scene_file import load_scene
from vibrissa.formats.truth_poses import read_truth
from vibrissa.msgs import RobotPose, WhiskerWrenchArray
from vibrissa.msgs.codec import encode
from vibrissa.nodes.wrench_source import MAX_POSES, WrenchSourceParams, run_scene, scene_stream
from vibrissa.scene import back_and_forth, simulate

N = 200
SCENE = """\
mu: 0.3
objects:
  - {name: cup, shape: paraboloid, a_per_m: 10.0, b_per_m: 20.0, h_m: 0.02}
whiskers:
  - {name: plain, length_m: 0.05, ei_nm2: 2.0e-5, mount: {}}
  - {name: aside, length_m: 0.05, ei_nm2: 2.0e-5, mount: {position_m: [0.0, 0.01, 0.0]}}
path: path.csv
"""


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("legs")
    x = np.linspace(0.1, -0.1, N).tolist()
    (folder / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + "".join(
        f"{0.01 * i!r},{x[i]!r},0,0,0,0,0,1\n" for i in range(N)))
    (folder / "scene.yaml").write_text(SCENE)
    return folder / "scene.yaml"


def params(scene_file: Path, **kwargs: object) -> WrenchSourceParams:
    return WrenchSourceParams(mode="scene", scene=str(scene_file), workers=1, epoch_s=1000.0,
                              **kwargs)  # type: ignore[arg-type]


def test_passes_and_loop_are_checked_when_the_parameters_load(scene_file: Path) -> None:
    with pytest.raises(ValueError, match="parameter 'passes' must be a count of legs >= 1"):
        params(scene_file, passes=0)
    for kwargs in ({"passes": 2}, {"loop": True}):
        with pytest.raises(ValueError, match="parameter 'simulated' must be empty with passes"):
            params(scene_file, simulated=str(scene_file.parent), **kwargs)


def test_a_repeated_cycle_runs_on_in_time_and_seq(scene_file: Path) -> None:
    """Three cycles of the loop's stream: each cycle's wrenches are the first cycle's, shifted
    by its duration, without the turn's sample twice; poses at their own rate and delay never
    repeat a stamp either; the noise is drawn anew each cycle."""
    scene = load_scene(scene_file)
    cycle = dataclasses.replace(scene, path=back_and_forth(scene.path, 2))
    results = simulate(cycle, workers=1)
    duration = cycle.path.t[-1] - cycle.path.t[0]
    n = len(cycle.path.t)
    for noise in (0.0, 1e-4):
        p = params(scene_file, loop=True, pose_rate_hz=30.0, pose_delay_s=0.05,
                   noise_force_n=noise)
        once = list(scene_stream(cycle, results, p))
        looped = list(itertools.islice(scene_stream(cycle, results, p, repeat=True),
                                       3 * len(once)))
        times = [t for t, _ in looped]
        assert times == sorted(times)
        wrenches = [m for _, m in looped if isinstance(m, WhiskerWrenchArray)]
        poses = [m for _, m in looped if isinstance(m, RobotPose)]
        assert [w.seq for w in wrenches] == list(range(len(wrenches)))
        assert np.all(np.diff([w.stamp for w in wrenches]) > 0)
        assert np.all(np.diff([q.stamp for q in poses]) > 0)
        first = [m for _, m in once if isinstance(m, WhiskerWrenchArray)]
        assert len(first) == n and len(wrenches) >= 3 * (n - 1)
        for c in (1, 2):
            for k in (1, n // 3, n - 1):
                again = wrenches[c * (n - 1) + k]
                assert again.stamp == pytest.approx(first[k].stamp + c * duration, abs=1e-9)
                assert again.whisker_ids == first[k].whisker_ids
                same = np.array_equal(again.f0, first[k].f0)
                assert same == (noise == 0.0 or not first[k].whisker_ids)
        in_contact = [w for w in first if w.whisker_ids and np.any(w.f0 != 0)]
        assert len(in_contact) > 20
        # a pose stamped on the path at the wrench's time carries the path's pose there
        for q in poses[:: max(1, len(poses) // 20)]:
            _, p_WR, _ = cycle.path.at([(q.stamp - p.epoch_s) % duration])
            np.testing.assert_allclose(q.position, p_WR[0], rtol=0, atol=1e-9)


def test_a_stream_of_three_legs_ends(scene_file: Path) -> None:
    node = FakeNode()
    sent = run_scene(node, params(scene_file, passes=3))  # type: ignore[arg-type]
    wrenches = node.publishers["wrench"].sent
    assert wrenches[-1] == "EOS" and node.publishers["/robot/pose"].sent[-1] == "EOS"
    stamps = [w.stamp for w in wrenches[:-1]]
    assert len(stamps) == 3 * N - 2 and np.all(np.diff(stamps) > 0)
    events = node.publishers["events"].sent
    assert events[-1] == "EOS"
    assert sent == 2 * (3 * N - 2) + len(events) - 1


class StoppingPublisher(FakePublisher):
    """Asks its node to stop after ``limit`` messages, as a Ctrl-C would."""

    def __init__(self, topic: str, node: FakeNode, limit: int) -> None:
        super().__init__(topic)
        self.node, self.limit = node, limit

    def publish(self, msg: object) -> None:
        super().publish(msg)
        self.node.stop_requested |= len(self.sent) >= self.limit


def test_a_loop_plays_until_stopped_then_ends_its_streams(scene_file: Path) -> None:
    node = FakeNode()
    limit = 10 * N  # five cycles of wrenches
    node.publishers["wrench"] = StoppingPublisher("wrench", node, limit)
    sent = run_scene(node, params(scene_file, loop=True))  # type: ignore[arg-type]
    wrenches = node.publishers["wrench"].sent
    assert wrenches[-1] == "EOS" and len(wrenches) == limit + 1
    assert sent >= limit
    stamps = [w.stamp for w in wrenches[:-1]]
    assert np.all(np.diff(stamps) > 0)
    assert stamps[-1] - stamps[0] > 4 * 2 * 0.01 * (N - 1)  # more than four cycles of time
    # cycle 5 repeats cycle 2 bit for bit (noise-free)
    cycle = 2 * N - 2
    assert [encode(dataclasses.replace(w, stamp=0.0, seq=0)) for w in wrenches[cycle + 1:2 * cycle]] \
        == [encode(dataclasses.replace(w, stamp=0.0, seq=0)) for w in wrenches[3 * cycle + 1:4 * cycle]]


def test_a_loop_is_refused_where_a_cycle_does_not_end_as_it_began(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A whisker clamped inside an object is never free: its cycle would not repeat."""
    scene_file = write_scene_with_a_buried_whisker(tmp_path)
    node = FakeNode()
    with caplog.at_level(logging.ERROR):
        sent = run_scene(node, params(scene_file, loop=True))  # type: ignore[arg-type]
    assert sent == -1
    assert "buried not free at both ends of the path" in caplog.text
    assert node.publishers["wrench"].sent == ["EOS"]


def test_the_pose_bound_counts_every_leg(scene_file: Path) -> None:
    duration_s = 0.01 * (N - 1)
    rate = 0.6 * MAX_POSES / duration_s  # within the bound for one leg, beyond it for two
    assert params(scene_file, pose_rate_hz=rate).pose_rate_hz == rate
    for kwargs in ({"passes": 2}, {"loop": True}):
        with pytest.raises(ValueError, match=r"poses over the path's 1.99 s x 2 leg\(s\)"):
            params(scene_file, pose_rate_hz=rate, **kwargs)


def test_a_drifting_odometry_publishes_odom_poses_and_writes_their_truth(
        scene_file: Path, tmp_path: Path) -> None:
    """With odom_drift_per_m the poses are odom -> base_link, drifting on through a loop's
    cycles; truth_poses.csv holds each published pose's truth (the path's pose at its stamp)
    and the published one; the wrenches are those without drift, bit for bit."""
    truth_file = tmp_path / "truth_poses.csv"
    runs = {}
    for drift in (0.0, 0.05):
        node = FakeNode()
        node.publishers["wrench"] = StoppingPublisher("wrench", node, 6 * N)  # three cycles
        run_scene(node, params(scene_file, loop=True, odom_drift_per_m=drift, map_frame="odom",
                               seed=4, truth_file=str(truth_file) if drift else ""))  # type: ignore[arg-type]
        runs[drift] = node.publishers
    assert [encode(w) for w in runs[0.0]["wrench"].sent[:-1]] == \
        [encode(w) for w in runs[0.05]["wrench"].sent[:-1]]
    poses = [p for p in runs[0.05]["/robot/pose"].sent if p != "EOS"]
    assert {p.frame_id for p in poses} == {"odom"}
    truth = read_truth(truth_file)
    assert len(truth.stamp_s) == len(poses)
    np.testing.assert_array_equal(truth.stamp_s, [p.stamp for p in poses])
    np.testing.assert_array_equal(truth.p_odom_m, [p.position for p in poses])
    exact = [p for p in runs[0.0]["/robot/pose"].sent if p != "EOS"]
    np.testing.assert_array_equal(truth.p_map_m, [p.position[:] for p in exact[:len(poses)]])
    off = np.linalg.norm(truth.p_odom_m - truth.p_map_m, axis=1)
    assert off[0] == 0 and off[-1] > 1e-4  # starts at the truth, then drifts
    # the drift runs on through the cycles: the third cycle's poses are not the first's
    cycle = len(poses) // 3
    assert not np.allclose(truth.p_odom_m[1:cycle] - truth.p_map_m[1:cycle],
                           truth.p_odom_m[2 * cycle + 1:3 * cycle] - truth.p_map_m[2 * cycle + 1:3 * cycle])
