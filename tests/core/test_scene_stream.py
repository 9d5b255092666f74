"""Step 1 along a path that arrives while it runs (`SceneStream`): fed in chunks of any size,
with the path's own step, every whisker's results are `simulate`'s (phases exact, wrenches to
round-off: episodes, landings, other objects, pauses); samples go out only once final; a
commanded path (`CommandedPath`) is the same samples whether its waypoints come in one segment
or two."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.core.test_sampling import L_M, yawing_scene
from tests.core.test_scene_batched import random_scene
from vibrissa.formats.scene_file import load_scene
from vibrissa.frames import Transform
from vibrissa.paths import CommandedPath, PathLimits, check_segment, waypoint_samples
from vibrissa.scene import (
    SamplePhase,
    Scene,
    SceneStream,
    StreamSamples,
    _WhiskerSteps,
    simulate,
    snaps,
)
from vibrissa.sweep import EARLY_MULTIPLES

DEMO = Path(__file__).parents[2] / "launch" / "robot" / "scene.yaml"


def fed(scene: Scene, steps: list[float], chunks: list[int]) -> tuple[StreamSamples, list[int]]:
    """The stream of ``scene``'s path fed in ``chunks`` (the rest at the end): every sample
    handed out, and how many were handed out after each chunk."""
    stream = SceneStream(scene, steps)
    t, p, q = scene.path.t, scene.path.p_WR, scene.path.R_WR.as_quat()
    bounds = np.minimum(np.cumsum([0, *chunks]), len(t)).tolist() + [len(t)]
    parts: list[StreamSamples] = []
    out = []
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        stream.extend(t[a:b], p[a:b], q[a:b])
        parts.append(stream.advance())
        out.append(len(parts[-1].t))
        # nothing is handed out before its sample arrived
        assert sum(out) <= b
    parts.append(stream.finish())
    for part in parts:  # a jump goes out once its sample is out, and its episode has ended
        assert all(told.snap.t <= part.t[-1] for told in part.snaps)
    return StreamSamples(*(np.concatenate([getattr(s, f) for s in parts]) for f in
                           ("t", "p_WR", "q_WR", "phase", "f0_n", "m0_nm")),
                         tuple(told for s in parts for told in s.snaps)), out


def own_steps(scene: Scene) -> list[float]:
    """Each whisker's step along the whole path, as `simulate` takes it."""
    return [_WhiskerSteps(scene, w).path.h for w in scene.whiskers]


def assert_simulate_bits(scene: Scene, samples: StreamSamples) -> None:
    """The same samples and phases; wrenches within 1e-10 of the whisker's peak. A window of
    the path bisects a touch on its own fractional sample indices, so the first equilibrium's
    Newton start may differ from the whole path's in its last bits (the demo fed in chunks of
    50: 204 rows of one whisker within 8.3e-14 N of a 0.056 N peak)."""
    results = simulate(scene, workers=1)
    assert np.array_equal(samples.t, scene.path.t)
    for i, r in enumerate(results):
        assert np.array_equal(samples.phase[:, i], r.phase), r.name
        for got, want in ((samples.f0_n[:, i], r.f0_n), (samples.m0_nm[:, i], r.m0_nm)):
            assert np.array_equal(np.isnan(got), np.isnan(want)), r.name
            peak = np.nanmax(np.abs(want), initial=0.0)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-10 * peak, err_msg=r.name)


@pytest.mark.parametrize("chunk", [13, 50, 2000])
def test_the_demo_fed_in_chunks_is_simulate(chunk: int) -> None:
    scene = load_scene(DEMO)
    samples, out = fed(scene, own_steps(scene), [chunk] * (len(scene.path.t) // chunk + 1))
    assert_simulate_bits(scene, samples)
    contact = np.isin(samples.phase, [SamplePhase.TIP, SamplePhase.TANGENTIAL])
    assert contact.any(axis=0).sum() >= 6  # the demo touches with most of its whiskers
    if chunk < 100:  # samples go out as they come, a few held back for Step 1's look-ahead
        held = EARLY_MULTIPLES[-1] + 4  # the early steps' longest, a snap-off's two, and two
        assert max(out[1:-1]) <= chunk + held and sum(out[:-1]) >= len(scene.path.t) - 2 * chunk


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(8))
def test_random_scenes_fed_at_random_are_simulate(seed: int) -> None:
    """Several objects, pauses, spins: landings, rods that meet a second object and go on
    with two contacts (seeds 0, 1 and 6: 55, 39 and 277 samples), and the jumps told."""
    rng = np.random.default_rng(400 + seed)
    scene = random_scene(rng)
    chunks = rng.integers(1, 40, size=len(scene.path.t)).tolist()
    samples, _ = fed(scene, own_steps(scene), chunks)
    assert_simulate_bits(scene, samples)
    names = [obj.name for obj in scene.objects]
    want = sorted((s.t, k, s.kind, s.object) for k, r in enumerate(simulate(scene, workers=1))
                  for s in snaps(r, names))
    assert sorted((g.snap.t, g.whisker, g.snap.kind, g.snap.object)
                  for g in samples.snaps) == want


def test_with_a_larger_step_the_wrenches_agree_within_newtons_tolerance() -> None:
    """The commanded robot's step comes from its speed limits (`PathLimits.rod_step`), not
    from the path: the touches are then bisected on another coordinate and the equilibria,
    solved to residuals of 1e-12 L, agree to 1e-12 N; the phases are the same."""
    scene = load_scene(DEMO)
    limits = PathLimits(rate_hz=500.0, max_speed_mps=0.1, max_turn_rate_rps=1.0)
    steps = [limits.rod_step(w.X_RC, w.length_m) for w in scene.whiskers]
    assert all(a > b for a, b in zip(steps, own_steps(scene), strict=True))
    samples, _ = fed(scene, steps, [50] * 40)
    for i, r in enumerate(simulate(scene, workers=1)):
        assert np.array_equal(samples.phase[:, i], r.phase)
        np.testing.assert_allclose(samples.f0_n[:, i], r.f0_n, rtol=0, atol=1e-12)
        np.testing.assert_allclose(samples.m0_nm[:, i], r.m0_nm, rtol=0, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("tilt_deg, elevation_deg, mu, radius_m, per_sample", [
    (50.0, 40.0, 0.5, 0.02, 4), (45.0, -20.0, 0.5, 0.01, 1), (40.0, 10.0, 0.3, 0.005, 4)])
@pytest.mark.parametrize("slower", [10, 100])
def test_a_robot_slower_than_its_step_gives_simulates_contacts(
        tilt_deg: float, elevation_deg: float, mu: float, radius_m: float, per_sample: int,
        slower: int) -> None:
    """A commanded robot's step is the rod's motion at its limits: one driving ``slower``
    times slower has its contacts all the same. A tip touching a ball at mu 0.3-0.5 slips by
    the rod's shortening at first (too little for eq. 7's direction over one sample): it takes
    longer steps over the first 0.01 L of the rod's travel, not of the coordinate's (which
    would be one sample at 10x), and a slide is far by the rod's motion, not the coordinate's.
    The same phases as `simulate` but at most two samples (an unresolved one next to the
    touch), the wrenches within 1e-7 N of a 0.075-0.16 N peak."""
    scene = yawing_scene(tilt_deg, elevation_deg, mu, radius_m, per_sample)
    (want,) = simulate(scene, workers=1)
    samples, _ = fed(scene, [slower * h for h in own_steps(scene)],
                     [50] * (len(scene.path.t) // 50 + 1))
    same = samples.phase[:, 0] == want.phase
    assert np.count_nonzero(~same) <= 2
    assert np.isin(want.phase, [SamplePhase.TIP, SamplePhase.TANGENTIAL]).sum() > 200
    np.testing.assert_allclose(samples.f0_n[same, 0], want.f0_n[same], rtol=0, atol=1e-7)
    np.testing.assert_allclose(samples.m0_nm[same, 0], want.m0_nm[same], rtol=0,
                               atol=1e-7 * L_M)


def test_a_stop_hands_out_every_sample_and_a_hold_keeps_the_last() -> None:
    scene = load_scene(DEMO)
    t, p, q = scene.path.t, scene.path.p_WR, scene.path.R_WR.as_quat()
    stream = SceneStream(scene, own_steps(scene))
    cut = 520  # most whiskers in contact (w12 from 512 on, in its first steps)
    stream.extend(t[:cut], p[:cut], q[:cut])
    held = len(stream.advance().t)
    assert cut - 20 <= held < cut - 1  # the last sample waits, and the look-ahead of w12
    assert held + len(stream.advance(hold=False).t) == cut  # a robot that stopped: all out
    stream.extend(t[cut:], p[cut:], q[cut:])
    assert cut + len(stream.advance().t) + len(stream.finish().t) == len(t)


def test_two_segments_are_the_samples_of_one() -> None:
    rng = np.random.default_rng(5)
    n = 9
    position = np.cumsum(rng.uniform(-0.02, 0.02, (n, 3)), axis=0)
    orientation = Rotation.from_rotvec(np.cumsum(rng.uniform(-0.2, 0.2, (n, 3)), axis=0)).as_quat()
    limits = PathLimits(rate_hz=500.0, max_speed_mps=0.1, max_turn_rate_rps=1.0)
    start = (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    whole = CommandedPath(limits, *start)
    assert whole.command(position, orientation, 0.05, 0.5) is None
    split = CommandedPath(limits, *start)
    assert split.command(position[:4], orientation[:4], 0.05, 0.5) is None
    assert split.command(position[4:], orientation[4:], 0.05, 0.5) is None
    assert split.queued == whole.queued
    a, b = whole.take(10**6), split.take(10**6)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    # each waypoint is a sample, to the bit, and no leg is faster than commanded
    p, q = waypoint_samples(*start, position, orientation, 0.05, 0.5, 500.0)
    assert np.array_equal(p, a[0]) and all((p == w).all(axis=1).any() for w in position)
    step = np.linalg.norm(np.diff(np.vstack([start[0], p]), axis=0), axis=1)
    assert step.max() <= 0.05 / 500.0 * (1 + 1e-9)
    turn = (Rotation.from_quat(q[:-1]).inv() * Rotation.from_quat(q[1:])).magnitude()
    assert turn.max() <= 0.5 / 500.0 * (1 + 1e-9)


def test_replace_drives_from_where_the_robot_is() -> None:
    limits = PathLimits(rate_hz=100.0, max_speed_mps=0.1, max_turn_rate_rps=1.0)
    path = CommandedPath(limits, np.zeros(3), [0.0, 0.0, 0.0, 1.0])
    assert path.command([[0.05, 0.0, 0.0]], [[0.0, 0.0, 0.0, 1.0]], 0.1, 1.0) is None
    path.take(20)  # 0.02 m on
    assert path.command([[0.02, 0.05, 0.0]], [[0.0, 0.0, 0.0, 1.0]], 0.1, 1.0,
                        replace=True) is None
    p, _ = path.take(10**6)
    assert len(p) == 50 and np.array_equal(p[-1], [0.02, 0.05, 0.0])
    np.testing.assert_allclose(p[0], [0.02, 0.001, 0.0], atol=1e-15)


@pytest.mark.parametrize(("change", "why"), [
    ({"position": [[np.nan, 0.0, 0.0]]}, "non-finite"),
    ({"orientation": [[0.0, 0.0, 0.0, 2.0]]}, "not unit"),
    ({"speed": 0.0}, "speed_mps 0.0 not in"),
    ({"speed": 0.2}, "speed_mps 0.2 not in"),
    ({"turn": -1.0}, "turn_rate_rps -1.0 not in"),
    ({"position": [[0.5, 0.0, 0.0]]}, "first waypoint is 0.5 m"),
    ({"orientation": [[0.0, 0.0, 1.0, 0.0]]}, "3.142 rad"),
    ({"position": np.zeros((0, 3)), "orientation": np.zeros((0, 4))}, "N >= 1"),
])
def test_bad_segments_are_refused_with_the_reason(change: dict[str, object], why: str) -> None:
    limits = PathLimits(rate_hz=500.0, max_speed_mps=0.1, max_turn_rate_rps=1.0)
    args: dict[str, object] = {"position": [[0.01, 0.0, 0.0]],
                               "orientation": [[0.0, 0.0, 0.0, 1.0]], "speed": 0.05, "turn": 0.5}
    args.update(change)
    reason = check_segment(limits, np.zeros(3), [0.0, 0.0, 0.0, 1.0], args["position"],  # type: ignore[arg-type]
                           args["orientation"], args["speed"], args["turn"])  # type: ignore[arg-type]
    assert reason is not None and why in reason
    path = CommandedPath(limits, np.zeros(3), [0.0, 0.0, 0.0, 1.0])
    assert path.command(args["position"], args["orientation"], args["speed"],  # type: ignore[arg-type]
                        args["turn"]) == reason and path.queued == 0  # type: ignore[arg-type]


@pytest.mark.parametrize(("waypoints", "speed", "takes"), [
    ([[0.01, 0.0, 0.0], [1e300, 0.0, 0.0]], 0.05, "inf s"),  # the leg's time overflows
    ([[0.01, 0.0, 0.0]], 1e-300, "1e+298 s"),  # a crawl
    ([[0.01, 0.0, 0.0], [2000.0, 0.0, 0.0]], 0.1, "2e+04 s"),  # 10 million samples
])
def test_a_segment_that_would_queue_more_than_max_queued_s_is_refused(
        waypoints: list[list[float]], speed: float, takes: str) -> None:
    """A leg of finite numbers can still take forever (or overflow): the queue holds at most
    ``max_queued_s`` of path time, so what a robot holds stays bounded; refused, the queue is
    as before and the robot takes the next good segment."""
    limits = PathLimits(rate_hz=500.0, max_speed_mps=0.1, max_turn_rate_rps=1.0,
                        max_queued_s=60.0)
    path = CommandedPath(limits, np.zeros(3), [0.0, 0.0, 0.0, 1.0])
    quaternions = [[0.0, 0.0, 0.0, 1.0]] * len(waypoints)
    reason = path.command(waypoints, quaternions, speed, 1.0)
    assert reason is not None and takes in reason and "max_queued_s 60" in reason, reason
    assert path.queued == 0
    assert path.command([[0.01, 0.0, 0.0]], [[0.0, 0.0, 0.0, 1.0]], 0.05, 1.0) is None
    assert path.queued == 100  # 0.01 m at 0.05 m/s, 500 Hz


def test_the_queue_bound_counts_what_is_queued_and_a_replace_drops_it() -> None:
    """0.6 s queued of 1 s: another 0.6 s is refused, 0.3 s is not; a replace of 0.9 s
    drops the queue first."""
    limits = PathLimits(rate_hz=100.0, max_speed_mps=0.1, max_turn_rate_rps=1.0,
                        max_queued_s=1.0)
    path = CommandedPath(limits, np.zeros(3), [0.0, 0.0, 0.0, 1.0])
    unit = [[0.0, 0.0, 0.0, 1.0]]
    assert path.command([[0.06, 0.0, 0.0]], unit, 0.1, 1.0) is None and path.queued == 60
    why = path.command([[0.12, 0.0, 0.0]], unit, 0.1, 1.0)
    assert why is not None and "0.4 s of path time left" in why and path.queued == 60
    assert path.command([[0.09, 0.0, 0.0]], unit, 0.1, 1.0) is None and path.queued == 90
    assert path.command([[0.09, 0.0, 0.0]], unit, 0.1, 1.0, replace=True) is None
    assert path.queued == 90  # from the start, where the robot still stands: 0.09 m
    assert PathLimits().max_queued_s == 600.0
    with pytest.raises(ValueError, match="max_queued_s must be a finite number > 0"):
        PathLimits(max_queued_s=math.inf)


def test_the_step_bounds_the_rod_motion_of_a_sample() -> None:
    limits = PathLimits(rate_hz=500.0, max_speed_mps=0.1, max_turn_rate_rps=1.0)
    mount = Transform(Rotation.from_euler("x", 90, degrees=True), [0.0, -0.02, 0.01])
    length = 0.05
    h = limits.rod_step(mount, length)
    reach = np.linalg.norm(mount.translation) + length
    assert h == pytest.approx((0.1 + 1.0 * reach) / 500.0 / length, rel=1e-15)


@pytest.mark.slow
@pytest.mark.parametrize("chunk", [7, 100])
def test_the_jumps_of_a_streamed_path_are_simulates(chunk: int) -> None:
    """A tip on a ball slowing to a hold (tests/core/test_sampling.py): snap-off, landing and
    snap-through, streamed once their samples are out, as `snaps` of `simulate` finds them,
    with the wrenches of the streamed samples before and at each."""
    scene = yawing_scene(50.0, 40.0, 0.5, 0.02, 4)
    samples, _ = fed(scene, own_steps(scene), [chunk] * (len(scene.path.t) // chunk + 1))
    (result,) = simulate(scene, workers=1)
    want = snaps(result, ["ball"])
    assert [s.kind for s in want] == ["snap-off", "landing", "snap-through"]
    got = samples.snaps
    assert [(g.snap.t, g.snap.kind, g.snap.object) for g in got] == [
        (w.t, w.kind, w.object) for w in want]
    for g in got:
        after = int(np.flatnonzero(samples.t == g.snap.t)[0])
        assert np.array_equal(g.f0_before, samples.f0_n[after - 1, 0])
        assert np.array_equal(g.m0_before, samples.m0_nm[after - 1, 0])
        assert np.array_equal(g.f0_after, samples.f0_n[after, 0])
        assert np.array_equal(g.m0_after, samples.m0_nm[after, 0])
