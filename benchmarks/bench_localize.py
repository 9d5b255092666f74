"""Localizer benchmark: the robot demo driven four legs through a drifting odometry, its
contacts corrected by `vibrissa.mapping.Localizer` (in process, the node's feeding), against
the same contacts uncorrected (the baseline, same run).

Per drift seed: the contacts' mean distance to the true surfaces without and with the
correction (their ratio), the end's ``map -> odom`` error with and without (the true drift),
what a perfect registration would reach (every contact moved by its true error less the first
contact's, which nothing observes: the map is as far off as the first contact was, and the
end as far as the drift since the last contact), and the localizer's CPU time per second of
robot time (the demo's path is 13.6 s of robot time at 500 Hz, 8 whiskers). ``--png FILE``
also runs ``launch/robot.yaml`` for the first seed with and without ``localize`` (real
processes) and puts the two map.png side by side in FILE.

``--random K`` also runs K scenes of random objects beside the demo's path (`random_objects`).

Usage: ``python benchmarks/bench_localize.py [--seeds 6] [--drift 0.02] [--random K] [--png FILE]``
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from vibrissa.formats.scene_file import load_scene
from vibrissa.frames import Transform
from vibrissa.mapping.localize import Localizer, LocalizeSettings
from vibrissa.odometry import OdometryDrift, drift_rng
from vibrissa.scene import (
    SamplePhase,
    Scene,
    SceneObject,
    WhiskerResult,
    back_and_forth,
    reconstruct_along,
    robot_path,
    simulate,
)
from vibrissa.status import ContactStatus

LAUNCH = Path(__file__).parents[1] / "launch"
LEGS = 4

Demo = tuple[Scene, list[WhiskerResult]]


def demo(legs: int = LEGS, objects: tuple[SceneObject, ...] | None = None) -> Demo:
    """The robot demo's scene driven ``legs`` legs forth and back (with ``objects`` instead of
    its own), simulated."""
    scene = load_scene(LAUNCH / "robot" / "scene.yaml")
    scene = replace(scene, path=back_and_forth(scene.path, legs),
                    objects=scene.objects if objects is None else objects)
    return scene, simulate(scene, workers=1)


def random_objects(rng: np.random.Generator, n: int = 3) -> tuple[SceneObject, ...]:
    """``n`` objects beside the robot demo's path, on its whiskers' side and within their reach:
    each a sphere, an ellipsoid turned about z or a mound (a paraboloid on the floor), 12-30 mm,
    its side nearest the path 45-60 mm from it (the clamps are 20 mm from it, the rods 30-60 mm
    long), apart along the path by their sizes and 10 mm."""
    path = load_scene(LAUNCH / "robot" / "scene.yaml").path
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path.p_WR, axis=0), axis=1))])
    objects: list[SceneObject] = []
    taken: list[tuple[float, float]] = []  # (distance along the path, size)
    while len(objects) < n:
        shape = str(rng.choice(["sphere", "ellipsoid", "paraboloid"]))
        size = float(rng.uniform(0.012, 0.03))
        at = float(rng.uniform(0.15, 0.85)) * along[-1]
        if any(abs(at - a) < size + r + 0.01 for a, r in taken):
            continue
        k = int(np.searchsorted(along, at))
        right = path.R_WR[k].apply([0.0, -1.0, 0.0])  # the whiskers' side
        yaw = float(rng.uniform(0.0, np.pi))
        turn = Rotation.from_euler("z", yaw)
        if shape == "sphere":
            sizes: dict[str, Any] = {"radius_m": size}
            reach, height = size, 0.025
        elif shape == "ellipsoid":
            axes = np.array([size, rng.uniform(0.5, 1.0) * size, rng.uniform(0.015, 0.025)])
            sizes = {"semi_axes_m": axes.tolist()}
            # the ellipsoid's extent towards the path: its support along -right
            reach = float(np.sqrt(np.sum((turn.inv().apply(right) * axes) ** 2)))
            height = 0.025
        else:  # z >= a (x^2 + y^2) - h in its frame, turned upside down: a mound of footprint size
            h = float(rng.uniform(0.03, 0.05))
            sizes = {"a_per_m": h / size**2, "b_per_m": h / size**2, "h_m": -h}
            turn, reach, height = Rotation.from_euler("x", np.pi), size, 0.0
        gap = float(rng.uniform(0.045, 0.06))
        centre = path.p_WR[k] + (gap + reach) * right + [0.0, 0.0, height]
        objects.append(SceneObject(f"{shape}{len(objects)}", shape, sizes,
                                   Transform(turn, centre)))
        taken.append((at, size))
    return tuple(objects)


def contacts(demo: Demo, drift: float, seed: int) -> dict[str, Any]:
    """The demo's contacts placed with a drifting odometry's poses (the odom frame; the drift
    of ``launch/robot.yaml seed:=seed``), the true ones, their forces and whiskers, the
    odometry's poses and its true error map -> odom."""
    scene, results = demo
    path = scene.path
    p_o, q_o, error = OdometryDrift(drift, drift_rng(seed)).odom(
        path.p_WR, path.R_WR.as_quat())
    n = len(results)
    t = np.repeat(path.t, n)
    names = np.array([r.name for r in results] * len(path.t))
    f0 = np.stack([r.f0_n for r in results], axis=1).reshape(-1, 3)
    m0 = np.stack([r.m0_nm for r in results], axis=1).reshape(-1, 3)
    ok = np.stack([r.phase != SamplePhase.UNRESOLVED for r in results], axis=1).reshape(-1)
    odom = reconstruct_along(replace(scene, path=robot_path(path.t, p_o, q_o)), t[ok],
                             list(names[ok]), f0[ok], m0[ok])
    true = reconstruct_along(scene, t[ok], list(names[ok]), f0[ok], m0[ok])
    keep = odom.pose_ok & np.isin(odom.status, [ContactStatus.OK, ContactStatus.AXIAL_LOAD])
    return {"t": t[ok][keep], "names": names[ok][keep], "odom": odom.point_m[keep],
            "force": odom.force_n[keep], "true": true.point_m[keep], "pose_t": path.t,
            "pose_odom": p_o, "pose_q_odom": q_o, "pose_true": path.p_WR,
            "pose_q_true": path.R_WR.as_quat(), "error": error}


def localize(c: dict[str, Any], settings: LocalizeSettings, poses_first: bool = False
             ) -> tuple[Localizer, np.ndarray, list[int]]:
    """Feed the contacts tick by tick (each tick's poses before it, or every pose first), as
    the node does; the placed points in input order, and after how many ticks each batch
    came out."""
    loc = Localizer(settings)
    placed = np.full_like(c["odom"], np.nan)
    out_at: list[int] = []
    t = c["t"]
    ticks = np.split(np.arange(len(t)), np.flatnonzero(np.diff(t) > 0) + 1)
    k = 0
    if poses_first:
        for stamp, p in zip(c["pose_t"], c["pose_odom"], strict=True):
            loc.add_pose(stamp, p)
    for fed, rows in enumerate(ticks, 1):
        while not poses_first and k < len(c["pose_t"]) and c["pose_t"][k] <= t[rows[0]]:
            loc.add_pose(c["pose_t"][k], c["pose_odom"][k])
            k += 1
        loc.add(t[rows[0]], c["odom"][rows], c["force"][rows], list(c["names"][rows]), None,
                tuple(rows))
        for batch in loc.take():
            placed[list(batch.token)] = batch.points_m
            out_at.append(fed)
    loc.finish()
    for batch in loc.take():
        placed[list(batch.token)] = batch.points_m
        out_at.append(len(ticks))
    return loc, placed, out_at


def surface_error(demo: Demo, points: np.ndarray) -> float:
    """Mean distance of ``points`` to the nearest true object, m."""
    scene, _ = demo
    return float(np.mean(np.min([np.abs(obj.surface(1.0).signed_distance(points))
                                 for obj in scene.objects], axis=0)))


def perfect(demo: Demo, c: dict[str, Any]) -> tuple[float, float]:
    """What a perfect registration of ``c``'s contacts reaches: the mean distance to the true
    surfaces (m) of the contacts each moved by its true error less the first contact's (the map
    is anchored where the first contact was placed: nothing before it observes the drift), and
    the end's ``map -> odom`` error (m) of the estimate at the last contact, so anchored (the
    drift after it is not observed either)."""
    shift = c["true"] - c["odom"]
    first = np.searchsorted(c["pose_t"], c["t"][0])
    last = np.searchsorted(c["pose_t"], c["t"][-1])
    error = c["error"][:, :2]
    end = error[-1] - (error[last] - error[first])
    return surface_error(demo, c["odom"] + shift - shift[0]), float(np.hypot(*end))


def side_by_side(seed: int, drift: float, png: Path) -> None:
    """launch/robot.yaml for ``seed`` with and without ``localize``; their map.png in one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    images = []
    with tempfile.TemporaryDirectory() as tmp:
        for localize_ in ("false", "true"):
            out = Path(tmp) / localize_
            subprocess.run([sys.executable, "-m", "vibrissa.cli.main", "launch",
                            str(LAUNCH / "robot.yaml"), f"out:={out}", f"passes:={LEGS}",
                            f"odom_drift:={drift}", f"seed:={seed}", f"localize:={localize_}"],
                           check=True, stdout=subprocess.DEVNULL)
            images.append(plt.imread(out / "map.png"))
    fig, axes = plt.subplots(1, 2, figsize=(16, 7), dpi=100)
    for ax, image, title in zip(axes, images, (
            f"odometry drifting {drift} per metre: the contacts as it placed them",
            "the same contacts corrected by the localizer"), strict=True):
        ax.imshow(image)
        ax.set_title(title)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(png)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--drift", type=float, default=0.02)
    parser.add_argument("--random", type=int, default=0,
                        help="also this many scenes of random objects (random_objects, seeds 0..)")
    parser.add_argument("--png", type=Path)
    args = parser.parse_args()
    scenes = [("robot demo", demo())] + [
        (f"random {k}", demo(objects=random_objects(np.random.default_rng(k))))
        for k in range(args.random)]
    for name, data in scenes:
        robot_s = float(data[0].path.t[-1] - data[0].path.t[0])
        print(f"{name} ({', '.join(o.name for o in data[0].objects)}), {LEGS} legs "
              f"({robot_s:.1f} s of robot time), drift {args.drift} per m")
        print(f"{'seed':>4} {'without mm':>11} {'with mm':>8} {'ratio':>6} {'end drift mm':>13} "
              f"{'end error mm':>13} {'perfect mm':>11} {'ratio':>6} {'end error mm':>13} "
              f"{'CPU s per robot s':>18}")
        ratios, cpu = [], []
        for seed in range(args.seeds):
            c = contacts(data, args.drift, seed)
            start = time.process_time()
            loc, placed, _ = localize(c, LocalizeSettings(drift_per_m=args.drift))
            cpu.append((time.process_time() - start) / robot_s)
            before, after = surface_error(data, c["odom"]), surface_error(data, placed)
            ratios.append(before / after)
            true_end = c["error"][-1, :2]
            best, best_end = perfect(data, c)
            print(f"{seed:>4} {before * 1e3:>11.2f} {after * 1e3:>8.2f} {before / after:>6.2f} "
                  f"{np.hypot(*true_end) * 1e3:>13.2f} "
                  f"{np.hypot(*(loc.estimate_m - true_end)) * 1e3:>13.2f} {best * 1e3:>11.2f} "
                  f"{before / best:>6.2f} {best_end * 1e3:>13.2f} {cpu[-1]:>18.2f}")
        if not ratios:
            continue
        print(f"median ratio {np.median(ratios):.2f} (lowest {min(ratios):.2f}), median CPU "
              f"{np.median(cpu):.2f} s per second of robot time (the baseline: 1, keeping up "
              "live)")
    if args.png:
        side_by_side(0, args.drift, args.png)
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
