"""Commanded robot benchmark: path commands simulated as they come against the fixed path.

The robot demo (launch/robot/scene.yaml: 8 whiskers, 500 Hz, a 3.4 s arc past a ball and an
egg) on two paths, each the demo's samples commanded as waypoints of one segment
(`vibrissa.paths.CommandedPath`, the node's limits: 0.1 m/s, 1 rad/s):

* ``contact``: the demo's own path: 7 of the 8 whiskers touch, about a fifth of the samples;
* ``free``: the same path 0.3 m further from the objects: no contact (an explorer between
  objects).

* ``fixed``: `vibrissa.scene.simulate` of the whole path at once in this process (the wrench
  source's fixed path, ``workers`` 1): the baseline of the ratio.
* ``commanded``: the commanded mode's work without sockets: the segment queued, then taken
  and simulated `vibrissa.nodes.wrench_source.COMMAND_CHUNK` (100) samples at a time by
  `vibrissa.scene.SceneStream` with the step of the limits.

Each time is the median of ``--repeat`` runs after one warm-up run (numba's compilation
excluded), in one process; ``x real time`` is the path's duration over it, ``x fixed`` the
fixed path's median over this one. Not a test.

Usage: ``python benchmarks/bench_commanded.py [--repeat 5]``
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

from vibrissa.formats.scene_file import load_scene
from vibrissa.nodes.wrench_source import COMMAND_CHUNK
from vibrissa.paths import CommandedPath, PathLimits
from vibrissa.scene import Scene, SceneStream, robot_path, simulate

SCENE = Path(__file__).parents[1] / "launch" / "robot" / "scene.yaml"


def commanded(scene: Scene, limits: PathLimits) -> int:
    """The segment of the path's samples driven as the node drives it; samples handed out."""
    q = scene.path.R_WR.as_quat()
    path = CommandedPath(limits, scene.path.p_WR[0], q[0])
    why = path.command(scene.path.p_WR[1:], q[1:], limits.max_speed_mps,
                       limits.max_turn_rate_rps)
    assert why is None, why
    stream = SceneStream(scene, [limits.rod_step(w.X_RC, w.length_m) for w in scene.whiskers])
    stream.extend([0.0], scene.path.p_WR[:1], q[:1])
    taken, out = 1, 0
    while path.queued:
        p, q_next = path.take(COMMAND_CHUNK)
        stream.extend(np.arange(taken, taken + len(p)) / limits.rate_hz, p, q_next)
        taken += len(p)
        out += len(stream.advance(hold=bool(path.queued)).t)
    return out + len(stream.finish().t)


def median_s(run: Callable[[], object], repeat: int) -> float:
    run()  # warm-up
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    demo = load_scene(SCENE)
    q = demo.path.R_WR.as_quat()
    t = np.arange(len(q)) / 500.0  # the commanded clock: the same samples, k / 500 s
    scenes = {"contact": dataclasses.replace(demo, path=robot_path(t, demo.path.p_WR, q)),
              "free": dataclasses.replace(demo, path=robot_path(
                  t, demo.path.p_WR + [0.0, 0.3, 0.0], q))}
    limits = PathLimits(rate_hz=500.0, max_speed_mps=0.1, max_turn_rate_rps=1.0)
    print("| path | samples | path s | fixed s | commanded s | x real time | x fixed |")
    print("|---|---|---|---|---|---|---|")
    for name, scene in scenes.items():
        n = len(scene.path.t)
        assert commanded(scene, limits) == n
        fixed = median_s(partial(simulate, scene, workers=1), args.repeat)
        stream = median_s(partial(commanded, scene, limits), args.repeat)
        duration = float(scene.path.t[-1])
        print(f"| {name} | {n} | {duration:.2f} | {fixed:.3f} | {stream:.3f} | "
              f"{duration / stream:.2f} | {fixed / stream:.2f} |")


if __name__ == "__main__":
    main()
