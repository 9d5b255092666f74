"""How a contact ends: a detachment leaves a free rod, so at the sample after the last contact
the straight rod is outside the object or on its way out (less of it inside than at the last
contact). Two whiskers of independent checks' scenes (tests/data/detachment_inside):

* ``scene.yaml`` (mu 0.8): a tip's force halved in the last sub-step before a fold, with the
  straight rod going deeper into the cup. Step 1 called that a detachment, by the force alone.
* ``scene_slide_off.yaml`` (mu 0): a rod slides off its tip as the force falls linearly to zero,
  its last sample in contact at 0.6 % of the force four samples before. That is a detachment:
  at the next sample its straight rod is outside the ball (a sample whose straight rod still
  grazes it would be unresolved, not free).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from vibrissa.formats.scene_file import load_scene
from vibrissa.scene import SamplePhase, simulate_whisker

DATA = Path(__file__).parents[1] / "data" / "detachment_inside"


def _inside_m(points_W: np.ndarray, obj: dict[str, Any]) -> np.ndarray:
    """Whether each point lies inside the scene file's object ``obj`` (its implicit function)."""
    x, y, z = Rotation.from_quat(obj["quaternion_xyzw"]).inv().apply(
        points_W - np.asarray(obj["position_m"])).T
    if obj["shape"] == "sphere":
        return np.asarray(x**2 + y**2 + z**2 < obj["radius_m"] ** 2)
    if obj["shape"] == "ellipsoid":
        a, b, c = obj["semi_axes_m"]
        return np.asarray((x / a) ** 2 + (y / b) ** 2 + (z / c) ** 2 < 1.0)
    assert obj["shape"] == "paraboloid"
    return np.asarray(z > obj["a_per_m"] * x**2 + obj["b_per_m"] * y**2 + obj["h_m"])


def _straight_rod_inside_m(raw: dict[str, Any], path: np.ndarray, row: int, obj: dict[str, Any]
                           ) -> float:
    """How much of the undeformed rod (10 001 points) lies inside ``obj`` at path sample ``row``,
    m: the clamp pose X_WR X_RC composed by scipy from the scene and path files."""
    whisker = raw["whiskers"][0]
    X = path[row]
    R_WR = Rotation.from_quat(X[4:8])
    p_WC = X[1:4] + R_WR.apply(whisker["mount"]["position_m"])
    R_WC = R_WR * Rotation.from_quat(whisker["mount"]["quaternion_xyzw"])
    s = np.linspace(0.0, whisker["length_m"], 10_001)
    inside = _inside_m(p_WC + R_WC.apply([0.0, 0.0, 1.0]) * s[:, None], obj)
    return float(np.count_nonzero(inside) * (s[1] - s[0]))


@pytest.mark.parametrize(("scene_file", "end", "deeper"), [
    ("scene.yaml", "snap-off", True),
    ("scene_slide_off.yaml", "detachment", False),
])
@pytest.mark.slow
def test_a_detachment_leaves_the_straight_rod_on_its_way_out(scene_file: str, end: str,
                                                              deeper: bool) -> None:
    scene = load_scene(DATA / scene_file)
    (whisker,) = scene.whiskers
    result = simulate_whisker(scene, whisker)
    episode, *later = result.episodes
    in_contact = np.isin(result.phase, (SamplePhase.TIP, SamplePhase.TANGENTIAL))
    if later:  # the episode's rows end where the next begins
        in_contact &= result.t < later[0].t_first_contact
    last = np.flatnonzero(in_contact)[-1]
    raw = yaml.safe_load((DATA / scene_file).read_text())
    obj = next(o for o in raw["objects"] if o["name"] == episode.object)
    path = np.loadtxt(DATA / raw["path"], delimiter=",", skiprows=1)
    assert np.array_equal(path[:, 0], result.t)
    at_last, after = (_straight_rod_inside_m(raw, path, row, obj) for row in (last, last + 1))
    assert (after > at_last) is deeper
    if end == "snap-off":  # the rod lands on the object again at the next sample
        assert later[0].start == "landing" and later[0].t_first_contact == result.t[last + 1]
        assert after > 1e-4 * whisker.length_m  # the independent geometry: not free there
    elif after > 0.0:  # a rod whose straight line still grazes the object is not called free
        assert result.phase[last + 1] == SamplePhase.UNRESOLVED and not later
    else:
        assert result.phase[last + 1] == SamplePhase.NONE and not later
    assert episode.end == end
