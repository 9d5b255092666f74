"""Live map benchmark: an incremental update after new points against a full fit of the cloud.

The cloud: the demo's paraboloid (launch/demo.yaml) swept by its 5 trails (Step 1,
``simulate_sweeps``, mu 0.2) at a step of ``STEP`` m, one whisker, in the order touched; its
first ``--base`` points are one object (10^4 by default), then ``--new`` more arrive (1 000).

* ``full``: ``fit_frame`` on all ``base + new`` points (objects, normals, the GP fit with its
  hyperparameters, the mesh and its std, the next sweeps): the baseline of the ratio.
* ``update``: ``LiveMap.update`` with the same points, after an update with the first ``base``
  (not timed): the object grew, so its GP is conditioned on the new points and meshed on
  ``LiveSettings.cells`` (``--cells``); its next sweeps are kept.
* ``double``: the same update with its vertex stds solved in double precision
  (``LiveSettings(single=False)``): what ``LiveSettings.single`` saves.
* ``final``: ``LiveMap.final`` after that update: the full fit of the grown object.

Each time is the median of ``--repeat`` runs after one warm-up run (numba's compilation and
Open3D's import excluded), in one process; ``x full`` is the full fit's median over this one.
One BLAS thread (``OPENBLAS_NUM_THREADS`` etc. set to 1 unless already set), as the mapper runs.
Not a test.

Usage: ``python benchmarks/bench_map_update.py [--base 10000] [--new 1000] [--repeat 5]
[--cells 32]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from functools import partial  # noqa: E402

import numpy as np  # noqa: E402

from vibrissa.mapping import (  # noqa: E402
    ContactBatch,
    FrameCloud,
    LiveMap,
    LiveSettings,
    fit_frame,
)
from vibrissa.surfaces import parse_surface  # noqa: E402
from vibrissa.sweep import Trail, contact_lines, simulate_sweeps  # noqa: E402

PARABOLOID = "paraboloid:a=0.5,b=1,h=0.4"  # launch/demo.yaml
TRAILS = (-0.4, -0.2, 0.0, 0.2, 0.4)
MU = 0.2
STEP = 0.0009
"""Step along a trail, m: the 5 trails give about 11 600 contact points."""
FRAME = "world"


def cloud_of(points: np.ndarray, forces: np.ndarray) -> FrameCloud:
    """A frame's cloud of one whisker's points (N, 3) m and forces (N, 3) N, in order."""
    cloud = FrameCloud()
    cloud.add(ContactBatch(FRAME, points, forces, ["w0"] * len(points)), None,
              np.full((len(points), 3, 3), np.nan))
    return cloud


def timed(run: Callable[[], object]) -> float:
    """Seconds one call of ``run`` takes."""
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=int, default=10_000)
    parser.add_argument("--new", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--cells", type=int, default=LiveSettings.cells,
                        help="LiveSettings.cells: the grid of a conditioned object's mesh")
    args = parser.parse_args()
    points, forces, _ = contact_lines(simulate_sweeps(
        parse_surface(PARABOLOID), [Trail(y0, MU) for y0 in TRAILS], STEP))
    total = args.base + args.new
    if total > len(points):
        raise SystemExit(f"--base + --new must be at most {len(points)}, got {total}")
    before, after = cloud_of(points[:args.base], forces[:args.base]), cloud_of(
        points[:total], forces[:total])
    times: dict[str, list[float]] = {"full": [], "update": [], "double": [], "final": []}
    for run in range(args.repeat + 1):
        live = LiveMap(LiveSettings(cells=args.cells))
        live.update(FRAME, before)
        update = timed(partial(live.update, FRAME, after))
        final = timed(partial(live.final, FRAME, after))
        in_double = LiveMap(LiveSettings(cells=args.cells, single=False))
        in_double.update(FRAME, before)
        double = timed(partial(in_double.update, FRAME, after))
        full = timed(lambda: fit_frame(FRAME, after))
        if run:  # the first is the warm-up
            for name, value in (("full", full), ("update", update), ("double", double),
                                ("final", final)):
                times[name].append(value)
    median = {name: statistics.median(values) for name, values in times.items()}
    print(f"{args.base} points + {args.new} new, {args.cells} cells, {args.repeat} runs, load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; fits of the last run: "
          f"{dict(live.fits)}")
    print(f"{'':8} {'median s':>9} {'min s':>7} {'max s':>7} {'x full':>7}")
    for name, values in times.items():
        print(f"{name:8} {median[name]:9.3f} {min(values):7.3f} {max(values):7.3f} "
              f"{median['full'] / median[name]:7.2f}")


if __name__ == "__main__":
    main()
