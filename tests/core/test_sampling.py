"""Step 1's contact events do not depend on how finely the path is sampled: a rod on a yawing
robot, its tip on a sphere at 40-55 degrees from the surface normal (the rod's plane tilted
out of the sphere's equator), driven along the same arc at 1, 4 and 10 samples per 0.1 mm of
tip travel, gives the same episodes (how each begins and ends, in the same order) with their
starts within one coarse sample.

At 10 samples, the tip's slip just after a touch is about 1e-6 L per sample, too short a chord
for eq. 7's friction direction (`vibrissa.sweep.RESOLVED_CHORD_L`), and at mu 0.8 such a slow
slide goes on beyond 0.01 L past the touch (`vibrissa.sweep._unresolved_slip`): the cases are
ones where either took the fine samplings through snap-offs and landings the coarse one
does not have."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vibrissa.cli.scenes import episode_summary
from vibrissa.formats.scene_results import read_results, write_results
from vibrissa.frames import Transform
from vibrissa.scene import (
    RobotPath,
    SamplePhase,
    Scene,
    SceneObject,
    Whisker,
    WhiskerResult,
    simulate,
    snaps,
)

L_M, EI_NM2 = 0.035, 1e-4
TIP_STEP_M = 1e-4  # tip travel per coarse sample


def yawing_scene(tilt_deg: float, elevation_deg: float, mu: float, radius_m: float,
                 per_sample: int, arc_rad: float = 1.0) -> Scene:
    """A rod along W's x from the robot's origin, the robot yawing about z from -0.05 to
    ``arc_rad``; a sphere whose surface holds the point 0.95 L along the rod, its outward
    normal there turned ``tilt_deg`` from -x towards -y, then ``elevation_deg`` about y."""
    contact = np.array([0.95 * L_M, 0.0, 0.0])
    tilt = np.radians(tilt_deg)
    normal = Rotation.from_euler("y", np.radians(elevation_deg)).apply(
        [-np.cos(tilt), -np.sin(tilt), 0.0])
    centre = contact - radius_m * normal
    yaw = np.arange(-0.05, arc_rad, TIP_STEP_M / L_M / per_sample)
    path = RobotPath(np.arange(len(yaw)) * 0.01, np.zeros((len(yaw), 3)),
                     Rotation.from_euler("z", yaw[:, None]))
    ball = SceneObject("ball", "sphere", {"radius_m": radius_m},
                       Transform(Rotation.identity(), centre))
    rod = Whisker("w", L_M, EI_NM2, Transform(Rotation.from_euler("y", np.pi / 2), np.zeros(3)))
    return Scene(mu, (ball,), (rod,), path)


@pytest.mark.slow
@pytest.mark.parametrize("tilt_deg, elevation_deg, mu, radius_m", [
    (50.0, 40.0, 0.5, 0.02), (45.0, -20.0, 0.5, 0.01), (40.0, 10.0, 0.3, 0.005),
    (45.0, 10.0, 0.8, 0.005), (55.0, -20.0, 0.8, 0.01),
    # a sub-step's predictor within the sub-step: the 1x run stopped 1.2 samples before the fold
    (45.0, 10.0, 0.5, 0.005),
    # the touch's load guess scaled to a longer early step: at 10x no step was found at all
    (40.0, -20.0, 0.5, 0.005),
    # the secant stage for a sub-step's shorter chord: a creeping tip snapped off at 4x only;
    # where the tip creeps after its landing, round-off decides whether it meets a fold 7
    # samples on (an AMD EPYC with FMA: at 4x and 10x only)
    pytest.param(40.0, -20.0, 0.3, 0.005, marks=pytest.mark.xfail(
        reason="the tip's creep after its landing is decided by round-off on some CPUs "
               "(docs/LIMITS.md)", strict=False))])
def test_the_episodes_are_the_same_at_1_4_and_10_samples(
        tilt_deg: float, elevation_deg: float, mu: float, radius_m: float) -> None:
    agree, episodes, events = sampled_alike(tilt_deg, elevation_deg, mu, radius_m)
    assert agree, (episodes, events)


SAMPLINGS = (1, 4, 10)
"""Samples per 0.1 mm of tip travel that `sampled_alike` compares."""


def sampled_alike(tilt_deg: float, elevation_deg: float, mu: float, radius_m: float,
                  arc_rad: float = 1.0) -> tuple[bool, dict[int, list[tuple[str, str, float]]],
                                                 dict[int, list[tuple[str, float]]]]:
    """`yawing_scene` at each of `SAMPLINGS`: whether its episodes (how each begins and ends)
    are the same at all three, at least one, each starting within one coarse sample of the
    coarse path's, and its snaps (snap-offs, landings, snap-throughs) the same kinds in the same
    order, each told less than a coarse sample from the coarse path's; with each sampling's
    episodes (start, end, first contact) and snaps (kind, sample after), in coarse samples."""
    episodes, events = {}, {}
    for per_sample in SAMPLINGS:
        (result,) = simulate(yawing_scene(tilt_deg, elevation_deg, mu, radius_m, per_sample,
                                          arc_rad), workers=1)
        coarse_sample = result.t / 0.01 / per_sample
        episodes[per_sample] = [
            (e.start, e.end, float(np.interp(e.t_first_contact, result.t, coarse_sample)))
            for e in result.episodes]
        events[per_sample] = [(snap.kind, float(coarse_sample[snap.after]))
                              for snap in snaps(result, ["ball"])]
    kinds = {n: [(start, end) for start, end, _ in eps] for n, eps in episodes.items()}
    coarse, *finer = SAMPLINGS
    agree = bool(kinds[coarse]) and all(kinds[n] == kinds[coarse] for n in finer)
    agree = agree and all(abs(a[2] - b[2]) <= 1.0 for n in finer
                          for a, b in zip(episodes[n], episodes[coarse], strict=True))
    agree = agree and all([k for k, _ in events[n]] == [k for k, _ in events[coarse]]
                          for n in finer)
    agree = agree and all(abs(a[1] - b[1]) < 1.0 for n in finer
                          for a, b in zip(events[n], events[coarse], strict=True))
    return agree, episodes, events


@pytest.mark.slow
@pytest.mark.parametrize("tilt_deg, elevation_deg, mu, radius_m", [
    (50.0, 40.0, 0.5, 0.02), (40.0, 10.0, 0.3, 0.005), (45.0, 10.0, 0.8, 0.005)])
def test_no_jump_of_the_wrench_inside_an_episode_is_left_untold(
        tilt_deg: float, elevation_deg: float, mu: float, radius_m: float) -> None:
    """At 10 samples per 0.1 mm, between two samples in contact with the ball that no snap
    lies between, the clamp wrench changes by at most 4 times the median of its changes over
    the five samples on each side: the fold where the tip's slip runs away (the first case, at
    about sample 201.5) is a told snap-through, not a drop of the axial force by a fifth inside
    one sample."""
    (result,) = simulate(yawing_scene(tilt_deg, elevation_deg, mu, radius_m, 10), workers=1)
    untold, checked = untold_jumps(result, L_M, EI_NM2, ["ball"])
    assert not untold, untold
    assert checked > 1000


def wrench_units(result: WhiskerResult, length_m: float, ei_nm2: float) -> np.ndarray:
    """The clamp wrench of ``result`` (N, 6): f0 in units of EI/L^2, m0 in EI/L."""
    return np.hstack([result.f0_n / (ei_nm2 / length_m**2), result.m0_nm / (ei_nm2 / length_m)])


def untold_jumps(result: WhiskerResult, length_m: float, ei_nm2: float,
                 object_names: list[str], growth: float = 4.0, floor: float = 0.0,
                 same_phase: bool = False) -> tuple[list[tuple[int, float, float]], int]:
    """The samples k of ``result`` whose clamp wrench (units of EI/L^2 and EI/L) changes to
    k + 1 by more than ``growth`` times the median of its changes over the five samples on each
    side and more than ``floor``, between two samples in contact (``same_phase``: in the same
    phase) with no snap told between them (sample, change, median); and how many samples were
    checked (those with four such neighbours at least)."""
    told = {snap.before for snap in snaps(result, object_names)}
    change = np.linalg.norm(np.diff(wrench_units(result, length_m, ei_nm2), axis=0),
                            axis=1)  # sample k to k + 1
    contact = np.isin(result.phase, [SamplePhase.TIP, SamplePhase.TANGENTIAL])
    held = contact[:-1] & contact[1:]
    if same_phase:
        held &= result.phase[:-1] == result.phase[1:]
    untold, checked = [], 0
    for k in np.flatnonzero(held):
        around = [j for j in range(k - 5, k + 6) if j != k and 0 <= j < len(change) and held[j]]
        if k in told or len(around) < 4:
            continue
        checked += 1
        median = float(np.median(change[around]))
        if change[k] > max(growth * median, floor):
            untold.append((int(k), float(change[k]), median))
    return untold, checked


def test_a_jump_of_the_contact_inside_an_episode_is_told_with_its_wrenches(tmp_path: Path
                                                                          ) -> None:
    """A far slide taken where no nearer state exists (the contact jumps to another branch) is
    a snap-through: in the episode, in summary.json with the wrenches of the samples before and
    at it (read back), and in `vibrissa simulate`'s closing line."""
    scene = yawing_scene(50.0, 40.0, 0.5, 0.02, 4)
    (result,) = simulate(scene, workers=1)
    jumps = [t for e in result.episodes for t in e.snap_throughs]
    assert jumps, result.episodes
    tip_step_m = TIP_STEP_M / 4
    for t in jumps:
        k = int(np.flatnonzero(result.t == t)[0])
        moved_m = np.linalg.norm(result.p_W_m[k] - result.p_W_m[k - 1])
        assert moved_m > 2 * tip_step_m  # `vibrissa.sweep.FAR_STEPS`: more than two steps

    write_results(tmp_path, scene, [result])
    summary = json.loads((tmp_path / "summary.json").read_text())
    told = [s for e in summary["whiskers"]["w"]["episodes"] for s in e["snap_throughs"]]
    assert [s["t"] for s in told] == jumps and {s["kind"] for s in told} == {"snap-through"}
    for s in told:
        k = int(np.flatnonzero(result.t == s["t"])[0])
        assert s["f0_before"] == result.f0_n[k - 1].tolist()
        assert s["m0_after"] == result.m0_nm[k].tolist()
    every = summary["whiskers"]["w"]["snaps"]  # snap-offs and landings too, in time order
    assert [(s["t"], s["kind"]) for s in every] == [
        (snap.t, snap.kind) for snap in snaps(result, [obj.name for obj in scene.objects])]
    assert {s["kind"] for s in every} >= {"snap-through", "snap-off", "landing"}
    (back,) = read_results(tmp_path, scene)
    assert [e.snap_throughs for e in back.episodes] == [e.snap_throughs for e in result.episodes]
    assert f"{len(jumps)} snap-through" in episode_summary([result])


def test_every_snap_of_the_path_is_a_jump_of_the_wrench_told_with_its_two_samples() -> None:
    """`snaps`: a snap-off (the rod's last sample in contact to the next), the landing on the
    sample after it and a snap-through, in time order; at each the clamp wrench changes by
    more than five times what it changes from sample to sample around it, and at the
    snap-off the contact point leaves for another place on the ball."""
    scene = yawing_scene(50.0, 40.0, 0.5, 0.02, 4)
    (result,) = simulate(scene, workers=1)
    found = snaps(result, [obj.name for obj in scene.objects])
    assert [s.kind for s in found] == ["snap-off", "landing", "snap-through"], result.episodes
    wrench = np.hstack([result.f0_n, result.m0_nm / L_M])
    change = np.linalg.norm(np.diff(wrench, axis=0), axis=1)  # sample k to k + 1
    for snap in found:
        assert snap.after == snap.before + 1 and snap.t == result.t[snap.after]
        around = np.r_[change[snap.before - 5:snap.before], change[snap.after:snap.after + 5]]
        assert change[snap.before] > 5 * np.median(around), (snap, change[snap.before], around)
    snap_off, landing, through = found
    assert result.phase[snap_off.before] != SamplePhase.NONE
    assert (landing.before, landing.after) == (snap_off.before, snap_off.after)
    moved_m = np.linalg.norm(result.p_W_m[snap_off.after] - result.p_W_m[snap_off.before])
    assert moved_m > 10 * TIP_STEP_M / 4
    assert through.t in result.episodes[1].snap_throughs


def turning_scene(per_sample: int) -> Scene:
    """A 44 mm rod, its mount turned 5 degrees about its x, on a robot yawing about z past an
    ellipsoid (semi-axes 16.5, 7.1 and 10.8 mm) turned askew, mu 0.2, at ``per_sample``
    samples per 0.1 mm of tip travel: its side contact slips along the ellipsoid in runs that
    end far (snap-throughs)."""
    length_m = 0.04405828818438578
    yaw = np.arange(-0.05, 1.0485, TIP_STEP_M / length_m / per_sample)
    path = RobotPath(np.arange(len(yaw)) * 0.01, np.zeros((len(yaw), 3)),
                     Rotation.from_euler("z", yaw[:, None]))
    egg = SceneObject("egg", "ellipsoid", {"semi_axes_m": [0.016464621887173375,
                                                            0.0071294453828924685,
                                                            0.010816787675806919]},
                      Transform(Rotation.from_quat([-0.17404648584945479, 0.5154699486635417,
                                                    -0.8068164585250307, -0.23031664082603465]),
                                [0.020179354568770555, 0.023059121988000086,
                                 0.004496611772256579]))
    rod = Whisker("w", length_m, 0.0002308186307667127,
                  Transform(Rotation.from_euler("yx", [np.pi / 2, 0.08719834969098161]),
                            np.zeros(3)))
    return Scene(0.2, (egg,), (rod,), path)


@pytest.mark.slow
def test_a_slide_that_runs_far_and_the_friction_it_turns_over_are_told_at_any_sampling(
) -> None:
    """A slide that runs far lands with the friction against it; the next sample turns the
    friction over, the clamp force changing by 0.09-0.14 EI/L^2: a jump as large at 4
    samples per 0.1 mm as at 1 (it does not shrink with the step), told as a snap-through
    right after the slide's own. At 1 sample no other change of the wrench inside the episode
    is larger than 4 times those around it; at 4, 3 samples
    change by 10 times those around (a steep stretch the finer step resolves, where the 1x path
    slides far), none of them after a told slide."""
    turned = {}
    for per_sample in (1, 4):
        (result,) = simulate(turning_scene(per_sample), workers=1)
        untold, checked = untold_jumps(result, 0.04405828818438578, 0.0002308186307667127,
                                       ["egg"], floor=1e-3, same_phase=True)
        assert checked > 200 * per_sample
        after = [snap.after for snap in snaps(result, ["egg"]) if snap.kind == "snap-through"]
        assert not {k for k, _, _ in untold} & set(after), (per_sample, untold, after)
        assert per_sample > 1 or not untold, untold
        pairs = [k for k in after if k + 1 in after]  # a far slide, then its friction turned
        assert len(pairs) >= (3 if per_sample == 1 else 1), (per_sample, after)
        f0 = result.f0_n / (0.0002308186307667127 / 0.04405828818438578**2)
        turned[per_sample] = [float(np.linalg.norm(f0[k + 1] - f0[k])) for k in pairs]
    assert min(turned[1] + turned[4]) > 0.05, turned  # EI/L^2
    assert np.median(turned[4]) > 0.5 * np.median(turned[1]), turned  # no smaller: a jump
