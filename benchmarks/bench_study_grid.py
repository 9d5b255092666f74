"""Study grids on local workers and on a Dask LocalCluster (``vibrissa study grid``).

Prints two tables, each with its baseline in the same run:

* the paper's grid (``studies/paper.yaml``, 25 sweeps): serial (one process) against
  ``--workers 2``; median wall time of ``--repeats`` runs each and the ratio;
* a grid of 1 000 cases (2 paraboloids, 2 ellipsoids and a sphere, 8 rods of 40-110 mm,
  5 trails, 5 mu; ``--step`` in units of L): 2 local worker processes against a 2-worker
  LocalCluster; wall time, equilibria per second and the ratio (one run each: minutes).

Every run starts from an empty store (no case reused) and writes it, as the command does; the
tables of the runs compared are checked equal. The load average before and after is printed:
the machine may be shared. CPU s counts this process and its ended worker processes: on a
loaded machine, where wall times say little, the CPU ratio shows what parallel running costs.

Usage: ``python benchmarks/bench_study_grid.py [--repeats 3] [--step 0.01] [--skip-large]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import itertools  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

from vibrissa.grid_study import GridCase  # noqa: E402
from vibrissa.studies.grid_file import PAPER_GRID, Grid, load_grid  # noqa: E402
from vibrissa.studies.grid_run import CaseStore, GridRun, run_grid, same_bits, warm_up  # noqa: E402

# Objects in m, for rods of 40-110 mm clamped at the origin along +z.
LARGE_SURFACES = (
    "paraboloid:a=10,b=20,h=0.03",
    "paraboloid:a=5,b=5,h=0.035,roll=0.1",
    "ellipsoid:rx=0.03,ry=0.02,rz=0.015,cz=0.06",
    "ellipsoid:rx=0.015,ry=0.025,rz=0.02,cz=0.065,yaw=0.5",
    "sphere:r=0.02,cz=0.06",
)
LARGE_RODS = tuple((0.04 + 0.01 * i, 2e-5 * (1 + i)) for i in range(8))
LARGE_Y0_M = (-0.01, -0.005, 0.0, 0.005, 0.01)
LARGE_MU = (0.0, 0.1, 0.2, 0.3, 0.4)


def large_grid(step: float) -> Grid:
    """The 1 000 cases, surfaces outermost as a grid file's product."""
    cases = tuple(GridCase(surface, y0, mu, step, length_m, ei_nm2)
                  for surface, (length_m, ei_nm2), y0, mu
                  in itertools.product(LARGE_SURFACES, LARGE_RODS, LARGE_Y0_M, LARGE_MU))
    return Grid("large", cases)


def cpu_s() -> float:
    """CPU time of this process and its ended child processes, s."""
    own, children = (resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def timed(grid: Grid, workers: int, scheduler: str | None) -> tuple[GridRun, float]:
    """The run from an empty store and its CPU time (this process and its workers), s."""
    before = cpu_s()
    with tempfile.TemporaryDirectory() as tmp:
        run = run_grid(grid, CaseStore(Path(tmp)), workers, scheduler)
    return run, cpu_s() - before


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per paper row (median)")
    parser.add_argument("--paper-step", type=float, default=0.001, help="the paper grid's step, L")
    parser.add_argument("--step", type=float, default=0.01, help="the large grid's step, L")
    parser.add_argument("--skip-large", action="store_true", help="only the paper grid")
    args = parser.parse_args()
    print(f"cores: {os.cpu_count()}, load average (1, 5, 15 min) before: {load()}")
    warm_up()

    paper = load_grid(PAPER_GRID, args.paper_step)
    rows = {}
    for name, workers in (("serial (1 process)", 1), ("2 local workers", 2)):
        runs = [timed(paper, workers, None) for _ in range(args.repeats)]
        rows[name] = (statistics.median(r.elapsed_s for r, _cpu in runs),
                      statistics.median(cpu for _r, cpu in runs), runs[0][0])
    (serial_s, serial_cpu, serial), (workers_s, workers_cpu, parallel) = rows.values()
    assert same_bits(serial.equilibria, parallel.equilibria) and same_bits(serial.summary, parallel.summary)
    print(f"\npaper grid: {len(paper.cases)} cases, step {args.paper_step} L, "
          f"{serial.equilibria.num_rows} equilibria, median of {args.repeats}")
    print(f"{'run':<22}{'wall s':>10}{'CPU s':>10}{'equilibria/s':>15}")
    for name, (seconds, cpu, run) in rows.items():
        print(f"{name:<22}{seconds:>10.2f}{cpu:>10.2f}{run.equilibria.num_rows / seconds:>15.0f}")
    print(f"speed-up of 2 workers: {serial_s / workers_s:.2f}x wall, CPU ratio "
          f"{workers_cpu / serial_cpu:.2f}   (load after: {load()})")

    if args.skip_large:
        return
    large = large_grid(args.step)
    (local, local_cpu), (cluster, cluster_cpu) = timed(large, 2, None), timed(large, 2, "local")
    assert same_bits(local.equilibria, cluster.equilibria) and same_bits(local.summary, cluster.summary)
    ends = statistics.multimode(local.summary.column("end").to_pylist())
    print(f"\nlarge grid: {len(large.cases)} cases, step {args.step} L, "
          f"{local.equilibria.num_rows} equilibria (most end by {', '.join(ends)})")
    print(f"{'run':<26}{'wall s':>10}{'CPU s':>10}{'equilibria/s':>15}")
    for name, run, cpu in (("2 local workers", local, local_cpu),
                           ("LocalCluster, 2 workers", cluster, cluster_cpu)):
        print(f"{name:<26}{run.elapsed_s:>10.2f}{cpu:>10.2f}"
              f"{run.equilibria.num_rows / run.elapsed_s:>15.0f}")
    print(f"LocalCluster / local workers: {cluster.elapsed_s / local.elapsed_s:.3f}   "
          f"(load after: {load()})")


if __name__ == "__main__":
    main()
