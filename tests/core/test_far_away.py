"""Step 1 of a scene 1.2 km from the origin: a tilted nose whisker leaning on a ball until it
snaps off, with its clamp then running into the ball (tests/data/far_away). Rotated and moved
there, the scene gives the same samples, rigidly moved. There, a Newton step's finite-difference
Jacobian came out not finite, LAPACK refused it in both of Step 1's solvers, and the simulation
stopped with numba's "Unreachable condition reached" (vibrissa.equilibrium._solve)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from vibrissa.formats.scene_file import load_scene
from vibrissa.scene import SamplePhase, simulate

DATA = Path(__file__).resolve().parents[1] / "data" / "far_away"
R_G = Rotation.from_euler("ZYX", [71.0, -33.0, 152.0], degrees=True)  # world W -> G
P_G = np.array([1234.567, -89.01, 45.6])  # W's origin in G, m


def _unit(q: np.ndarray) -> list[float]:
    return [float(v) for v in (q if q[3] >= 0 else -q)]


def moved_scene(folder: Path) -> Path:
    """The scene with its objects and path in G (the mounts stay on the robot), by scipy."""
    scene = yaml.safe_load((DATA / "scene.yaml").read_text())
    for obj in scene["objects"]:
        obj["position_m"] = [float(v) for v in R_G.apply(obj["position_m"]) + P_G]
        obj["quaternion_xyzw"] = _unit((R_G * Rotation.from_quat(obj["quaternion_xyzw"])).as_quat())
    path = np.loadtxt(DATA / "path.csv", delimiter=",", skiprows=1)
    p_G = R_G.apply(path[:, 1:4]) + P_G
    q_G = (R_G * Rotation.from_quat(path[:, 4:8])).as_quat()
    q_G[q_G[:, 3] < 0] *= -1
    rows = np.column_stack([path[:, 0], p_G, q_G])
    np.savetxt(folder / "path.csv", rows, delimiter=",", header="t,x,y,z,qx,qy,qz,qw",
               comments="", fmt="%.17g")
    (folder / "scene.yaml").write_text(yaml.safe_dump(scene, sort_keys=False))
    return folder / "scene.yaml"


@pytest.mark.slow
def test_a_scene_moved_far_from_the_origin_gives_the_same_samples_moved(tmp_path: Path) -> None:
    (here,) = simulate(load_scene(DATA / "scene.yaml"), workers=1)
    (there,) = simulate(load_scene(moved_scene(tmp_path)), workers=1)
    assert [(e.start, e.end) for e in here.episodes] == [("touch", "snap-off")]
    assert [(e.start, e.end) for e in there.episodes] == [("touch", "snap-off")]
    assert np.array_equal(here.phase, there.phase)
    touching = (here.phase == SamplePhase.TIP) | (here.phase == SamplePhase.TANGENTIAL)
    assert touching.sum() > 50 and (here.phase == SamplePhase.UNRESOLVED).sum() > 10
    length = load_scene(DATA / "scene.yaml").whiskers[0].length_m
    moved = R_G.apply(here.p_W_m[touching]) + P_G
    assert np.abs(moved - there.p_W_m[touching]).max() <= 1e-9 * length
    # the clamp's wrench is in the clamp frame: the same, but for the round-off of positions
    # 1.2 km out (1e-13 m), which the fold before the snap-off amplifies (3e-10 of the peak)
    peak = np.abs(here.f0_n[touching]).max()
    assert np.abs(here.f0_n[touching] - there.f0_n[touching]).max() <= 1e-6 * peak
