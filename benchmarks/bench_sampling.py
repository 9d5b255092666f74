"""Step 1's snaps against the path's sampling: in how many cases of a grid they agree.

Each case is tests/core/test_sampling.py's yawing scene (a 35 mm rod on a robot yawing about z,
its tip on a sphere whose normal at the tip is tilted from the rod), simulated at 1, 4 and 10
samples per 0.1 mm of tip travel; it agrees when its episodes and snaps (snap-offs, landings,
snap-throughs) are the same at all three, each within a coarse sample (`sampled_alike`, the
test's own criterion). Grids (docs/LIMITS.md gives their counts):

* ``folds``: tilts 40, 45, 50 and 55 degrees from the normal, elevations -20, 10 and 40 degrees,
  mu 0.3, 0.5 and 0.8, radii 5, 10 and 20 mm, arcs to 1 rad: 108 cases;
* ``between``: tilts 42, 47 and 52 degrees, the same elevations, mu 0.4 and 0.6, radii 7 and
  15 mm: 36 cases between the first grid's;
* ``tilt45``: a tilt of 45 degrees at mu 0.5, elevations -5, 0 and 5 degrees, radii 5, 10 and
  20 mm, arcs to 0.5 and 1 rad: 18 cases.

A case whose tip touches nothing at the coarse sampling is counted apart. Prints every case
that does not agree with its snaps at each sampling, then the counts.

``--eggs N`` adds two contacts: N random scenes of tests/core/test_two_contacts_scene.py's kind
(a 50 mm rod leaning on a ball of radius 8.5-13 mm, driven into an egg turned at random, semi-
axes 3.5-6.2 mm, mu 0.3-0.7, low on its way), drawn from ``--seed`` until N have two contacts at
either sampling, at 0.11 mm of travel per sample and 4 times finer: in how many the two
contacts start at both, the episodes (how each begins and ends, in order) agree, and how many
samples are unresolved at each. Not a test: about a minute a grid on 2 cores.

Usage: ``python benchmarks/bench_sampling.py [--grid folds,between,tilt45] [--eggs 30]
[--seed 1] [--workers 2]``
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from multiprocessing import Pool
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository's tests package
from tests.core.test_sampling import sampled_alike  # noqa: E402
from tests.core.test_two_contacts_scene import egg_scene_of  # noqa: E402
from vibrissa.scene import SamplePhase, simulate  # noqa: E402

Case = tuple[float, float, float, float, float]  # tilt deg, elevation deg, mu, radius m, arc rad

GRIDS: dict[str, list[Case]] = {
    "folds": list(itertools.product((40.0, 45.0, 50.0, 55.0), (-20.0, 10.0, 40.0),
                                    (0.3, 0.5, 0.8), (0.005, 0.01, 0.02), (1.0,))),
    "between": list(itertools.product((42.0, 47.0, 52.0), (-20.0, 10.0, 40.0), (0.4, 0.6),
                                      (0.007, 0.015), (1.0,))),
    "tilt45": list(itertools.product((45.0,), (-5.0, 0.0, 5.0), (0.5,), (0.005, 0.01, 0.02),
                                     (0.5, 1.0))),
}


def _case(case: Case) -> tuple[Case, bool, bool, dict[int, list[tuple[str, float]]]]:
    """A case: whether it agrees, whether its tip touched at all, its snaps per sampling."""
    agree, episodes, events = sampled_alike(*case)
    return case, agree, bool(episodes[1]), events


EGG_SAMPLES = (590, 2357)
"""Samples of an egg scene's path: sample k of the first is sample 4 k of the second."""


def _egg(seed: int) -> tuple[int, list[bool], list[list[tuple[str, str]]], list[int]]:
    """Random egg scene ``seed``: per sampling of `EGG_SAMPLES`, whether two contacts start,
    the episodes (start, end) and the unresolved samples."""
    rng = np.random.default_rng(seed)
    scene = (rng.uniform(0.0085, 0.013), [rng.uniform(0.0197, 0.0209), 0.0,
                                          rng.uniform(0.030, 0.0325)],
             rng.uniform(0.0035, 0.0062, 3).tolist(),
             Rotation.random(random_state=rng.integers(2**31)).as_quat().tolist(),
             [rng.uniform(0.0239, 0.025), rng.uniform(-2e-4, 2e-4), rng.uniform(0.0047, 0.0062)],
             rng.uniform(0.3, 0.7))
    pairs, episodes, unresolved = [], [], []
    for samples in EGG_SAMPLES:
        (result,) = simulate(egg_scene_of(samples, *scene), workers=1)
        pairs.append(any(e.start == "second-contact" for e in result.episodes))
        episodes.append([(e.start, e.end) for e in result.episodes])
        unresolved.append(int(np.count_nonzero(result.phase == SamplePhase.UNRESOLVED)))
    return seed, pairs, episodes, unresolved


def _eggs(pool: Any, n: int, seed: int) -> None:
    """`_egg` from ``seed`` on until ``n`` scenes have two contacts at either sampling."""
    start, found, tried = time.perf_counter(), [], seed
    while len(found) < n and tried < seed + 20 * n:
        batch = pool.map(_egg, range(tried, tried + 2 * (n - len(found))), chunksize=1)
        tried += len(batch)
        found += [egg for egg in batch if any(egg[1])][:n - len(found)]
    both = sum(all(pairs) for _, pairs, _, _ in found)
    same = [egg for egg in found if egg[2][0] == egg[2][1]]
    print(f"\neggs: scenes whose episodes differ at {EGG_SAMPLES[0]} / {EGG_SAMPLES[1]} samples")
    for egg_seed, _, episodes, unresolved in found:
        if episodes[0] != episodes[1]:
            print(f"  seed {egg_seed}: {episodes[0]}, {unresolved[0]} unresolved")
            print(f"  {' ' * len(f'seed {egg_seed}')}  {episodes[1]}, {unresolved[1]} unresolved")
    print(f"eggs: {len(found)} scenes with two contacts ({tried - seed} drawn from seed {seed}); "
          f"two contacts at both samplings in {both}, the same episodes in {len(same)}; "
          f"unresolved samples {sum(e[3][0] for e in found)} of {len(found) * EGG_SAMPLES[0]} / "
          f"{sum(e[3][1] for e in found)} of {len(found) * EGG_SAMPLES[1]}; "
          f"{time.perf_counter() - start:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", default="folds,between,tilt45",
                        help=f"comma-separated, of {', '.join(GRIDS)}")
    parser.add_argument("--eggs", type=int, default=0, help="random two-contact scenes")
    parser.add_argument("--seed", type=int, default=1, help="the first egg scene's seed")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    args = parser.parse_args()
    grids = [grid for grid in args.grid.split(",") if grid]
    unknown = sorted(set(grids) - set(GRIDS))
    if unknown:
        parser.error(f"unknown grid {', '.join(unknown)}; the grids are {', '.join(GRIDS)}")
    with Pool(args.workers) as pool:
        for grid in grids:
            start = time.perf_counter()
            results = pool.map(_case, GRIDS[grid], chunksize=1)
            touched = [r for r in results if r[2]]
            agree = sum(r[1] for r in touched)
            print(f"\n{grid}: cases that do not agree (tilt deg, elevation deg, mu, radius m, "
                  "arc rad): the snaps at 1x / 4x / 10x, (kind, coarse sample after)")
            for case, same, hit, events in results:
                if hit and not same:
                    print(f"  {case}")
                    for n, snaps in events.items():
                        print(f"    {n:2d}x {[(kind, round(at, 1)) for kind, at in snaps]}")
            print(f"{grid}: {agree} of {len(touched)} agree; {len(results) - len(touched)} "
                  f"touched nothing; {time.perf_counter() - start:.0f} s")
        if args.eggs:
            _eggs(pool, args.eggs, args.seed)


if __name__ == "__main__":
    main()
