"""Mechanics benchmark: Step 1 and Step 2 of the library against straightforward scipy ports.

Prints one table. Baselines, in the same run and on the same inputs:

* Step 2: the paper's IVP (eq. 11 with the initial values of eq. 23) integrated by
  ``scipy.integrate.solve_ivp`` with a terminal event at kappa = 0, one sample at a time.
* Step 2 with covariance: the point's covariance J Sigma J^T with J by central differences
  of the library's Step 2 in SI (12 more calls over the batch), against the closed-form J.
* Step 1: shooting for one tip-contact equilibrium at mu = 0 (BCs eq. 14): ``solve_ivp`` of
  eq. 11 inside ``scipy.optimize.root`` over (psi, fn, kappa0, contact x, contact y), warm-started
  from the library's previous step, as a sweep would.
* Step 1 of a robot's scene: its whiskers one after another (each alone) against the library's
  whiskers solved together.
* Step 1's retaking of steep steps in sub-steps (``vibrissa.sweep``): the paper's study with the
  check switched off, interleaved with the study as it is.

The scipy baselines are checked against the library's results (max difference printed), and
a whisker alone gives the same bits as solved together, so the timings compare equal answers.
Everything runs on one core (BLAS threads pinned to 1), but the scene over 2 worker processes.

Usage: ``python benchmarks/bench_mechanics.py [--study-step 0.001] [--samples 1000000]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.optimize import root  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from vibrissa import sweep as sweep_module  # noqa: E402
from vibrissa.frames import Transform  # noqa: E402
from vibrissa.reconstruct import reconstruct, reconstruct_si  # noqa: E402
from vibrissa.scene import (  # noqa: E402
    Scene,
    SceneObject,
    Whisker,
    robot_path,
    simulate,
    simulate_whisker,
)
from vibrissa.study import PAPER_SURFACE, run_study  # noqa: E402
from vibrissa.surfaces import Surface, parse_surface  # noqa: E402
from vibrissa.sweep import Sweep, Trail, simulate_sweeps  # noqa: E402
from vibrissa.units import RodScale  # noqa: E402

FloatArray = NDArray[np.float64]
IVP_TOL = {"rtol": 1e-11, "atol": 1e-13}


def print_table(rows: list[tuple[str, str, str]]) -> None:
    """One benchmark's table: quantity, value, note per row."""
    width = max(len(r[0]) for r in rows)
    print(f"\n{'quantity':<{width}}  {'value':>22}  note")
    print("-" * (width + 40))
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:>22}  {note}")


def median_of(fn: Callable[[], object], repeat: int) -> float:
    """Median wall time of ``repeat`` calls, s (robust to other load on the machine)."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


# --- Step 2 baseline ------------------------------------------------------------------------


def _rhs(fu: float, fv: float) -> Callable[[float, FloatArray], list[float]]:
    """Eq. 11 in the plane E_psi; kappa' = f cos(phi - alpha) = fu sin(phi) - fv cos(phi)."""

    def rhs(_s: float, y: FloatArray) -> list[float]:
        phi, kappa = y[2], y[3]
        return [np.cos(phi), np.sin(phi), kappa, fu * np.sin(phi) - fv * np.cos(phi)]

    return rhs


def _kappa_zero(_s: float, y: FloatArray) -> float:
    return float(y[3])


_kappa_zero.terminal = True  # type: ignore[attr-defined]
_kappa_zero.direction = -1  # type: ignore[attr-defined]


def ivp_reconstruct(p0: FloatArray, f0: FloatArray, m0: FloatArray) -> FloatArray:
    """Baseline Step 2 for one sample: eqs. 20-23 and solve_ivp to the event kappa = 0."""
    force = -f0
    m_h = float(np.hypot(m0[0], m0[1]))
    e_u = np.array([m0[1], -m0[0], 0.0]) / m_h  # e_w = -m0/|m0| so that kappa0 = |m0| >= 0
    fu, fv = float(force @ e_u), float(force[2])
    sol = solve_ivp(_rhs(fu, fv), (0.0, 2.0), [0.0, 0.0, np.pi / 2, m_h], events=_kappa_zero,
                    **IVP_TOL)
    if not sol.t_events[0].size:
        return np.full(3, np.nan)
    u1, v1 = sol.y_events[0][0][:2]
    return np.asarray(p0 + u1 * e_u + np.array([0.0, 0.0, v1]), dtype=float)


# --- Step 1 baseline ------------------------------------------------------------------------


def shooting_residual(z: FloatArray, surface: Surface, p0: FloatArray) -> FloatArray:
    """Tip contact at mu = 0 (eq. 14): z = (psi, fn, kappa0, x1, y1); five residuals.

    The contact P1 = (x1, y1, z(x1, y1)) lies on the surface; the force on the rod is fn n(P1);
    the rod's tip must reach P1 with zero curvature, and the force must lie in E_psi.
    """
    psi, fn, kappa0, x1, y1 = z
    lo, _hi = surface.line_interval(np.array([[x1, y1, 0.0]]), np.array([[0.0, 0.0, 1.0]]))
    p1 = np.array([x1, y1, lo[0]])
    force = fn * surface.normal(p1)[0]
    e_u = np.array([np.cos(psi), np.sin(psi), 0.0])
    e_w = np.array([np.sin(psi), -np.cos(psi), 0.0])
    fu, fv = float(force @ e_u), float(force[2])
    sol = solve_ivp(_rhs(fu, fv), (0.0, 1.0), [0.0, 0.0, np.pi / 2, kappa0], **IVP_TOL)
    u, v, _phi, kappa = sol.y[:, -1]
    tip = p0 + u * e_u + np.array([0.0, 0.0, v])
    return np.array([kappa, *(tip - p1), force @ e_w])


def shooting_step(surface: Surface, p0: FloatArray, guess: FloatArray) -> tuple[FloatArray, bool]:
    solution = root(shooting_residual, guess, args=(surface, p0), method="hybr", tol=1e-12)
    return solution.x, bool(solution.success)


def _unknowns(sweep: Sweep, i: int) -> FloatArray:
    """(psi, fn, kappa0, x1, y1) of the library's equilibrium i, in the baseline's convention."""
    m0 = sweep.m0[i]
    e_u = np.array([m0[1], -m0[0]]) / np.hypot(m0[0], m0[1])
    return np.array([np.arctan2(e_u[1], e_u[0]), sweep.fn[i], np.hypot(m0[0], m0[1]),
                     *sweep.contact[i, :2]])


# --- driver ---------------------------------------------------------------------------------


def _robot_scene() -> Scene:
    """8 whiskers (L 30-65 mm, three stiffnesses, tilted mounts) on a robot driving an arc
    of 0.8 rad past a ball and a posed ellipsoid, 2000 samples."""
    objects = (SceneObject("ball", "sphere", {"radius_m": 0.02},
                           Transform(translation=[0.0, 0.03, 0.04])),
               SceneObject("egg", "ellipsoid", {"semi_axes_m": [0.015, 0.01, 0.012]},
                           Transform.from_xyz_rpy([-0.08, 0.0, 0.045], [0.0, 0.2, 0.5])))
    whiskers = tuple(
        Whisker(f"w{i}", 0.03 + 0.005 * i, 1e-5 * (1 + i % 3),
                Transform.from_xyz_rpy([0.0, -0.02 + 0.006 * i, 0.0], [0.15 * (i % 3 - 1), 0.1, 0.0]))
        for i in range(8))
    n = 2000
    theta = np.linspace(0.0, 0.8, n)
    positions = np.column_stack([0.1 - 0.2 * np.sin(theta), 0.2 * (1 - np.cos(theta)) - 0.01,
                                 np.zeros(n)])
    path = robot_path(np.arange(n) * 0.005, positions,
                      Rotation.from_euler("z", -theta[:, None]).as_quat())
    return Scene(0.3, objects, whiskers, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study-step", type=float, default=0.001)
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--ivp-samples", type=int, default=300)
    parser.add_argument("--shooting-steps", type=int, default=5)
    parser.add_argument("--retake-repeat", type=int, default=5)
    args = parser.parse_args()
    surface = parse_surface(PAPER_SURFACE)
    rows: list[tuple[str, str, str]] = []

    # Step 1, library: the whole study, one batched call (+ Step 2 and the error, negligible).
    print(f"running the 25-sweep study at step {args.study_step} ...", flush=True)
    study = run_study(surface, step=args.study_step)
    n_equilibria = sum(case.sweep.n_steps for case in study.cases)
    lib_step = study.elapsed_s / n_equilibria
    rows.append(("Step 1 library: 25-sweep study (figures excluded)",
                 f"{study.elapsed_s:.1f} s", f"{n_equilibria} equilibria"))
    rows.append(("Step 1 library: per equilibrium (study wall / equilibria)",
                 f"{lib_step * 1e3:.2f} ms", ""))

    # What retaking steep steps in sub-steps costs (vibrissa.sweep._through_steep_step): the
    # study with it and with the check switched off, interleaved, medians of --retake-repeat.
    plain, retaken = [], []
    check = sweep_module._steep
    for _ in range(args.retake_repeat):
        for switched_off, times in ((True, plain), (False, retaken)):
            sweep_module._steep = (lambda track: False) if switched_off else check
            times.append(run_study(surface, step=args.study_step).elapsed_s)
    sweep_module._steep = check
    rows.append(("Step 1: the study with steep steps retaken / without (a baseline)",
                 f"{np.median(retaken) / np.median(plain):.3f}x",
                 f"medians of {args.retake_repeat}: {np.median(retaken):.2f} s, "
                 f"{np.median(plain):.2f} s"))

    # Step 1, baseline: shooting for a few consecutive tip-contact steps of y0 = 0.2, mu = 0.
    sweep = study.case(0.2, 0.0).sweep
    start_index = min(100, sweep.n_steps // 4)
    steps = range(start_index, start_index + args.shooting_steps)
    assert all(sweep.phase[i] == 1 for i in steps), "baseline steps must be tip contacts"
    guess = _unknowns(sweep, start_index - 1)
    worst_point, worst_m0, failures = 0.0, 0.0, 0
    start = time.perf_counter()
    for i in steps:
        z, ok = shooting_step(surface, sweep.p0[i], guess)
        failures += not ok
        guess = z
        lo, _hi = surface.line_interval(np.array([[z[3], z[4], 0.0]]), np.array([[0.0, 0.0, 1.0]]))
        worst_point = max(worst_point, float(np.abs(np.array([z[3], z[4], lo[0]])
                                                    - sweep.contact[i]).max()))
        e_w = np.array([np.sin(z[0]), -np.cos(z[0]), 0.0])
        worst_m0 = max(worst_m0, float(np.abs(-z[2] * e_w - sweep.m0[i]).max()))
    shoot_step = (time.perf_counter() - start) / args.shooting_steps
    rows.append((f"Step 1 baseline: solve_ivp in root, tip step mu=0 ({args.shooting_steps} steps)",
                 f"{shoot_step * 1e3:.1f} ms/step", f"{failures} failed"))
    rows.append(("Step 1 ratio baseline / library per step (study)", f"{shoot_step / lib_step:.0f}x",
                 ""))
    # One sweep alone, as `vibrissa sweep` runs it (no batching to hide per-step overhead).
    single = median_of(lambda: simulate_sweeps(surface, [Trail(0.2, 0.3)], 0.002), 3)
    n_single = simulate_sweeps(surface, [Trail(0.2, 0.3)], 0.002)[0].n_steps
    rows.append(("Step 1 library: one sweep y0=0.2 mu=0.3 step 0.002, per equilibrium",
                 f"{single / n_single * 1e3:.2f} ms", f"{n_single} equilibria, {single:.2f} s"))
    rows.append(("Step 1 ratio baseline / library per step (one sweep)",
                 f"{shoot_step / (single / n_single):.0f}x", ""))
    rows.append(("Step 1 agreement: max |P1|, |m0| difference",
                 f"{worst_point:.1e}, {worst_m0:.1e}", "L, EI/L"))

    # A robot's scene: 8 whiskers of their own L, EI and tilted mounts on an arc past two
    # posed objects, 2000 path samples: the whiskers solved together (one batched attempt per
    # step) in one process and over 2 worker processes, against whisker after whisker.
    scene = _robot_scene()
    results = simulate(scene, workers=1)
    contacts = sum(int(np.sum((r.phase == 1) | (r.phase == 2))) for r in results)
    for workers in (1, 2):
        scene_s = median_of(functools.partial(simulate, scene, workers=workers), 3)
        rows.append((f"Step 1 library: scene of 8 whiskers x 2000 samples, {workers} worker(s)",
                     f"{scene_s:.2f} s", f"{contacts} contact samples"))
    alone_s = median_of(lambda: [simulate_whisker(scene, w) for w in scene.whiskers], 3)
    rows.append(("Step 1 baseline: the same scene, whisker after whisker, one process",
                 f"{alone_s:.2f} s", "no batching across whiskers"))
    alone = [simulate_whisker(scene, w) for w in scene.whiskers]
    same = all(np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True)
               for a, b in zip(results, alone, strict=True)
               for name in ("phase", "s1_m", "f0_n", "m0_nm", "p_W_m", "object"))
    rows.append(("Step 1 agreement: scene together vs whisker after whisker",
                 "same bits" if same else "DIFFERENT", ""))

    # Step 2, library: a real study sweep (both phases, friction) tiled to `samples`.
    sweep = study.case(0.2, 0.3).sweep
    reps = -(-args.samples // sweep.n_steps)
    p0, f0, m0 = (np.tile(a, (reps, 1))[: args.samples] for a in (sweep.p0, sweep.f0, sweep.m0))
    batch = median_of(lambda: reconstruct(p0, f0, m0), 3)
    rows.append((f"Step 2 library: reconstruct() on {args.samples:.0e} samples, one core",
                 f"{args.samples / batch:.3g} samples/s", f"{batch:.2f} s"))
    n_single = min(2000, sweep.n_steps)
    single = median_of(lambda: [reconstruct(sweep.p0[i], sweep.f0[i], sweep.m0[i])
                                 for i in range(n_single)], 5) / n_single
    rows.append(("Step 2 library: single-sample latency, reconstruct() of (3,) vectors",
                 f"{single * 1e6:.1f} us", ""))

    # Step 2, baseline: solve_ivp with an event, one sample at a time.
    picks = np.linspace(1, sweep.n_steps - 2, args.ivp_samples).astype(int)
    start = time.perf_counter()
    points = np.array([ivp_reconstruct(sweep.p0[i], sweep.f0[i], sweep.m0[i]) for i in picks])
    ivp = (time.perf_counter() - start) / len(picks)
    library_points = reconstruct(sweep.p0[picks], sweep.f0[picks], sweep.m0[picks]).point
    rows.append((f"Step 2 baseline: solve_ivp + event ({len(picks)} samples)",
                 f"{1 / ivp:.3g} samples/s", f"{ivp * 1e6:.0f} us/sample"))
    rows.append(("Step 2 ratio baseline / library batched per sample",
                 f"{ivp / (batch / args.samples):.0f}x", ""))
    rows.append(("Step 2 ratio baseline / library single sample", f"{ivp / single:.0f}x", ""))
    rows.append(("Step 2 agreement: max |P1 baseline - library|",
                 f"{np.nanmax(np.abs(points - library_points)):.1e}", "L"))
    rows.append(("Step 2 agreement: max |P1 library - Step 1 contact|",
                 f"{np.nanmax(np.abs(library_points - sweep.contact[picks])):.1e}", "L"))

    # Step 2 with covariance, SI, a tilted clamp: library against central differences.
    rod = RodScale(0.05, 2e-5)
    q = np.tile(Rotation.from_rotvec([0.3, -0.2, 0.5]).as_quat(), (len(p0), 1))
    f0_n, m0_nm, p0_m = f0 * rod.force_n, m0 * rod.moment_nm, p0 * rod.length_m
    sigma = 1e-4 * np.repeat([np.linalg.norm(sweep.f0, axis=1).max() * rod.force_n,
                              np.linalg.norm(sweep.m0, axis=1).max() * rod.moment_nm], 3)
    cov_w = np.diag(sigma**2)
    plain_si = median_of(lambda: reconstruct_si(q, p0_m, f0_n, m0_nm, rod), 3)
    with_cov = median_of(lambda: reconstruct_si(q, p0_m, f0_n, m0_nm, rod, cov_w), 3)
    rows.append((f"Step 2 library: reconstruct_si() on {args.samples:.0e} samples, one core",
                 f"{args.samples / plain_si:.3g} samples/s", f"{plain_si:.2f} s"))
    rows.append(("Step 2 library: reconstruct_si() + covariance, one core",
                 f"{args.samples / with_cov:.3g} samples/s", f"{with_cov:.2f} s"))

    def central_differences() -> FloatArray:
        wrench = np.c_[f0_n, m0_nm]
        jacobian = np.empty((len(wrench), 3, 6))
        for j in range(6):
            h = 1e-6 * (np.abs(wrench[:, j]) + sigma[j])
            plus, minus = wrench.copy(), wrench.copy()
            plus[:, j] += h
            minus[:, j] -= h
            up = reconstruct_si(q, p0_m, plus[:, :3], plus[:, 3:], rod).point_m
            down = reconstruct_si(q, p0_m, minus[:, :3], minus[:, 3:], rod).point_m
            jacobian[:, :, j] = (up - down) / (2 * h[:, None])
        return np.einsum("nij,jk,nlk->nil", jacobian, cov_w, jacobian)

    start = time.perf_counter()
    cov_fd = central_differences()
    baseline_cov = time.perf_counter() - start + plain_si
    cov_lib = reconstruct_si(q, p0_m, f0_n, m0_nm, rod, cov_w).covariance_m2
    rows.append(("Step 2 baseline: + covariance by central differences (12 more calls)",
                 f"{args.samples / baseline_cov:.3g} samples/s", f"{baseline_cov:.2f} s"))
    rows.append(("Step 2 ratio baseline / library with covariance",
                 f"{baseline_cov / with_cov:.1f}x", ""))
    both = np.isfinite(cov_fd).all(axis=(1, 2)) & np.isfinite(cov_lib).all(axis=(1, 2))
    scale = np.abs(cov_lib[both]).max(axis=(1, 2))
    rows.append(("Step 2 agreement: max |cov central diff. - library| / max |cov|",
                 f"{np.max(np.abs(cov_fd[both] - cov_lib[both]).max(axis=(1, 2)) / scale):.1e}",
                 f"{both.sum()} samples with both (at tip contacts the differences cross "
                 "the rod's end)"))

    print_table(rows)


if __name__ == "__main__":
    main()
