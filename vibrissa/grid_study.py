"""Study grids: cases of a sweep past an object by a rod, their equilibria and summaries.

A case is one trail (Sec. II-E) past one object by one rod. The object and the trail are given
in metres and scaled by the rod's length L into the paper's units (eq. 1), in which Step 1
(:mod:`vibrissa.sweep`) and Step 2 (:func:`vibrissa.reconstruct.reconstruct`) run; a rod of
L = 1 m keeps every number as written (x / 1.0 is x, to the bit). The cases of one call of
`run_cases` are solved together (`vibrissa.sweep.advance_together`), each with the same bits as
alone, so a grid gives the same numbers however its cases are dealt out.

Pure computation: no files; a case's columns are numpy arrays (`case_columns`) and its summary
a dict of numbers and text (`case_summary`), for the table writers above this layer.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vibrissa.frames import Transform
from vibrissa.status import ContactPhase
from vibrissa.study import StudyCase, reconstruct_sweep
from vibrissa.surfaces import Ellipsoid, Paraboloid, Sphere, Surface, parse_surface
from vibrissa.sweep import STATE_NAMES, STICK, SweepRun, Trail, advance_together
from vibrissa.units import RodScale

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class GridCase:
    """One case of a grid: a trail at ``y0_m`` with friction ``mu`` past ``surface_m`` by a rod.

    Attributes
    ----------
    surface_m : str
        The object as a :func:`vibrissa.surfaces.parse_surface` spec with lengths in m
        (a paraboloid's curvatures a, b in 1/m).
    y0_m : float
        Lateral offset of the trail, m.
    mu : float
        Friction coefficient, >= 0.
    step : float
        Clamp displacement per step along -x, units of L (> 0).
    length_m, ei_nm2 : float
        The rod: length L (m) and bending stiffness EI (N m^2).
    """

    surface_m: str
    y0_m: float
    mu: float
    step: float
    length_m: float = 1.0
    ei_nm2: float = 1.0

    def __post_init__(self) -> None:
        parse_surface(self.surface_m)  # names the bad key
        RodScale(self.length_m, self.ei_nm2)
        for name in ("y0_m", "mu", "step"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)}")
        if not self.mu >= 0:
            raise ValueError(f"mu must be >= 0, got {self.mu}")
        if not self.step > 0:
            raise ValueError(f"step must be > 0, got {self.step}")

    @property
    def rod(self) -> RodScale:
        return RodScale(self.length_m, self.ei_nm2)

    @property
    def surface(self) -> Surface:
        """The object in units of L."""
        return scaled_surface(parse_surface(self.surface_m), self.length_m)

    @property
    def trail(self) -> Trail:
        """The trail in units of L."""
        return Trail(self.y0_m / self.length_m, self.mu)

    def parameters(self) -> dict[str, float | str]:
        """The case's inputs by name, as they appear in its tables' columns."""
        return {"surface_m": parse_surface(self.surface_m).spec, "y0_m": self.y0_m, "mu": self.mu,
                "step": self.step, "length_m": self.length_m, "ei_nm2": self.ei_nm2}


def scaled_surface(surface: Surface, length_m: float) -> Surface:
    """``surface`` (lengths in m) in units of a rod of length ``length_m``: sizes and the
    position of its body frame divided by L, a paraboloid's curvatures multiplied by it."""
    pose = Transform(surface.pose.rotation, np.asarray(surface.pose.translation) / length_m)
    if isinstance(surface, Sphere):
        return Sphere(float(surface.radii[0]) / length_m, pose)
    if isinstance(surface, Ellipsoid):
        rx, ry, rz = (float(r) / length_m for r in surface.radii)
        return Ellipsoid(rx, ry, rz, pose)
    if isinstance(surface, Paraboloid):
        return Paraboloid(surface.a * length_m, surface.b * length_m, surface.h / length_m, pose)
    raise ValueError(f"no scaling for {type(surface).__name__}")


def run_cases(cases: Sequence[GridCase]) -> list[StudyCase]:
    """Step 1 and Step 2 of every case, solved together: one `SweepRun` per case advanced by
    `advance_together` (the same bits as each case alone), then Step 2 on each sweep and its
    error against the object (`vibrissa.study.reconstruct_sweep`). Plain Python, picklable:
    a function to hand to a process pool or a Dask worker."""
    surfaces = [case.surface for case in cases]
    runs = [SweepRun(surface, [case.trail], case.step) for case, surface in zip(cases, surfaces, strict=True)]
    while not all(run.done for run in runs):
        advance_together(runs)
    return [reconstruct_sweep(surface, run.sweeps()[0]) for surface, run in zip(surfaces, runs, strict=True)]


EQUILIBRIUM_COLUMNS = (
    "x0", "y0", "phase", "s1", "psi",
    "f0x", "f0y", "f0z", "m0x", "m0y", "m0z",
    "px", "py", "pz", "fn", "ft",
    "state", "nx", "ny", "nz", "refined",
    "rx", "ry", "rz", "status", "err",
)
"""Columns of a case's equilibria after its parameters: the sweep CSV's (``vibrissa sweep``),
then Step 2's reconstructed point and status (``vibrissa reconstruct``) and its error against
the object, in units of L, EI/L^2, EI/L."""


def case_columns(result: StudyCase) -> dict[str, NDArray[np.generic]]:
    """One array (N,) per `EQUILIBRIUM_COLUMNS` name for the N equilibria of ``result``:
    ``phase`` and ``state`` as text (``tip``, ``slide``), ``refined`` bool, ``status`` the
    :class:`vibrissa.status.ContactStatus` flags (0: a contact)."""
    sweep, rec = result.sweep, result.reconstruction
    n = sweep.n_steps
    vectors = {"f0": sweep.f0, "m0": sweep.m0, "p": sweep.contact, "n": sweep.normal, "r": rec.point}
    columns: dict[str, NDArray[np.generic]] = {
        "x0": sweep.x0[:n], "y0": np.full(n, sweep.y0),
        "phase": np.array([ContactPhase(p).label for p in sweep.phase[:n].tolist()], dtype=object),
        "s1": sweep.s1[:n], "psi": sweep.psi[:n], "fn": sweep.fn[:n], "ft": sweep.ft[:n],
        "state": np.array([STATE_NAMES[s] for s in sweep.state[:n].tolist()], dtype=object),
        "refined": sweep.refined[:n].astype(bool), "status": rec.status.astype(np.int64),
        "err": result.error,
    }
    for prefix, array in vectors.items():
        for axis, component in enumerate("xyz"):
            columns[f"{prefix}{component}"] = np.ascontiguousarray(array[:n, axis])
    return {name: columns[name] for name in EQUILIBRIUM_COLUMNS}


def case_summary(case: GridCase, result: StudyCase) -> dict[str, float | int | str]:
    """How the case went: ``end`` (a :class:`vibrissa.status.SweepEnd`), ``x0_start`` and
    ``x0_end`` (L; NaN without a step), ``n_steps``, ``phase_changes`` (their number) and
    ``phase_path`` (``tip>tangential>...``), ``stick_steps``, the peak |f0| and |m0| (EI/L^2,
    EI/L and in N, N m for the rod), ``max_reconstruction_error`` (L; NaN without a contact)
    and ``n_invalid`` (equilibria where Step 2 found none)."""
    sweep = result.sweep
    n = sweep.n_steps
    peak_f0 = float(np.linalg.norm(sweep.f0[:n], axis=1).max()) if n else 0.0
    peak_m0 = float(np.linalg.norm(sweep.m0[:n], axis=1).max()) if n else 0.0
    first = [ContactPhase(sweep.phase[0]).label] if n else []
    max_error = result.max_error
    return {
        "end": str(sweep.end),
        "x0_start": float(sweep.x0[0]) if n else math.nan,
        "x0_end": float(sweep.x0_end),
        "n_steps": n,
        "phase_changes": len(sweep.phase_changes),
        "phase_path": ">".join(first + [new for _x0, _old, new in sweep.phase_changes]),
        "stick_steps": int(np.sum(sweep.state[:n] == STICK)) if n else 0,
        "peak_f0": peak_f0,
        "peak_m0": peak_m0,
        "peak_f0_n": peak_f0 * case.rod.force_n,
        "peak_m0_nm": peak_m0 * case.rod.moment_nm,
        "max_reconstruction_error": math.nan if max_error is None else max_error,
        "n_invalid": int(np.count_nonzero(~result.reconstruction.valid)),
    }
