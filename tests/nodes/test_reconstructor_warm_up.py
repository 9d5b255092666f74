"""The reconstructor compiles (or loads from numba's cache) every kernel its per-tick paths call
before its first wrench: a kernel loaded on a robot's first tick made it 4-6 ms late, and the
seven ticks behind it, which was a fifth of a 4-s run's slowest 1 %. Run in a fresh interpreter:
a test process has compiled whatever other tests called."""

from __future__ import annotations

import json
import subprocess
import sys

SCRIPT = r'''
import json, sys
import numpy as np
from numba.core.registry import CPUDispatcher
from scipy.spatial.transform import Rotation
from vibrissa.contact_detection import ContactDetector, wrench_covariance
from vibrissa.frames import Transform
from vibrissa.msgs import RobotPose, WhiskerWrenchArray
from vibrissa.msgs.codec import decode, encode
from vibrissa.nodes.reconstructor import (RodTable, _compile_kernels, reconstruct_messages,
                                          robot_frames)
from vibrissa.scene import Whisker


def signatures():
    """Each compiled kernel's signatures of every loaded vibrissa module."""
    return {f"{module.__name__}.{name}": len(kernel.signatures)
            for module in list(sys.modules.values())
            if module is not None and module.__name__.startswith("vibrissa")
            for name, kernel in vars(module).items() if isinstance(kernel, CPUDispatcher)}


def wire(msg):
    return decode(encode(msg), type(msg))


whiskers = [Whisker("a", 0.05, 1e-4, Transform(Rotation.from_rotvec([0.3, -0.2, 0.1]), [0.01, 0.0, 0.0])),
            Whisker("b", 0.04, 5e-5, Transform(Rotation.from_rotvec([0.0, 0.4, 0.0]), [0.0, 0.01, 0.0]))]
rod = RodTable({w.name: w.scale for w in whiskers})
detector = ContactDetector(wrench_covariance(1e-4, 1e-6), 7.0, 5.0)
before = signatures()
_compile_kernels(rod, detector)
warm = signatures()


def tick(stamp, names=("a", "b")):
    n = len(names)
    return wire(WhiskerWrenchArray(
        stamp=stamp, seq=0, whisker_ids=list(names), frame_ids=[f"{w}/clamp" for w in names],
        f0=[[0.01, 0.002, 0.0]] * n, m0=[[0.0, 1e-4, 2e-4]] * n))


def pose(parent, child, stamp, x):
    return wire(RobotPose(stamp=stamp, frame_id=parent, child_frame_id=child,
                          position=[x, 0.1, 0.0], orientation=[0.0, 0.0, 0.1 * x, 1.0]))


points = 0
for chain in ([("world", "base_link")], [("odom", "base_link"), ("world", "odom")]):
    for noise in (None, detector):
        frames = robot_frames(whiskers)
        for parent, child in chain:
            for k, stamp in enumerate((0.0, 0.01)):
                p = pose(parent, child, stamp, 0.01 * k)
                frames.add_pose(p.frame_id, p.child_frame_id, p.stamp, p.position,
                                p.orientation)
        single = tick(0.004, ("b",))  # one whisker: a batch of one row
        for batch in ([tick(0.01)], [tick(0.005)], [tick(0.002), tick(0.007, ("b", "a"))],
                      [single], [single, tick(0.003)]):
            for outcome in reconstruct_messages(batch, rod, frames, "world", noise):
                points += outcome.contacts is not None
after = signatures()
print(json.dumps({"before": before, "warm": warm, "after": after, "points": points}))
'''


def test_the_node_warm_up_compiles_every_kernel_a_robot_tick_calls() -> None:
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True,
                         timeout=300, check=True)
    found = json.loads(out.stdout.strip().splitlines()[-1])
    assert found["points"] > 0  # the paths ran through Step 2
    grown_by_warm_up = {k for k, n in found["warm"].items() if n > found["before"].get(k, 0)}
    assert {"vibrissa.frames.mounted_poses", "vibrissa.frames.mounted_poses_between"
            } <= grown_by_warm_up  # the check sees kernels being loaded
    compiled_after = {k: (found["warm"].get(k, 0), n) for k, n in found["after"].items()
                      if n > found["warm"].get(k, 0)}
    assert compiled_after == {}
