"""The paper's study (Sec. III): 25 frictional sweeps past the paraboloid, Step 2 and its error.

Object: eq. 2 with a = 0.5, b = 1, h = 0.4; trails y0 = -0.4 : 0.2 : 0.4 along -x; friction
mu = 0 : 0.1 : 0.4; clamp step 0.001 (units of L, eq. 1). All sweeps run in one batched
:func:`vibrissa.sweep.simulate_sweeps` call. Every equilibrium's support reactions are then fed
to Step 2 (:func:`vibrissa.reconstruct.reconstruct`, eqs. 20-23) and the reconstructed contact
point is compared with the object: the error is the distance to the surface (Fig. 10).

Pure computation: no files, no plotting.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vibrissa.reconstruct import Reconstruction, reconstruct
from vibrissa.reconstruct_rods import reconstruct_rod
from vibrissa.surfaces import Surface, parse_surface
from vibrissa.sweep import ProgressCallback, Sweep, Trail, simulate_sweeps

FloatArray = NDArray[np.float64]

PAPER_SURFACE = "paraboloid:a=0.5,b=1,h=0.4"
PAPER_Y0 = (-0.4, -0.2, 0.0, 0.2, 0.4)
PAPER_MU = (0.0, 0.1, 0.2, 0.3, 0.4)
PAPER_STEP = 0.001


@dataclass(frozen=True)
class StudyCase:
    """One sweep of the study with its Step 2 reconstruction.

    Attributes
    ----------
    sweep : Sweep
        Step 1 equilibria, N steps.
    reconstruction : Reconstruction
        Step 2 from the sweep's (p0, f0, m0), N samples.
    error : ndarray, shape (N,)
        |signed distance| of each reconstructed point to the surface, units of L; NaN where
        Step 2 found no consistent contact.
    """

    sweep: Sweep
    reconstruction: Reconstruction
    error: FloatArray

    @property
    def y0(self) -> float:
        return self.sweep.y0

    @property
    def mu(self) -> float:
        return float(self.sweep.trail.mu)

    @property
    def max_error(self) -> float | None:
        """Largest reconstruction error (units of L); None if no sample had a contact."""
        finite = self.error[np.isfinite(self.error)]
        return float(finite.max()) if finite.size else None

    def summary(self) -> dict[str, object]:
        """The sweep's summary plus ``max_reconstruction_error`` and ``n_invalid``, JSON-ready."""
        summary = self.sweep.summary()
        summary["y0"], summary["mu"] = self.y0, self.mu
        summary["max_reconstruction_error"] = self.max_error
        summary["n_invalid"] = int(np.count_nonzero(~self.reconstruction.valid))
        return summary


@dataclass(frozen=True)
class StudyResult:
    """All sweeps of a study, ordered by y0 then mu, and the wall time of the computation."""

    surface: Surface
    step: float
    cases: list[StudyCase]
    elapsed_s: float

    def case(self, y0: float, mu: float) -> StudyCase:
        """The case with trail offset ``y0`` and friction ``mu`` (matched to 1e-9)."""
        for case in self.cases:
            if abs(case.y0 - y0) < 1e-9 and abs(case.mu - mu) < 1e-9:
                return case
        raise KeyError(f"no sweep with y0={y0}, mu={mu} in the study")

    @property
    def y0_values(self) -> list[float]:
        return sorted({case.y0 for case in self.cases})

    @property
    def mu_values(self) -> list[float]:
        return sorted({case.mu for case in self.cases})

    @property
    def max_error(self) -> float | None:
        """Largest reconstruction error over all sweeps, units of L."""
        errors = [case.max_error for case in self.cases if case.max_error is not None]
        return max(errors) if errors else None


def reconstruction_error(surface: Surface, points: FloatArray) -> FloatArray:
    """Distance (N,) of points (N, 3) to the surface, units of L; NaN rows stay NaN."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    error = np.full(len(points), np.nan)
    finite = np.all(np.isfinite(points), axis=1)
    if finite.any():
        error[finite] = np.abs(surface.signed_distance(points[finite]))
    return error


def reconstruct_sweep(surface: Surface, sweep: Sweep) -> StudyCase:
    """Step 2 on every equilibrium of ``sweep`` and the error against ``surface`` (a tapered or
    pre-curved rod's: its samples as one stream, each point by continuity with the one
    before, `vibrissa.reconstruct_rods`)."""
    if sweep.shape.uniform:
        rec = reconstruct(sweep.p0, sweep.f0, sweep.m0)
    else:
        rec = reconstruct_rod(sweep.p0, sweep.f0, sweep.m0, sweep.shape, stream=True)[0]
    return StudyCase(sweep, rec, reconstruction_error(surface, rec.point))


def run_study(
    surface: Surface | str = PAPER_SURFACE,
    y0_values: Sequence[float] = PAPER_Y0,
    mu_values: Sequence[float] = PAPER_MU,
    step: float = PAPER_STEP,
    progress: ProgressCallback | None = None,
) -> StudyResult:
    """Run Step 1 for every (y0, mu) in one batched call, then Step 2 and its error.

    Parameters
    ----------
    surface : Surface or str
        The object, or its spec for :func:`vibrissa.surfaces.parse_surface`.
    y0_values, mu_values : sequence of float
        Trail offsets (units of L) and friction coefficients; all combinations are swept.
    step : float
        Clamp displacement per step along -x, units of L (> 0).
    progress : callable, optional
        ``progress(finished_sweeps, total_sweeps)``, passed to ``simulate_sweeps``.
    """
    if isinstance(surface, str):
        surface = parse_surface(surface)
    if not step > 0:
        raise ValueError(f"step must be > 0, got {step}")
    trails = [Trail(float(y0), float(mu)) for y0 in y0_values for mu in mu_values]
    start = time.perf_counter()
    sweeps = simulate_sweeps(surface, trails, step=step, progress=progress)
    cases = [reconstruct_sweep(surface, sweep) for sweep in sweeps]
    return StudyResult(surface, float(step), cases, time.perf_counter() - start)
