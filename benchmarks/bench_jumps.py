"""Step 1's jumps inside episodes that no snap tells, on random scenes.

Each scene is one rod on a robot yawing about z past one posed object: a straight, tapered
(tip over base diameter 0.25-0.9) or pre-curved rod of 30-60 mm, mounted tilted; a sphere, an
ellipsoid turned at random or a paraboloid opening away from the rod; mu 0, 0.2, 0.4, 0.6 or
0.9; 1, 2 or 4 samples per 0.1 mm of tip travel. A sample is flagged when the clamp wrench
changes to the next by more than 4 times the median of its changes over the five samples on
each side, and by more than 1e-3 (EI/L^2, EI/L), between two samples in contact in the same
phase with no snap told between them (tests/core/test_sampling.py's `untold_jumps`, the
criterion of its test). A flag is a lead, not a verdict: a stick phase shorter than a sample
between two slides (a pinned contact is stiffer than a sliding one) or a steep stretch after a
gentle one is flagged too. So each flagged scene is simulated again with its path ``--finer``
times as finely sampled (the same samples and more between), and each flagged sample k is
printed with the largest change of the finer run between the same two samples, as a fraction
of the coarse change (NaN: unresolved there): a smooth stretch shrinks to about 1/finer, a
jump does not shrink. In stick-slip the finer run's cycle may be out of phase with the coarse
one (docs/LIMITS.md): a small fraction there says only that the finer run has no jump between
those samples. Prints each flagged scene, then the counts. Not a test: about 1 min for 220
scenes on 2 cores.

Usage: ``python benchmarks/bench_jumps.py [--scenes 220] [--seed 0] [--workers 2] [--finer 4]``
"""

from __future__ import annotations

import argparse
import math
import sys
from functools import partial
from multiprocessing import Pool
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.core.test_sampling import untold_jumps, wrench_units  # noqa: E402
from vibrissa.frames import Transform  # noqa: E402
from vibrissa.scene import RobotPath, Scene, SceneObject, Whisker, simulate  # noqa: E402

TIP_STEP_M = 1e-4  # tip travel per sample at 1 sample per 0.1 mm


def scene_of(seed: int, finer: int = 1) -> tuple[Scene, dict[str, Any]]:
    """Random scene ``seed`` and what it was drawn with; its path sampled ``finer`` times as
    finely (the same arc)."""
    rng = np.random.default_rng(seed)
    length_m, ei_nm2 = rng.uniform(0.03, 0.06), rng.uniform(5e-5, 3e-4)
    taper = 1.0 if rng.random() < 0.5 else rng.uniform(0.25, 0.9)
    curvature_1pm = 0.0 if rng.random() < 0.5 else rng.uniform(-0.2, 0.2) * 2 * math.pi / length_m
    mu = float(rng.choice([0.0, 0.2, 0.4, 0.6, 0.9]))
    shape = str(rng.choice(["sphere", "ellipsoid", "paraboloid"]))
    along = rng.uniform(0.5, 1.0) * length_m
    if shape == "sphere":
        radius = rng.uniform(0.004, 0.02)
        sizes: dict[str, Any] = {"radius_m": radius}
    elif shape == "ellipsoid":
        axes = rng.uniform(0.003, 0.02, 3)
        sizes, radius = {"semi_axes_m": axes.tolist()}, float(axes.max())
    else:
        sizes, radius = {"a_per_m": rng.uniform(10, 200), "b_per_m": rng.uniform(10, 200),
                         "h_m": 0.0}, 0.0
    yaw_at = rng.uniform(0.15, 0.4)  # the robot's yaw where the rod meets the object
    centre = np.array([along * math.cos(yaw_at), along * math.sin(yaw_at),
                       rng.uniform(-0.3, 0.3) * radius])
    if shape == "paraboloid":  # its axis (O's z) along the sweep, opening away from the rod
        rotation = (Rotation.from_euler("zx", [yaw_at, -math.pi / 2])
                    * Rotation.from_euler("xy", rng.uniform(-0.4, 0.4, 2)))
    else:  # its surface, not its centre, on the rod's way
        centre += np.array([-math.sin(yaw_at), math.cos(yaw_at), 0.0]) * radius
        rotation = Rotation.random(random_state=seed)
    per_sample = int(rng.choice([1, 2, 4]))
    step = TIP_STEP_M / length_m / per_sample
    yaw = np.arange(-0.05, yaw_at + rng.uniform(0.3, 0.8), step)
    if finer > 1:  # the same samples and finer ones between
        yaw = np.interp(np.arange(finer * (len(yaw) - 1) + 1) / finer,
                        np.arange(len(yaw)), yaw)
    path = RobotPath(np.arange(len(yaw), dtype=np.float64) * 0.01, np.zeros((len(yaw), 3)),
                     Rotation.from_euler("z", yaw[:, None]))
    mount = Transform(Rotation.from_euler("yx", [math.pi / 2, rng.uniform(-0.6, 0.6)]),
                      np.zeros(3))
    rod = Whisker("w", length_m, ei_nm2, mount, taper_ratio=taper,
                  precurvature_1pm=curvature_1pm)
    drawn = {"shape": shape, "mu": mu, "L_mm": round(1e3 * length_m, 1), "taper": round(taper, 2),
             "curvature_1pm": round(curvature_1pm, 1), "per_sample": per_sample}
    return Scene(mu, (SceneObject("obj", shape, sizes, Transform(rotation, centre)),), (rod,),
                 path), drawn


Flag = tuple[int, float, float, float]
"""A flagged sample: its index, the wrench's change to the next, the median of the changes
around it, and the finer run's largest change between the same samples over it (NaN: no
finer run, or unresolved there)."""


def _scene(seed: int, finer: int) -> tuple[int, dict[str, Any], list[Flag], int]:
    scene, drawn = scene_of(seed)
    (result,) = simulate(scene, workers=1)
    rod = scene.whiskers[0]
    untold, checked = untold_jumps(result, rod.length_m, rod.ei_nm2, ["obj"], floor=1e-3,
                                   same_phase=True)
    if not untold or finer < 2:
        return seed, drawn, [(*flag, math.nan) for flag in untold], checked
    (fine,) = simulate(scene_of(seed, finer)[0], workers=1)
    change = np.linalg.norm(np.diff(wrench_units(fine, rod.length_m, rod.ei_nm2), axis=0), axis=1)
    return seed, drawn, [(k, coarse, median, float(change[k * finer:(k + 1) * finer].max()) / coarse)
                         for k, coarse, median in untold], checked


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=220)
    parser.add_argument("--seed", type=int, default=0, help="the first scene's seed")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--finer", type=int, default=4,
                        help="resample flagged scenes this many times as finely (1: not at all)")
    args = parser.parse_args()
    touching = flagged = samples = 0
    shrunk = unresolved = 0
    with Pool(args.workers) as pool:
        for seed, drawn, flags, checked in pool.imap(
                partial(_scene, finer=args.finer), range(args.seed, args.seed + args.scenes)):
            touching += checked > 0
            samples += checked
            if flags:
                flagged += 1
                shrunk += sum(fraction <= 0.5 for *_, fraction in flags)
                unresolved += sum(math.isnan(fraction) for *_, fraction in flags)
                print(f"scene {seed} {drawn}: {len(flags)} flagged, e.g. "
                      + ", ".join(f"sample {k} {change:.4f} ({change / median:.1f}x; "
                                  f"{args.finer}x finer: {fraction:.2f} of it)"
                                  for k, change, median, fraction in flags[:3]), flush=True)
    print(f"{args.scenes} scenes, {touching} with contact samples checked ({samples} samples): "
          f"{flagged} with a change of the wrench untold")
    if args.finer > 1 and flagged:
        print(f"at {args.finer}x finer sampling, between the same samples: {shrunk} of the flagged "
              f"changes at most half as large, {unresolved} unresolved")


if __name__ == "__main__":
    main()
