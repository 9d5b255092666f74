"""A tangential contact with friction where the robot's path turns back (tests/data/reversal: a
whisker of an independent check's scene, mu 0.6, leaning on a ball as its arc reverses).

Coulomb's friction cannot flip from one edge of its cone to the other without passing through
it: where the contact's slide would turn back, the contact first holds where it is (the rod
rolling over it) for as long as its force stays inside the cone. Step 1 once slid it back at
once, the contact jumping 0.091 L over the ball in one sample into the neighbouring ball."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.core.test_random_scenes_rod import check_against_the_rod
from vibrissa.formats.scene_file import load_scene
from vibrissa.scene import SamplePhase, simulate_whisker

DATA = Path(__file__).parents[1] / "data" / "reversal"


@pytest.mark.slow
def test_a_tangential_contact_holds_while_its_friction_turns_back() -> None:
    scene = load_scene(DATA / "scene.yaml")
    whisker = scene.whiskers[0]
    result = simulate_whisker(scene, whisker)
    on_ball = np.flatnonzero(result.object == 1)
    rows = on_ball[result.phase[on_ball] == SamplePhase.TANGENTIAL]
    assert np.all(np.diff(rows) == 1) and len(rows) > 50
    p1 = result.p_W_m[rows] / whisker.length_m
    moved = np.diff(p1, axis=0)
    # friction of each row, from its clamp wrench: F = -f0 in W, its share across the normal
    R_WC = scene.path.R_WR[rows] * whisker.X_RC.rotation
    force = -R_WC.apply(result.f0_n[rows])
    normal = scene.objects[1].surface(1.0).normal(result.p_W_m[rows])
    fn = np.einsum("ni,ni->n", force, normal)
    ft = np.linalg.norm(force - fn[:, None] * normal, axis=1)
    held = np.flatnonzero(np.linalg.norm(moved, axis=1) <= 1e-12) + 1
    # the slides before turn back after: the held rows lie between a forward slide and a
    # backward one, with the force inside the cone
    assert len(held) >= 2
    first, last = held[0], held[-1]
    assert moved[first - 2] @ moved[last] < 0
    assert np.all(ft[held] < scene.mu * fn[held] * (1 - 1e-3))
    assert np.allclose(ft[first - 3:first], scene.mu * fn[first - 3:first], rtol=1e-9)
    # statics of every contact row, held ones too, by an independent rod from the clamp wrench
    worst = check_against_the_rod(scene)
    assert worst["reach"] <= 1e-10 and worst["tangent"] <= 1e-10
    assert worst["inside"] <= 1e-10 and worst["cone"] <= 1e-10
