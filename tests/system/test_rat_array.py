"""The rat-like array (launch/robot/rat.yaml: 3 rows x 4 columns of tapered, pre-curved
whiskers of 21-60 mm) through the robot graph with real processes: simulated by the wrench
source, placed by the reconstructor through the robot description's rod shapes, mapped."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from tests.system.test_first_hour import Launch
from vibrissa.formats.scene_file import load_scene
from vibrissa.msgs.codec import decode
from vibrissa.wire.bag import BagReader

LAUNCH = Path(__file__).parents[2] / "launch"
DOMAIN = 9860 + os.getpid() % 12 * 128


def test_the_rat_array_maps_both_objects_from_its_shaped_whiskers(tmp_path: Path) -> None:
    scene = load_scene(LAUNCH / "robot" / "rat.yaml")
    assert len(scene.whiskers) == 12
    assert all(w.taper_ratio < 1 and w.precurvature_1pm > 0 for w in scene.whiskers)
    lengths = sorted(w.length_m for w in scene.whiskers)
    assert 0.02 <= lengths[0] and lengths[-1] <= 0.06
    out = tmp_path / "out"
    launch = Launch(LAUNCH / "robot.yaml", f"scene:={LAUNCH / 'robot' / 'rat.yaml'}",
                    f"out:={out}", "epoch:=0", domain=DOMAIN)
    assert launch.wait(900) == 0, launch.text()
    report = json.loads((out / "report.json").read_text())
    assert report["lost"] == 0 and report["n_points"] > 500, report
    # every contact point on its object: Step 2 of the shaped rods' wrenches (the mapper's
    # distance of the cloud to the true surfaces)
    assert report["max_reconstruction_error_m"] < 1e-9, report
    wrenches = [decode(r.payload) for r in BagReader(out / "robot.mcap")
                if r.topic == "/robot/wrench"]
    assert len(wrenches) == len(scene.path.t) + 1  # and the end of the stream
    touching = {name for m in wrenches[:-1] for name, f in zip(m.whisker_ids, m.f0,
                                                                strict=True)
                if np.any(f != 0.0)}
    assert len(touching) >= 4, touching
