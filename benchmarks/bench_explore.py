"""Exploration benchmark: the two planners' final coverage on random scenes, real processes.

Each scene is launch/explore/scene.yaml's robot, workspace and friction with its objects
replaced by ``--objects`` random ones (a sphere, an ellipsoid turned about z, or a mound: a
paraboloid turned over), sizes 15-35 mm, standing on the floor inside the workspace, apart
from each other and from the start's body and rods. Every scene is explored by
``vibrissa launch launch/explore.yaml scene:=... budget_m:=...`` once per planner; the table
gives each run's path length, final coverage (report.json's ``exploration``) and wall time (a
run that touched nothing fails the launch, the mapper's map being empty: coverage 0).
``--default`` adds the shipped scene. Not a test: minutes per run.

Usage: ``python benchmarks/bench_explore.py [--scenes 2] [--seed 1] [--budget 0.3] [--default]
[--planners uncertainty,lawnmower] [--cluster-eps M]``
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

LAUNCH = Path(__file__).parents[1] / "launch"
SCENE = LAUNCH / "explore" / "scene.yaml"
PLANNERS = ("uncertainty", "lawnmower")


def random_objects(rng: np.random.Generator, n: int, workspace: list[list[float]],
                   clear_m: float) -> list[dict[str, Any]]:
    """n objects on the floor within ``workspace``, each its footprint radius plus 20 mm from
    the others and ``clear_m`` from the start (the origin)."""
    (x0, y0, _), (x1, y1, _) = workspace
    objects: list[dict[str, Any]] = []
    placed: list[tuple[list[float], float]] = []
    while len(objects) < n:
        shape = str(rng.choice(["sphere", "ellipsoid", "paraboloid"]))
        size = float(rng.uniform(0.015, 0.035))
        centre = rng.uniform([x0 + 0.05, y0 + 0.05], [x1 - 0.05, y1 - 0.05]).tolist()
        if math.dist(centre, (0.0, 0.0)) < size + clear_m or any(
                math.dist(centre, c) < size + r + 0.02 for c, r in placed):
            continue
        name = f"{shape}{len(objects)}"
        if shape == "sphere":
            obj = {"shape": shape, "radius_m": size, "position_m": [*centre, size]}
        elif shape == "ellipsoid":
            yaw = float(rng.uniform(0.0, math.pi))
            axes = [size, float(rng.uniform(0.5, 1.0)) * size, float(rng.uniform(0.02, 0.03))]
            obj = {"shape": shape, "semi_axes_m": axes, "position_m": [*centre, axes[2]],
                   "quaternion_xyzw": [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]}
        else:  # below z = h - a (x^2 + y^2), footprint radius `size`
            height = float(rng.uniform(0.03, 0.05))
            a_per_m = height / size**2
            obj = {"shape": shape, "a_per_m": a_per_m, "b_per_m": a_per_m,
                   "h_m": -height, "position_m": [*centre, 0.0],
                   "quaternion_xyzw": [1.0, 0.0, 0.0, 0.0]}
        objects.append({"name": name, **obj})
        placed.append((centre, size))
    return objects


def random_scene(rng: np.random.Generator, n: int) -> dict[str, Any]:
    """The default scene with ``n`` random objects (`random_objects`) instead of its own, clear
    of the start's body and rods by 30 mm."""
    base = yaml.safe_load(SCENE.read_text())
    clear_m = base["explore"]["body_radius_m"] + max(w["length_m"] for w in base["whiskers"]) + 0.03
    return {**base, "objects": random_objects(rng, n, base["explore"]["workspace_m"], clear_m)}


def explore(scene: Path, planner: str, budget_m: float, out: Path,
            cluster_eps: str = "") -> dict[str, Any]:
    """One exploration in real processes (``cluster_eps``: the launch's argument, m; empty:
    its default); its report's exploration and the wall time."""
    start = time.monotonic()
    run = subprocess.run(
        [sys.executable, "-m", "vibrissa.cli.main", "launch", str(LAUNCH / "explore.yaml"),
         f"scene:={scene}", f"out:={out}", f"budget_m:={budget_m}", f"planner:={planner}",
         *([f"cluster_eps:={cluster_eps}"] if cluster_eps else [])],
        capture_output=True, text=True)
    report_path = out / "report.json"
    empty = report_path.exists() and json.loads(report_path.read_text())["n_points"] == 0
    if run.returncode != 0 and not empty:  # an empty map (nothing touched) fails the launch
        raise RuntimeError(f"{scene} {planner}: exit {run.returncode}\n{run.stdout[-3000:]}"
                           f"\n{run.stderr[-3000:]}")
    report = json.loads(report_path.read_text())
    return {**report["exploration"], "wall_s": time.monotonic() - start}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=2)
    parser.add_argument("--objects", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--budget", type=float, default=0.3)
    parser.add_argument("--default", action="store_true", help="the shipped scene too")
    parser.add_argument("--cluster-eps", default="",
                        help="the launch's cluster_eps, m (0: the mapper's from the data)")
    parser.add_argument("--planners", default=",".join(PLANNERS),
                        help="comma-separated, of: " + ", ".join(PLANNERS))
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    work = Path(tempfile.mkdtemp(prefix="bench-explore-"))
    scenes = [("default", SCENE)] if args.default else []
    for k in range(args.scenes):
        path = work / f"scene{k}.yaml"
        scene = random_scene(rng, args.objects)
        path.write_text(yaml.safe_dump(scene, sort_keys=False))
        scenes.append((f"random {k} ({', '.join(o['name'] for o in scene['objects'])})", path))
    print(f"budget {args.budget} m, seed {args.seed}, scenes in {work}")
    print("| scene | planner | path m | coverage | wall s |")
    print("|---|---|---|---|---|")
    for name, path in scenes:
        for planner in args.planners.split(","):
            result = explore(path, planner, args.budget, work / f"{path.stem}-{planner}",
                             args.cluster_eps)
            print(f"| {name} | {planner} | {result['path_length_m']:.3f} | "
                  f"{result['coverage_final']:.3f} | {result['wall_s']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
