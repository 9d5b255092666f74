"""Scenes: whiskers of their own L and EI on a moving robot, past posed objects; contact
episodes along the path, checked by physics and by Step 2 (round trip in the world frame)."""

from __future__ import annotations

import multiprocessing
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vibrissa.equilibrium import NEWTON_TOL
from vibrissa.frames import Transform
from vibrissa.reconstruct import reconstruct_si
from vibrissa.scene import (
    RobotPath,
    SamplePhase,
    Scene,
    SceneObject,
    SimulationStopped,
    Whisker,
    robot_path,
    simulate,
)

L0 = 0.05
CUP = SceneObject("cup", "paraboloid", {"a_per_m": 0.5 / L0, "b_per_m": 1 / L0, "h_m": 0.4 * L0})
BALL = SceneObject("ball", "sphere", {"radius_m": 0.3 * L0},
                   Transform(translation=[-2.5 * L0, 0.0, 0.8 * L0]))
STRAIGHT = robot_path(np.arange(900) * 0.01,
                      np.column_stack([np.linspace(1.2 * L0, -3.3 * L0, 900), np.zeros((900, 2))]),
                      np.tile([0.0, 0.0, 0.0, 1.0], (900, 1)))
TILTED = Whisker("tilted", 0.8 * L0, 1e-5, Transform.from_xyz_rpy([0, 0.1 * L0, 0], [0.1, 0, 0]))
PLAIN = Whisker("plain", L0, 2e-5)
ASIDE = Whisker("aside", L0, 2e-5, Transform(translation=[0.0, 5 * L0, 0.0]))


@pytest.fixture(scope="module")
def results() -> dict[str, object]:
    scene = Scene(0.2, (CUP, BALL), (PLAIN, TILTED, ASIDE), STRAIGHT)
    return {r.name: r for r in simulate(scene, workers=2)} | {"scene": scene}


def clamp_poses(scene: Scene, whisker: Whisker) -> tuple[np.ndarray, Rotation]:
    R_WR = scene.path.R_WR
    return (scene.path.p_WR + R_WR.apply(np.array(whisker.X_RC.translation)),
            R_WR * whisker.X_RC.rotation)


def test_snap_off_then_a_landing_then_a_second_object(results) -> None:
    r, scene = results["tilted"], results["scene"]
    assert [(e.object, e.start) for e in r.episodes] == [
        ("cup", "touch"), ("cup", "landing"), ("ball", "touch"), ("ball", "landing")]
    assert r.episodes[0].end == r.episodes[2].end == "snap-off"
    in_contact = np.isin(r.phase, (SamplePhase.TIP, SamplePhase.TANGENTIAL))
    landing = int(np.searchsorted(r.t, r.episodes[1].t_first_contact))
    assert r.t[landing] == r.episodes[1].t_first_contact
    assert in_contact[landing - 1] and in_contact[landing] and r.object[landing] == 0
    # independently: the straight rod is inside the cup there, so the rod cannot be free
    p_WC, R_WC = clamp_poses(scene, TILTED)
    rod = p_WC[landing] + np.outer(np.linspace(0, TILTED.length_m, 400),
                                   R_WC[landing].apply([0, 0, 1]))
    assert np.min(CUP.surface(1.0).value(rod)) < 0
    assert not np.any(r.phase == SamplePhase.UNRESOLVED)
    second = np.flatnonzero(r.object == 1)
    assert second[0] > np.flatnonzero(r.object == 0)[-1]
    assert r.t[second[0]] >= r.episodes[2].t_first_contact > r.t[second[0] - 1]


def test_a_side_graze_starts_tangential(results) -> None:
    r = results["plain"]
    ball = np.flatnonzero((r.object == 1) & (r.phase != SamplePhase.UNRESOLVED))
    first = ball[0]
    assert r.phase[first] == SamplePhase.TANGENTIAL and r.s1_m[first] < 0.99 * PLAIN.length_m


def test_a_whisker_that_never_touches_is_free_throughout(results) -> None:
    r = results["aside"]
    assert r.episodes == [] and np.all(r.phase == SamplePhase.NONE)
    assert np.all(r.f0_n == 0) and np.all(np.isnan(r.p_W_m))


@pytest.mark.parametrize("name", ["plain", "tilted"])
def test_every_contact_sample_obeys_statics_and_round_trips_through_step_2(results, name) -> None:
    r, scene = results[name], results["scene"]
    whisker = next(w for w in scene.whiskers if w.name == name)
    rows = np.flatnonzero((r.phase == SamplePhase.TIP) | (r.phase == SamplePhase.TANGENTIAL))
    assert len(rows) > 100
    p_WC, R_WC = clamp_poses(scene, whisker)
    # statics in C: m0 + r x F = 0 with F = -f0
    r_C = R_WC[rows].inv().apply(r.p_W_m[rows] - p_WC[rows])
    moment = r.m0_nm[rows] - np.cross(r_C, r.f0_n[rows])
    assert np.max(np.abs(moment)) < 1e-9 * whisker.ei_nm2 / whisker.length_m
    assert np.max(np.abs(r.m0_nm[rows, 2])) < 1e-12 * whisker.ei_nm2 / whisker.length_m
    # the contact on the object touched, in units of L
    for index, obj in enumerate(scene.objects):
        mine = rows[r.object[rows] == index]
        if len(mine):
            gap = obj.surface(whisker.length_m).signed_distance(r.p_W_m[mine] / whisker.length_m)
            assert np.max(np.abs(gap)) < 1e-9
    # Step 2 from the clamp pose and (f0, m0) alone recovers the world contact point
    rec = reconstruct_si(R_WC[rows].as_quat(), p_WC[rows], r.f0_n[rows], r.m0_nm[rows],
                         whisker.scale)
    assert np.max(np.linalg.norm(rec.point_m - r.p_W_m[rows], axis=1)) < 1e-9 * whisker.length_m
    np.testing.assert_allclose(rec.s1_m, r.s1_m[rows], rtol=0, atol=1e-9 * whisker.length_m)


def test_bad_scenes_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="row 2: quaternion"):
        robot_path([0.0, 1.0], np.zeros((2, 3)), [[0, 0, 0, 1.0], [0, 0, 0.5, 1.0]])
    with pytest.raises(ValueError, match="increase strictly"):
        robot_path([0.0, 0.0], np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    with pytest.raises(ValueError, match="object 'x': a sphere needs radius_m"):
        SceneObject("x", "sphere", {})
    with pytest.raises(ValueError, match="shape must be one of"):
        SceneObject("x", "cube", {})
    with pytest.raises(ValueError, match="whisker names must be unique"):
        Scene(0.1, (), (PLAIN, PLAIN), STRAIGHT)


@pytest.mark.parametrize("far_m", [0.0, 1500.0])
def test_moving_the_whole_scene_moves_the_contacts_and_keeps_every_clamp_wrench(far_m: float) -> None:
    """Also far from W's origin (an odometry or map frame 1.5 km from the robot), where Step 1
    once found no equilibrium at all: it works in a frame at the path's middle."""
    rng = np.random.default_rng(21)
    X = Transform(Rotation.random(random_state=rng),
                  rng.uniform(-0.3, 0.3, 3) + far_m * np.array([0.6, -0.8, 0.0]))
    n = 600
    theta = np.linspace(0.0, 0.9, n)
    path = robot_path(np.arange(n) * 0.01,
                      np.column_stack([0.12 - 0.2 * np.sin(theta), 0.2 * (1 - np.cos(theta)) - 0.03,
                                       np.zeros(n)]),
                      Rotation.from_euler("z", -theta[:, None]).as_quat())
    egg = SceneObject("egg", "ellipsoid", {"semi_axes_m": [0.015, 0.01, 0.012]},
                      Transform.from_xyz_rpy([0.0, 0.025, 0.04], [0.1, 0.2, 0.5]))
    whisker = Whisker("w", 0.045, 2e-5, Transform.from_xyz_rpy([0.0, 0.01, 0.0], [-0.2, 0.1, 0]))
    scene = Scene(0.3, (egg,), (whisker,), path)
    moved = Scene(0.3, (SceneObject("egg", "ellipsoid", egg.sizes, X @ egg.X_WO),), (whisker,),
                  robot_path(path.t, X.apply(path.p_WR), (X.rotation * path.R_WR).as_quat()))
    (a,), (b,) = simulate(scene, workers=1), simulate(moved, workers=1)
    assert a.episodes and [e.end for e in a.episodes] == [e.end for e in b.episodes]
    np.testing.assert_array_equal(a.phase, b.phase)
    rows = np.flatnonzero((a.phase == SamplePhase.TIP) | (a.phase == SamplePhase.TANGENTIAL))
    scale_f, scale_m = whisker.scale.force_n, whisker.scale.moment_nm
    # Each run solves every step's equilibrium to NEWTON_TOL (1e-12) of its residual, from the
    # step before: over 600 steps the two runs' roundings part by a few 1e-12 in the paper's
    # units (2.2e-12 in f0 on an AVX-512 host; under 1e-12 on earlier hosts). A wrong frame is
    # off by O(1).
    wrench_tol = 100 * NEWTON_TOL
    # Far away the moved scene's own numbers carry far_m * 1.1e-16 m of round-off (1.7e-13 m,
    # 3.7e-12 L at 1.5 km): its contacts can only agree to that.
    point_tol = 1e-12 * whisker.length_m + 4 * np.finfo(float).eps * far_m
    # A sample reached in sub-steps towards a fold (``refined``) lies where the equilibrium's
    # Jacobian is nearly singular, which magnifies that residual: 1.05e-10 in f0 at 1.5 km.
    for near_fold, tol in ((False, wrench_tol), (True, 1e-9)):
        at = rows[a.refined[rows] == near_fold]
        np.testing.assert_allclose(b.f0_n[at] / scale_f, a.f0_n[at] / scale_f, rtol=0, atol=tol)
        np.testing.assert_allclose(b.m0_nm[at] / scale_m, a.m0_nm[at] / scale_m, rtol=0,
                                   atol=tol)
    np.testing.assert_allclose(b.p_W_m[rows], X.apply(a.p_W_m[rows]), rtol=0, atol=point_tol)


def test_long_work_reports_how_far_along_the_path_it_is(monkeypatch: pytest.MonkeyPatch) -> None:
    import vibrissa.scene

    monkeypatch.setattr(vibrissa.scene, "PROGRESS_PERIOD_S", 0.0)  # report at every step
    reports: list[tuple[str, int, int]] = []
    scene = Scene(0.2, (CUP,), (PLAIN,), STRAIGHT)
    (result,) = simulate(scene, workers=1, sample_progress=lambda *r: reports.append(r))
    samples = [sample for name, sample, total in reports]
    assert {(name, total) for name, _, total in reports} == {("plain", 900)}
    assert len(samples) > 100 and samples == sorted(samples)
    contact = np.flatnonzero(result.phase != SamplePhase.NONE)
    assert contact[0] <= samples[0] and samples[-1] <= contact[-1] + 1


@pytest.mark.parametrize("workers", [1, 3])
def test_a_stop_ends_the_simulation_and_its_worker_processes(workers: int) -> None:
    asked = 0

    def stop() -> bool:
        nonlocal asked
        asked += 1
        return asked > 3

    scene = Scene(0.2, (CUP, BALL), (PLAIN, TILTED, ASIDE), STRAIGHT)
    # stopped before the end; the rods that touch little may end within the first three asks
    with pytest.raises(SimulationStopped, match=r"stopped with [012] of 3 whisker\(s\) done"):
        simulate(scene, workers=workers, stop=stop)
    assert asked == 4
    assert multiprocessing.active_children() == []


def test_a_worker_told_to_end_before_it_has_set_its_signals_ends() -> None:
    """A node's SIGTERM handler only records: a worker forked from it that ran it for the
    pool's SIGTERM (one that comes before the worker's own actions are set, as a Ctrl-C right
    as the robot's wrench source starts its workers can on a loaded machine) would live on
    and hang `terminate`. Here every worker is slow to start (1 s after its fork), so the
    SIGTERM comes first."""
    script = (
        "import os, signal, time\n"
        "from vibrissa.scene import worker_pool\n"
        "signal.signal(signal.SIGTERM, lambda signum, frame: None)\n"
        "os.register_at_fork(after_in_child=lambda: time.sleep(1.0))\n"
        "pool = worker_pool(2)\n"
        "pool.terminate()\n"
        "print('terminated', flush=True)\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=60)
    assert (run.returncode, run.stdout) == (0, "terminated\n"), run.stderr


def test_a_pause_repeats_the_sample_before_it_and_changes_nothing_else() -> None:
    """Coulomb friction does not depend on rate: a robot that stops in contact (here while the
    rod slides along the cup's side) holds its wrench, and the rest of the run is unchanged."""
    x = np.linspace(1.2 * L0, -1.0 * L0, 300)
    k, pause = 150, 40
    paused_x = np.concatenate([x[:k], np.full(pause, x[k - 1]), x[k:]])

    def run(xs: np.ndarray, t: np.ndarray) -> object:
        path = robot_path(t, np.column_stack([xs, np.zeros((len(xs), 2))]),
                          np.tile([0.0, 0.0, 0.0, 1.0], (len(xs), 1)))
        return simulate(Scene(0.2, (CUP,), (PLAIN,), path), workers=1)[0]

    plain = run(x, np.arange(len(x)) * 0.01)
    t = np.concatenate([np.arange(k) * 0.01, (k - 1) * 0.01 + np.arange(1, pause + 1) * 0.001,
                        (k - 1) * 0.01 + pause * 0.001 + np.arange(1, len(x) - k + 1) * 0.01])
    paused = run(paused_x, t)
    assert plain.phase[k - 1] in (SamplePhase.TIP, SamplePhase.TANGENTIAL)  # in contact
    moving = np.r_[0:k, k + pause:len(paused_x)]
    for name in ("phase", "s1_m", "f0_n", "m0_nm", "p_W_m", "object"):
        before, after = getattr(plain, name), getattr(paused, name)
        np.testing.assert_array_equal(after[moving], before, err_msg=name)
        np.testing.assert_array_equal(after[k:k + pause], np.repeat(before[[k - 1]], pause, 0),
                                      err_msg=name)
    [before], [after] = plain.episodes, paused.episodes
    assert before.end == after.end and after.t_first_contact == before.t_first_contact
    # what happened after the pause happened later by the pause's duration
    shift = pause * 0.001
    assert [(round(t0 + (shift if t0 > (k - 1) * 0.01 else 0), 9), a, b)
            for t0, a, b in before.phase_changes] == \
        [(round(t1, 9), a, b) for t1, a, b in after.phase_changes]


@pytest.mark.parametrize(("x_m", "expected"), [(0.0, SamplePhase.UNRESOLVED),
                                              (3 * L0, SamplePhase.NONE)])
def test_a_robot_that_never_moves(x_m: float, expected: SamplePhase) -> None:
    path = robot_path(np.arange(5) * 0.1, np.tile([x_m, 0.0, 0.0], (5, 1)),
                      np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)))
    [r] = simulate(Scene(0.2, (CUP,), (PLAIN,), path), workers=1)
    assert np.all(r.phase == expected) and r.episodes == []  # the rod stands in the cup, or free


def _straight_rod_depth(scene: Scene, whisker: Whisker, k: int) -> float:
    """How deep (m, > 0: inside) the straight rod of sample ``k`` reaches into the objects."""
    p_WC, R_WC = clamp_poses(scene, whisker)
    rod = p_WC[k] + np.outer(np.linspace(0, whisker.length_m, 801), R_WC[k].apply([0, 0, 1]))
    return max(-float(np.min(obj.surface(1.0).signed_distance(rod))) for obj in scene.objects)


@pytest.mark.parametrize("name", ["plain", "tilted", "aside"])
def test_a_free_sample_has_its_straight_rod_outside_every_object(results, name) -> None:
    r, scene = results[name], results["scene"]
    whisker = next(w for w in scene.whiskers if w.name == name)
    for k in np.flatnonzero(r.phase == SamplePhase.NONE):
        assert _straight_rod_depth(scene, whisker, int(k)) <= 1e-12, k


@pytest.mark.parametrize("slant", [0.05, 0.15, 0.3])
def test_a_steep_poke_with_strong_friction_is_unresolved_not_free_nor_elsewhere(slant) -> None:
    """The rod's tip hits a ball nearly along the rod and within the friction cone (mu 0.8):
    the tip sticks and the inextensible rod can only buckle, a branch Step 1 does not follow.
    The samples from the touch on are unresolved while the straight rod is inside the ball.
    Longer steps after the touch once skipped 8 samples (0.08 L) and found a tip state 4 mm
    from the touch, on no branch from it, with the samples skipped called free."""
    n, ds = 60, 5e-4
    heading = np.array([np.sin(slant), 0.0, -np.cos(slant)])  # the clamp moves down, a bit aside
    p_WR = np.array([-0.003, 0.0, 0.072]) + np.outer(np.arange(n) * ds, heading)
    path = robot_path(np.arange(n) * 0.01, p_WR, np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)))  # rod down
    ball = SceneObject("ball", "sphere", {"radius_m": 0.02})
    scene = Scene(0.8, (ball,), (PLAIN,), path)
    [r] = simulate(scene, workers=1)
    [episode] = r.episodes
    touch = int(np.searchsorted(r.t, episode.t_first_contact))
    assert episode.end == "no-equilibrium" and 3 <= touch < n // 2
    assert np.all(r.phase[:touch] == SamplePhase.NONE)
    depth = np.array([_straight_rod_depth(scene, PLAIN, k) for k in range(n)])
    assert np.all(depth[:touch] <= 0) and np.all(depth[touch:] > 0)  # inside from the touch on
    assert np.all(r.phase[touch:] == SamplePhase.UNRESOLVED)
    assert np.all(np.isnan(r.f0_n[touch:])) and np.all(np.isnan(r.p_W_m[touch:]))


def test_a_path_that_jumps_past_the_front_of_a_ball_finds_the_touch_between_samples() -> None:
    """One sample carries the clamp 2 L, from beyond a ball to past its front: neither sample's
    straight rod is inside the ball, but the rod passes through it in between. The touch is
    found at sub-samples and Step 1 follows the rod around the ball from there: from the
    landing on, every sample is what a fine path gives. Once this path was free throughout."""
    ball = SceneObject("ball", "sphere", {"radius_m": 0.3 * L0},
                       Transform(translation=[0.6 * L0, 0.0, 0.8 * L0]))
    x = np.linspace(2.0, -1.2, 200) * L0  # 0.016 L a sample
    fine, coarse = (robot_path(np.arange(len(xs)) * 0.01, np.column_stack([xs, np.zeros((len(xs), 2))]),
                               np.tile([0.0, 0.0, 0.0, 1.0], (len(xs), 1)))
                    for xs in (x, np.concatenate([x[:1], x[124:]])))
    [f], [c] = (simulate(Scene(0.25, (ball,), (PLAIN,), path), workers=1) for path in (fine, coarse))
    touching = f.phase[124:] != SamplePhase.NONE
    assert touching[0] and touching.sum() > 10  # the fine rod is around the ball at the landing
    assert np.array_equal(c.phase[1:], f.phase[124:])
    scale = np.abs(f.f0_n[124:]).max()
    assert np.abs(c.f0_n[1:] - f.f0_n[124:]).max() <= 1e-9 * scale
    assert np.abs(c.m0_nm[1:] - f.m0_nm[124:]).max() <= 1e-9 * np.abs(f.m0_nm[124:]).max()
    [episode] = c.episodes
    assert c.t[0] < episode.t_first_contact < c.t[1]


def test_a_path_of_no_sample_is_refused_and_one_sample_stands_still() -> None:
    with pytest.raises(ValueError, match=r"^a path needs at least 1 sample, got 0$"):
        RobotPath(np.zeros(0), np.zeros((0, 3)), Rotation.identity(0))
    q = [0.0, 0.0, 0.6, 0.8]
    still = RobotPath(np.array([2.0]), np.array([[0.1, 0.2, 0.3]]), Rotation.from_quat([q]))
    covered, p, R = still.at([1.0, 2.0, 3.0])
    assert covered.tolist() == [False, True, False]
    np.testing.assert_array_equal(p[1], [0.1, 0.2, 0.3])
    assert np.isnan(p[[0, 2]]).all()
    np.testing.assert_allclose(R[1].as_quat(), q, atol=1e-15)
