"""The robot poses of the wrench source's mode ``scene`` through the Step 2 stream's frame buffer
(socket-free): with ``pose_rate_hz`` 0 (a pose at each path sample, ``launch/robot.yaml``'s
default) the points of a robot on an unevenly sampled S-curve are Step 1's contact points; at a
fixed rate the frame buffer interpolates chords between the poses, off the bending path."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from vibrissa.formats.scene_file import load_scene
from vibrissa.msgs import ContactPointArray, RobotPose, WhiskerWrenchArray
from vibrissa.nodes.wrench_source import MAX_POSES, WrenchSourceParams, scene_stream
from vibrissa.runtime import ParamError, load_params
from vibrissa.scene import Scene, WhiskerResult, simulate
from vibrissa.streaming import RodTable, reconstruct_messages, robot_frames

# Two different rods pointing to the robot's right (clamp z along the robot's -y), one tilted
# in yaw, one in roll, past a ball on the right of an S-curve.
SCENE = """\
mu: 0.3
objects:
  - {name: ball, shape: sphere, radius_m: 0.02, position_m: [0.0, -0.062, 0.004]}
whiskers:
  - {name: a, length_m: 0.05, ei_nm2: 1.0e-4,
     mount: {position_m: [0.01, -0.01, 0.0], quaternion_xyzw: [0.704416, 0.061628, 0.061628, 0.704416]}}
  - {name: b, length_m: 0.045, ei_nm2: 4.0e-5,
     mount: {position_m: [-0.01, -0.01, 0.002], quaternion_xyzw: [0.766044, 0.0, 0.0, 0.642788]}}
path: path.csv
"""
SAMPLES = 400


def write_scene(folder: Path) -> Path:
    """An S-curve y = 8 mm sin(pi x / 0.08 m), heading along it, with a roll and pitch sway,
    sampled unevenly (steps of 1.4-2.6 ms)."""
    k = np.arange(SAMPLES)
    t = np.concatenate([[0.0], np.cumsum(0.002 * (1 + 0.3 * np.sin(1.7 * k[1:])))])
    x = np.linspace(-0.08, 0.08, SAMPLES)
    y = 0.008 * np.sin(np.pi * x / 0.08)
    yaw = np.arctan(0.008 * np.pi / 0.08 * np.cos(np.pi * x / 0.08))
    roll, pitch = 0.03 * np.sin(9 * x / 0.08), 0.02 * np.sin(5 * x / 0.08 + 1)
    cr, sr, cp, sp, cy, sy = (f(a / 2) for a in (roll, pitch, yaw) for f in (np.cos, np.sin))
    q = np.column_stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                         cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])  # ZYX
    rows = "".join(",".join(repr(float(v)) for v in (t[i], x[i], y[i], 0.0, *q[i])) + "\n"
                   for i in range(SAMPLES))
    (folder / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + rows)
    (folder / "scene.yaml").write_text(SCENE)
    return folder / "scene.yaml"


@pytest.fixture(scope="module")
def scene_results(tmp_path_factory: pytest.TempPathFactory
                  ) -> tuple[Path, Scene, list[WhiskerResult]]:
    scene_file = write_scene(tmp_path_factory.mktemp("s_curve"))
    scene = load_scene(scene_file)
    return scene_file, scene, simulate(scene, workers=1)


def played_points(scene_file: Path, scene: Scene, results: list[WhiskerResult],
                  pose_rate_hz: float) -> tuple[list[float], dict[str, np.ndarray]]:
    """The poses' stamps, and each whisker's points (N, 3; NaN without one) as the Step 2 stream
    places the played wrenches through the played poses."""
    params = WrenchSourceParams(mode="scene", scene=str(scene_file), pose_rate_hz=pose_rate_hz)
    messages = [msg for _, msg in scene_stream(scene, results, params)]
    poses = [m for m in messages if isinstance(m, RobotPose)]
    frames = robot_frames(scene.whiskers)
    for pose in poses:
        frames.add_pose(pose.frame_id, pose.child_frame_id, pose.stamp, pose.position,
                        pose.orientation)
    rods = RodTable({w.name: w.scale for w in scene.whiskers})
    points = {w.name: np.full((len(scene.path.t), 3), np.nan) for w in scene.whiskers}
    for msg in messages:
        if isinstance(msg, WhiskerWrenchArray):
            (outcome,) = reconstruct_messages([msg], rods, frames, "world")
            assert outcome.no_pose == 0 and not outcome.errors
            contacts = outcome.contacts
            assert isinstance(contacts, ContactPointArray)
            for name, point in zip(contacts.whisker_ids, contacts.point, strict=True):
                points[name][msg.seq] = point
    return [pose.stamp for pose in poses], points


def test_poses_at_the_path_samples_give_step_1s_points_on_an_uneven_s_curve(
        scene_results: tuple[Path, Scene, list[WhiskerResult]]) -> None:
    scene_file, scene, results = scene_results
    stamps, points = played_points(scene_file, scene, results, 0.0)
    assert stamps == scene.path.t.tolist()
    contacts = 0
    for whisker, result in zip(scene.whiskers, results, strict=True):
        touched = ~np.isnan(result.p_W_m[:, 0])
        contacts += int(touched.sum())
        assert np.array_equal(~np.isnan(points[whisker.name][:, 0]), touched)
        off = np.linalg.norm(points[whisker.name][touched] - result.p_W_m[touched], axis=1)
        assert off.max() <= 1e-12 * whisker.length_m
    assert contacts >= 50  # both whiskers lean on the ball through the S-curve's bends


def test_poses_at_a_fixed_rate_are_interpolated_as_chords_off_the_bending_path(
        scene_results: tuple[Path, Scene, list[WhiskerResult]]) -> None:
    scene_file, scene, results = scene_results
    _, points = played_points(scene_file, scene, results, 100.0)
    off = [np.nanmax(np.linalg.norm(points[w.name] - r.p_W_m, axis=1)) / w.length_m
           for w, r in zip(scene.whiskers, results, strict=True)]
    # a 10-ms chord across samples 2 ms apart on a path that turns: far above round-off,
    # still a small part of the rod
    assert 1e-7 < max(off) < 1e-2


def test_a_pose_rate_beyond_max_poses_over_the_path_is_refused_naming_it(
        scene_results: tuple[Path, Scene, list[WhiskerResult]]) -> None:
    scene_file, scene, _ = scene_results
    duration_s = scene.path.t[-1] - scene.path.t[0]
    too_fast = float(2 * MAX_POSES / duration_s)  # the poses alone would fill gigabytes
    with pytest.raises(ParamError, match=r"'pose_rate_hz' must be a rate of at most 1e\+07 poses "
                                         rf"over the path's .* \(0: one at each of its {SAMPLES}"):
        load_params(WrenchSourceParams, overrides={
            "mode": "scene", "scene": str(scene_file), "pose_rate_hz": repr(too_fast)})
    assert load_params(WrenchSourceParams, overrides={
        "mode": "scene", "scene": str(scene_file), "pose_rate_hz": "0"}).pose_rate_hz == 0.0


@pytest.mark.filterwarnings("error")  # no overflow warning on the way to the one-line refusal
def test_a_pose_rate_whose_pose_count_overflows_is_refused_naming_it() -> None:
    """The robot demo's path lasts 3.4 s: 1.8e308 poses a second would be more than a float."""
    scene_file = Path(__file__).parents[2] / "launch" / "robot" / "scene.yaml"
    assert float(load_scene(scene_file).path.t[-1]) * sys.float_info.max == math.inf
    with pytest.raises(ParamError, match=r"'pose_rate_hz' must be a rate of at most 1e\+07 poses "
                                         r"over the path's 3.398 s"):
        load_params(WrenchSourceParams, overrides={
            "mode": "scene", "scene": str(scene_file), "pose_rate_hz": repr(sys.float_info.max)})
