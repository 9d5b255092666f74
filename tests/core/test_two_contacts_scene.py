"""A rod leaning on one ball that runs into a second one goes on with both contacts (Step 1's
``second-contact`` episodes), checked sample by sample against an integration of its own: from
the clamp wrench alone (SI, scipy's `solve_ivp`) the rod must reach the inner contact point;
there, the moment left must be the outer force's about the outer point, which gives that force
up to its component along the chord between the points; that one number chosen by least
squares, the rod must reach the outer point too, touching both balls and staying outside them.
Step 2 given the wrench says it is no single contact."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from vibrissa.formats.scene_results import read_results, write_results
from vibrissa.frames import Transform
from vibrissa.reconstruct import reconstruct_si
from vibrissa.scene import (
    RobotPath,
    SamplePhase,
    Scene,
    SceneObject,
    Whisker,
    WhiskerResult,
    simulate,
)
from vibrissa.status import ContactStatus

L_M, EI_NM2 = 0.05, 1e-4


def leaning_scene(lift_m: float) -> Scene:
    """A rod up W's z from a robot driving along x under ball a, then into ball b low on its
    way, b ``lift_m`` out of the plane of the path."""
    x = np.linspace(-0.0025, 0.045, 951)
    path = RobotPath(0.01 * np.arange(len(x)), np.column_stack([x, 0 * x, 0 * x]),
                     Rotation.identity(len(x)))
    a = SceneObject("a", "sphere", {"radius_m": 0.015},
                    Transform(Rotation.identity(), [0.015, 0.0, 0.04]))
    b = SceneObject("b", "sphere", {"radius_m": 0.005},
                    Transform(Rotation.identity(), [0.0175, lift_m, 0.0075]))
    return Scene(0.3, (a, b), (Whisker("w", L_M, EI_NM2, Transform()),), path)


def rod_from(p0: np.ndarray, t0: np.ndarray, m0: np.ndarray, n: np.ndarray, s_m: float,
             ei_nm2: float = EI_NM2) -> np.ndarray:
    """(r, t, m) after ``s_m`` of rod from (p0, t0, m0) under the internal force ``n`` (SI):
    r' = t, t' = m x t / EI, m' = n x t."""
    def rhs(_s: float, y: np.ndarray) -> np.ndarray:
        t, m = y[3:6], y[6:9]
        return np.concatenate([t, np.cross(m, t) / ei_nm2, np.cross(n, t)])

    return solve_ivp(rhs, (0.0, s_m), np.concatenate([p0, t0, m0]), method="DOP853",
                     rtol=1e-12, atol=1e-15).y[:, -1]


def two_contacts_worst(scene: Scene, whisker: Whisker, result: WhiskerResult
                       ) -> dict[str, float]:
    """The worst of the independent checks over a whisker's samples with two contacts, units
    of its L: each contact on its object (``on``); from the clamp wrench alone the rod reaching
    the inner point (``inner``); the moment left there about the chord to the outer point
    (``chord``, of |m|); the outer point reached with the one unknown left fitted (``outer``);
    the rod tangent to each object at a tangential contact (``tangent``); its depth in any
    object, the straight rest past the outer contact included (``inside``); each contact's
    force (the outer one fitted, the inner one what balances the clamp's and it) outside the
    friction cone (``cone``, (|F_t| - mu F_n) / |F|) beyond what the fit resolves, and least
    pushing (``push``, F_n / |F|). Statics leaves the outer force's part along the chord to the
    rod's shape between the contacts, which hardly depends on it where that piece is nearly
    straight: the fit's miss of the outer point (at least 1e-9 L) resolves it to that miss over
    the miss per N along the chord."""
    L, EI = whisker.length_m, whisker.ei_nm2
    surfaces = [obj.surface(1.0) for obj in scene.objects]
    worst = dict.fromkeys(("on", "inner", "chord", "outer", "tangent", "inside", "cone"), 0.0)
    worst["push"], worst["samples"] = 1.0, 0
    for k in np.flatnonzero(result.second_object >= 0):
        worst["samples"] += 1
        R_WR = scene.path.R_WR[k]
        p0 = scene.path.p_WR[k] + R_WR.apply(np.array(whisker.X_RC.translation))
        R = (R_WR * whisker.X_RC.rotation).as_matrix()
        f0, m0 = R @ result.f0_n[k], R @ result.m0_nm[k]
        (s_in, p_in, j_in), (s_out, p_out, j_out) = sorted(
            [(result.s1_m[k], result.p_W_m[k], result.object[k]),
             (result.second_s_m[k], result.second_W_m[k], result.second_object[k])],
            key=lambda c: c[0])
        for p, j in ((p_in, j_in), (p_out, j_out)):
            worst["on"] = max(worst["on"], abs(float(surfaces[j].signed_distance(p[None])[0])) / L)
        y = rod_from(p0, R[:, 2], -m0, -f0, s_in, EI)
        worst["inner"] = max(worst["inner"], float(np.linalg.norm(y[:3] - p_in)) / L)
        chord = p_out - p_in
        m_in = y[6:9]  # = chord x F_out
        worst["chord"] = max(worst["chord"], abs(m_in @ chord) / (np.linalg.norm(m_in)
                                                                  * np.linalg.norm(chord)))
        across = np.cross(m_in, chord) / (chord @ chord)  # F_out's part across the chord

        def miss(lam: np.ndarray, y: np.ndarray = y, across: np.ndarray = across,
                 chord: np.ndarray = chord, s: float = s_out - s_in,
                 p_out: np.ndarray = p_out) -> np.ndarray:
            return (rod_from(y[:3], y[3:6], y[6:9], across + lam[0] * chord, s, EI)[:3]
                    - p_out) / L

        fit = least_squares(miss, [0.0], xtol=1e-15, ftol=1e-15, gtol=1e-15)
        worst["outer"] = max(worst["outer"], float(np.linalg.norm(fit.fun)))
        outer_force = across + fit.x[0] * chord
        step_n = 1e-6 * float(np.linalg.norm(f0))  # along the chord
        per_n = float(np.linalg.norm(miss(fit.x + step_n / np.linalg.norm(chord))
                                     - miss(fit.x - step_n / np.linalg.norm(chord)))) / (2 * step_n)
        resolved_n = max(1e-9, float(np.linalg.norm(fit.fun))) / per_n
        for force, p, j in ((-f0 - outer_force, p_in, j_in), (outer_force, p_out, j_out)):
            n = surfaces[j].normal(p[None])[0]
            normal, size = float(force @ n), float(np.linalg.norm(force))
            tangential = float(np.linalg.norm(force - normal * n))
            worst["cone"] = max(worst["cone"],
                                (tangential - scene.mu * normal - resolved_n) / size)
            worst["push"] = min(worst["push"], normal / size)
        end = rod_from(y[:3], y[3:6], y[6:9], outer_force, s_out - s_in, EI)
        for t, p, j, s in ((y[3:6], p_in, j_in, s_in), (end[3:6], p_out, j_out, s_out)):
            if s < L * (1.0 - 1e-9):  # a tangential contact
                n = surfaces[j].normal(p[None])[0]
                worst["tangent"] = max(worst["tangent"], abs(float(t @ n)))
        on_rod = [rod_from(p0, R[:, 2], -m0, -f0, s, EI)[:3] for s in np.linspace(0, s_in, 9)[1:-1]]
        on_rod += [rod_from(y[:3], y[3:6], y[6:9], outer_force, s, EI)[:3]
                   for s in np.linspace(0, s_out - s_in, 9)[1:-1]]
        on_rod += [end[:3] + f * (L - s_out) * end[3:6] for f in (0.5, 1.0)]
        for q in on_rod:
            for surface in surfaces:
                worst["inside"] = max(worst["inside"],
                                      -float(surface.signed_distance(np.asarray(q)[None])[0]) / L)
    return worst


@pytest.mark.slow
@pytest.mark.parametrize("lift_m", [0.001, 0.003])
def test_two_contacts_against_the_rod_integrated_from_the_clamp_wrench(lift_m: float) -> None:
    scene = leaning_scene(lift_m)
    (result,) = simulate(scene, workers=1)
    starts = [(e.start, e.object, e.second_object) for e in result.episodes]
    assert ("second-contact", "a", "b") in starts, starts
    two = np.flatnonzero(result.second_object >= 0)
    assert len(two) >= 20
    worst = two_contacts_worst(scene, scene.whiskers[0], result)
    assert worst["on"] < 1e-12 and worst["inner"] < 1e-10 and worst["chord"] < 1e-8, worst
    assert worst["outer"] < 1e-10 and worst["tangent"] < 1e-8 and worst["inside"] <= 1e-12, worst
    assert worst["cone"] < 1e-8 and worst["push"] > 0.0, worst
    # Step 2 from the clamp wrench alone: no single contact gives it, and it says so
    rec = reconstruct_si(np.tile([0.0, 0.0, 0.0, 1.0], (len(two), 1)), scene.path.p_WR[two],
                         result.f0_n[two], result.m0_nm[two], [scene.whiskers[0].scale] * len(two))
    assert np.all(rec.status & int(ContactStatus.MULTI_CONTACT)) and not rec.valid.any()


def egg_below_scene() -> Scene:
    """A tilted rod, mu 0.67, on a robot driving along x and yawing 0.04 rad: it leans on ball
    a and runs into a small turned egg b low on its way, sliding along b as it touches."""
    x = np.linspace(-0.02, 0.045, 700)
    yaw = np.linspace(0.0, -0.041623, len(x))
    path = RobotPath(0.01 * np.arange(len(x)), np.column_stack([x, 0 * x, 0 * x]),
                     Rotation.from_euler("z", yaw[:, None]))
    a = SceneObject("a", "sphere", {"radius_m": 0.0090278},
                    Transform(Rotation.identity(), [0.020721, 0.0, 0.029736]))
    b = SceneObject("b", "ellipsoid", {"semi_axes_m": [0.0059108, 0.0038152, 0.0044715]},
                    Transform(Rotation.from_quat([-0.73749, -0.011138, 0.67199, 0.066458]),
                              [0.022218, -0.00016759, 0.0055061]))
    mount = Transform(Rotation.from_quat([0.017339, 0.047542, -0.00082541, 0.99872]),
                      np.zeros(3))
    return Scene(0.66939, (a, b), (Whisker("w", L_M, EI_NM2, mount),), path)


@pytest.mark.slow
def test_a_pair_whose_new_contact_touches_within_a_sample_starts_there_at_every_sampling(
        ) -> None:
    """At the first sample past egg b's touch, reached at once from the rod leaning on ball a,
    no guess of egg b's load reaches both contacts pushing (Newton converges to egg b pulling,
    or not at all): the pair starts where the rod has just touched the egg (the first of the
    finest sub-steps of that sample that reaches both pushing), as 4x finer sampling starts
    it. Both samplings give the same episodes, started within a coarse sample of each other,
    no sample unresolved, every sample of both contacts passing the independent check."""
    coarse, fine = coarse_and_fine("within", 3)
    assert [(e.start, e.end) for e in coarse.episodes] == [
        (e.start, e.end) for e in fine.episodes] == [
        ("touch", "another-object"), ("second-contact", "detachment"), ("landing", "detachment")]
    for i in (1, 2):
        starts = [e.t_first_contact / 0.01 / scale for e, scale in ((coarse.episodes[i], 1),
                                                                   (fine.episodes[i], 4))]
        assert abs(starts[0] - starts[1]) <= 1.0, (i, starts)
    for result in (coarse, fine):
        assert not np.any(result.phase == SamplePhase.UNRESOLVED)


@pytest.mark.slow
def test_a_second_contact_slides_from_where_it_touched() -> None:
    """The new contact's friction at its first sample opposes its slide from where the rod
    touched the object (eq. 7's chord from the touch, as for a first contact), not from a point
    inside it: from there the pair has an equilibrium, and the rod leans on both."""
    scene = egg_below_scene()
    (result,) = simulate(scene, workers=1)
    starts = [(e.start, e.object, e.second_object) for e in result.episodes]
    assert ("second-contact", "a", "b") in starts, starts
    worst = two_contacts_worst(scene, scene.whiskers[0], result)
    assert worst["samples"] >= 5, worst
    assert worst["on"] < 1e-12 and worst["inner"] < 1e-10 and worst["chord"] < 1e-8, worst
    assert worst["outer"] < 1e-9 and worst["tangent"] < 1e-8 and worst["inside"] <= 1e-12, worst
    assert worst["cone"] < 1e-8 and worst["push"] > 0.0, worst


def test_the_second_contact_is_written_and_read_back_bit_for_bit(tmp_path: Path) -> None:
    scene = leaning_scene(0.001)
    (result,) = simulate(scene, workers=1)
    write_results(tmp_path, scene, [result])
    (back,) = read_results(tmp_path, scene)
    for name in ("second_s_m", "second_W_m", "second_object", "p_W_m", "f0_n"):
        np.testing.assert_array_equal(getattr(back, name), getattr(result, name))
    assert back.episodes == result.episodes
    assert "object2" in (tmp_path / "w.csv").read_text().splitlines()[0]


def test_a_rod_that_meets_nothing_else_is_as_before() -> None:
    """Without the second ball the rod's path has no second contact, and the ball moved out of
    reach gives the same samples as no ball at all."""
    scene = leaning_scene(0.001)
    alone = dataclasses.replace(scene, objects=scene.objects[:1])
    far = dataclasses.replace(scene, objects=(scene.objects[0], dataclasses.replace(
        scene.objects[1], X_WO=Transform(Rotation.identity(), [1.0, 1.0, 1.0]))))
    (a,) = simulate(alone, workers=1)
    (b,) = simulate(far, workers=1)
    assert not np.any(a.second_object >= 0)
    np.testing.assert_array_equal(a.f0_n, b.f0_n)
    np.testing.assert_array_equal(a.p_W_m, b.p_W_m)


EGG_SCENES = {  # ball a (radius, centre), egg b (semi-axes, quaternion, centre), mu
    "deep": (0.0087503, [0.020461, 0.0, 0.031685], [0.0058456, 0.0042664, 0.0049674],
             [-0.85270, 0.0083982, -0.48241, -0.20028], [0.024098, -0.00021675, 0.0046554],
             0.43838),
    "near": (0.012597, [0.020857, 0.0, 0.031614], [0.0060893, 0.0036206, 0.0044535],
             [0.78061, -0.066951, 0.56164, -0.26595], [0.024327, 0.00010536, 0.0062134],
             0.49483),
    "leaves": (0.011184808436607272, [0.019809360141291612, 0.0, 0.030122920571808584],
               [0.0035446246159270287, 0.005695829645840735, 0.0059644400586498485],
               [0.5799686609772983, 0.13155995106814497, 0.32178033684031665,
                0.7367399448801996],
               [0.02442654310306872, 0.00013769793659039903, 0.005359062478663557],
               0.6740289695151073),
    "within": (0.012154916594445557, [0.02008284000050277, 0.0, 0.032108217916746166],
               [0.005822320723962005, 0.005231557198128045, 0.004980580663795947],
               [0.9914331562476824, 0.05060637596200202, 0.11118529628315307,
                -0.04622900923855653],
               [0.02504925369012477, 0.00012978862958402428, 0.00516792188477713],
               0.5289835752730587),
    "goes-on": (0.008428245835718122, [0.0197104315197883, 0.0, 0.03240382339561919],
                [0.005071837497373793, 0.0037541473340490777, 0.00466944273863848],
                [0.6823224186903585, 0.1665189061942498, 0.03681166144364953,
                 -0.7108814756442652],
                [0.023916205192563336, -0.00020415665121775283, 0.005836442878523036],
                0.34546880796856133)}


def egg_scene(samples: int, case: str) -> Scene:
    """egg_below_scene's kind with another ball, egg and friction (`EGG_SCENES`), 0.11 mm of
    travel per sample at 590 samples: ``deep``, the rod, leaning on ball a, is 0.1 mm inside
    egg b at the first sample past the touch; ``near``, the rod leans on egg b 3.5-5 mm from the
    clamp; ``leaves``, the contact on egg b runs out of force as the clamp runs into ball a."""
    return egg_scene_of(samples, *EGG_SCENES[case])


def egg_scene_of(samples: int, radius: float, centre: list[float], axes: list[float],
                 quaternion: list[float], position: list[float], mu: float) -> Scene:
    """`egg_scene` of ball a (``radius``, ``centre``), egg b (semi-axes ``axes``, turned by
    ``quaternion`` (x, y, z, w), at ``position``; m) and friction ``mu``."""
    x = np.linspace(-0.02, 0.045, samples)
    yaw = np.linspace(0.0, -0.04, len(x))
    path = RobotPath(0.01 * np.arange(len(x)), np.column_stack([x, 0 * x, 0 * x]),
                     Rotation.from_euler("z", yaw[:, None]))
    a = SceneObject("a", "sphere", {"radius_m": radius}, Transform(Rotation.identity(), centre))
    b = SceneObject("b", "ellipsoid", {"semi_axes_m": axes},
                    Transform(Rotation.from_quat(quaternion), position))
    mount = Transform(Rotation.from_quat([0.017339, 0.047542, -0.00082541, 0.99872]),
                      np.zeros(3))
    return Scene(mu, (a, b), (Whisker("w", L_M, EI_NM2, mount),), path)


def coarse_and_fine(case: str, samples: int) -> tuple[WhiskerResult, WhiskerResult]:
    """`egg_scene` ``case`` at 590 and 2 357 samples (sample k of the first is sample 4 k of
    the second), each with at least ``samples`` samples of two contacts, every one passing
    the independent check."""
    results = []
    for n in (590, 2357):
        scene = egg_scene(n, case)
        (result,) = simulate(scene, workers=1)
        worst = two_contacts_worst(scene, scene.whiskers[0], result)
        assert worst["samples"] >= samples, worst
        assert worst["on"] < 1e-12 and worst["inner"] < 1e-10 and worst["chord"] < 1e-8, worst
        assert worst["outer"] < 1e-9 and worst["tangent"] < 1e-8, worst
        assert worst["inside"] <= 1e-12 and worst["cone"] < 1e-8 and worst["push"] > 0.0, worst
        results.append(result)
    return results[0], results[1]


@pytest.mark.slow
def test_an_object_entered_deeply_within_a_sample_starts_the_pair_that_finer_samples_follow(
        ) -> None:
    """From a small guess of the new contact's load Newton reaches no admissible state at the
    pair's first sample (the episode ended `another-object`, its samples unresolved); a
    larger guess (`PAIR_START_LOADS`) reaches the state that 4x finer sampling follows from
    the touch: the same episodes, started within a sample of each other, and at the samples
    both have the same wrench within 5e-3 of its size (friction's chords differ with the
    step), every one passing the independent check."""
    coarse, fine = coarse_and_fine("deep", 5)
    assert [(e.start, e.end) for e in coarse.episodes][:2] == [
        (e.start, e.end) for e in fine.episodes][:2] == [
        ("touch", "another-object"), ("second-contact", "detachment")]
    starts = [e.t_first_contact / 0.01 / scale for e, scale in ((coarse.episodes[1], 1),
                                                               (fine.episodes[1], 4))]
    assert abs(starts[0] - starts[1]) <= 1.0, starts
    pair = np.flatnonzero(coarse.second_object >= 0)
    assert np.all(fine.second_object[4 * pair] >= 0)
    for k in pair:
        size = np.linalg.norm(coarse.f0_n[k])
        assert np.linalg.norm(coarse.f0_n[k] - fine.f0_n[4 * k]) <= 5e-3 * size, k


@pytest.mark.slow
def test_a_pair_near_the_clamp_is_followed_until_a_contact_leaves() -> None:
    """The rod's line checked for clearance, integrated in steps of 1/256 L where the solve
    took 0.07/256 L (the inner contact 3.5 mm from the clamp), dipped 2e-9 L into the egg
    beside its contact: the stretch ended `another-object` and 87 samples were unresolved.
    Integrated with the solve's own steps, it goes on until the contact on the egg leaves;
    the rod lands on the ball, meets the egg again, and no sample is left unresolved; every
    two-contact sample passes the independent check."""
    scene = egg_scene(590, "near")
    (result,) = simulate(scene, workers=1)
    assert [(e.start, e.end) for e in result.episodes][:3] == [
        ("touch", "another-object"), ("second-contact", "detachment"),
        ("landing", "another-object")], result.episodes
    assert result.counts()["unresolved"] == 0
    worst = two_contacts_worst(scene, scene.whiskers[0], result)
    assert worst["samples"] >= 10, worst
    assert worst["on"] < 1e-12 and worst["inner"] < 1e-10 and worst["chord"] < 1e-8, worst
    assert worst["outer"] < 1e-9 and worst["tangent"] < 1e-8, worst
    assert worst["inside"] <= 1e-12 and worst["cone"] < 1e-8 and worst["push"] > 0.0, worst


@pytest.mark.slow
def test_a_contact_running_out_of_force_leaves_at_every_sampling_not_onto_another_branch(
        ) -> None:
    """Egg b's contact loses about 0.45 EI/L^2 of force a sample down to 0.08: a whole step
    past where it leaves reached another equilibrium (b's contact at 270 times its force, a
    tip instead of a side contact), and the pair went on there to a snap-off, where 4x finer
    sampling has b's contact leave smoothly. Both samplings now end the pair with b leaving,
    at the same place within a coarse sample, and go on alike."""
    results = {n: simulate(egg_scene(n, "leaves"), workers=1)[0] for n in (590, 2357)}
    kinds = {n: [(e.start, e.end) for e in r.episodes] for n, r in results.items()}
    assert kinds[590] == kinds[2357], kinds
    assert ("second-contact", "detachment") in kinds[590], kinds
    last = {n: int(np.flatnonzero(r.second_object >= 0)[-1]) for n, r in results.items()}
    assert abs(last[590] - last[2357] / 4) <= 1.0, last
