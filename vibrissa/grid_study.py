"""Study grids: cases of a sweep past an object by a rod, or of a whole scene along its robot
path, their equilibria and summaries.

A `GridCase` is one trail (Sec. II-E) past one object by one rod. The object and the trail are given
in metres and scaled by the rod's length L into the paper's units (eq. 1), in which Step 1
(:mod:`vibrissa.sweep`) and Step 2 (:func:`vibrissa.reconstruct.reconstruct`) run; a rod of
L = 1 m keeps every number as written (x / 1.0 is x, to the bit). The cases of one call of
`run_cases` are solved together (`vibrissa.sweep.advance_together`), each with the same bits as
alone, so a grid gives the same numbers however its cases are dealt out. A `SceneCase` is a
scene (objects, whiskers, robot path: :mod:`vibrissa.scene`) with its friction and, if given, its
rods replaced; its Step 1 is `vibrissa.scene.simulate` in the calling process, its Step 2
`vibrissa.scene.reconstruct_along` of the clamp wrenches, its error the distance to the true
contact point, in SI units.

Pure computation: no files; a case's columns are numpy arrays (`case_columns`) and its summary
a dict of numbers and text (`case_summary`), for the table writers above this layer.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vibrissa.frames import Transform
from vibrissa.reconstruct import ReconstructionSI
from vibrissa.rods import RodShape
from vibrissa.scene import SamplePhase, Scene, WhiskerResult, reconstruct_along, scene_digest, simulate
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
        The rod: length L (m) and bending stiffness EI (N m^2, at its base).
    taper_ratio, precurvature_1pm, poisson_ratio : float
        Its shape (`vibrissa.scene.Whisker`'s keys): tip over base diameter, the unloaded
        rod's curvature towards the clamp's +x (1/m), nu; the straight uniform rod by default.
    """

    surface_m: str
    y0_m: float
    mu: float
    step: float
    length_m: float = 1.0
    ei_nm2: float = 1.0
    taper_ratio: float = 1.0
    precurvature_1pm: float = 0.0
    poisson_ratio: float = 0.3

    def __post_init__(self) -> None:
        parse_surface(self.surface_m)  # names the bad key
        RodScale(self.length_m, self.ei_nm2)
        self.shape  # noqa: B018 - checks the rod's shape
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
    def shape(self) -> RodShape:
        """The rod's shape in its own units (`vibrissa.rods`)."""
        return RodShape(self.taper_ratio, self.precurvature_1pm * self.length_m,
                        self.poisson_ratio)

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
                "step": self.step, "length_m": self.length_m, "ei_nm2": self.ei_nm2,
                "taper_ratio": self.taper_ratio, "precurvature_1pm": self.precurvature_1pm,
                "poisson_ratio": self.poisson_ratio}

    def inputs(self) -> dict[str, float | str]:
        """What the case's results depend on: its `parameters`, the shape's only where the rod
        is not the straight uniform one (whose results nu does not change)."""
        inputs = self.parameters()
        if self.shape.uniform:
            for key in ("taper_ratio", "precurvature_1pm", "poisson_ratio"):
                del inputs[key]
        return inputs


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


def run_cases(cases: Sequence[GridCase | SceneCase]) -> list[StudyCase | SceneStudy]:
    """Step 1 and Step 2 of every case; the cases of a list are all trails or all scenes.

    Trails are solved together: one `SweepRun` per case advanced by `advance_together` (the
    same bits as each case alone), then Step 2 on each sweep and its error against the object
    (`vibrissa.study.reconstruct_sweep`). Scenes one after the other (`run_scene`). Plain
    Python, picklable: a function to hand to a process pool or a Dask worker."""
    scenes = [case for case in cases if isinstance(case, SceneCase)]
    if scenes:
        if len(scenes) != len(cases):
            raise ValueError("a list of cases must be all trails or all scenes")
        return [run_scene(case) for case in scenes]
    done: list[StudyCase | SceneStudy] = []
    done.extend(_run_trails([case for case in cases if isinstance(case, GridCase)]))
    return done


def _run_trails(cases: Sequence[GridCase]) -> list[StudyCase]:
    surfaces = [case.surface for case in cases]
    runs = [SweepRun(surface, [case.trail], case.step, shape=case.shape)
            for case, surface in zip(cases, surfaces, strict=True)]
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


@dataclass(frozen=True)
class SceneCase:
    """One case of a grid of whole scenes: ``scene`` (as read: objects, whiskers, robot path)
    with friction ``mu`` and, unless NaN, every whisker's length ``length_m`` (m) and bending
    stiffness ``ei_nm2`` (N m^2) replaced; its mounts stay. ``name`` says which scene it is in
    the tables (the file as the grid names it)."""

    name: str
    scene: Scene
    mu: float
    length_m: float = math.nan
    ei_nm2: float = math.nan

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mu) and self.mu >= 0):
            raise ValueError(f"mu must be finite and >= 0, got {self.mu}")
        if math.isnan(self.length_m) != math.isnan(self.ei_nm2):
            raise ValueError("length_m and ei_nm2 are replaced together (both NaN: the scene's)")
        if not math.isnan(self.length_m):
            RodScale(self.length_m, self.ei_nm2)

    @property
    def run_scene(self) -> Scene:
        """The scene this case simulates: ``mu`` and the rods replaced."""
        whiskers = self.scene.whiskers
        if not math.isnan(self.length_m):
            whiskers = tuple(dataclasses.replace(w, length_m=self.length_m, ei_nm2=self.ei_nm2)
                             for w in whiskers)
        return dataclasses.replace(self.scene, mu=self.mu, whiskers=whiskers)

    def parameters(self) -> dict[str, float | str]:
        """The case's inputs by name, as they appear in its tables' columns."""
        return {"scene": self.name, "mu": self.mu, "length_m": self.length_m,
                "ei_nm2": self.ei_nm2}

    def inputs(self) -> dict[str, float | str]:
        """`parameters` and the SHA-256 of the scene simulated (`vibrissa.scene.scene_digest`):
        what its results depend on, the scene's content rather than its file's name."""
        return {**self.parameters(), "scene_sha256": scene_digest(self.run_scene)}


@dataclass(frozen=True)
class SceneStudy:
    """A scene case's Step 1 (``results``, one per whisker in the scene's order), Step 2 of
    their rows, whisker by whisker (``reconstruction``), and ``error_m``: the distance of each
    reconstructed point to the true contact point, m (NaN where either is missing)."""

    results: list[WhiskerResult]
    reconstruction: ReconstructionSI
    error_m: FloatArray


def run_scene(case: SceneCase) -> SceneStudy:
    """Step 1 of the case's scene in this process (`vibrissa.scene.simulate`), then Step 2 of
    every row from its clamp wrench and the robot pose (`vibrissa.scene.reconstruct_along`)."""
    scene = case.run_scene
    results = simulate(scene, workers=1)
    t = np.concatenate([r.t for r in results])
    names = [r.name for r in results for _ in range(len(r.t))]
    f0, m0, truth = (np.concatenate([getattr(r, name) for r in results])
                     for name in ("f0_n", "m0_nm", "p_W_m"))
    rec = reconstruct_along(scene, t, names, f0, m0)
    return SceneStudy(results, rec, np.linalg.norm(rec.point_m - truth, axis=1))


SCENE_EQUILIBRIUM_COLUMNS = (
    "whisker", "t", "phase", "object", "s1_m",
    "f0x", "f0y", "f0z", "m0x", "m0y", "m0z",
    "px", "py", "pz", "refined",
    "rx", "ry", "rz", "status", "err_m",
)
"""Columns of a scene case's rows after its parameters, one row per whisker and path sample:
`vibrissa simulate`'s CSV columns (the clamp's reaction in the clamp frame, N and N m; the
contact point in W, m; ``object`` by name, empty when free), then Step 2's point in W (m), its
status flags and its distance to the true contact point (m)."""


def scene_columns(case: SceneCase, result: SceneStudy) -> dict[str, NDArray[np.generic]]:
    """One array per `SCENE_EQUILIBRIUM_COLUMNS` name for every row of ``result``."""
    objects = [obj.name for obj in case.scene.objects] + [""]  # index -1: none
    results, rec = result.results, result.reconstruction
    columns: dict[str, NDArray[np.generic]] = {
        "whisker": np.array([r.name for r in results for _ in range(len(r.t))], dtype=object),
        "t": np.concatenate([r.t for r in results]),
        "phase": np.array([SamplePhase(p).label for r in results for p in r.phase.tolist()],
                          dtype=object),
        "object": np.array([objects[k] for r in results for k in r.object.tolist()], dtype=object),
        "s1_m": np.concatenate([r.s1_m for r in results]),
        "refined": np.concatenate([r.refined for r in results]).astype(bool),
        "status": rec.status.astype(np.int64), "err_m": result.error_m,
    }
    vectors = {"f0": np.concatenate([r.f0_n for r in results]),
               "m0": np.concatenate([r.m0_nm for r in results]),
               "p": np.concatenate([r.p_W_m for r in results]), "r": rec.point_m}
    for prefix, array in vectors.items():
        for axis, component in enumerate("xyz"):
            columns[f"{prefix}{component}"] = np.ascontiguousarray(array[:, axis])
    return {name: columns[name] for name in SCENE_EQUILIBRIUM_COLUMNS}


def scene_summary(case: SceneCase, result: SceneStudy) -> dict[str, float | int | str]:
    """How the scene case went: ``n_rows`` (whiskers x samples), ``contact_rows`` (tip or
    tangential), ``unresolved_rows``, ``episodes`` and ``ends`` (``snap-off:2,detachment:1``,
    by the episodes' ends), ``phase_changes``, the peak |f0| (N) and |m0| (N m) of any whisker,
    ``max_reconstruction_error_m`` (NaN without a contact) and ``n_invalid`` (contact rows
    where Step 2 found no point)."""
    results = result.results
    phase = np.concatenate([r.phase for r in results])
    contact = (phase == SamplePhase.TIP) | (phase == SamplePhase.TANGENTIAL)
    f0, m0 = (np.concatenate([getattr(r, name) for r in results]) for name in ("f0_n", "m0_nm"))
    episodes = [e for r in results for e in r.episodes]
    ends: dict[str, int] = {}
    for episode in episodes:
        ends[episode.end] = ends.get(episode.end, 0) + 1
    errors = result.error_m[contact]
    errors = errors[np.isfinite(errors)]
    return {
        "n_rows": int(len(phase)),
        "contact_rows": int(np.count_nonzero(contact)),
        "unresolved_rows": int(np.count_nonzero(phase == SamplePhase.UNRESOLVED)),
        "episodes": len(episodes),
        "ends": ",".join(f"{end}:{n}" for end, n in ends.items()),
        "phase_changes": sum(len(e.phase_changes) for e in episodes),
        "peak_f0_n": float(np.linalg.norm(f0[contact], axis=1).max()) if contact.any() else 0.0,
        "peak_m0_nm": float(np.linalg.norm(m0[contact], axis=1).max()) if contact.any() else 0.0,
        "max_reconstruction_error_m": float(errors.max()) if len(errors) else math.nan,
        "n_invalid": int(np.count_nonzero(contact & ~np.isfinite(result.reconstruction.point_m[:, 0]))),
    }
