"""Step 2 over a simulated robot scene from a plain script, through `vibrissa.streaming` alone:
no node, no sockets, no codec (the script checks that none of them got loaded).

Tolerance: the poses come at the path's samples and the wrenches are Step 1's own (float64,
not through the wire), so each point is Step 1's contact up to the round-off of Step 1's
equilibrium (residual ~1e-13 of L), of Step 2's inversion and of composing X_WR with the mount
X_RC (a few 1e-16 m): 1e-12 L leaves a factor of ten over that, while a wrong mount, frame or
interpolation is off by 1e-7 L or more (`tests/streaming/test_scene_poses.py`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from tests.streaming.test_scene_poses import SCENE  # two rods past a ball

SCRIPT = r'''
import json, sys
import numpy as np
from vibrissa.formats.scene_file import load_scene
from vibrissa.frames import clamp_frame
from vibrissa.msgs import RobotPose, WhiskerWrenchArray
from vibrissa.scene import simulate
from vibrissa.streaming import Step2Stream, StreamSettings, warm_up

scene = load_scene(sys.argv[1])
truth = simulate(scene, workers=1)  # Step 1: each whisker's wrenches and contact points
settings = StreamSettings(whiskers=tuple(scene.whiskers))
warm_up(settings)
stream = Step2Stream(settings)
path = scene.path
stream.add_poses(RobotPose(stamp=float(t), frame_id="world", child_frame_id="base_link",
                           position=p, orientation=q)
                 for t, p, q in zip(path.t, path.p_WR, path.R_WR.as_quat()))
names = [w.name for w in scene.whiskers]
stream.add_wrenches([WhiskerWrenchArray(
    stamp=float(t), seq=k, whisker_ids=names, frame_ids=[clamp_frame(n) for n in names],
    f0=[r.f0_n[k] for r in truth], m0=[r.m0_nm[k] for r in truth]) for k, t in enumerate(path.t)])
off, rows, contacts = 0.0, 0, 0
for outcome in stream.take():
    k = outcome.contacts.seq
    for name, point in zip(outcome.contacts.whisker_ids, outcome.contacts.point):
        w = names.index(name)
        off = max(off, float(np.linalg.norm(point - truth[w].p_W_m[k])) / scene.whiskers[w].length_m)
        rows += 1
contacts = sum(int((~np.isnan(r.p_W_m[:, 0])).sum()) for r in truth)
loaded = [m for m in ("zmq", "msgpack", "vibrissa.wire", "vibrissa.runtime", "vibrissa.nodes",
                      "vibrissa.msgs.codec") if m in sys.modules]
print(json.dumps({"off": off, "rows": rows, "contacts": contacts, "counts": stream.counts,
                  "waiting": len(stream), "loaded": loaded}))
'''


def write_scene(folder: Path) -> Path:
    """Two whiskers on a robot driving past a ball along x, yawing a little."""
    t = np.arange(120) * 0.002
    x = np.linspace(-0.06, 0.06, len(t))
    yaw = 0.05 * np.sin(x / 0.06)
    rows = "".join(",".join(repr(float(v)) for v in (t[i], x[i], 0.0, 0.0, 0.0, 0.0,
                                                     np.sin(yaw[i] / 2), np.cos(yaw[i] / 2))) + "\n"
                   for i in range(len(t)))
    (folder / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + rows)
    (folder / "scene.yaml").write_text(SCENE)
    return folder / "scene.yaml"


def test_a_plain_script_gets_step_1s_contacts_through_the_library_alone(tmp_path: Path) -> None:
    scene = write_scene(tmp_path)
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(scene)], capture_output=True,
                         text=True, timeout=600, check=True)
    found = json.loads(out.stdout.strip().splitlines()[-1])
    assert found["loaded"] == []  # no socket, no codec, no node
    assert found["waiting"] == 0
    assert found["contacts"] >= 20  # both whiskers lean on the ball
    assert found["rows"] == found["contacts"] == found["counts"]["contacts"]
    assert found["counts"]["robot_poses"] == 120 and found["counts"]["no_pose"] == 0
    assert found["off"] <= 1e-12
