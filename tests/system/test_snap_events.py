"""The jumps of a simulated robot's path reach the stream: the wrench source, a real process,
publishes each snap-off, landing and snap-through as a `SnapEvent` stamped as the wrench sample
it is told at, and a recorder (another process) records them with the wrenches."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tests.core.test_sampling import yawing_scene
from tests.system.test_first_hour import Launch
from vibrissa.formats.scene_file import load_scene
from vibrissa.msgs import SnapEvent, WhiskerWrenchArray
from vibrissa.msgs.codec import decode
from vibrissa.scene import simulate, snaps
from vibrissa.wire.bag import BagReader

EPOCH_S = 1000.0
DOMAIN = 12700 + os.getpid() % 90  # ports below the ephemeral ones, away from the others


def write_scene(folder: Path) -> Path:
    """`yawing_scene`'s tilted tip on a ball (a snap-off, a landing, a snap-through) as a
    scene file."""
    scene = yawing_scene(50.0, 40.0, 0.5, 0.02, 4)
    (ball,), (rod,), path = scene.objects, scene.whiskers, scene.path
    rows = "".join(",".join(repr(float(v)) for v in (t, 0, 0, 0, *q)) + "\n"
                   for t, q in zip(path.t, path.R_WR.as_quat(), strict=True))
    (folder / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + rows)
    mount = rod.X_RC.rotation.as_quat()
    (folder / "scene.yaml").write_text(textwrap.dedent(f"""\
        mu: {float(scene.mu)!r}
        objects:
          - {{name: ball, shape: sphere, radius_m: {float(ball.sizes['radius_m'])!r},
             position_m: {[float(v) for v in ball.X_WO.translation]!r}}}
        whiskers:
          - {{name: w, length_m: {float(rod.length_m)!r}, ei_nm2: {float(rod.ei_nm2)!r},
             mount: {{quaternion_xyzw: {[float(v) for v in mount]!r}}}}}
        path: path.csv
        """))
    return folder / "scene.yaml"


@pytest.mark.live
@pytest.mark.timeout(900)
def test_the_wrench_source_publishes_every_jump_after_its_wrench(tmp_path: Path) -> None:
    scene_file = write_scene(tmp_path)
    bag = tmp_path / "events.mcap"
    launch_file = tmp_path / "events.yaml"
    launch_file.write_text(textwrap.dedent(f"""\
        launch:
          - node:
              exec: recorder
              name: rec
              param:
                - {{name: output, value: "{bag}"}}
                - {{name: topics, value: [/robot/wrench, /robot/pose, /robot/events]}}
                - {{name: stop_on_eos, value: true}}
          - node:
              exec: wrench_source
              name: wrench_source
              namespace: /robot
              required: true
              finite: true
              param:
                - {{name: mode, value: scene}}
                - {{name: scene, value: "{scene_file}"}}
                - {{name: workers, value: 1}}
                - {{name: epoch_s, value: {EPOCH_S!r}}}
                - {{name: wait_for, value: [/rec]}}
        """))
    launch = Launch(launch_file, domain=DOMAIN)
    assert launch.wait(600) == 0, launch.text()

    scene = load_scene(scene_file)
    (result,) = simulate(scene, workers=1)
    expected = snaps(result, ["ball"])
    assert {snap.kind for snap in expected} == {"snap-off", "landing", "snap-through"}
    recorded = [(r.topic, decode(r.payload)) for r in BagReader(bag)]
    events = [m for topic, m in recorded if isinstance(m, SnapEvent)]
    assert [(e.kind, e.stamp) for e in events] == [
        (snap.kind, EPOCH_S + snap.t) for snap in expected]
    for event, snap in zip(events, expected, strict=True):
        assert event.whisker_id == "w" and event.frame_id == "w/clamp" and event.object == "ball"
        np.testing.assert_array_equal(event.f0_before, result.f0_n[snap.before])
        np.testing.assert_array_equal(event.m0_after, result.m0_nm[snap.after])
    # each stamped as the wrench of its sample (whose f0 is the event's f0_after); the topics
    # come on connections of their own, so a subscriber of both may get either first
    wrenches = {m.stamp: m for _, m in recorded if isinstance(m, WhiskerWrenchArray)}
    for event in events:
        np.testing.assert_array_equal(wrenches[event.stamp].f0[0], event.f0_after)
