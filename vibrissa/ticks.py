"""Simulated sweeps as the ticks a force/torque sensor graph reads, in SI.

A tick is what the sensors of a whisker array read at one instant: one row per whisker that
reads anything, with its clamp position and the clamp's reactions. Sweeps simulated one after
the other (one whisker) give a tick of one row per equilibrium; the sweeps of one rigid array
(simulated on one grid, ``simulate_sweeps(..., x_grid=)``) give a tick per grid step with a
row per whisker.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vibrissa.status import SweepEnd
from vibrissa.sweep import Sweep
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


def sequential_ticks(sweeps: Sequence[Sweep], rod: RodScale) -> Iterator[Tick]:
    """Every equilibrium of ``sweeps``, in order, as a tick of one row (whisker = sweep index).

    Reads only ``p0``, ``f0``, ``m0`` and ``n_steps`` of each sweep.
    """
    for index, sweep in enumerate(sweeps):
        p0 = sweep.p0 * rod.length_m
        f0, m0 = rod.wrench_to_si(sweep.f0, sweep.m0)
        for i in range(sweep.n_steps):
            yield Tick([index], p0[i:i + 1], f0[i:i + 1], m0[i:i + 1])


def array_ticks(sweeps: Sequence[Sweep], x_grid: float, step: float, rod: RodScale
                ) -> Iterator[Tick]:
    """The sweeps of one rigid array, simulated on the grid x0 = ``x_grid`` - k ``step``, as
    one tick per grid step from k = 0 to the last step of any sweep.

    Row i is the whisker of ``sweeps[i]`` at (x0, y0_i, 0). A whisker that does not touch the
    object (before its first contact, after its detachment, or on a trail that misses the
    object) reads the straight rod's zero wrench, as a real sensor would. Rows the simulation
    has no equilibrium for are left out: positions skipped by a longer step just after the
    touch, and everything after a snap-off (the rod leaves the branch; where it lands is not
    simulated).
    """
    by_step: list[dict[int, int]] = []
    last = -1
    for sweep in sweeps:
        ks = np.rint((x_grid - sweep.x0) / step).astype(int)
        by_step.append({int(k): i for i, k in enumerate(ks)})
        if len(ks):
            last = max(last, int(ks[-1]))
    si = [(sweep.p0 * rod.length_m, *rod.wrench_to_si(sweep.f0, sweep.m0)) for sweep in sweeps]
    zero = np.zeros(3)
    for k in range(last + 1):
        x0 = x_grid - k * step
        whiskers, p0, f0, m0 = [], [], [], []
        for index, (sweep, rows, (p0_m, f0_n, m0_nm)) in enumerate(zip(sweeps, by_step, si,
                                                                         strict=True)):
            i = rows.get(k)
            if i is not None:
                p0.append(p0_m[i])
                f0.append(f0_n[i])
                m0.append(m0_nm[i])
            elif _touch_free(sweep, x0):
                p0.append(np.array([x0, sweep.trail.y0, 0.0]) * rod.length_m)
                f0.append(zero)
                m0.append(zero)
            else:
                continue
            whiskers.append(index)
        n = len(whiskers)
        yield Tick(whiskers, np.reshape(p0, (n, 3)), np.reshape(f0, (n, 3)), np.reshape(m0, (n, 3)))


def _touch_free(sweep: Sweep, x0: float) -> bool:
    """Whether the rod of ``sweep`` is straight and free at clamp position ``x0`` (a grid point
    without a row): before the first contact, after a detachment, or on a trail that misses
    the object. (x0 decreases along a sweep.)"""
    if sweep.end is SweepEnd.NO_CONTACT or x0 >= sweep.x_touch:
        return True
    return sweep.end is SweepEnd.DETACHMENT and sweep.n_steps > 0 and x0 < sweep.x0[-1]
