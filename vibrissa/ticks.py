"""Simulated sweeps as the ticks a force/torque sensor graph reads, in SI, as they are solved.

A tick is what the sensors of a whisker array read at one instant: one row per whisker that
reads anything, with its clamp position and the clamp's reactions. Sweeps simulated one after
the other (one whisker) give a tick of one row per equilibrium; the sweeps of one rigid array
(simulated on one grid, ``SweepRun(..., x_grid=)``) give a tick per grid step with a row per
whisker. Both advance their `SweepRun` only as far as the next tick needs, so a consumer gets
each tick as soon as its equilibria are solved.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vibrissa.status import SweepEnd
from vibrissa.sweep import SweepProgress, SweepRun
from vibrissa.units import RodScale


@dataclass(frozen=True)
class Tick:
    """The rows of one tick, SI; the clamp frame C is parallel to W (the sweep's frame).

    Attributes
    ----------
    whiskers : list of int
        Index of each row's whisker (its sweep).
    p_WC_m : ndarray, shape (n, 3)
        Clamp positions, m.
    f0_C_n, m0_C_nm : ndarray, shape (n, 3)
        Clamp reactions on the rod, N and N m (moment about the clamp point).
    """

    whiskers: list[int]
    p_WC_m: NDArray[np.float64]
    f0_C_n: NDArray[np.float64]
    m0_C_nm: NDArray[np.float64]


def sequential_ticks(run: SweepRun, rod: RodScale) -> Iterator[Tick]:
    """Every equilibrium of ``run``'s sweeps, sweep after sweep, as a tick of one row
    (whisker = sweep index), each as soon as it is solved."""
    for index, trail in enumerate(run.trails):
        sent = 0
        while True:
            x0, f0, m0 = run.reactions(index, sent)
            p0 = trail.clamp_pose(x0)[0]
            p0_m, (f0_n, m0_nm) = p0 * rod.length_m, rod.wrench_to_si(f0, m0)
            for i in range(len(x0)):
                yield Tick([index], p0_m[i:i + 1], f0_n[i:i + 1], m0_nm[i:i + 1])
            sent += len(x0)
            if run.progress(index).end is not None and len(x0) == 0:
                break
            run.advance()


def array_ticks(run: SweepRun, rod: RodScale) -> Iterator[Tick]:
    """The sweeps of one rigid array (``run.x_grid`` set) as one tick per grid step
    x0 = x_grid - k step, k = 0, 1, ... up to the last step of any sweep, each as soon as every
    whisker's reading there is known.

    Row i is the whisker of sweep i at (x0, y0_i, 0). A whisker that does not touch the
    object (before its first contact, after its detachment, or on a trail that misses the
    object) reads the straight rod's zero wrench, as a real sensor would. Rows the simulation
    has no equilibrium for are left out: positions skipped by a longer step just after the
    touch, and everything after a snap-off (the rod leaves the branch; where it lands is not
    simulated).
    """
    if run.x_grid is None:
        raise ValueError("array_ticks needs a SweepRun on one grid (x_grid)")
    x_grid, step = run.x_grid, run.step
    n = len(run.trails)
    rows: list[dict[int, tuple[float, NDArray[np.float64], NDArray[np.float64]]]] = [
        {} for _ in range(n)]
    taken = [0] * n
    last = -1  # the highest grid index of any equilibrium so far
    zero = np.zeros(3)
    k = 0
    while True:
        x0 = x_grid - k * step
        while not run.done and not all(_decided(run.progress(i), x0, step) for i in range(n)):
            run.advance()
        for i in range(n):  # collect what was solved since the last look
            xs, f0, m0 = run.reactions(i, taken[i])
            taken[i] += len(xs)
            for x, f, m in zip(xs, f0, m0, strict=True):
                index = int(np.rint((x_grid - x) / step))
                rows[i][index] = (float(x), f, m)
                last = max(last, index)
        if k > last and run.done:
            return
        whiskers, p0, f0_rows, m0_rows = [], [], [], []
        for i, trail in enumerate(run.trails):
            row = rows[i].pop(k, None)
            if row is None and not _touch_free(run.progress(i), x0):
                continue
            x, f, m = row if row is not None else (x0, zero, zero)
            whiskers.append(i)
            p0.append(trail.clamp_pose(np.array([x]))[0][0])
            f0_rows.append(f)
            m0_rows.append(m)
        count = len(whiskers)
        f0_n, m0_nm = rod.wrench_to_si(np.reshape(f0_rows, (count, 3)), np.reshape(m0_rows, (count, 3)))
        yield Tick(whiskers, np.reshape(p0, (count, 3)) * rod.length_m, f0_n, m0_nm)
        k += 1


def _decided(progress: SweepProgress, x0: float, step: float) -> bool:
    """Whether a sweep's reading at clamp position ``x0`` is known: it ended, or it has
    stepped to ``x0`` or beyond (x0 decreases along a sweep)."""
    return progress.end is not None or progress.x0 <= x0 + 1e-9 * step


def _touch_free(progress: SweepProgress, x0: float) -> bool:
    """Whether the rod is straight and free at clamp position ``x0`` (a grid point without a
    row): before the first contact, after a detachment, or on a trail that misses the
    object."""
    if progress.end is SweepEnd.NO_CONTACT or x0 >= progress.x_touch:
        return True
    return progress.end is SweepEnd.DETACHMENT and progress.n_steps > 0 and x0 < progress.x0
