"""A rod that snaps off with its straight rod still inside an object lands on it at the next
sample, and its contact goes on from there (tests/data/landing: one whisker each of three
independent checks' scenes):

* ``scene_n.yaml`` (mu 0): a tilted rod on an arc; its tangential contact on a paraboloid folds
  with the straight rod deep inside. Before, the 518 samples after it (58 % of the path) were
  ``unresolved``.
* ``scene_k.yaml`` (mu 0.6): a snap-off from a paraboloid, then a landing that holds and ends
  in a detachment.
* ``scene_m.yaml`` (mu 0.5): snap-offs from a ball and an egg; after the egg the straight rod
  is inside the cup, another object, and the rod lands there.

The checks are independent of Step 1: the objects' implicit functions from the scene file
(scipy frames), and a rod integrated from each row's clamp wrench.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from tests.core.test_detachment_label import _straight_rod_inside_m
from tests.core.test_random_scenes_rod import check_against_the_rod
from vibrissa.cli.main import main
from vibrissa.formats.scene_file import load_scene
from vibrissa.formats.scene_results import read_results
from vibrissa.frames import Transform
from vibrissa.scene import RobotPath, SamplePhase, simulate_whisker

DATA = Path(__file__).parents[1] / "data" / "landing"


def _outward_normal(p_W: np.ndarray, obj: dict[str, Any]) -> np.ndarray:
    """The outward unit normal of the scene file's object ``obj`` at ``p_W`` (m): the gradient
    of its implicit function (negative inside)."""
    R_WO = Rotation.from_quat(obj["quaternion_xyzw"])
    x, y, z = R_WO.inv().apply(p_W - np.asarray(obj["position_m"]))
    if obj["shape"] == "sphere":
        gradient = np.array([x, y, z])
    elif obj["shape"] == "ellipsoid":
        gradient = np.array([x, y, z]) / np.asarray(obj["semi_axes_m"]) ** 2
    else:  # paraboloid: inside where z > a x^2 + b y^2 + h
        gradient = np.array([2.0 * obj["a_per_m"] * x, 2.0 * obj["b_per_m"] * y, -1.0])
    n_W = R_WO.apply(gradient)
    return np.asarray(n_W / np.linalg.norm(n_W))


@pytest.mark.slow
@pytest.mark.parametrize(("name", "landings"), [("n", 1), ("k", 1), ("m", 4)])
def test_a_rod_that_snaps_off_inside_an_object_lands_on_it(name: str, landings: int) -> None:
    scene = load_scene(DATA / f"scene_{name}.yaml")
    (whisker,) = scene.whiskers
    L = whisker.length_m
    result = simulate_whisker(scene, whisker)
    raw = yaml.safe_load((DATA / f"scene_{name}.yaml").read_text())
    path = np.loadtxt(DATA / raw["path"], delimiter=",", skiprows=1)
    assert np.array_equal(path[:, 0], result.t)
    in_contact = np.isin(result.phase, (SamplePhase.TIP, SamplePhase.TANGENTIAL))
    landed = [k for k, e in enumerate(result.episodes) if e.start == "landing"]
    assert len(landed) == landings
    for k in landed:
        before, episode = result.episodes[k - 1], result.episodes[k]
        assert before.end == "snap-off"
        first = int(np.searchsorted(result.t, episode.t_first_contact))
        assert result.t[first] == episode.t_first_contact  # on the sample after the last contact
        assert in_contact[first - 1] and in_contact[first]
        obj = raw["objects"][result.object[first]]
        assert obj["name"] == episode.object
        # the straight rod there is inside the object: no free rod, as a snap-off leaves it
        assert _straight_rod_inside_m(raw, path, first, obj) > 1e-3 * L
        # landed without friction: the contact force is along the object's outward normal
        R_WC = Rotation.from_quat(path[first, 4:8]) * Rotation.from_quat(
            raw["whiskers"][0]["mount"]["quaternion_xyzw"])
        F_W = -R_WC.apply(result.f0_n[first])
        n_W = _outward_normal(result.p_W_m[first], obj)
        assert F_W @ n_W > 0.0
        assert np.linalg.norm(np.cross(F_W, n_W)) <= 1e-9 * np.linalg.norm(F_W)
    assert not np.any(result.phase == SamplePhase.UNRESOLVED)
    # every contact row (the landings' included) against a rod integrated from its wrench
    worst = check_against_the_rod(scene)
    assert worst["reach"] <= 1e-10 and worst["tangent"] <= 1e-10
    assert worst["inside"] <= 1e-10
    # a held state at the cone's edge is taken within 1e-9 of it (Step 1's admissibility);
    # m's worst row, held on the cup after landing: 1.7e-10
    assert worst["cone"] <= 1e-9
    assert worst["free inside"] <= 0.0  # and every free row's straight rod is outside


def test_simulate_says_which_episodes_are_landings(tmp_path: Path, capsys: Any) -> None:
    """``vibrissa simulate``: summary.json's ``start`` of each episode, read back as written,
    and the closing line's count of landings."""
    scene_file = DATA / "scene_n.yaml"
    assert main(["simulate", str(scene_file), "-o", str(tmp_path), "--workers", "1"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    starts = [e["start"] for e in summary["whiskers"]["n3"]["episodes"]]
    assert starts == ["touch", "touch", "landing"]
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("3 contact episodes (") and ", 1 of them landing after a snap-off;" in last
    (result,) = read_results(tmp_path, load_scene(scene_file))
    assert [e.start for e in result.episodes] == starts


def _mirrored(X: Transform) -> Transform:
    """X reflected across W's xz-plane (M X M, M = diag(1, -1, 1)): a proper pose again."""
    M = np.diag([1.0, -1.0, 1.0])
    return Transform(Rotation.from_matrix(M @ X.R @ M), M @ X.translation)


# On some CPUs (seen on an AMD EPYC with FMA) round-off decides where the tip of the mirrored
# scene holds: k tips onto its side two samples apart and then holds up to 10 mm away; m's
# tip holds 5e-7 m off its mirror image. Which equilibrium a transition picks is left to the
# sampling and the last bits (docs/LIMITS.md): not yet a symmetry that holds everywhere.
@pytest.mark.xfail(reason="the tip's hold after a transition is decided by round-off on some "
                          "CPUs (docs/LIMITS.md)", strict=False)
@pytest.mark.parametrize("name", ["k", "m"])
@pytest.mark.slow
def test_a_mirrored_scene_lands_in_the_mirror_image(name: str) -> None:
    """Symmetry: the scene reflected across W's xz-plane (objects, mounts and path; the objects
    are symmetric in their own y) gives the same episodes, landings included, with every
    contact point the mirror image."""
    scene = load_scene(DATA / f"scene_{name}.yaml")
    M = np.diag([1.0, -1.0, 1.0])
    R_WR = scene.path.R_WR.as_matrix()
    mirror = replace(
        scene,
        objects=tuple(replace(o, X_WO=_mirrored(o.X_WO)) for o in scene.objects),
        whiskers=tuple(replace(w, X_RC=_mirrored(w.X_RC)) for w in scene.whiskers),
        path=RobotPath(scene.path.t, scene.path.p_WR @ M,
                       Rotation.from_matrix(M @ R_WR @ M)))
    (whisker,), (mirrored_whisker,) = scene.whiskers, mirror.whiskers
    result = simulate_whisker(scene, whisker)
    image = simulate_whisker(mirror, mirrored_whisker)
    assert [(e.object, e.start, e.end) for e in image.episodes] == [
        (e.object, e.start, e.end) for e in result.episodes]
    assert any(e.start == "landing" for e in result.episodes)
    assert np.array_equal(image.phase, result.phase)
    contact = np.isin(result.phase, (SamplePhase.TIP, SamplePhase.TANGENTIAL))
    assert np.abs(image.p_W_m[contact] - result.p_W_m[contact] @ M).max() <= 1e-9 * whisker.length_m


@pytest.mark.parametrize("extra", [0, 1])
def test_a_path_that_ends_just_after_the_snap_off(extra: int) -> None:
    """The path ends on the sample after the snap-off (no episode starts on a path's last
    sample: it stays unresolved) or one later (the landing's two samples)."""
    scene = load_scene(DATA / "scene_n.yaml")
    (whisker,) = scene.whiskers
    full = simulate_whisker(scene, whisker)
    landing = next(e for e in full.episodes if e.start == "landing")
    end = int(np.searchsorted(full.t, landing.t_first_contact)) + 1 + extra
    short = replace(scene, path=RobotPath(scene.path.t[:end], scene.path.p_WR[:end],
                                          scene.path.R_WR[:end]))
    result = simulate_whisker(short, whisker)
    starts = [e.start for e in result.episodes]
    last = result.phase[-1]
    if extra:
        assert starts[-1] == "landing" and result.episodes[-1].end == "path-end"
        assert np.array_equal(result.f0_n, full.f0_n[:end])  # the same states as on the full path
    else:
        assert "landing" not in starts and last == SamplePhase.UNRESOLVED
        assert np.array_equal(result.f0_n[:-1], full.f0_n[:end - 1])
