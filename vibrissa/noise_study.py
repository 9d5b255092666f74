"""The noise study: how far Step 2's contact points move for a given sensor and a given rod.

A stated rod (default L = 0.05 m, EI = 2e-5 N m^2) sweeps past the paper's object
(:data:`vibrissa.study.PAPER_SURFACE`) on trails y0 = 0, 0.2, 0.4 (units of L) with mu = 0.2,
computed once (Step 1). Every contact sample's SI wrench is then fed to Step 2
(:func:`vibrissa.reconstruct.reconstruct_si`) in two experiments, and the error is the 3D
distance |p_reconstructed - p_true| to Step 1's contact point, in mm, per true contact phase
(tip, tangential: Step 1's phase):

* **Wrench noise.** Gaussian noise, independent per component, with std sigma_f = fraction x
  the peak |f0| and sigma_m = fraction x the peak |m0| over all samples of the study (the
  definition of ``tests/core/test_uncertainty.py``), ``draws`` seeded draws per sample, and
  Step 2 told the noise (``wrench_cov = diag(sigma^2)``: points get their covariance, a tip
  contact found past the tip within 3 std is the tip). The *predicted* error is that of the
  first-order covariance: for every valid point one seeded draw |z|, z ~ N(0, covariance_m2),
  so its median and 95th percentile compare directly with the measured ones.
* **Rod errors.** No noise; Step 2 with a wrong L or a wrong EI (relative error e, one at a
  time). The *predicted* error is first order, from the closed-form Jacobian of Step 2
  (:func:`vibrissa.uncertainty.point_jacobian`) at the true wrench: in paper units the point
  is P1 - P0 = L g(F L^2/EI, M L/EI), so dP/de = L (g + J (2f, m)) for L and -L J (f, m) for
  EI, and the prediction is |e| |dP/de|. For L it vanishes: the elastica from the clamp to the
  contact is set by F, M and EI alone, so a wrong L moves no point; it only moves the tip, and
  contacts past the assumed tip are lost (``points_fraction``).

Statistics are over the valid points of a phase; ``points_fraction`` is valid points over
samples (draws included). Pure computation: no files, no plotting.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vibrissa.reconstruct import ReconstructionSI, reconstruct_si
from vibrissa.status import ContactPhase
from vibrissa.study import PAPER_STEP, PAPER_SURFACE
from vibrissa.surfaces import Surface, parse_surface
from vibrissa.sweep import ProgressCallback, Sweep, Trail, simulate_sweeps
from vibrissa.uncertainty import point_jacobian
from vibrissa.units import RodScale

FloatArray = NDArray[np.float64]

ROD_LENGTH_M = 0.05
ROD_EI_NM2 = 2e-5
NOISE_Y0 = (0.0, 0.2, 0.4)
NOISE_MU = 0.2
NOISE_FRACTIONS = tuple(float(f) for f in np.logspace(-5.0, -1.0, 9))
ROD_RELATIVE_ERRORS = tuple(float(e) for e in np.linspace(-0.05, 0.05, 11))
DRAWS = 4
SEED = 18
PHASES = (ContactPhase.TIP, ContactPhase.TANGENTIAL)


@dataclass(frozen=True)
class ContactSamples:
    """The contact samples of a study's sweeps, in SI, clamp frame C parallel to W.

    Attributes
    ----------
    rod : RodScale
        The rod of the SI conversion.
    p0_m, f0_n, m0_nm, contact_m : ndarray, shape (N, 3)
        Clamp position (W, m), clamp reaction on the rod (C, N and N m about P0) and Step 1's
        contact point (W, m).
    f0, m0 : ndarray, shape (N, 3)
        The same reactions in the paper's units (EI/L^2, EI/L).
    phase : ndarray of int, shape (N,)
        Step 1's :class:`ContactPhase` (TIP or TANGENTIAL).
    """

    rod: RodScale
    p0_m: FloatArray
    f0_n: FloatArray
    m0_nm: FloatArray
    contact_m: FloatArray
    f0: FloatArray
    m0: FloatArray
    phase: NDArray[np.int64]

    @classmethod
    def from_sweeps(cls, sweeps: Sequence[Sweep], rod: RodScale) -> ContactSamples:
        """The samples of ``sweeps`` (paper units, L = 1) with a contact, scaled to ``rod``."""
        def touching(name: str) -> FloatArray:
            return np.concatenate([getattr(s, name)[s.phase > 0] for s in sweeps])

        p0, f0, m0, contact = (touching(name) for name in ("p0", "f0", "m0", "contact"))
        phase = touching("phase").astype(np.int64)
        f0_n, m0_nm = rod.wrench_to_si(f0, m0)
        return cls(rod, p0 * rod.length_m, f0_n, m0_nm, contact * rod.length_m, f0, m0, phase)

    def __len__(self) -> int:
        return len(self.phase)

    @property
    def peak_force_n(self) -> float:
        """Largest |f0|, N: the scale of the force noise."""
        return float(np.linalg.norm(self.f0_n, axis=1).max())

    @property
    def peak_moment_nm(self) -> float:
        """Largest |m0|, N m: the scale of the moment noise."""
        return float(np.linalg.norm(self.m0_nm, axis=1).max())

    def reconstruct(self, f0_n: FloatArray, m0_nm: FloatArray, rod: RodScale,
                    wrench_cov: FloatArray | None = None) -> ReconstructionSI:
        """Step 2 of wrenches (k N, 3) measured at these samples' clamps (repeated k times)."""
        reps = len(f0_n) // len(self)
        q = np.tile([0.0, 0.0, 0.0, 1.0], (len(f0_n), 1))
        return reconstruct_si(q, np.tile(self.p0_m, (reps, 1)), f0_n, m0_nm, rod, wrench_cov)


@dataclass(frozen=True)
class ErrorStats:
    """The error of one phase at one setting: sample counts and percentiles in mm (NaN: none)."""

    phase: str
    samples: int
    points: int
    error_median_mm: float
    error_p95_mm: float
    predicted_median_mm: float
    predicted_p95_mm: float

    @property
    def points_fraction(self) -> float:
        return self.points / self.samples if self.samples else float("nan")


@dataclass(frozen=True)
class NoiseRow:
    """:class:`ErrorStats` at one noise fraction, with the stds it stands for."""

    noise_fraction: float
    sigma_force_n: float
    sigma_moment_nm: float
    stats: ErrorStats


@dataclass(frozen=True)
class RodErrorRow:
    """:class:`ErrorStats` with ``parameter`` ("L" or "EI") off by ``relative_error``."""

    parameter: str
    relative_error: float
    stats: ErrorStats


def _percentiles(values: FloatArray) -> tuple[float, float]:
    if values.size == 0:
        return float("nan"), float("nan")
    median, p95 = np.percentile(values, [50.0, 95.0])
    return float(median), float(p95)


def _stats(phase: ContactPhase, in_phase: NDArray[np.bool_], valid: NDArray[np.bool_],
           error_m: FloatArray, predicted_m: FloatArray) -> ErrorStats:
    kept = in_phase & valid
    measured = _percentiles(error_m[kept] * 1e3)
    predicted_mm = predicted_m[kept] * 1e3
    predicted = _percentiles(predicted_mm[np.isfinite(predicted_mm)])
    return ErrorStats(phase.label, int(in_phase.sum()), int(kept.sum()), *measured, *predicted)


def gaussian_norms(covariance_m2: FloatArray, rng: np.random.Generator) -> FloatArray:
    """One draw |z|, z ~ N(0, C), per covariance C (N, 3, 3), m; NaN where C is not finite."""
    norms = np.full(len(covariance_m2), np.nan)
    finite = np.isfinite(covariance_m2).all(axis=(1, 2))
    z = rng.standard_normal((len(covariance_m2), 3))
    if finite.any():
        values, axes = np.linalg.eigh(covariance_m2[finite])
        scaled = np.sqrt(np.maximum(values, 0.0)) * z[finite]  # along the principal axes
        norms[finite] = np.linalg.norm(np.einsum("nij,nj->ni", axes, scaled), axis=1)
    return norms


def noise_errors(samples: ContactSamples, fractions: Sequence[float] = NOISE_FRACTIONS,
                 draws: int = DRAWS, seed: int = SEED) -> list[NoiseRow]:
    """The error against wrench noise: one row per (fraction, phase); see the module docstring.

    ``fractions`` >= 0 (0: no noise, the exact wrenches once per draw); one seeded generator
    for the whole table, so the result depends only on the arguments.
    """
    if draws < 1:
        raise ValueError(f"draws must be >= 1, got {draws}")
    if any(not f >= 0 for f in fractions):
        raise ValueError(f"fractions must be >= 0, got {list(fractions)}")
    rng = np.random.default_rng(seed)
    wrench = np.tile(np.c_[samples.f0_n, samples.m0_nm], (draws, 1))
    truth = np.tile(samples.contact_m, (draws, 1))
    phase = np.tile(samples.phase, draws)
    rows: list[NoiseRow] = []
    for fraction in fractions:
        sigma = fraction * np.repeat([samples.peak_force_n, samples.peak_moment_nm], 3)
        noisy = wrench + rng.standard_normal(wrench.shape) * sigma
        out = samples.reconstruct(noisy[:, :3], noisy[:, 3:], samples.rod, np.diag(sigma**2))
        assert out.covariance_m2 is not None  # given a wrench covariance
        error = np.linalg.norm(out.point_m - truth, axis=1)
        predicted = gaussian_norms(out.covariance_m2, rng)
        rows.extend(NoiseRow(float(fraction), float(sigma[0]), float(sigma[3]),
                             _stats(p, phase == p, out.valid, error, predicted))
                    for p in PHASES)
    return rows


def rod_error_sensitivity(samples: ContactSamples) -> dict[str, FloatArray]:
    """First-order dP/de (N, 3), m, of the true contact points for L -> L (1 + e) and for
    EI -> EI (1 + e), from the closed-form Jacobian of Step 2 (see the module docstring)."""
    jacobian = np.empty((len(samples), 4, 6))
    for i in range(len(samples)):  # a compiled scalar kernel per sample
        if not point_jacobian(samples.f0[i], samples.m0[i], jacobian[i]):
            jacobian[i] = np.nan
    j_point = jacobian[:, :3]
    length_m = samples.rod.length_m
    g = (samples.contact_m - samples.p0_m) / length_m  # P1 - P0 in C (= W here), units of L
    d_ei = -np.einsum("nij,nj->ni", j_point, np.c_[samples.f0, samples.m0])
    d_l = g + np.einsum("nij,nj->ni", j_point, np.c_[2.0 * samples.f0, samples.m0])
    return {"L": d_l * length_m, "EI": d_ei * length_m}


def rod_errors(samples: ContactSamples,
               relative_errors: Sequence[float] = ROD_RELATIVE_ERRORS) -> list[RodErrorRow]:
    """The error of Step 2 with a wrong L or EI, no noise: one row per (parameter, error,
    phase); see the module docstring. ``relative_errors`` > -1."""
    if any(not e > -1.0 for e in relative_errors):
        raise ValueError(f"relative_errors must be > -1, got {list(relative_errors)}")
    rod = samples.rod
    slope = {name: np.linalg.norm(d, axis=1) for name, d in rod_error_sensitivity(samples).items()}
    rows: list[RodErrorRow] = []
    for name in ("L", "EI"):
        for e in relative_errors:
            wrong = (RodScale(rod.length_m * (1.0 + e), rod.ei_nm2) if name == "L"
                     else RodScale(rod.length_m, rod.ei_nm2 * (1.0 + e)))
            out = samples.reconstruct(samples.f0_n, samples.m0_nm, wrong)
            error = np.linalg.norm(out.point_m - samples.contact_m, axis=1)
            rows.extend(RodErrorRow(name, float(e), _stats(p, samples.phase == p, out.valid,
                                                           error, abs(e) * slope[name]))
                        for p in PHASES)
    return rows


@dataclass(frozen=True)
class NoiseStudyResult:
    """The sweeps, their contact samples and both error tables, and the wall time."""

    surface: Surface
    rod: RodScale
    step: float
    sweeps: list[Sweep]
    samples: ContactSamples
    noise: list[NoiseRow]
    rod_errors: list[RodErrorRow]
    draws: int
    seed: int
    elapsed_s: float


def run_noise_study(
    rod: RodScale | None = None,
    surface: Surface | str = PAPER_SURFACE,
    y0_values: Sequence[float] = NOISE_Y0,
    mu: float = NOISE_MU,
    step: float = PAPER_STEP,
    fractions: Sequence[float] = NOISE_FRACTIONS,
    relative_errors: Sequence[float] = ROD_RELATIVE_ERRORS,
    draws: int = DRAWS,
    seed: int = SEED,
    progress: ProgressCallback | None = None,
) -> NoiseStudyResult:
    """Step 1 once (one batched call over the trails), then :func:`noise_errors` and
    :func:`rod_errors`. ``rod`` defaults to L = 0.05 m, EI = 2e-5 N m^2; ``step`` is the clamp
    step in units of L; ``progress(finished_sweeps, total)`` as in ``simulate_sweeps``."""
    rod = RodScale(ROD_LENGTH_M, ROD_EI_NM2) if rod is None else rod
    if isinstance(surface, str):
        surface = parse_surface(surface)
    if not step > 0:
        raise ValueError(f"step must be > 0, got {step}")
    start = time.perf_counter()
    sweeps = simulate_sweeps(surface, [Trail(float(y0), float(mu)) for y0 in y0_values],
                             step=step, progress=progress)
    samples = ContactSamples.from_sweeps(sweeps, rod)
    if len(samples) == 0:
        raise ValueError(f"no contact on the trails y0={list(y0_values)} past {surface.spec}")
    noise = noise_errors(samples, fractions, draws, seed)
    rods = rod_errors(samples, relative_errors)
    return NoiseStudyResult(surface, rod, float(step), sweeps, samples, noise, rods, draws, seed,
                            time.perf_counter() - start)
