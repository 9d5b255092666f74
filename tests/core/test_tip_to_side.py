"""A tip that rolls onto the rod's side and holds there (tests/data/tip_to_side: a whisker of an
independent check's scene, mu 0.8, as sampled and with 4 samples per sample).

The tip slides over an ellipsoid; then its contact moves from the tip onto the rod's side
(s1 just below L) and holds there, the rod rolling over it, while its force turns inside the
cone. Step 1 held only a contact that was already tangential: at 4x the tip found neither a
slide nor a stick, and the episode ended as a snap-off 37 samples before 1x's, with the
force rising smoothly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.core.test_random_scenes_rod import check_against_the_rod
from vibrissa.formats.scene_file import load_scene
from vibrissa.scene import SamplePhase, simulate_whisker

DATA = Path(__file__).parents[1] / "data" / "tip_to_side"


@pytest.mark.slow
def test_a_tip_rolls_onto_the_side_at_any_sampling() -> None:
    ends = {}
    for sampling in ("x1", "x4"):
        scene = load_scene(DATA / f"scene_{sampling}.yaml")
        result = simulate_whisker(scene, scene.whiskers[0])
        episode, *later = result.episodes  # a snap-off may be followed by a landing
        contact = np.isin(result.phase, (SamplePhase.TIP, SamplePhase.TANGENTIAL))
        if later:
            contact &= result.t < later[0].t_first_contact
        tip, side = (np.flatnonzero((result.phase == p) & contact)
                     for p in (SamplePhase.TIP, SamplePhase.TANGENTIAL))
        assert len(tip) and len(side) and tip[-1] < side[0]  # the tip first, then the side
        assert [(a, b) for _, a, b in episode.phase_changes] == [("tip", "tangential")]
        ends[sampling] = result.t[np.flatnonzero(contact)[-1]]
        # statics of every contact row by an independent rod from the clamp wrench
        worst = check_against_the_rod(scene)
        assert worst["reach"] <= 1e-10 and worst["inside"] <= 1e-10 and worst["cone"] <= 1e-10
        assert worst["tangent"] <= 1e-10
    # both samplings follow the contact to the same end, within one sample of the coarse path
    sample_s = 0.002
    assert abs(ends["x4"] - ends["x1"]) <= sample_s + 1e-9, ends
