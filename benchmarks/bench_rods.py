"""Rods benchmark: Step 1 and Step 2 of a tapered pre-curved rod (``vibrissa.rods``).

Prints one table; the issue's speed contract, measured in one run:

* Step 2 at >= 100 000 samples/s on one core: ``reconstruct_rod`` on ``--samples`` wrenches of
  a rod of taper 0.4, pre-curvature 2.0, nu 0.3 (2 000 distinct wrenches, tiled: random
  contact forces |F| in 0.05..1.5 in random directions at s1 in 0.2..1, clamp moments by
  ``loaded_rod``), median of ``--repeat`` after a warm-up call. For the ratio, the uniform
  rod's closed form ``reconstruct`` on as many uniform-rod wrenches (same F and s1).
* Step 1 at >= 20x a ``solve_ivp`` shooting baseline per equilibrium. The library: a sweep of
  the same rod past a sphere (y0 0.1, mu 0.3), its wall time (median of ``--repeat``, after
  a warm-up) over its rows. The baseline: ``--equilibria`` rows spread over that sweep, each
  solved again by ``scipy.optimize.root`` over the clamp moment m0 (3) on m(s1) = 0, the rod
  (r, R as 12 states) integrated by ``solve_ivp`` (DOP853, rtol 1e-10, atol 1e-12) under the
  row's contact force F at the row's s1, warm-started from the previous row's m0 (as a sweep
  warm-starts). The baseline only solves the rod for a given F and s1; the library also
  finds F and s1 (contact on the surface, friction cone, stick/slip), so the baseline is a
  lower bound of what a scipy shooting Step 1 costs and the ratio understates the speed-up.
* The uniform rod's figures are unchanged: ``benchmarks/bench_mechanics.py`` covers them.

Agreement, so that the timings compare equal answers: Step 2's s1 against the s1 each wrench
was made with (the true contact among the candidates, and the one returned), the baseline's m0
against the sweep's (the library integrates by RK4 on `vibrissa.rods.N_STEPS` steps per L: expect ~1e-6 or better).
Everything runs on one core (BLAS threads pinned to 1).

Usage: ``python benchmarks/bench_rods.py [--samples 200000] [--repeat 5] [--equilibria 20]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402
from bench_mechanics import median_of, print_table  # noqa: E402  (beside this file)
from numpy.typing import NDArray  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.optimize import root  # noqa: E402

from vibrissa import parse_surface  # noqa: E402
from vibrissa.reconstruct import reconstruct  # noqa: E402
from vibrissa.reconstruct_rods import reconstruct_rod  # noqa: E402
from vibrissa.rods import UNIFORM, RodShape, loaded_rod  # noqa: E402
from vibrissa.sweep import simulate_sweep  # noqa: E402

FloatArray = NDArray[np.float64]
SHAPE = RodShape(taper_ratio=0.4, precurvature=2.0, poisson_ratio=0.3)
SURFACE = "sphere:r=0.3,cx=0,cy=0,cz=0.6"
Y0, MU, STEP = 0.1, 0.3, 0.001
DISTINCT = 2000
STEP2_CONTRACT, STEP1_CONTRACT = 100_000.0, 20.0


def _wrenches(shape: RodShape, forces: FloatArray, s1: FloatArray
              ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(f0, m0, s1) of the loads ``loaded_rod`` solves (those past the rod's folds dropped)."""
    f0, m0, kept = [], [], []
    for force, s in zip(forces, s1, strict=True):
        try:
            m0.append(loaded_rod(shape, force, float(s)))
        except ValueError:
            continue
        f0.append(-force)
        kept.append(s)
    return np.array(f0), np.array(m0), np.array(kept)


def _step2(rows: list[tuple[str, str, str]], name: str, shape: RodShape, forces: FloatArray,
           s1_made: FloatArray, args: argparse.Namespace) -> float:
    """Step 2 of ``shape``'s wrenches of ``forces`` at ``s1_made``, tiled to ``args.samples``:
    its rows into ``rows``; returns samples/s."""
    f0, m0, s1_true = _wrenches(shape, forces, s1_made)
    reps = -(-args.samples // len(f0))
    f0_n, m0_n = (np.tile(a, (reps, 1))[: args.samples] for a in (f0, m0))
    p0_n = np.zeros_like(f0_n)

    def call() -> object:  # the uniform rod: its closed form, as reconstruct_rod hands it
        if shape.uniform:
            return reconstruct(p0_n, f0_n, m0_n)
        return reconstruct_rod(p0_n, f0_n, m0_n, shape)

    call()  # warm-up (compilation, caches)
    wall = median_of(call, args.repeat)
    rate = args.samples / wall
    result, candidates = reconstruct_rod(np.zeros_like(f0), f0, m0, shape)
    near = np.nanmin(np.abs(candidates - s1_true[:, None]), axis=1)
    returned = np.abs(result.s1 - s1_true) < 1e-5
    rows.append((f"Step 2 {name}: {args.samples:.0e} samples, one core",
                 f"{rate:.3g} samples/s", f"{wall:.3f} s, {len(f0)} distinct wrenches"))
    rows.append((f"Step 2 {name}: agreement, max |s1 - true| where found",
                 f"{np.nanmax(np.where(near < 1e-3, near, np.nan)):.1e}",
                 f"true s1 a candidate: {np.mean(near < 1e-5):.1%}, the one returned: "
                 f"{np.mean(returned):.1%}"))
    return rate


# --- Step 1 baseline ------------------------------------------------------------------------


def _rod_rhs(f0: FloatArray, m0: FloatArray, shape: RodShape
             ) -> Callable[[float, FloatArray], FloatArray]:
    """The Kirchhoff rod of ``vibrissa.rods``: y = (r, R row-major); r' = d3, R' = R [u]x."""
    taper, kappa_hat, torsion = shape.taper_ratio, shape.precurvature, 1.0 + shape.poisson_ratio

    def rhs(s: float, y: FloatArray) -> FloatArray:
        r, rot = y[:3], y[3:].reshape(3, 3)
        m_mat = rot.T @ (np.cross(r, f0) - m0)
        compliance = 1.0 / (1.0 - (1.0 - taper) * s) ** 4
        u = np.array([m_mat[0] * compliance, m_mat[1] * compliance + kappa_hat,
                      m_mat[2] * torsion * compliance])
        hat = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
        return np.concatenate([rot[:, 2], (rot @ hat).ravel()])

    return rhs


_CLAMP = np.concatenate([np.zeros(3), np.eye(3).ravel()])


def _moment_at_contact(m0: FloatArray, force: FloatArray, s1: float, shape: RodShape
                       ) -> FloatArray:
    f0 = -force
    sol = solve_ivp(_rod_rhs(f0, m0, shape), (0.0, s1), _CLAMP, method="DOP853", rtol=1e-10,
                    atol=1e-12)
    return np.asarray(np.cross(sol.y[:3, -1], f0) - m0, dtype=float)


def shooting_m0(force: FloatArray, s1: float, guess: FloatArray, shape: RodShape
                ) -> tuple[FloatArray, bool]:
    """Baseline Step 1 (the rod alone): m0 with m(s1) = 0 under ``force`` at ``s1``."""
    solution = root(_moment_at_contact, guess, args=(force, s1, shape), method="hybr",
                    tol=1e-12)
    return np.asarray(solution.x, dtype=float), bool(solution.success)


# --- driver ---------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--equilibria", type=int, default=20)
    args = parser.parse_args()
    rows: list[tuple[str, str, str]] = []
    rng = np.random.default_rng(7)

    # Step 2: 2000 distinct loads, the same for both rods, tiled to --samples.
    direction = rng.normal(size=(DISTINCT, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    forces = direction * rng.uniform(0.05, 1.5, size=(DISTINCT, 1))
    s1_made = rng.uniform(0.2, 1.0, size=DISTINCT)
    rod_rate = _step2(rows, "tapered pre-curved", SHAPE, forces, s1_made, args)
    uniform_rate = _step2(rows, "uniform (closed form)", UNIFORM, forces, s1_made, args)
    rows.append(("Step 2 ratio uniform closed form / tapered pre-curved",
                 f"{uniform_rate / rod_rate:.1f}x", ""))
    rows.append((f"Step 2 contract: tapered pre-curved >= {STEP2_CONTRACT:.0f} samples/s",
                 "MET" if rod_rate >= STEP2_CONTRACT else "NOT MET",
                 f"{rod_rate / STEP2_CONTRACT:.2f}x the contract"))

    # Step 1, library: one sweep of the same rod past a sphere.
    surface = parse_surface(SURFACE)
    sweep = simulate_sweep(surface, Y0, MU, STEP, shape=SHAPE)  # warm-up, and the rows
    wall = median_of(lambda: simulate_sweep(surface, Y0, MU, STEP, shape=SHAPE), args.repeat)
    lib_step = wall / sweep.n_steps
    rows.append((f"Step 1 library: sweep y0={Y0} mu={MU} step {STEP}, per equilibrium",
                 f"{lib_step * 1e3:.3f} ms", f"{sweep.n_steps} equilibria, {wall:.2f} s, "
                 f"end {sweep.end}"))

    # Step 1, baseline: rows spread over the sweep, the rod alone by shooting.
    picks = np.unique(np.linspace(1, sweep.n_steps - 1, args.equilibria).astype(int))
    worst_m0, failures, times = 0.0, 0, []
    for i in picks:
        start = time.perf_counter()
        m0_i, ok = shooting_m0(sweep.force[i], float(sweep.s1[i]), sweep.m0[i - 1], SHAPE)
        times.append(time.perf_counter() - start)
        failures += not ok
        worst_m0 = max(worst_m0, float(np.abs(m0_i - sweep.m0[i]).max()))
    shoot_step = float(np.median(times))
    rows.append((f"Step 1 baseline: solve_ivp in root, rod alone ({len(picks)} equilibria)",
                 f"{shoot_step * 1e3:.1f} ms", f"median; {failures} failed"))
    ratio = shoot_step / lib_step
    rows.append(("Step 1 ratio baseline / library per equilibrium", f"{ratio:.1f}x",
                 "baseline a lower bound (F and s1 given)"))
    rows.append((f"Step 1 contract: ratio >= {STEP1_CONTRACT:.0f}",
                 "MET" if ratio >= STEP1_CONTRACT else "NOT MET",
                 f"{ratio / STEP1_CONTRACT:.2f}x the contract"))
    rows.append(("Step 1 agreement: max |m0 baseline - sweep|", f"{worst_m0:.1e}", "EI/L"))

    print_table(rows)


if __name__ == "__main__":
    main()
