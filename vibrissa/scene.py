"""Scenes: objects placed in the world, whiskers on a robot, the robot's path; Step 1 for every
whisker along the path (``vibrissa.simulate``, ``vibrissa simulate SCENE.yaml``).

SI at this boundary (m, N, N m, s); inside, each whisker is dimensionless in its own L and EI
(``RodScale``): the objects and the path are scaled by 1/L for it.

Along the path a whisker has contact episodes. Each starts where its unloaded rod first
touches an object between two samples (at its tip, or a side graze of the shaft) and is one
sweep of Step 1 (``vibrissa.sweep``) on that object, one equilibrium per path sample, until it
ends: ``detachment`` (the rod came free smoothly), ``snap-off`` (no equilibrium near the last
one) or ``path-end``. After a snap-off the unloaded rod may still be inside an object (the same
or another): the rod lands on it at the next sample, in the state a frictionless approach from
the side it was pushed to reaches (`_WhiskerSteps._landing`), and a ``landing`` episode goes on
from there (inside several objects: on the deepest where the landed rod enters no other).
Where no landing is found, those samples are ``unresolved`` (no wrench, no point) until it is
free again; then the next touch is searched for. Samples that Step 1 stepped over (the first
steps after a touch may be taken as 2-32 samples at once, see ``vibrissa.sweep``) are
``unresolved`` as well.

Several objects: a whisker touches one at a time. An episode follows the object touched
first; where its bent rod would enter another object, the episode ends (``another-object``:
contact with two objects at once is not modelled) and the samples from there on are
``unresolved`` until the unloaded rod is outside every object; then the next touch is searched
for.

Whiskers are solved together: a group of them advances step by step, the equilibria of all
those in an episode found by one batched attempt each step (each row its own object, scaled to
its whisker's L, and its own step), with the same bits as each whisker alone
(`simulate_group`); `simulate` spreads the whiskers over processes in such groups.
"""

from __future__ import annotations

import enum
import functools
import hashlib
import math
import multiprocessing
import multiprocessing.pool
import os
import signal
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa import two_contacts as two
from vibrissa.frames import PoseSamples, Transform, non_unit_quaternion
from vibrissa.paths import SUBSAMPLE_L, SampledPath, rod_motion
from vibrissa.reconstruct import ReconstructionSI, reconstruct_si
from vibrissa.rods import MAX_PRECURVATURE, RodShape, unloaded_points, unloaded_segments
from vibrissa.status import SNAP_KINDS, ContactPhase, SweepEnd
from vibrissa.surfaces import Ellipsoid, Paraboloid, Sphere, Surface, segments_meet
from vibrissa.sweep import (
    EARLY_MULTIPLES,
    Landing,
    Sweep,
    SweepRun,
    advance_together,
    carried_on,
    next_grid_point,
)
from vibrissa.units import RodScale, finite_number, rod_units

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]

SHAPES = ("sphere", "ellipsoid", "paraboloid")


class SamplePhase(enum.IntEnum):
    """A whisker at one path sample: free, in tip or tangential contact, or unresolved."""

    NONE = ContactPhase.NONE.value
    TIP = ContactPhase.TIP.value
    TANGENTIAL = ContactPhase.TANGENTIAL.value
    UNRESOLVED = 3

    @property
    def label(self) -> str:
        """``none``, ``tip``, ``tangential`` or ``unresolved``."""
        return self.name.lower()


@dataclass(frozen=True)
class SceneObject:
    """A convex solid placed in W: ``shape`` with its sizes in m, and its pose X_WO (m).

    ``sizes``: sphere ``radius_m``; ellipsoid ``semi_axes_m`` (a, b, c along O's x, y, z);
    paraboloid ``a_per_m``, ``b_per_m``, ``h_m`` (the solid z >= a x^2 + b y^2 + h in O).
    """

    name: str
    shape: str
    sizes: Mapping[str, Any]
    X_WO: Transform = field(default_factory=Transform)

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"object {self.name!r}: shape must be one of {', '.join(SHAPES)}, "
                             f"got {self.shape!r}")
        self.surface(1.0)  # checks the sizes

    def surface(self, length_m: float, origin_m: ArrayLike = (0.0, 0.0, 0.0)) -> Surface:
        """The object in units of a rod of length ``length_m``, in W moved to ``origin_m`` (m)."""
        pose = Transform(self.X_WO.rotation,
                         (np.asarray(self.X_WO.translation) - np.asarray(origin_m)) / length_m)
        try:
            if self.shape == "sphere":
                return Sphere(self._size("radius_m") / length_m, pose)
            if self.shape == "ellipsoid":
                a, b, c = (self._size("semi_axes_m", i) / length_m for i in range(3))
                return Ellipsoid(a, b, c, pose)
            return Paraboloid(self._size("a_per_m") * length_m, self._size("b_per_m") * length_m,
                              self._size("h_m") / length_m, pose)
        except ValueError as exc:
            raise ValueError(f"object {self.name!r}: {exc}") from None

    def _size(self, key: str, index: int | None = None) -> float:
        if key not in self.sizes:
            raise ValueError(f"a {self.shape} needs {key}")
        value = self.sizes[key]
        if index is not None:
            if not isinstance(value, (list, tuple)) or len(value) != 3:
                raise ValueError(f"{key} must be 3 numbers, got {value!r}")
            value = value[index]
        if not finite_number(value):
            raise ValueError(f"{key} must be a finite number, got {value!r}")
        return float(value)


@dataclass(frozen=True)
class Whisker:
    """A rod of length ``length_m`` and bending stiffness ``ei_nm2`` (at its base), clamped at
    X_RC on the robot; it leaves the clamp along C's +z. Its force/torque sensor measures in
    the frame S at X_CS in the clamp frame (``vibrissa.calibration``; identity: S = C).

    A built whisker may taper (``taper_ratio``: tip over base diameter) and be pre-curved
    (``precurvature_1pm``: the unloaded rod's curvature towards C's +x, 1/m), with torsion from
    ``poisson_ratio`` (`vibrissa.rods.RodShape`); by default the straight uniform cylinder."""

    name: str
    length_m: float
    ei_nm2: float
    X_RC: Transform = field(default_factory=Transform)
    X_CS: Transform = field(default_factory=Transform)
    taper_ratio: float = 1.0
    precurvature_1pm: float = 0.0
    poisson_ratio: float = 0.3

    def __post_init__(self) -> None:
        bound = MAX_PRECURVATURE / self.length_m
        if not abs(self.precurvature_1pm) <= bound:  # in the unit it is given in
            raise ValueError(f"whisker {self.name!r}: precurvature_1pm must be within +-2 pi / "
                             f"length_m = +-{bound:.6g} /m, got {self.precurvature_1pm!r}")
        try:
            self.shape  # noqa: B018 - checks the rod
        except ValueError as exc:
            raise ValueError(f"whisker {self.name!r}: {exc}") from None

    @property
    def scale(self) -> RodScale:
        return RodScale(self.length_m, self.ei_nm2)

    @property
    def shape(self) -> RodShape:
        """The rod's shape in its own units (pre-curvature in 1/L)."""
        return RodShape(self.taper_ratio, self.precurvature_1pm * self.length_m,
                        self.poisson_ratio)


@dataclass(frozen=True)
class RobotPath:
    """Stamped robot poses X_WR: times ``t`` (N >= 1,) s, strictly increasing; positions
    ``p_WR`` (N, 3) m; orientations ``R_WR`` (N rotations)."""

    t: FloatArray
    p_WR: FloatArray
    R_WR: Rotation

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1:
            raise ValueError(f"path times must be one column, got shape {t.shape}")
        if len(t) < 1:  # one sample: a robot standing still
            raise ValueError(f"a path needs at least 1 sample, got {len(t)}")
        with np.errstate(over="ignore"):
            steps = np.diff(t)
            span = float(t[-1]) - float(t[0])
        if not np.all(steps > 0):
            first = int(np.flatnonzero(~(steps > 0))[0]) + 2  # 1-based row of the later sample
            raise ValueError(f"path times must increase strictly (row {first})")
        if not (np.isfinite(t).all() and math.isfinite(span)):
            raise ValueError(f"path times must be finite and span a finite time, got "
                             f"{float(t[0])!r} .. {float(t[-1])!r} s")
        p = np.asarray(self.p_WR, dtype=float)
        if p.shape != (len(t), 3) or len(self.R_WR) != len(t):
            raise ValueError(f"path: {len(t)} times, positions {p.shape}, {len(self.R_WR)} rotations")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "p_WR", p)

    def at(self, t: ArrayLike) -> tuple[NDArray[np.bool_], FloatArray, Rotation]:
        """Robot poses at stamps ``t`` (n,): whether the path covers each stamp, and there the
        position (n, 3) and R_WR, interpolated between the samples around it (position linear,
        orientation slerp; `vibrissa.frames.PoseSamples`). A stamp outside [t_0, t_N-1] is not
        covered (never extrapolated): NaN position and identity rotation."""
        from scipy.spatial.transform import Rotation  # on first use (vibrissa.frames)

        t = np.asarray(t, dtype=float).reshape(-1)
        covered = (t >= self.t[0]) & (t <= self.t[-1])
        p = np.full((len(t), 3), np.nan)
        q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
        if covered.any() and len(self.t) == 1:  # standing still: the one pose
            p[covered], q[covered] = self.p_WR[0], self.R_WR[0].as_quat()
        elif covered.any():
            p[covered], rotations = PoseSamples(self.t, self.p_WR, self.R_WR).poses_at(t[covered])
            q[covered] = rotations.as_quat()
        return covered, p, Rotation.from_quat(q)


def back_and_forth(path: RobotPath, legs: int) -> RobotPath:
    """``path`` driven ``legs`` times, forth and back: leg 0 is ``path``, leg 1 the same poses
    in reverse order, leg 2 forward again, and so on; time runs on.

    The robot turns at an end without stopping: a leg starts at the second sample of its own
    order (its first is the previous leg's last, the same pose), and the sample intervals of a
    reversed leg are the forward leg's in reverse, so that a reversed leg takes as long as the
    forward one and every pose is at the same time from the turn on either side. One path of
    all legs is simulated at once (`simulate`): each whisker's state (its contact, stick or
    slip) carries over a turn. ``legs`` 1 gives ``path`` itself; ValueError below 1.
    """
    if legs < 1:
        raise ValueError(f"legs must be >= 1, got {legs}")
    n = len(path.t)
    forth, back = np.arange(n), np.arange(n - 1, -1, -1)
    duration = float(path.t[-1] - path.t[0])
    rows = [forth] + [(back if leg % 2 else forth)[1:] for leg in range(1, legs)]
    t = [path.t] + [path.t[0] + leg * duration
                    + ((path.t[-1] - path.t[::-1]) if leg % 2 else (path.t - path.t[0]))[1:]
                    for leg in range(1, legs)]
    index = np.concatenate(rows)
    return RobotPath(np.concatenate(t), path.p_WR[index], path.R_WR[index])


@dataclass(frozen=True)
class Scene:
    """Objects in W, whiskers on the robot, the robot's path, one friction ``mu``."""

    mu: float
    objects: tuple[SceneObject, ...]
    whiskers: tuple[Whisker, ...]
    path: RobotPath

    def __post_init__(self) -> None:
        if not self.mu >= 0:
            raise ValueError(f"mu must be >= 0, got {self.mu}")
        for kind, items in (("object", self.objects), ("whisker", self.whiskers)):
            names = [item.name for item in items]
            if len(set(names)) != len(names):
                raise ValueError(f"{kind} names must be unique, got {names}")
        if not self.whiskers:
            raise ValueError("a scene needs at least one whisker")


EPISODE_STARTS = ("touch", "landing", "second-contact")
"""How an episode begins: the unloaded rod touches an object, the rod lands on one after a
snap-off, or the rod in contact with one meets a second (`Episode.second_object`) and goes on
with both (its samples: the first object's contact in the usual columns, the second's in
``second_*``)."""


@dataclass(frozen=True)
class Episode:
    """One contact of a whisker: the object, when it began (``start``: the unloaded rod's touch,
    or a landing after a snap-off) and how it ended, the time of every phase change (t, from,
    to) and of every snap-through inside it (the contact jumped to another branch:
    `vibrissa.sweep.Sweep.jumped`)."""

    object: str
    t_first_contact: float
    end: str
    phase_changes: list[tuple[float, str, str]]
    start: str = "touch"  # one of EPISODE_STARTS
    snap_throughs: tuple[float, ...] = ()
    second_object: str = ""  # (start "second-contact") the second object the rod leans on


@dataclass
class WhiskerResult:
    """Step 1 of one whisker along the path, one row per path sample.

    ``phase`` (N,) `SamplePhase`; ``s1_m`` (N,) the contact's arc length, m; ``f0_n``,
    ``m0_nm`` (N, 3) the clamp's reaction on the rod about the clamp point in the clamp frame
    C, N and N m (zero when free, NaN when unresolved); ``p_W_m`` (N, 3) the contact point in
    W, m (NaN without one); ``object`` (N,) index into the scene's objects (-1: none);
    ``refined`` (N,) whether Step 1 reached the sample through sub-steps, or by a longer step
    after the touch (`vibrissa.sweep.Sweep`): eq. 7's chord is then a sub-step's, not the one
    from the sample before. Where the rod leans on a second object too (an episode that
    starts ``second-contact``), ``second_s_m`` (N,), ``second_W_m`` (N, 3) and
    ``second_object`` (N,) are that contact's (NaN and -1 elsewhere); the wrench is both
    contacts'.
    """

    name: str
    t: FloatArray
    phase: NDArray[np.int64]
    s1_m: FloatArray
    f0_n: FloatArray
    m0_nm: FloatArray
    p_W_m: FloatArray
    object: NDArray[np.int64]
    refined: NDArray[np.bool_]
    episodes: list[Episode]
    second_s_m: FloatArray = field(default_factory=lambda: np.empty(0))
    second_W_m: FloatArray = field(default_factory=lambda: np.empty((0, 3)))
    second_object: NDArray[np.int64] = field(default_factory=lambda: np.empty(0, np.int64))

    def __post_init__(self) -> None:
        n = len(self.t)  # not given: no second contact anywhere
        if len(self.second_s_m) != n:
            self.second_s_m = np.full(n, np.nan)
        if len(self.second_W_m) != n:
            self.second_W_m = np.full((n, 3), np.nan)
        if len(self.second_object) != n:
            self.second_object = np.full(n, -1, dtype=np.int64)

    def counts(self) -> dict[str, int]:
        """Samples per phase."""
        return {phase.label: int(np.sum(self.phase == phase)) for phase in SamplePhase}


@dataclass(frozen=True)
class Snap:
    """A jump between samples ``before`` and ``after`` (indices into the result's rows) of a
    contact with ``object``: ``kind`` one of `SNAP_KINDS`, told at ``t``, the time of
    ``after``."""

    t: float
    kind: str
    object: str
    before: int
    after: int


def snaps(result: WhiskerResult, object_names: Sequence[str]) -> list[Snap]:
    """Every jump of ``result``'s path, in time order: each episode's snap-throughs, its
    landing (its first sample, the one after the snap-off it follows) and its snap-off (from
    its last sample in contact to the next). ``object_names``: the scene's objects, in order
    (``result.object`` indexes them)."""
    t = result.t
    contact = (result.phase == SamplePhase.TIP) | (result.phase == SamplePhase.TANGENTIAL)

    def sample(at: float) -> int:  # a landing's and a snap-through's time is a sample's
        return int(np.argmin(np.abs(t - at)))

    # an episode's first sample: its landing's, or the first past its touch
    firsts = [sample(e.t_first_contact) if e.start == "landing"
              else int(np.searchsorted(t, e.t_first_contact, side="right"))
              for e in result.episodes]
    found: list[Snap] = []
    for i, episode in enumerate(result.episodes):
        first, bound = firsts[i], firsts[i + 1] if i + 1 < len(firsts) else len(t)
        if episode.start == "landing" and first > 0:
            found.append(Snap(float(t[first]), "landing", episode.object, first - 1, first))
        for at in episode.snap_throughs:
            k = sample(at)
            found.append(Snap(at, "snap-through", episode.object, k - 1, k))
        if episode.end == str(SweepEnd.SNAP_OFF):
            index = object_names.index(episode.object)
            held = np.flatnonzero(contact[first:bound] & (result.object[first:bound] == index))
            last = first + int(held[-1]) if len(held) else -1
            if 0 <= last < len(t) - 1:
                found.append(Snap(float(t[last + 1]), "snap-off", episode.object, last,
                                  last + 1))
    return sorted(found, key=lambda snap: (snap.after, SNAP_KINDS.index(snap.kind)))


def free_at_both_ends(results: Sequence[WhiskerResult]) -> list[str]:
    """The whiskers of ``results`` that are not free (`SamplePhase.NONE`: no contact, the
    unloaded rod outside every object) at both the first and the last sample of their path,
    by name. On a path that ends where it starts (`back_and_forth` with an even number of
    legs) a whisker free at both ends is in the same state at the end as at the start: Step 1
    keeps no state between contact episodes and does not depend on time, so driving the path
    again gives the same results, sample for sample."""
    return [r.name for r in results
            if not (r.phase[0] == SamplePhase.NONE and r.phase[-1] == SamplePhase.NONE)]


def scene_digest(scene: Scene) -> str:
    """SHA-256 of what a scene's results depend on: mu, the objects, the whiskers (rods,
    mounts, sensor frames) and the path, bit for bit."""
    digest = hashlib.sha256(repr(scene.mu).encode())
    for obj in scene.objects:
        digest.update(repr((obj.name, obj.shape, sorted(obj.sizes.items()))).encode())
        digest.update(obj.X_WO.matrix.tobytes())
    for whisker in scene.whiskers:
        digest.update(repr((whisker.name, whisker.length_m, whisker.ei_nm2)).encode())
        digest.update(whisker.X_RC.matrix.tobytes() + whisker.X_CS.matrix.tobytes())
    for array in (scene.path.t, scene.path.p_WR, scene.path.R_WR.as_matrix()):
        digest.update(np.ascontiguousarray(array, dtype=float).tobytes())
    return digest.hexdigest()


SampleProgress = Callable[[str, int, int], None]
"""``progress(whisker, sample, samples)``: how far along the path a whisker's Step 1 is."""

PROGRESS_PERIOD_S = 2.0

AXIS_SEGMENTS = 256
"""Segments of the polyline a bent rod's axis is checked against the other objects with: its
chords stray from the arc by at most kappa / (8 x 256^2), 2e-6 L at a curvature of 1/L."""

LANDING_SIDEWAYS = 0.01
"""A snap-off whose last contact force is within this fraction of the rod's axis (a poke) has
no side for the rod to land on."""

LANDING_DISTANCES = 2.0 ** np.arange(-6.0, 2.0)
"""How far back (units of L) a landing's approach starts: the first at which the unloaded rod
is free."""

LANDING_TURNS = np.pi / 4.0 * np.array([1.0, 2.0, 3.0])
"""Turns (rad, either way) about the rod of the force's side, and then its opposite, where a
landing's first two approaches fold on their way."""

LANDING_STEPS = (16, 256)
"""Fewest and most steps of a landing's approach (steps of the path's sample where they fit)."""

PAUSE_L = 1e-12
"""A sample where no point of the unloaded rod moved more than this (units of L) since the
sample before is a pause: it repeats that sample."""


class SimulationStopped(Exception):
    """`simulate` ended early because its ``stop()`` said so."""


def simulate(scene: Scene, workers: int | None = None,
             progress: Callable[[int, int], None] | None = None,
             sample_progress: SampleProgress | None = None,
             stop: Callable[[], bool] | None = None) -> list[WhiskerResult]:
    """Step 1 of every whisker of ``scene`` along its path. The whiskers are dealt round robin
    into ``workers`` groups (default: all cores), one process each (1: in this process); a
    group's whiskers are solved together, one step of all those in contact per batched attempt
    (`simulate_group`). ``progress(done, total)`` as whiskers finish (from worker processes:
    as groups finish); ``sample_progress`` (picklable, for the worker processes) every 2 s of a
    group's work, for each of its whiskers in contact. ``stop()``, asked after every step (in
    this process) or every `STOP_POLL_S` (while worker processes compute, which it then ends),
    raises `SimulationStopped` when true. Worker processes ignore SIGINT (the caller decides)."""
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    total = len(scene.whiskers)
    if progress:
        progress(0, total)
    groups = [scene.whiskers[g::workers] for g in range(min(workers, total))]
    if len(groups) == 1:
        done = 0

        def finished(_result: WhiskerResult) -> None:
            nonlocal done
            done += 1
            if progress:
                progress(done, total)
        return simulate_group(scene, groups[0], sample_progress, finished, stop)
    by_name: dict[str, WhiskerResult] = {}
    with worker_pool(len(groups)) as pool:  # terminates
        pending = [pool.apply_async(simulate_group, (scene, group, sample_progress))
                   for group in groups]
        while pending:
            if stop and stop():
                raise SimulationStopped(f"stopped with {len(by_name)} of {total} whisker(s) done")
            pending[0].wait(STOP_POLL_S)
            for job in [job for job in pending if job.ready()]:
                by_name.update((result.name, result) for result in job.get())
                pending.remove(job)
                if progress:
                    progress(len(by_name), total)
    return [by_name[whisker.name] for whisker in scene.whiskers]


STOP_POLL_S = 0.05
"""How often `simulate` asks its ``stop()`` while worker processes compute, s."""


WORKER_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals a worker process of `worker_pool` starts with blocked."""


def worker_pool(processes: int, context: Any = multiprocessing) -> multiprocessing.pool.Pool:
    """A pool of ``processes`` workers (of ``context``, a `multiprocessing` context) that
    ignore SIGINT (a terminal's Ctrl-C reaches the whole process group; the parent decides)
    and end on SIGTERM (`multiprocessing.pool.Pool.terminate`, which its ``with`` exit calls).
    They start with both signals blocked until their actions are set: one that came before
    would run this process's handlers there, and a worker that lived on after its SIGTERM
    would hang the pool's `terminate`."""
    unblocked = signal.pthread_sigmask(signal.SIG_BLOCK, WORKER_SIGNALS)
    try:
        return context.Pool(processes, initializer=_worker_signals)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, unblocked)


def _worker_signals() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, WORKER_SIGNALS)  # a pending SIGTERM ends it


def simulate_whisker(scene: Scene, whisker: Whisker,
                     progress: SampleProgress | None = None) -> WhiskerResult:
    """Step 1 of one whisker of ``scene`` along the path (its contact episodes): a group of
    one (`simulate_group`)."""
    return simulate_group(scene, [whisker], progress)[0]


def simulate_group(scene: Scene, whiskers: Sequence[Whisker],
                   progress: SampleProgress | None = None,
                   finished: Callable[[WhiskerResult], None] | None = None,
                   stop: Callable[[], bool] | None = None) -> list[WhiskerResult]:
    """Step 1 of ``whiskers`` of ``scene`` along the path, solved together: every iteration
    advances each whisker in an episode by one step, all in one batched attempt
    (`vibrissa.sweep.advance_together`), and moves the others on (past unresolved samples, to
    their next touch, or to their end). A whisker's results are the same bits as alone.
    ``progress(name, sample, samples)`` every 2 s of work, for each whisker in an episode;
    ``finished(result)`` as each whisker ends; `SimulationStopped` when ``stop()`` (asked
    before every step) is true."""
    pending = [_WhiskerSteps(scene, whisker) for whisker in whiskers]
    results: dict[str, WhiskerResult] = {}
    next_report = time.monotonic() + PROGRESS_PERIOD_S
    while pending:
        if stop and stop():
            raise SimulationStopped(f"stopped with {len(results)} of {len(whiskers)} "
                                    "whisker(s) done")
        for steps in pending:
            if steps.run is None:
                steps.start_episode()
        advance_together([steps.run for steps in pending if steps.run is not None])
        report = progress if progress and time.monotonic() >= next_report else None
        for steps in pending:
            if steps.run is not None and steps.run.done:
                steps.end_episode()
            elif steps.run is not None and report:
                report(steps.whisker.name, *steps.where())
            if steps.ended:
                results[steps.whisker.name] = result = steps.result()
                if finished:
                    finished(result)
        if report:
            next_report = time.monotonic() + PROGRESS_PERIOD_S
        pending = [steps for steps in pending if not steps.ended]
    return [results[whisker.name] for whisker in whiskers]


def local_origin(path: RobotPath) -> FloatArray:
    """Where Step 1 puts W's origin for ``path`` (m): the middle of the path, rounded to whole
    metres. Its equilibria are solved to residuals of 1e-12 L, and coordinates x L from the
    origin carry x 1e-16 L of round-off: in a world frame 1 km from the robot (an odometry or
    map frame) Step 1 found no equilibrium at all, 100 m away it moved contacts by 1e-7 m."""
    return np.round((path.p_WR.min(axis=0) + path.p_WR.max(axis=0)) / 2.0)


PAIR_START_LOADS = (1e-3, 1e-2, 0.1, 0.3, 1.0, 3.0)
"""Guesses of a second contact's force at its first sample, in units of the first contact's,
tried in turn (`_WhiskerSteps._start_pair`): the first from which Newton reaches an admissible
state of both contacts. A second object entered deeply within one sample bears a load of the
first's order there, which Newton does not find from a small guess. Where none reaches it at
once, the smallest is tried again from where the second contact has just touched
(`vibrissa.two_contacts.TwoContactFollower`'s ``from_touch``)."""


@dataclass
class _Pair:
    """A stretch of two contacts being followed (`_WhiskerSteps.go_on_pair`): its follower,
    the objects of its inner and outer contact, which of the two is the episode's own
    (``mine``, 0 inner) and the other's object, its first moving sample, the rows of the
    episode it follows and the stretch's rows recorded so far."""

    follower: two.TwoContactFollower
    objects: tuple[int, int]
    mine: int
    other: int
    k_first: int
    rows_before: int
    recorded: int = 0


class _WhiskerSteps:
    """One whisker's Step 1 along the path, a state machine that `simulate_group` steps: past
    unresolved samples, searching the next touch, in an episode (``run``, a `SweepRun` of one
    sweep), ``ended``.

    Step 1 runs on the samples where the clamp moves (``kept``): where the robot pauses
    nothing changes (Coulomb friction does not depend on rate), and each pause repeats the
    sample before it (``result``).
    """

    def __init__(self, scene: Scene, whisker: Whisker) -> None:
        length = whisker.length_m
        self.scene, self.whisker = scene, whisker
        self.shape = whisker.shape
        self.origin_m = local_origin(scene.path)
        self.surfaces = [obj.surface(length, self.origin_m) for obj in scene.objects]
        mount = Transform(whisker.X_RC.rotation, whisker.X_RC.translation / length)
        p_WR = (scene.path.p_WR - self.origin_m) / length
        q_WR = scene.path.R_WR.as_quat()
        moved = np.concatenate([[True], rod_motion(p_WR, q_WR, mount) > PAUSE_L])
        moved[-1] |= not moved[1:].any()  # a robot that never moves: its first and last sample
        self.moved = moved
        self.kept = np.flatnonzero(moved)
        self.path = SampledPath(p_WR[self.kept], q_WR[self.kept], scene.mu, mount)
        n = self.path.n_samples
        self.phase = np.full(n, SamplePhase.NONE, dtype=np.int64)
        self.s1, self.f0, self.m0 = np.full(n, np.nan), np.zeros((n, 3)), np.zeros((n, 3))
        self.contact, self.touched = np.full((n, 3), np.nan), np.full(n, -1, dtype=np.int64)
        self.refined = np.zeros(n, dtype=bool)
        self.second_s, self.second_contact = np.full(n, np.nan), np.full((n, 3), np.nan)
        self.second_touched = np.full(n, -1, dtype=np.int64)
        self.t_all = scene.path.t
        self._init_state()
        self.k = self._skip_unresolved(0)

    final = True
    """Whether ``path`` is the whole path (`SceneStream`: more samples may come)."""
    hold = False
    """(More samples to come) whether the last sample waits for the next (`SceneStream.advance`)."""

    def _init_state(self) -> None:
        self.episodes: list[Episode] = []
        self.run: SweepRun | None = None
        self.ended = False
        self.k = 0  # the moving sample from which the next touch is searched
        self._searched = -1  # (more samples may come) no touch from k up to this sample
        self._object = -1  # the episode's object
        self._snapped: FloatArray | None = None  # a snap-off's last contact force: land at k
        self._inside: list[int] = []  # ... on one of these objects, the deepest first
        self._carried: Landing | None = None  # ... or in this state: a pair's contact goes on
        self._landed = False  # the episode started from a landing
        self._pair: _Pair | None = None  # two contacts being followed

    def start_episode(self) -> None:
        """Land on the object at sample ``k`` after a snap-off, or search the first touch from
        ``k`` on; start its episode, or end."""
        self._landed = False
        if self._snapped is not None:
            force, self._snapped = self._snapped, None
            carried, self._carried = self._carried, None
            for j in self._inside:
                self._object = j
                # (a pair's contact goes on where no approach lands, or its rod is not inside)
                inside = self.path.penetrates(self.surfaces[j], self.path.x0_of(
                    np.array([self.k])), self.shape)[0]
                landing = self._landing(self.k, force) if inside else None
                landing = carried if landing is None else landing
                if landing is not None:
                    rest = self.path.tail(self.k)
                    self.run = SweepRun(self.surfaces[self._object], [rest], rest.h,
                                        landings=[landing], shape=self.shape)
                    self._landed = True
                    return
        if self._searched < self.k:  # (more samples may come: a skip may go on)
            self.k = self._skip_unresolved(self.k)
        n = len(self.kept)
        if self.k >= n - 1:
            self.ended = self.final
            return
        if self._searched > self.k and (self._searched >= n - 1
                                        or not self._touch_after(self._searched)):
            self._searched = n - 1
            self.ended = self.final
            return
        rest = self.path.tail(self.k)
        touches = [(touch, i) for i, surface in enumerate(self.surfaces)
                   if (touch := rest.first_contact(surface, self.shape)) is not None]
        if not touches:
            self._searched = n - 1
            self.ended = self.final
            return
        (_x_touch, _p), self._object = max(touches, key=lambda item: item[0][0])  # the first
        self.run = SweepRun(self.surfaces[self._object], [rest], rest.h, shape=self.shape)

    def _touch_after(self, j: int) -> bool:
        """Whether the unloaded rod, free at moving sample ``j``, touches an object after it.

        First, for all objects at once: none where the rod enters no object at any sample and
        moves at most `SUBSAMPLE_L` from one to the next (`SampledPath.first_contact` then has
        no sub-samples to check)."""
        if not self.surfaces:
            return False
        p_WR, q_WR = self._samples_from(j)
        window = SampledPath(p_WR, q_WR, self.scene.mu, self.mount, self.h)
        p_WC, R_WC = window.clamp_pose(window.x0_of(np.arange(window.n_samples, dtype=float)))
        starts, chords = unloaded_segments(self.shape, p_WC, R_WC)
        if self.max_motion <= SUBSAMPLE_L and not segments_meet(starts, chords, *self._objects):
            return False
        return any(window.first_contact(surface, self.shape) is not None
                   for surface in self.surfaces)

    @functools.cached_property
    def _objects(self) -> tuple[FloatArray, ...]:
        """The scene's objects as the rows of `vibrissa.surfaces.segments_meet`."""
        return tuple(np.concatenate(rows) for rows in zip(*(s.kernel_arrays for s in self.surfaces),
                                                          strict=True))

    def _samples_from(self, j: int) -> tuple[FloatArray, FloatArray]:
        """The moving samples from ``j`` on: robot origins (units of L) and R_WR (unit
        quaternions)."""
        return self.path.p_WR[j:], self.path.q_WR[j:]

    @property
    def mount(self) -> Transform:
        """X_RC, units of L."""
        return self.path.mount

    @property
    def h(self) -> float:
        """Step 1's step, units of L: a sample."""
        return self.path.h

    max_motion = float("inf")
    """The most a point of the unloaded rod moved from one sample to the next, units of L
    (unknown: inf)."""

    def where(self) -> tuple[int, int]:
        """The moving sample the episode has reached, and the moving samples."""
        assert self.run is not None
        return self.k + int(-self.run.progress(0).x0 / self.path.h), self.path.n_samples

    def end_episode(self) -> None:
        """Record the ended episode's samples; go on from the sample after it (or end)."""
        assert self.run is not None
        sweep, k, h, i = self.run.sweeps()[0], self.k, self.path.h, self._object
        self.run = None
        rows = k + np.rint(-sweep.x0 / h).astype(np.int64)
        # the first sample past the touch (on the touch within 1e-9 of a step: the next one)
        after_touch = k + round(-next_grid_point(sweep.x_touch, 0.0, h) / h)
        n = self._rows_clear_of_others(sweep)  # rows kept: the rod meets another object at row n
        end, changes = sweep.end, sweep.phase_changes
        if n < len(rows):
            end = SweepEnd.ANOTHER_OBJECT
            changes = [change for change in changes if change[0] > sweep.x0[n]]
        # the last sample of the episode: its last row, or the one where the rod meets another
        last = int(rows[n]) if n < len(rows) else int(rows[-1]) if len(rows) else after_touch - 1
        self._write_rows(sweep, rows, self._span_start(sweep), last, 0, n)
        self.episodes.append(Episode(self.scene.objects[i].name,
                                     self._time_at(-sweep.x_touch / h + k), str(end),
                                     [(self._time_at(-x0 / h + k), old, new)
                                      for x0, old, new in changes],
                                     "landing" if self._landed else "touch",
                                     tuple(self._time_at(-x0 / h + k)
                                           for x0 in sweep.x0[:n][sweep.jumped[:n]])))
        snapped = sweep.force[-1] if len(sweep.force) else None
        if (end is SweepEnd.ANOTHER_OBJECT and self.two_contacts and n >= 1
                and self._start_pair(sweep, rows, n)):
            self.go_on_pair()
            return
        self._after_episode(end, last, snapped, len(rows))

    def _after_episode(self, end: SweepEnd, last: int, snapped: FloatArray | None,
                       n_rows: int) -> None:
        """Go on after an episode of ``n_rows`` rows that ended ``end`` at moving sample
        ``last`` with the contact force ``snapped`` on the rod (W, units of L): to the end, a
        landing, or the next touch."""
        if end in (SweepEnd.PATH_END, SweepEnd.MAX_STEPS):
            self.ended = True
            return
        # A rod that snaps off with its unloaded rod inside objects (the same or others) lands
        # on one of them, the deepest first (not twice from the same sample: a landing that
        # snaps off at once is left; not on the path's last sample, which, as for a touch,
        # starts no episode).
        if (end is SweepEnd.SNAP_OFF and not (self._landed and n_rows == 1)
                and self._lands(last, range(len(self.surfaces)), snapped)):
            return
        self.k = self._skip_unresolved(last + 1)

    def _lands(self, last: int, objects: Iterable[int], force: FloatArray | None) -> bool:
        """Whether the rod, last in contact at moving sample ``last`` with the contact force
        ``force`` on it (W, units of L), is to land at the next one on one of ``objects``
        that its unloaded rod enters there, the deepest first (not on the path's last
        sample, which, as for a touch, starts no episode)."""
        if force is None or last + 1 >= self.path.n_samples - 1:
            return False
        x0_next = self.path.x0_of(np.array([last + 1]))
        on_rod = self._unloaded_rod(last + 1)[2]
        self._inside = sorted(
            (j for j in objects if self.path.penetrates(self.surfaces[j], x0_next, self.shape)[0]),
            key=lambda j: float(self.surfaces[j].signed_distance(on_rod).min()))
        if not self._inside:
            return False
        self.k, self._snapped = last + 1, force
        return True

    two_contacts = True
    """Whether a rod in contact that meets a second object goes on with both contacts
    (`vibrissa.two_contacts`)."""

    def _start_pair(self, sweep: Sweep, rows: NDArray[np.int64], n: int) -> bool:
        """Start both contacts from the sample after the episode's last row before its rod met
        another object (row ``n``), where the two have an equilibrium at that first sample
        (`vibrissa.two_contacts`); whether they do."""
        k_first = int(rows[n - 1]) + 1
        if k_first >= self.path.n_samples or k_first > int(rows[n]):
            return False
        # the rod of row n, in the other object (its chords: its points may lie just outside)
        line = sweep.elastic_lines([n], AXIS_SEGMENTS + 1)[0]
        _depth, other = min((float(surface.signed_distance(line).min()), j)
                            for j, surface in enumerate(self.surfaces) if j != self._object)
        deepest = int(np.argmin(self.surfaces[other].signed_distance(line)))
        s_other = deepest / AXIS_SEGMENTS
        s_own, mode_own = float(sweep.s1[n - 1]), (two.MODE_TIP if sweep.phase[n - 1]
                                                    == SamplePhase.TIP else two.MODE_TANGENTIAL)
        mode_other = two.MODE_TIP if deepest == AXIS_SEGMENTS else two.MODE_TANGENTIAL
        normal = self.surfaces[other].normal(line[deepest][None])[0]
        # where the rod touched it: the surface's point nearest to the rod of the last row
        # clear of it (eq. 7's chord of the new contact starts there, as a touch's does)
        before = sweep.elastic_lines([n - 1], AXIS_SEGMENTS + 1)[0]
        nearest = int(np.argmin(self.surfaces[other].signed_distance(before)))
        touch = self.surfaces[other].closest_point(before[nearest][None])[0]
        force_own = sweep.force[n - 1]
        own = (s_own, force_own, mode_own, sweep.contact[n - 1], self._object)
        moment = -sweep.m0[n - 1]  # the rod's internal moment at the clamp, C
        # (the straight rod's unknowns leave out the twist about the clamp's axis: it has none)
        clamp_moment = moment[:2] if self.shape.uniform else moment
        # each guess at once, then the smallest from where the second contact touched
        for from_touch, load in [*((False, load) for load in PAIR_START_LOADS),
                                 (True, PAIR_START_LOADS[0])]:
            force_other = load * float(np.linalg.norm(force_own)) * normal
            theirs = (s_other, force_other, mode_other, touch, other)
            inner, outer = (own, theirs) if s_own <= s_other else (theirs, own)
            x_start = np.concatenate([clamp_moment, inner[1], outer[1], [inner[0], outer[0]]])
            follower = two.TwoContactFollower(
                self.surfaces, (inner[4], outer[4]), k_first, x_start,
                np.array([inner[2], outer[2]], dtype=np.int64), np.array([inner[3], outer[3]]),
                self.shape, from_touch)
            follower.advance(self.path, k_first + 1)
            if follower.stretch.rows:
                break
        else:
            return False
        self._pair = _Pair(follower, (inner[4], outer[4]), 0 if inner[4] == self._object else 1,
                           other, k_first, len(rows))
        return True

    def go_on_pair(self) -> None:
        """Follow the two contacts as far as the samples go, recording each sample as it is
        reached; once the stretch ends (and, more samples to come, the one after its end is
        there for a landing) end its episode and go on."""
        pair = self._pair
        assert pair is not None
        n = self.path.n_samples
        # (more samples to come: not onto the last sample, `_StreamSteps.can_step`)
        pair.follower.advance(self.path, n if self.final or not self.hold else n - 1)
        stretch = pair.follower.stretch
        length = self.whisker.length_m
        for row in stretch.rows[pair.recorded:]:
            k, mine = row.k, pair.mine
            point, _t, _n, _f = two.contact_info(row.state, mine)
            second, _t, _n, _f = two.contact_info(row.state, 1 - mine)
            self.phase[k] = (SamplePhase.TIP if row.modes[mine] in (two.MODE_TIP, two.MODE_STICK)
                             else SamplePhase.TANGENTIAL)
            self.s1[k], self.second_s[k] = row.x[-2 + mine] * length, row.x[-1 - mine] * length
            self.contact[k] = point * length + self.origin_m
            self.second_contact[k] = second * length + self.origin_m
            self.touched[k], self.second_touched[k] = self._object, pair.other
            self.f0[k], self.m0[k] = self.whisker.scale.wrench_to_si(row.f0, row.m0)
            self.refined[k] = row.refined
        pair.recorded = len(stretch.rows)
        if not stretch.end:
            if not self.final:
                return
            stretch.end = "path-end"
        last = stretch.rows[-1].k
        if stretch.end != "path-end" and not self.final and last + 2 > n - 1:
            return  # a landing needs the samples after the stretch
        self._pair = None
        end = SweepEnd(stretch.end) if stretch.end != "left" else SweepEnd.DETACHMENT
        self.episodes.append(Episode(self.scene.objects[self._object].name,
                                     self._time_at(pair.k_first - 0.5), str(end), [],
                                     "second-contact", self._pair_jumps(pair),
                                     self.scene.objects[pair.other].name))
        final = stretch.rows[-1].state
        force = two.contact_info(final, 1 if stretch.left != 1 else 0)[3]
        if end is SweepEnd.DETACHMENT:  # one contact left: the other goes on alone
            remaining = pair.objects[1 - stretch.left]
            carried = self._carried_on(last, remaining, stretch.rows[-1], 1 - stretch.left)
            if self._lands(last, [remaining], force) or carried is not None:
                self.k, self._snapped, self._inside = last + 1, force, [remaining]
                self._carried = carried
                return
            self.k = self._skip_unresolved(last + 1)
            return
        self._after_episode(end, last, force, pair.rows_before)

    def _carried_on(self, last: int, remaining: int, row: two.StretchRow, j: int
                    ) -> Landing | None:
        """Contact ``j`` of the stretch's ``row`` at moving sample ``last`` (its other contact
        left there), on object ``remaining``, gone on alone to the next sample with its friction
        from where it was (`vibrissa.sweep.carried_on`): what the rod lands in where no
        approach lands it; None where it does not go on (or the next sample is the path's
        last, which, as for a touch, starts no episode)."""
        if last + 1 >= self.path.n_samples - 1:
            return None
        point, _t, _n, _force = two.contact_info(row.state, j)
        x_last, x_next = self.path.x0_of(np.array([last, last + 1])).tolist()
        step = self.path.travel(x_last, x_next)  # the rod's, as a step's largest slide
        return carried_on(
            self.surfaces[remaining], self.path.tail(last + 1), row.f0, row.m0,
            float(row.x[-2 + j]), point,
            ContactPhase.TIP if row.modes[j] in (two.MODE_TIP, two.MODE_STICK)
            else ContactPhase.TANGENTIAL, row.modes[j] in (two.MODE_TIP, two.MODE_TANGENTIAL),
            max(20.0 * step, 0.01), self.shape)

    def _pair_jumps(self, pair: _Pair) -> tuple[float, ...]:
        """The times of the samples a contact of ``pair`` jumped to (a far slide,
        `vibrissa.two_contacts.StretchRow`): the stretch's snap-throughs so far."""
        return tuple(self._time_at(row.k) for row in pair.follower.stretch.rows if row.jumped)

    def _span_start(self, sweep: Sweep) -> int:
        """The episode's first sample: its landing's, or the first past the touch (on the
        touch within 1e-9 of a step: the next one)."""
        if self._landed:
            return self.k
        return self.k + round(-next_grid_point(sweep.x_touch, 0.0, self.path.h) / self.path.h)

    def _write_rows(self, sweep: Sweep, rows: NDArray[np.int64], start: int, last: int,
                    first: int, n: int) -> None:
        """Record the episode's samples ``start`` .. ``last``, its rows ``first`` .. ``n - 1``
        at samples ``rows``: unresolved where stepped over, each row's state at its own."""
        span = slice(start, last + 1)
        self.phase[span] = SamplePhase.UNRESOLVED  # stepped over, until a row says otherwise
        self.f0[span], self.m0[span] = np.nan, np.nan
        self.touched[span] = self._object
        kept, part = rows[first:n], slice(first, n)
        self.phase[kept] = sweep.phase[part]
        self.s1[kept] = sweep.s1[part] * self.whisker.length_m
        self.f0[kept], self.m0[kept] = self.whisker.scale.wrench_to_si(sweep.f0[part],
                                                                       sweep.m0[part])
        self.contact[kept] = sweep.contact[part] * self.whisker.length_m
        if self.origin_m.any():  # (so that a scene at W's origin keeps its bits, -0.0 too)
            self.contact[kept] += self.origin_m
        self.refined[kept] = sweep.refined[part]

    def _landing(self, k: int, force_W: FloatArray) -> Landing | None:
        """Where the rod lands at sample ``k`` after a snap-off, its unloaded rod inside the
        object ``_object``; None where it is not found.

        A quasi-static model cannot follow the jump. The state at k is found by approaching the
        object without friction: the clamp moved back perpendicular to its axis until the
        unloaded rod is free (`LANDING_DISTANCES`), then forward to its pose at k in
        `LANDING_STEPS`, the contact followed from its touch. Sides are tried in order: the
        side the last contact force pushed the rod to, the shortest way out of the object (the
        normal at the unloaded rod's deepest point), then the first turned about the rod
        (`LANDING_TURNS`); the first approach that reaches k without a fold of its own, the
        landed rod clear of every other object, gives the landing. The landed state's force
        is normal to the object, inside any friction cone: the contact holds where it landed,
        then goes on with the path's friction.
        """
        surface = self.surfaces[self._object]
        p_WC, axis, on_rod = self._unloaded_rod(k)
        deepest = on_rod[np.argmin(surface.signed_distance(on_rod))]
        sides = []  # unit vectors perpendicular to the rod
        for side in (force_W, surface.normal(deepest[None])[0]):
            away = side - (side @ axis) * axis
            if np.linalg.norm(away) > LANDING_SIDEWAYS * np.linalg.norm(side):
                sides.append(away / np.linalg.norm(away))
        if sides:  # then the first turned about the rod: each pair nearer the way out first
            first, way_out, across = sides[0], sides[-1], np.cross(axis, sides[0])
            for turn in LANDING_TURNS:
                pair = [np.cos(turn) * first + np.sin(sign * turn) * across for sign in (1, -1)]
                sides += sorted(pair, key=lambda v: -float(v @ way_out))
            sides.append(-first)
        for away in sides:
            landing = self._approach(k, surface, p_WC, axis, away, on_rod)
            if landing is not None:
                return landing
        return None

    def _unloaded_rod(self, k: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The unloaded rod at moving sample ``k``: its clamp p_WC (3,), the clamp's axis (3,)
        and ``AXIS_SEGMENTS`` + 1 points from the clamp to the tip, units of L."""
        p_WC, R_WC = (a[0] for a in self.path.clamp_pose(self.path.x0_of(np.array([k]))))
        axis = R_WC[:, 2]
        s = np.linspace(0.0, 1.0, AXIS_SEGMENTS + 1)
        if self.shape.precurvature == 0.0:
            return p_WC, axis, p_WC + s[:, None] * axis
        return p_WC, axis, p_WC + unloaded_points(self.shape, s) @ R_WC.T

    def _approach(self, k: int, surface: Surface, p_WC: FloatArray, axis: FloatArray,
                  away: FloatArray, on_rod: FloatArray) -> Landing | None:
        """The state at sample ``k`` reached by the clamp approaching it along -``away``
        (perpendicular to its ``axis``) without friction, from where the unloaded rod is free;
        None if there is no such start, the approach's contact snaps off on the way, or the
        landed rod (its axis as ``AXIS_SEGMENTS`` chords) enters another object."""
        def free(d: float) -> bool:
            if self.shape.precurvature == 0.0:
                return not surface.segment_inside((p_WC + d * away)[None], axis[None])[0]
            return not surface.segment_inside(on_rod[:-1] + d * away, np.diff(on_rod, axis=0)).any()

        distance = next((d for d in LANDING_DISTANCES if free(d)), None)
        if distance is None:
            return None
        steps = int(np.clip(np.ceil(distance / self.path.h), *LANDING_STEPS))
        back = np.linspace(distance, 0.0, steps + 1)[:, None] * away
        approach = SampledPath(self.path.p_WR[k] + back, self.path.q_WR[np.full(steps + 1, k)],
                               0.0, self.path.mount)
        run = SweepRun(surface, [approach], approach.h, shape=self.shape)
        while not run.done:
            run.advance()
        sweep = run.sweeps()[0]
        if (sweep.end is not SweepEnd.PATH_END or sweep.n_steps == 0
                or abs(sweep.x0[-1] - approach.x_end) > 1e-9 * approach.h):
            return None
        landed = sweep.n_steps - 1
        rod = sweep.elastic_lines([landed], AXIS_SEGMENTS + 1)[0]
        if any(other.segment_inside(rod[:-1], np.diff(rod, axis=0)).any()
               for j, other in enumerate(self.surfaces) if j != self._object):
            return None  # the landed rod would enter another object
        return sweep.landing(landed, 0.0)

    def _rows_clear_of_others(self, sweep: Sweep, start: int = 0) -> int:
        """How many of the episode's rows, from its first, have the rod's axis outside every
        other object of the scene (the axis as a polyline of ``AXIS_SEGMENTS`` chords), the
        rows before ``start`` known to."""
        others = [s for j, s in enumerate(self.surfaces) if j != self._object]
        if not others or sweep.n_steps <= start:
            return sweep.n_steps
        # A row's rod lies in two balls: the bent part (length s1 from the clamp P0 to the
        # contact P1) within s1 / 2 of (P0 + P1) / 2, the straight rest within 1 - s1 of P1.
        contact = sweep.contact[start:]
        middle, s1 = (sweep.p0[start:] + contact) / 2.0, sweep.s1[start:]
        near = np.zeros(sweep.n_steps - start, dtype=bool)
        for surface in others:
            near |= ((surface.signed_distance(middle) < s1 / 2.0 + 1e-9)
                     | (surface.signed_distance(contact) < 1.0 - s1 + 1e-9))
        candidates = start + np.flatnonzero(near)
        for first in range(0, len(candidates), 64):
            rows = candidates[first:first + 64]
            axes = sweep.elastic_lines(rows, AXIS_SEGMENTS + 1)
            starts, chords = axes[:, :-1].reshape(-1, 3), np.diff(axes, axis=1).reshape(-1, 3)
            meets = np.zeros(len(rows), dtype=bool)
            for surface in others:
                meets |= surface.segment_inside(starts, chords).reshape(len(rows), -1).any(axis=1)
            if meets.any():
                return int(rows[np.argmax(meets)])
        return sweep.n_steps

    def result(self) -> WhiskerResult:
        """The results at every sample of the path, a pause repeating the sample before it."""
        of_sample = np.cumsum(self.moved) - 1  # the moving sample each sample repeats
        return WhiskerResult(self.whisker.name, self.scene.path.t, self.phase[of_sample],
                             self.s1[of_sample], self.f0[of_sample], self.m0[of_sample],
                             self.contact[of_sample], self.touched[of_sample],
                             self.refined[of_sample], self.episodes,
                             self.second_s[of_sample], self.second_contact[of_sample],
                             self.second_touched[of_sample])

    def _skip_unresolved(self, k: int) -> int:
        """The first sample from ``k`` on where the unloaded rod is outside every object."""
        path, n = self.path, self.path.n_samples
        while k < n:
            x0 = path.x0_of(np.array([k]))
            if not any(path.penetrates(s, x0, self.shape)[0] for s in self.surfaces):
                break
            self.phase[k], self.f0[k], self.m0[k] = SamplePhase.UNRESOLVED, np.nan, np.nan
            k += 1
        return k

    def _time_at(self, lam: float) -> float:
        """The time at the fractional moving sample ``lam``: the clamp moves from the sample
        before kept[j] (where a pause ends) to kept[j]."""
        t_all, kept = self.t_all, self.kept
        j = min(int(np.ceil(lam)), len(kept) - 1)
        if j == 0:
            return float(t_all[kept[0]])
        start = t_all[kept[j] - 1]
        return float(start + (lam - (j - 1)) * (t_all[kept[j]] - start))


def clamp_inside(scene: Scene, whisker: Whisker) -> NDArray[np.int64]:
    """Per path sample (N,), the index of the object whose inside holds the whisker's clamp
    point (-1: none): a rod clamped there has no equilibrium outside the object, and its
    samples are `SamplePhase.UNRESOLVED`."""
    path = scene.path
    p_WC = path.p_WR + path.R_WR.apply(np.array(whisker.X_RC.translation, dtype=float))
    inside = np.full(len(p_WC), -1, dtype=np.int64)
    for k, obj in enumerate(scene.objects):
        inside[(inside < 0) & (obj.surface(1.0).value(p_WC) < 0.0)] = k
    return inside


def rod_inside_at_start(scene: Scene, whisker: Whisker) -> int:
    """The index of the first object that the whisker's unloaded rod enters at the path's
    first sample (-1: none): Step 1 follows a contact from its touch, so such a rod has no state
    to start from, and its samples are `SamplePhase.UNRESOLVED` until the unloaded rod is free."""
    path, X_RC = scene.path, whisker.X_RC
    p_WC = path.p_WR[0] + path.R_WR[0].apply(np.array(X_RC.translation, dtype=float))
    if whisker.precurvature_1pm == 0.0:
        rod = (path.R_WR[0] * X_RC.rotation).apply([0.0, 0.0, whisker.length_m])
        starts, rods = p_WC[None], rod[None]
    else:
        R_WC = (path.R_WR[0] * X_RC.rotation).as_matrix()
        starts, rods = unloaded_segments(whisker.shape, p_WC[None] / whisker.length_m,
                                         R_WC[None])
        starts, rods = starts * whisker.length_m, rods * whisker.length_m
    for k, obj in enumerate(scene.objects):
        if obj.surface(1.0).segment_inside(starts, rods).any():
            return k
    return -1


def reconstruct_along(scene: Scene, t_s: ArrayLike, whisker: Sequence[str],
                      f0_C_n: ArrayLike, m0_C_nm: ArrayLike) -> ReconstructionSI:
    """Step 2 of wrenches measured along the scene's path, one row per measurement.

    Row i: whisker ``whisker[i]`` (by name; its own L, EI and mount), at time ``t_s[i]``, with
    the clamp's reaction ``f0_C_n[i]``, ``m0_C_nm[i]`` in its clamp frame C (N, N m). The clamp
    is at X_WC = X_WR(t) X_RC with the robot pose interpolated at t (`RobotPath.at`); a row
    whose t the path does not cover has ``pose_ok`` False and no point. A row of a straight
    uniform rod gives the same bits alone or in any batch; a tapered or pre-curved rod's point
    is chosen by continuity with its whisker's row before (`vibrissa.reconstruct_rods`).
    ValueError names an unknown whisker and its index.
    """
    t = np.asarray(t_s, dtype=float).reshape(-1)
    f0, m0 = (np.asarray(a, dtype=float).reshape(-1, 3) for a in (f0_C_n, m0_C_nm))
    names = list(whisker)
    if not len(names) == len(t) == len(f0) == len(m0):
        raise ValueError(f"{len(t)} times, {len(names)} whisker names, {len(f0)} f0 and "
                         f"{len(m0)} m0 rows")
    index = {w.name: i for i, w in enumerate(scene.whiskers)}
    unknown = [i for i, name in enumerate(names) if name not in index]
    if unknown:
        raise ValueError(f"whisker[{unknown[0]}] = {names[unknown[0]]!r} is not in the scene "
                         f"({', '.join(index)})")
    rows_of = np.array([index[name] for name in names], dtype=np.int64)
    from scipy.spatial.transform import Rotation  # on first use (vibrissa.frames)

    covered, p_WR, R_WR = scene.path.at(t)
    out = ReconstructionSI(np.zeros(len(t), bool), np.full((len(t), 3), np.nan),
                           np.full(len(t), np.nan), np.zeros(len(t), np.int32),
                           np.full((len(t), 3), np.nan), np.zeros(len(t), np.int32))
    rows = np.flatnonzero(covered)
    if not len(rows):  # no rows, or none within the path
        return out
    which = rows_of[rows]
    mount_p = np.array([w.X_RC.translation for w in scene.whiskers])[which]
    mount_R = Rotation.from_quat(np.array([w.X_RC.quaternion_xyzw for w in scene.whiskers])[which])
    p_WC = p_WR[rows] + R_WR[rows].apply(mount_p)
    q_WC = (R_WR[rows] * mount_R).as_quat()
    units = rod_units([w.scale for w in scene.whiskers])[which]  # each row's rod
    shapes = chain = None
    if any(not w.shape.uniform for w in scene.whiskers):
        # a shaped rod's point by continuity with its whisker's row before (in row order)
        shapes = np.array([w.shape.params for w in scene.whiskers])[which]
        chain = np.full(len(rows), -1, dtype=np.int64)
        last: dict[int, int] = {}
        for i, w in enumerate(which.tolist()):
            chain[i] = last.get(w, -1)
            last[w] = i
    part = reconstruct_si(q_WC, p_WC, f0[rows], m0[rows], units, shapes=shapes, chain=chain)
    for name in ("pose_ok", "point_m", "s1_m", "phase", "force_n", "status"):
        getattr(out, name)[rows] = getattr(part, name)
    return out


def robot_path(t: ArrayLike, p_WR: ArrayLike, q_WR_xyzw: ArrayLike) -> RobotPath:
    """A `RobotPath` from quaternions (x, y, z, w), which must be unit
    (`vibrissa.frames.non_unit_quaternion`): a ValueError names the first row that is not."""
    q = np.asarray(q_WR_xyzw, dtype=float)
    bad = non_unit_quaternion(q)
    if bad is not None:
        row, norm = bad
        raise ValueError(f"row {row + 1}: quaternion {q[row].tolist()} is not a unit "
                         f"quaternion (norm {norm:.9g})")
    from scipy.spatial.transform import Rotation  # on first use (vibrissa.frames)

    return RobotPath(np.asarray(t, dtype=float), np.asarray(p_WR, dtype=float),
                     Rotation.from_quat(q))


@dataclass(frozen=True)
class StreamSamples:
    """Path samples of a `SceneStream` whose Step 1 is final, in path order (M samples, W
    whiskers in the scene's order).

    ``t`` (M,) s; ``p_WR`` (M, 3) m and ``q_WR`` (M, 4) (x, y, z, w): the robot's pose X_WR;
    ``phase`` (M, W) `SamplePhase`; ``f0_n``, ``m0_nm`` (M, W, 3) the clamp's reaction on each
    rod about its clamp point in its clamp frame C, N and N m (zero when free, NaN when
    unresolved), as `WhiskerResult`'s; ``snaps`` the jumps told at these samples, in time
    order (`simulate`'s `snaps` of the same path).
    """

    t: FloatArray
    p_WR: FloatArray
    q_WR: FloatArray
    phase: NDArray[np.int64]
    f0_n: FloatArray
    m0_nm: FloatArray
    snaps: tuple[StreamSnap, ...] = ()


@dataclass(frozen=True)
class StreamSnap:
    """A jump of a streamed whisker's path (`snaps`), told with the samples that hold its
    ``after`` sample: the whisker (index into the scene's), the `Snap` (its ``before`` and
    ``after`` not indices here) and the clamp wrenches (N, N m, in C) at its two samples."""

    whisker: int
    snap: Snap
    f0_before: FloatArray
    m0_before: FloatArray
    f0_after: FloatArray
    m0_after: FloatArray


class SceneStream:
    """Step 1 of every whisker of a scene along a path that arrives while it runs: the same
    state machine as `simulate` (episodes, landings, another object, pauses), each whisker's
    state carried from one sample to the next, results handed out as soon as no later sample
    can change them.

    The path is the scene's objects, whiskers and friction with poses fed by `extend` (the
    scene's own path only sets W's local origin, `local_origin`). Each whisker's step ``h``
    (units of its L) is given, not the path's largest motion: ``steps`` (one per whisker, e.g.
    `vibrissa.paths.PathLimits.rod_step`). With the path's own ``h`` and all of it fed, the
    results are `simulate`'s, to the bit, two contacts on a rod too (followed sample by sample
    as they come, `vibrissa.two_contacts.TwoContactFollower`). The jumps (`snaps`) go out with
    the samples that hold the sample each is told at (`StreamSamples.snaps`).

    What may wait for later samples: a contact in its first `vibrissa.sweep.EARLY_TRAVEL_L` of
    travel looks up to 32 samples ahead (`vibrissa.sweep.EARLY_MULTIPLES`), and a snap-off two
    samples (a landing is never on the path's last sample); `advance` with ``hold`` False
    steps as far as the samples go, as if the path ended there for the look-ahead (a robot
    that stopped: it gives up the longer early steps past that end); `finish` ends the path.
    """

    def __init__(self, scene: Scene, steps: Sequence[float]) -> None:
        if len(steps) != len(scene.whiskers) or not all(h > 0 for h in steps):
            raise ValueError(f"steps must be {len(scene.whiskers)} numbers > 0, got {steps}")
        origin_m = local_origin(scene.path)
        self.scene = scene
        self._steps = [_StreamSteps(scene, whisker, origin_m, h)
                       for whisker, h in zip(scene.whiskers, steps, strict=True)]
        self._t = np.zeros(0)
        self._p = np.zeros((0, 3))
        self._q = np.zeros((0, 4))
        self._sent = 0  # raw samples handed out

    def extend(self, t: ArrayLike, p_WR_m: ArrayLike, q_WR_xyzw: ArrayLike) -> None:
        """Add path samples: times (m,) s after the last, positions (m, 3) m, unit
        quaternions (m, 4)."""
        t = np.asarray(t, dtype=float).reshape(-1)
        p = np.asarray(p_WR_m, dtype=float).reshape(-1, 3)
        q = np.asarray(q_WR_xyzw, dtype=float).reshape(-1, 4)
        if not len(t) == len(p) == len(q):
            raise ValueError(f"{len(t)} times, {len(p)} positions, {len(q)} quaternions")
        if not len(t):
            return
        if not np.all(np.diff(np.concatenate([self._t[-1:], t])) > 0):
            raise ValueError("sample times must increase strictly")
        norm = np.linalg.norm(q, axis=1)
        if not np.all((norm > 0) & np.isfinite(norm)):
            raise ValueError("quaternions must be finite and non-zero")
        self._t, self._p, self._q = (np.concatenate([self._t, t]), np.vstack([self._p, p]),
                                     np.vstack([self._q, q]))
        q = q / norm[:, None]  # unit, as Rotation.from_quat makes them
        for steps in self._steps:
            steps.extend(t, p, q)

    def advance(self, hold: bool = True) -> StreamSamples:
        """Step every whisker as far as the samples allow; the samples now final."""
        for steps in self._steps:
            steps.hold = hold
        while True:
            for steps in self._steps:
                steps.go_on()
            ready = [steps for steps in self._steps if steps.can_step()]
            if ready:
                advance_together([steps.run for steps in ready if steps.run is not None])
            ended = [steps for steps in self._steps
                     if steps.run is not None and steps.run.done and steps.after_steps()]
            if ready or ended:
                continue
            # nothing can step: record the episodes' rows so far (or end one at another object)
            if not [steps for steps in self._steps if steps.after_steps()]:
                return self._take()

    def finish(self) -> StreamSamples:
        """End the path: step every whisker to its end; the samples left."""
        for steps in self._steps:
            steps.close()
        return self.advance(hold=False)

    def _take(self) -> StreamSamples:
        done = min(steps.final_samples() for steps in self._steps)  # raw samples, exclusive
        rows = slice(self._sent, max(done, self._sent))
        self._sent = rows.stop
        results = [steps.raw_results(rows) for steps in self._steps]
        told = [] if rows.stop == rows.start else sorted(
            (event for j, steps in enumerate(self._steps)
             for event in steps.snaps_until(j, float(self._t[rows.stop - 1]))),
            key=lambda e: (e.snap.t, e.whisker))
        for steps in self._steps:
            steps.forget(self._sent)
        return StreamSamples(self._t[rows], self._p[rows], self._q[rows],
                             np.stack([r[0] for r in results], axis=1).reshape(-1, len(results)),
                             np.stack([r[1] for r in results], axis=1).reshape(-1, len(results), 3),
                             np.stack([r[2] for r in results], axis=1).reshape(-1, len(results), 3),
                             tuple(told))


FORGET_SAMPLES = 64
"""A streamed whisker waiting for a touch drops the moving samples behind it once there are
this many (`_StreamSteps.forget`)."""


class _StreamSteps(_WhiskerSteps):
    """`_WhiskerSteps` on a path that grows (`SceneStream`): ``path`` holds the moving samples
    so far, ``final`` says whether more may come, and the rows of an episode are recorded as
    they pass the check against the other objects."""

    def __init__(self, scene: Scene, whisker: Whisker, origin_m: FloatArray, h: float) -> None:
        length = whisker.length_m
        self.scene, self.whisker, self.origin_m, self._h = scene, whisker, origin_m, h
        self.shape = whisker.shape
        self.surfaces = [obj.surface(length, origin_m) for obj in scene.objects]
        self._mount = Transform(whisker.X_RC.rotation, whisker.X_RC.translation / length)
        self.t_all = np.zeros(0)
        self.moved = np.zeros(0, dtype=bool)
        self.kept = np.zeros(0, dtype=np.int64)
        self._p_kept = np.zeros((0, 3))
        self._q_kept = np.zeros((0, 4))
        self._last: tuple[FloatArray, FloatArray] | None = None  # the last raw sample, units of L
        self._path: SampledPath | None = None  # built from the samples when asked for
        self.phase = np.zeros(0, dtype=np.int64)
        self.s1, self.f0, self.m0 = np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
        self.contact, self.touched = np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
        self.refined = np.zeros(0, dtype=bool)
        self.second_s, self.second_contact = np.zeros(0), np.zeros((0, 3))
        self.second_touched = np.zeros(0, dtype=np.int64)
        self.final = False
        self.hold = True
        self.max_motion = 0.0
        self._init_state()
        self._recorded = 0  # rows of the episode in progress already recorded
        self._recorded_run: SweepRun | None = None
        self._recorded_to = 0  # ... up to this moving sample (exclusive)
        self._idle_at: tuple[int, bool] = (-1, False)  # (samples, final) when it last waited
        self._base = 0  # moving samples dropped (`forget`): index 0 of ``path`` is this one
        self._pending: list[Snap] = []  # jumps found at samples not handed out yet
        self._told: set[tuple[float, str]] = set()  # (t, kind) of the jumps told

    def extend(self, t: FloatArray, p_WR_m: FloatArray, q_WR: FloatArray) -> None:
        p = (p_WR_m - self.origin_m) / self.whisker.length_m
        if self._last is None:
            motion = rod_motion(p, q_WR, self.mount)
            moved = np.concatenate([[True], motion > PAUSE_L])
        else:
            motion = rod_motion(np.vstack([self._last[0][None], p]),
                                np.vstack([self._last[1][None], q_WR]), self.mount)
            moved = motion > PAUSE_L
        self.max_motion = max(self.max_motion, float(np.max(motion, initial=0.0)))
        self._last = (p[-1], q_WR[-1])
        start = len(self.t_all)
        self.t_all = np.concatenate([self.t_all, t])
        self.moved = np.concatenate([self.moved, moved])
        self._add_kept(start + np.flatnonzero(moved), p[moved], q_WR[moved])

    @property  # type: ignore[override]
    def mount(self) -> Transform:
        return self._mount

    @property  # type: ignore[override]
    def h(self) -> float:
        return self._h

    @property
    def path(self) -> SampledPath | None:  # type: ignore[override]
        """The moving samples so far (None before two), built when asked for."""
        if self._path is None and len(self.kept) >= 2:
            self._path = SampledPath(self._p_kept, self._q_kept, self.scene.mu, self.mount,
                                     self.h)
        return self._path

    def _samples_from(self, j: int) -> tuple[FloatArray, FloatArray]:
        return self._p_kept[j:], self._q_kept[j:]

    def close(self) -> None:
        """The path ends: a robot that never moved has its first and last sample (`simulate`)."""
        self.final = True
        if len(self.kept) == 1 and len(self.t_all) > 1:
            assert self._last is not None
            self.moved[-1] = True
            self._add_kept(np.array([len(self.t_all) - 1]), self._last[0][None],
                           self._last[1][None])

    def _add_kept(self, index: NDArray[np.int64], p: FloatArray, q_WR: FloatArray) -> None:
        if not len(index):
            return
        m = len(index)
        self.kept = np.concatenate([self.kept, index])
        self._p_kept = np.vstack([self._p_kept, p])
        self._q_kept = np.vstack([self._q_kept, q_WR])
        self.phase = np.concatenate([self.phase, np.full(m, SamplePhase.NONE, dtype=np.int64)])
        self.s1 = np.concatenate([self.s1, np.full(m, np.nan)])
        self.f0, self.m0 = np.vstack([self.f0, np.zeros((m, 3))]), np.vstack([self.m0, np.zeros((m, 3))])
        self.contact = np.vstack([self.contact, np.full((m, 3), np.nan)])
        self.touched = np.concatenate([self.touched, np.full(m, -1, dtype=np.int64)])
        self.refined = np.concatenate([self.refined, np.zeros(m, dtype=bool)])
        self.second_s = np.concatenate([self.second_s, np.full(m, np.nan)])
        self.second_contact = np.vstack([self.second_contact, np.full((m, 3), np.nan)])
        self.second_touched = np.concatenate([self.second_touched, np.full(m, -1, dtype=np.int64)])
        self._path = None
        if self.run is not None and self.path is not None:
            self.run.follow(0, self.path.tail(self.k))

    def go_on(self) -> None:
        """Follow two contacts on, or start the next episode when there is none (or wait for
        samples)."""
        if self._pair is not None and self.path is not None:
            self.go_on_pair()
        if len(self.kept) < 2 or self.run is not None or self._pair is not None or self.ended:
            return
        if self._idle_at != (len(self.kept), self.final) or self._snapped is not None:
            self.start_episode()
            # waiting for samples: not again before more came
            self._idle_at = (len(self.kept), self.final) if self.run is None else (-1, False)

    def _next_sample(self) -> int:
        """The moving sample the episode's next step reaches (before longer early steps)."""
        assert self.run is not None and self.path is not None
        return self.k + math.floor(-self.run.progress(0).x0 / self.path.h + 1e-9) + 1

    def can_step(self) -> bool:
        """Whether the episode goes on, and its next step's samples are there."""
        if self.run is None or self.run.done or self.path is None:
            return False
        if self.final:
            return True
        need = self._next_sample()
        if not self.hold:
            return need <= self.path.n_samples - 1
        if self.run.early(0):
            need += EARLY_MULTIPLES[-1] - 1
        # not onto the last sample: a pose there is interpolated in the interval before it
        # (`vibrissa.frames.PoseSamples`), once more samples came in the one after it, which
        # differs in the last bit
        return need <= self.path.n_samples - 2

    def after_steps(self) -> bool:
        """Record the episode's rows clear of the other objects; end it where it ended (or met
        another object), when no later sample can change how; whether it did."""
        if self.run is None or self.path is None:
            return False
        sweep = self.run.sweeps()[0]
        if self._recorded_run is not self.run:
            self._recorded_run, self._recorded = self.run, 0
        clear = self._rows_clear_of_others(sweep, self._recorded)
        rows = self.k + np.rint(-sweep.x0 / self.path.h).astype(np.int64)
        if clear == sweep.n_steps and sweep.n_steps > self._recorded:
            start = int(rows[self._recorded - 1]) + 1 if self._recorded else self._span_start(sweep)
            self._write_rows(sweep, rows, start, int(rows[-1]), self._recorded, sweep.n_steps)
            self._recorded, self._recorded_to = sweep.n_steps, int(rows[-1]) + 1
        if clear == sweep.n_steps and not self.run.done:
            return False
        if (clear == sweep.n_steps and sweep.end is SweepEnd.SNAP_OFF and not self.final
                and (rows[-1] if len(rows) else self.k) + 2 > self.path.n_samples - 1):
            return False  # a landing needs the samples after the snap-off
        self.end_episode()
        return True

    def final_samples(self) -> int:
        """Raw samples (from the first) whose results no later sample changes."""
        if len(self.kept) < 2:
            return 0
        n = len(self.kept)
        if self.ended:
            kept_done = n
        elif self.run is not None:
            if self._recorded_run is self.run and self._recorded:
                kept_done = self._recorded_to
            else:
                progress = self.run.progress(0)
                kept_done = self.k if self._landed else self.k + round(
                    -next_grid_point(progress.x_touch, 0.0, self.h) / self.h)
        elif self._pair is not None:
            kept_done = self._pair.follower.k
        elif self._snapped is not None:
            kept_done = self.k
        else:
            kept_done = min(n, max(self.k + 1, self._searched + 1))
        # a raw sample repeats the moving sample before it: final with it
        of_sample = np.cumsum(self.moved) - 1
        return int(np.searchsorted(of_sample, self._base + kept_done, side="left"))

    def snaps_until(self, whisker: int, t_until: float) -> list[StreamSnap]:
        """The jumps (`snaps`) not told yet whose sample is at or before ``t_until``: `snaps`
        of the moving samples held and the episodes that begin among them (those before
        ended, and their jumps were told, before `forget` dropped their samples), the episode
        in progress (or the landing about to start) bounding the last one that ended. A
        snap-through is known once its episode ends: it is told then, later than its
        sample."""
        raw = np.flatnonzero(np.cumsum(self.moved) - 1 >= self._base)
        if not len(raw):
            return []
        of_sample = np.cumsum(self.moved)[raw] - 1 - self._base
        t = self.t_all[raw]
        episodes = [e for e in self.episodes if e.t_first_contact >= t[0]]
        if self._pair is not None:  # where the stretch of two contacts in progress begins
            episodes.append(Episode(self.scene.objects[self._object].name,
                                    self._time_at(self._pair.k_first - 0.5), "", [],
                                    "second-contact", self._pair_jumps(self._pair)))
        elif self.run is not None or self._snapped is not None:  # where the next one begins
            at = float(t[np.searchsorted(of_sample, self.k)]) if self.k <= of_sample[-1] else t[-1]
            episodes.append(Episode(self.scene.objects[self._object].name, at, "", [],
                                    "landing" if self.run is not None and self._landed
                                    else "touch"))
        window = WhiskerResult(
            self.whisker.name, t, self.phase[of_sample], self.s1[of_sample],
            self.f0[of_sample], self.m0[of_sample], self.contact[of_sample],
            self.touched[of_sample], self.refined[of_sample], episodes)
        told, self._pending = [], []
        for snap in snaps(window, [obj.name for obj in self.scene.objects]):
            key = (snap.t, snap.kind)
            if key in self._told:
                continue
            if snap.t > t_until:
                self._pending.append(snap)
                continue
            self._told.add(key)
            told.append(StreamSnap(whisker, snap, window.f0_n[snap.before],
                                   window.m0_nm[snap.before], window.f0_n[snap.after],
                                   window.m0_nm[snap.after]))
        return told

    def raw_results(self, rows: slice) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
        """Phase (m,), f0 (m, 3) N and m0 (m, 3) N m of raw samples ``rows``."""
        of_sample = (np.cumsum(self.moved) - 1)[rows] - self._base
        return self.phase[of_sample], self.f0[of_sample], self.m0[of_sample]

    def forget(self, sent: int) -> None:
        """Drop the moving samples before ``k`` when the whisker waits for a touch and every
        raw sample before ``sent`` is handed out: what follows depends only on the path from
        ``k`` on (a tail of the path is the same samples and coordinates, `SampledPath.tail`),
        and the path's cost stays that of the samples since then (not while a jump waits to be
        told, `snaps_until`)."""
        if (self.run is not None or self._pair is not None or self._snapped is not None
                or self.ended or self._pending
                or self.k < FORGET_SAMPLES or self.k >= len(self.kept) - 1
                or self.kept[self.k] >= sent):
            return
        b = self.k
        self._base += b
        self.kept, self._p_kept = self.kept[b:], self._p_kept[b:]
        self._q_kept = self._q_kept[b:]
        for name in ("phase", "s1", "f0", "m0", "contact", "touched", "refined", "second_s",
                     "second_contact", "second_touched"):
            setattr(self, name, getattr(self, name)[b:])
        self.k, self._searched = 0, max(self._searched - b, -1)
        self._idle_at, self._path = (-1, False), None
