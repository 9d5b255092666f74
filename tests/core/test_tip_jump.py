"""A tip sliding over a ball with friction (mu 0.3) where the sampling leaves it a choice
(tests/data/tip_jump: a whisker of an independent check's scene, as sampled and with 4 samples
per sample).

Where a tip can hold (its force turns inside the cone) or slip a little from where it holds, it
does: that is the state that goes on from the last one. A slide to a far point is a jump to
another branch. Step 1 once took such slides at one step per sample: the tip jumped 0.12-0.28 L
back and forth every other sample, for 43 samples, where 4 samples per sample stick and creep."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.core.test_random_scenes_rod import check_against_the_rod
from vibrissa.formats.scene_file import load_scene
from vibrissa.scene import SamplePhase, simulate_whisker

DATA = Path(__file__).parents[1] / "data" / "tip_jump"


@pytest.mark.slow
def test_a_tip_that_can_hold_does_not_jump() -> None:
    runs = {}
    for sampling in ("x1", "x4"):
        scene = load_scene(DATA / f"scene_{sampling}.yaml")
        runs[sampling] = scene, simulate_whisker(scene, scene.whiskers[0])
    scene, coarse = runs["x1"]
    _, fine = runs["x4"]
    L = scene.whiskers[0].length_m
    fine_tip = np.flatnonzero(fine.phase == SamplePhase.TIP)
    # up to a sample before the finely sampled tip snaps off (the fold of its branch), both
    # samplings follow one branch: the coarse tip moves at most 0.02 L a sample (a step is
    # 0.015 L) and lies within 0.01 L of the fine one at each shared sample. (In the sample
    # before the fold the coarse tip still jumps: the README's known limits.)
    until = fine.t[fine_tip[-1]] - (coarse.t[1] - coarse.t[0])
    rows = np.flatnonzero((coarse.phase == SamplePhase.TIP) & (coarse.t <= until + 1e-9))
    assert np.all(np.diff(rows) == 1) and len(rows) > 100
    steps = np.linalg.norm(np.diff(coarse.p_W_m[rows], axis=0), axis=1) / L
    assert steps.max() < 0.02, f"the tip jumps {steps.max():.3f} L in one sample"
    shared = 4 * rows
    assert np.all(fine.phase[shared] == SamplePhase.TIP)
    assert np.allclose(fine.t[shared], coarse.t[rows], atol=1e-12)
    apart = np.linalg.norm(fine.p_W_m[shared] - coarse.p_W_m[rows], axis=1) / L
    assert apart.max() < 0.01
    # it holds (the contact does not move) for some samples on the way
    assert np.sum(steps <= 1e-12) >= 3
    # statics of every contact row by an independent rod from the clamp wrench
    worst = check_against_the_rod(scene)
    assert worst["reach"] <= 1e-10 and worst["inside"] <= 1e-10 and worst["cone"] <= 1e-10
