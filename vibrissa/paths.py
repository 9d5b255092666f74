"""Clamp paths for Step 1 beyond the paper's straight trail: sampled poses X_WC of a clamp.

A robot drives a path of stamped poses X_WR; a whisker mounted at X_RC has its clamp at
X_WC = X_WR X_RC. Between two samples the clamp moves as the robot interpolates: position
linear, orientation along the shortest arc (slerp, ``vibrissa.frames``). Step 1
(``vibrissa.sweep``) follows such a path by a coordinate x0 = -lambda h that decreases along it,
lambda the fractional sample index and h (units of L) the largest distance any point of the
straight rod moves between two samples, so that a step of h is one sample, as a step of the
paper's trail is one clamp displacement.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa.compiled import compiled
from vibrissa.frames import (
    Transform,
    non_unit_quaternion,
    quaternion_matrices,
    quaternion_turns,
    sampled_poses,
)
from vibrissa.rods import UNIFORM, RodShape, unloaded_polyline, unloaded_segments
from vibrissa.surfaces import Surface, line_interval_world

FloatArray = NDArray[np.float64]

_TOUCH_ITERATIONS = 200  # bisection of the touch between two samples: to the last bit of lambda

SUBSAMPLE_L = 0.01
"""Between two samples where a point of the rod moves further than this (units of L), the
straight rod is checked at sub-samples this far apart for a touch: a rod that passes through an
object between two samples (a coarse path) touches it."""


def rod_motion(p_WR: FloatArray, q_WR: FloatArray, mount: Transform) -> FloatArray:
    """A bound on how far a point of the straight rod moves between consecutive samples (N-1,)
    of robot poses (origins p_WR (N, 3), unit quaternions q_WR (N, 4)), units of L: a point at
    most |p_RC| + 1 from R's origin moves at most |dp_WR| + |dtheta| (|p_RC| + 1)."""
    turn = quaternion_turns(np.ascontiguousarray(q_WR, dtype=float))
    reach = float(np.linalg.norm(mount.translation)) + 1.0
    return np.asarray(np.linalg.norm(np.diff(p_WR, axis=0), axis=1) + turn * reach)


@dataclass(frozen=True)
class SampledPath:
    """A clamp path through robot samples ``k = 0 .. N-1`` (x0 = -k h), with friction ``mu``.

    The robot's pose X_WR is interpolated between samples (position linear, orientation slerp)
    and the clamp follows at X_WC = X_WR X_RC (``mount``; identity: the samples are the
    clamp's own poses).

    Attributes
    ----------
    p_WR : ndarray, shape (N, 3)
        Robot origins, units of L.
    q_WR : ndarray, shape (N, 4)
        R_WR of the samples as unit quaternions (x, y, z, w).
    mu : float
        Coulomb friction of the contacts.
    mount : Transform
        X_RC, the clamp on the robot, units of L (the rod leaves along C's e_z).
    h : float, optional
        Path coordinate per sample, units of L; by default the largest distance a point of
        the straight rod moves between two samples (given: a part of a longer path keeps the
        whole path's).
    """

    p_WR: FloatArray
    q_WR: FloatArray
    mu: float
    mount: Transform = field(default_factory=Transform)
    h: float = 0.0
    x_end: float = field(init=False)
    x_grid: float = 0.0  # the steps of Step 1 are the samples
    _t: FloatArray = field(init=False, repr=False)  # the samples' indices, 0 .. N-1

    def __post_init__(self) -> None:
        p = np.array(self.p_WR, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
            raise ValueError(f"p_WR must be (N >= 2, 3), got shape {p.shape}")
        q = np.ascontiguousarray(self.q_WR, dtype=float)
        if q.shape != (len(p), 4):
            raise ValueError(f"q_WR must be ({len(p)}, 4) for {len(p)} positions, got {q.shape}")
        bad = non_unit_quaternion(q)
        if bad is not None:
            raise ValueError(f"q_WR row {bad[0]} is not a unit quaternion (norm {bad[1]:.9g})")
        if not np.all(np.isfinite(p)):
            raise ValueError("p_WR must be finite")
        if not self.mu >= 0:
            raise ValueError(f"mu must be >= 0, got {self.mu}")
        h = self.h or float(np.max(rod_motion(p, q, self.mount)))
        if not h > 0:
            h = 1.0  # the clamp stays put: the coordinate only counts samples
        object.__setattr__(self, "p_WR", p)
        object.__setattr__(self, "q_WR", q)
        object.__setattr__(self, "h", h)
        object.__setattr__(self, "x_end", -(len(p) - 1) * h)
        object.__setattr__(self, "_t", np.arange(len(p), dtype=float))

    @property
    def n_samples(self) -> int:
        return len(self.p_WR)

    def tail(self, k: int) -> SampledPath:
        """The path from sample ``k`` on (its x0 = this path's x0 + k h)."""
        return SampledPath(self.p_WR[k:], self.q_WR[k:], self.mu, self.mount, self.h)

    def x0_of(self, k: FloatArray) -> FloatArray:
        """The path coordinate x0 of (fractional) sample indices ``k``."""
        return -np.asarray(k, dtype=float) * self.h

    @functools.cached_property
    def _travelled(self) -> list[float]:
        """The straight rod's travel (`rod_motion` summed) from sample 0 to each sample (N,),
        units of L (a list: Step 1 reads it a float at a time)."""
        motion = rod_motion(self.p_WR, self.q_WR, self.mount)
        return [0.0, *np.cumsum(motion).tolist()]

    def _travelled_at(self, x0: float) -> float:
        at, total = -x0 / self.h, self._travelled
        if at <= 0.0:
            return 0.0
        k = min(int(at), len(total) - 2)
        return total[k] + (min(at, len(total) - 1.0) - k) * (total[k + 1] - total[k])

    def travel(self, x_from: float, x_to: float) -> float:
        """How far the straight rod moves from ``x_from`` to ``x_to`` <= ``x_from``, units of
        L (`rod_motion` summed over the samples, linear within one): at most ``x_from -
        x_to``, the coordinate advancing ``h`` a sample, at least the rod's motion."""
        return self._travelled_at(x_to) - self._travelled_at(x_from)

    def travel_end(self, x_from: float, travel: float) -> float:
        """The coordinate x0 <= ``x_from`` at which the straight rod has moved ``travel``
        (units of L, as `travel` measures it) since ``x_from``; ``x_end`` where it never
        does."""
        total = self._travelled
        goal = self._travelled_at(x_from) + travel
        k = bisect.bisect_left(total, goal)  # total[k - 1] < goal <= total[k]
        if k >= len(total):
            return self.x_end
        k = max(k, 1)
        return -(k - 1 + (goal - total[k - 1]) / (total[k] - total[k - 1])) * self.h

    def clamp_pose(self, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Clamp poses at ``x0`` (n,): origins (n, 3) and rotations R_WC (n, 3, 3); ValueError
        outside the path (no extrapolation)."""
        p_WC, R_WC, within = clamp_poses(-np.asarray(x0, dtype=float).reshape(-1) / self.h,
                                         self._t, self.p_WR, self.q_WR, self.mount.translation,
                                         self.mount.R)
        if not within:
            raise ValueError(f"x0 outside the path [{self.x_end}, 0]")
        return p_WC, R_WC

    def penetrates(self, surface: Surface, x0: FloatArray, shape: RodShape = UNIFORM
                   ) -> NDArray[np.bool_]:
        """Whether the unloaded rod of ``shape`` (straight by default) at ``x0`` (n,) has
        points inside the object (of its `unloaded_polyline`)."""
        p, R = self.clamp_pose(x0)
        starts, chords = unloaded_segments(shape, p, R)
        inside = surface.segment_inside(starts, chords).reshape(len(p), -1)
        return np.any(inside, axis=1)

    def first_contact(self, surface: Surface, shape: RodShape = UNIFORM
                      ) -> tuple[float, FloatArray] | None:
        """The first x0 where the straight rod, free just before, touches the object, and the
        touch point in W: the tip, or the point of a side graze (the rod's line tangent to the
        object with 0 < s < 1). None when it never does on the path, or when the rod starts
        inside the object (use ``tail`` to search from a later sample).

        The rod is checked at the samples, and between two where it moves further than
        `SUBSAMPLE_L` near the object, at sub-samples; between the last free one and the first
        that penetrates, the touch is found by bisection of the fractional sample index to the
        last bit.
        """
        grid = np.arange(self.n_samples, dtype=float)
        inside = self.penetrates(surface, self.x0_of(grid), shape)
        if inside[0]:
            return None  # the rod starts inside: no touch from outside here (unresolved)
        hits = np.flatnonzero(inside)
        between = self._sub_samples(surface, int(hits[0]) if len(hits) else self.n_samples - 1)
        met = (self.penetrates(surface, self.x0_of(between), shape) if len(between)
               else np.zeros(0, bool))
        if np.any(met):  # the rod passes into the object between two free samples
            i = int(np.argmax(met))
            lo, hi = max(between[i - 1] if i else 0.0, math.floor(between[i])), between[i]
        elif len(hits):
            lo, hi = grid[hits[0] - 1], grid[hits[0]]
        else:
            return None
        Q, linear, c, R_WB, p_WB = surface.kernel_arrays
        vertices = unloaded_polyline(shape)
        hi = _touch_bisection(float(lo), float(hi), self.h, self._t, self.p_WR, self.q_WR,
                              self.mount.translation, self.mount.R, Q[0], linear[0], float(c[0]),
                              R_WB[0], p_WB[0], vertices)
        x_touch = float(self.x0_of(np.array([hi]))[0])
        p, R = (a[0] for a in self.clamp_pose(np.array([x_touch])))
        if shape.precurvature == 0.0:
            t_in, t_out = surface.line_interval(p, R[:, 2])
            s = 1.0 if t_in[0] <= 1.0 <= t_out[0] else float(
                np.clip(0.5 * (t_in[0] + t_out[0]), 0, 1))
            return x_touch, p + s * R[:, 2]
        starts, chords = unloaded_segments(shape, p[None], R[None])
        t_in, t_out = surface.line_interval(starts, chords)
        with np.errstate(invalid="ignore"):
            meets = np.flatnonzero((t_in < 1.0) & (t_out > 0.0))
        k = int(meets[0]) if len(meets) else len(chords) - 1  # the chord nearest the clamp
        last = k == len(chords) - 1
        t = 1.0 if last and t_in[k] <= 1.0 <= t_out[k] else float(
            np.clip(0.5 * (t_in[k] + t_out[k]), 0, 1))
        return x_touch, starts[k] + t * chords[k]

    def _sub_samples(self, surface: Surface, end: int) -> FloatArray:
        """Fractional sample indices between samples 0 .. ``end`` where a point of the rod
        moves further than `SUBSAMPLE_L` from one sample to the next and the object is within
        the rod's reach (its clamp nearer than 1 + that motion): `SUBSAMPLE_L` apart."""
        motion = rod_motion(self.p_WR[:end + 1], self.q_WR[:end + 1], self.mount)
        coarse = np.flatnonzero(motion > SUBSAMPLE_L)
        if len(coarse) == 0:
            return np.zeros(0)
        p_WC = self.clamp_pose(self.x0_of(coarse.astype(float)))[0]
        near = coarse[surface.signed_distance(p_WC) <= 1.0 + motion[coarse]]
        parts = [k + np.arange(1, n) / n
                 for k, n in zip(near, np.ceil(motion[near] / SUBSAMPLE_L).astype(np.int64),
                                 strict=True)]
        return np.concatenate(parts) if parts else np.zeros(0)

    def symmetric(self, surface: Surface) -> bool:
        """Never assumed for a general path (psi is solved for)."""
        return False



@compiled
def clamp_poses(lam: FloatArray, t_s: FloatArray, p_WR: FloatArray, q_WR: FloatArray,
                p_RC: FloatArray, R_RC: FloatArray) -> tuple[FloatArray, FloatArray, bool]:
    """Clamp origins (n, 3) and R_WC (n, 3, 3) at fractional sample indices ``lam`` (n,),
    clipped to the samples' range, and whether every one was within it (to 1e-9): the robot's
    samples at ``t_s`` = 0 .. N-1 (p_WR (N, 3), unit q_WR (N, 4)) interpolated by
    `sampled_poses`, the clamp mounted at (p_RC, R_RC)."""
    last = t_s[-1]
    within = True
    for value in lam:
        within &= -1e-9 <= value <= last + 1e-9
    p, q = sampled_poses(t_s, p_WR, q_WR, np.minimum(np.maximum(lam, 0.0), last))
    R_WR = quaternion_matrices(q)[0]
    n = lam.shape[0]
    p_WC, R_WC = np.empty((n, 3)), np.empty((n, 3, 3))
    for k in range(n):
        for i in range(3):
            p_WC[k, i] = p[k, i] + (R_WR[k, i, 0] * p_RC[0] + R_WR[k, i, 1] * p_RC[1]
                                    + R_WR[k, i, 2] * p_RC[2])
            for j in range(3):
                R_WC[k, i, j] = (R_WR[k, i, 0] * R_RC[0, j] + R_WR[k, i, 1] * R_RC[1, j]
                                 + R_WR[k, i, 2] * R_RC[2, j])
    return p_WC, R_WC, within


@compiled
def _touch_bisection(lo: float, hi: float, h: float, t_s: FloatArray, p_WR: FloatArray,
                     q_WR: FloatArray, p_RC: FloatArray, R_RC: FloatArray, Q: FloatArray,
                     linear: FloatArray, c: float, R_WB: FloatArray, p_WB: FloatArray,
                     vertices: FloatArray) -> float:
    """The first fractional sample index in (lo, hi] where the unloaded rod (the polyline of
    ``vertices`` (K + 1, 3) in C, `vibrissa.rods.unloaded_polyline`, clamped as `clamp_poses`
    says) enters the object (the quadric (Q, linear, c) at (R_WB, p_WB)), by bisection to the
    last bit: free at ``lo``, inside at ``hi``. Each index k is tried where `SampledPath.clamp_pose`
    puts its x0 = -k h (``h`` the path's step): the touch found is inside there."""
    lam = np.empty(1)
    for _ in range(_TOUCH_ITERATIONS):
        mid = 0.5 * (lo + hi)
        if mid == lo or mid == hi:
            break
        lam[0] = -(-mid * h) / h  # as clamp_pose(x0_of(mid))
        p_WC, R_WC, _ = clamp_poses(lam, t_s, p_WR, q_WR, p_RC, R_RC)
        p, R = p_WC[0], R_WC[0]
        inside = False
        for k in range(vertices.shape[0] - 1):
            v, w = vertices[k], vertices[k + 1]
            dx, dy, dz = w[0] - v[0], w[1] - v[1], w[2] - v[2]
            t_in, t_out = line_interval_world(
                p[0] + R[0, 0] * v[0] + R[0, 1] * v[1] + R[0, 2] * v[2],
                p[1] + R[1, 0] * v[0] + R[1, 1] * v[1] + R[1, 2] * v[2],
                p[2] + R[2, 0] * v[0] + R[2, 1] * v[1] + R[2, 2] * v[2],
                R[0, 0] * dx + R[0, 1] * dy + R[0, 2] * dz,
                R[1, 0] * dx + R[1, 1] * dy + R[1, 2] * dz,
                R[2, 0] * dx + R[2, 1] * dy + R[2, 2] * dz, Q, linear, c, R_WB, p_WB)
            if t_in < 1.0 and t_out > 0.0:  # the chord 0 <= t <= 1 meets the inside
                inside = True
                break
        if inside:
            hi = mid
        else:
            lo = mid
    return hi

@dataclass(frozen=True)
class PathLimits:
    """What a commanded robot accepts (`CommandedPath`).

    Attributes
    ----------
    rate_hz : float
        Path samples per second of path time: the robot's pose is sampled every 1 / rate_hz s.
    max_speed_mps : float
        Largest commanded speed of the robot's origin, m/s.
    max_turn_rate_rps : float
        Largest commanded turn rate, rad/s.
    max_jump_m, max_jump_rad : float
        Largest distance (m) and turn (rad) from the pose a segment starts from to its first
        waypoint: a command further off is refused (a wrong frame, a stale plan).
    max_queued_s : float
        Most path time queued at once, s: a segment that would queue more (a leg of many km,
        or at a crawl) is refused, so that what a robot holds stays bounded (600 s at 500 Hz:
        300 000 poses, 17 MB).
    """

    rate_hz: float = 500.0
    max_speed_mps: float = 0.1
    max_turn_rate_rps: float = 1.0
    max_jump_m: float = 0.1
    max_jump_rad: float = 0.5
    max_queued_s: float = 600.0

    def __post_init__(self) -> None:
        for name in ("rate_hz", "max_speed_mps", "max_turn_rate_rps", "max_jump_m",
                     "max_jump_rad", "max_queued_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")

    def rod_step(self, mount: Transform, length_m: float) -> float:
        """The largest distance a point of a straight rod of ``length_m`` mounted at ``mount``
        (X_RC, m) moves in one sample at the largest speeds, units of L (`rod_motion`'s bound):
        Step 1's step ``h`` along a commanded path."""
        reach_m = float(np.linalg.norm(mount.translation)) + length_m
        return (self.max_speed_mps + self.max_turn_rate_rps * reach_m) / self.rate_hz / length_m


def check_segment(limits: PathLimits, p_start: ArrayLike, q_start_xyzw: ArrayLike,
                  position: ArrayLike, orientation_xyzw: ArrayLike, speed_mps: float,
                  turn_rate_rps: float) -> str | None:
    """Why a segment of waypoints (positions (N, 3) m, unit quaternions (N, 4)) driven from
    the pose (``p_start``, ``q_start_xyzw``) at ``speed_mps`` and ``turn_rate_rps`` is refused,
    or None when it is accepted: no waypoint, non-finite numbers, a quaternion that is not
    unit, a speed or turn rate not in (0, the limit], a first waypoint beyond ``max_jump_m`` or
    ``max_jump_rad`` from the start."""
    p = np.asarray(position, dtype=float)
    q = np.asarray(orientation_xyzw, dtype=float)
    if p.ndim != 2 or p.shape[1:] != (3,) or q.shape != (len(p), 4) or len(p) == 0:
        return f"waypoints need positions (N >= 1, 3) and quaternions (N, 4), got {p.shape} " \
               f"and {q.shape}"
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        return "waypoints hold non-finite numbers"
    bad = non_unit_quaternion(q)
    if bad is not None:
        return f"waypoint {bad[0]}: quaternion of norm {bad[1]:.9g} is not unit"
    for name, value, limit, unit in (("speed_mps", speed_mps, limits.max_speed_mps, "m/s"),
                                     ("turn_rate_rps", turn_rate_rps, limits.max_turn_rate_rps,
                                      "rad/s")):
        if not 0 < value <= limit:
            return f"{name} {value!r} not in (0, {limit:g}] {unit}"
    from scipy.spatial.transform import Rotation  # on first use (vibrissa.frames)

    jump_m = float(np.linalg.norm(p[0] - np.asarray(p_start, dtype=float)))
    turn = float((Rotation.from_quat(q_start_xyzw).inv() * Rotation.from_quat(q[0])).magnitude())
    if jump_m > limits.max_jump_m or turn > limits.max_jump_rad:
        return (f"the first waypoint is {jump_m:.4g} m and {turn:.4g} rad from where the segment "
                f"starts (at most {limits.max_jump_m:g} m, {limits.max_jump_rad:g} rad)")
    return None


def leg_durations_s(p_start: ArrayLike, q_start_xyzw: ArrayLike, position: ArrayLike,
                    orientation_xyzw: ArrayLike, speed_mps: float, turn_rate_rps: float
                    ) -> FloatArray:
    """How long each leg of a segment takes (from one pose to the next waypoint), s:
    max(distance / ``speed_mps``, angle / ``turn_rate_rps``) (inf where that overflows)."""
    from scipy.spatial.transform import Rotation  # on first use (vibrissa.frames)

    p = np.vstack([np.asarray(p_start, dtype=float)[None], np.asarray(position, dtype=float)])
    q = np.vstack([np.asarray(q_start_xyzw, dtype=float)[None],
                   np.asarray(orientation_xyzw, dtype=float)])
    with np.errstate(over="ignore"):
        distance = np.linalg.norm(np.diff(p, axis=0), axis=1)
        turn = quaternion_turns(np.ascontiguousarray(Rotation.from_quat(q).as_quat()))
        return np.maximum(distance / speed_mps, turn / turn_rate_rps)


def waypoint_samples(p_start: ArrayLike, q_start_xyzw: ArrayLike, position: ArrayLike,
                     orientation_xyzw: ArrayLike, speed_mps: float, turn_rate_rps: float,
                     rate_hz: float) -> tuple[FloatArray, FloatArray]:
    """The robot's poses X_WR every 1 / ``rate_hz`` s from the start pose through the
    waypoints, the start excluded: positions (M, 3) m and unit quaternions (M, 4) (x, y, z, w).

    Each leg, from one pose to the next waypoint, takes n = ceil(T rate_hz) samples with T its
    duration (`leg_durations_s`: at most those speeds), at fractions j / n (j = 1 .. n;
    position linear, orientation slerp as `PoseSamples`), its last sample the waypoint itself,
    to the bit; a waypoint where the robot already is adds none.
    """
    from scipy.spatial.transform import Rotation  # on first use (vibrissa.frames)

    p = np.vstack([np.asarray(p_start, dtype=float)[None], np.asarray(position, dtype=float)])
    q = np.vstack([np.asarray(q_start_xyzw, dtype=float)[None],
                   np.asarray(orientation_xyzw, dtype=float)])
    rotations = Rotation.from_quat(q)
    duration = leg_durations_s(p_start, q_start_xyzw, position, orientation_xyzw, speed_mps,
                               turn_rate_rps)
    counts = np.where(duration > 0, np.ceil(duration * rate_hz - 1e-9), 0).astype(np.int64)
    counts[(duration > 0) & (counts == 0)] = 1
    legs = np.repeat(np.arange(len(counts)), counts)
    fraction = np.concatenate([np.arange(1, n + 1) / n for n in counts] or [np.zeros(0)])
    positions = p[legs] + fraction[:, None] * (p[legs + 1] - p[legs])
    turns = (rotations[:-1].inv() * rotations[1:]).as_rotvec()
    quaternions = (rotations[legs] * Rotation.from_rotvec(fraction[:, None] * turns[legs])).as_quat() \
        if len(legs) else np.zeros((0, 4))
    ends = np.cumsum(counts)[counts > 0] - 1  # each leg's last sample: its waypoint
    positions[ends] = p[1:][counts > 0]
    quaternions[ends] = q[1:][counts > 0]
    return positions, quaternions


class CommandedPath:
    """A robot's path as it is commanded: segments of waypoints queued as poses every
    1 / ``limits.rate_hz`` s (`waypoint_samples`), taken sample by sample by whoever drives
    the robot (a simulation, a driver).

    The robot starts at (``p_start``, ``q_start_xyzw``). A segment is driven from the end of
    the queue (``replace`` False) or, the queue dropped, from the last pose taken (``replace``
    True); `command` refuses a bad one (`check_segment`, or one that would queue more than
    ``limits.max_queued_s`` of path time) with the reason, and the queue is then as before.
    """

    def __init__(self, limits: PathLimits, p_start: ArrayLike, q_start_xyzw: ArrayLike) -> None:
        self.limits = limits
        self._taken = (np.array(p_start, dtype=float), np.array(q_start_xyzw, dtype=float))
        self._p: FloatArray = np.zeros((0, 3))
        self._q: FloatArray = np.zeros((0, 4))

    @property
    def queued(self) -> int:
        """Samples queued and not yet taken."""
        return len(self._p)

    @property
    def last_taken(self) -> tuple[FloatArray, FloatArray]:
        """The robot's last pose taken (the start before any): position (3,) m, quaternion (4,)."""
        return self._taken

    def command(self, position: ArrayLike, orientation_xyzw: ArrayLike, speed_mps: float,
                turn_rate_rps: float, replace: bool = False) -> str | None:
        """Queue a segment of waypoints (positions (N, 3) m, unit quaternions (N, 4)); the
        reason it is refused, or None."""
        p0, q0 = self._taken if replace or not self.queued else (self._p[-1], self._q[-1])
        why = check_segment(self.limits, p0, q0, position, orientation_xyzw, speed_mps,
                            turn_rate_rps)
        if why is not None:
            return why
        room_s = self.limits.max_queued_s - (0 if replace else self.queued / self.limits.rate_hz)
        duration_s = float(leg_durations_s(p0, q0, position, orientation_xyzw, speed_mps,
                                           turn_rate_rps).sum())
        if not duration_s <= room_s:
            return (f"it takes {duration_s:.4g} s to drive, more than the {room_s:.4g} s of path "
                    f"time left in the queue (max_queued_s {self.limits.max_queued_s:g})")
        p, q = waypoint_samples(p0, q0, position, orientation_xyzw, speed_mps, turn_rate_rps,
                                self.limits.rate_hz)
        if replace:
            self._p, self._q = p, q
        else:
            self._p, self._q = np.vstack([self._p, p]), np.vstack([self._q, q])
        return None

    def take(self, n: int) -> tuple[FloatArray, FloatArray]:
        """The next ``n`` queued samples at most, off the queue: positions (m, 3), quaternions
        (m, 4)."""
        p, q = self._p[:n], self._q[:n]
        self._p, self._q = self._p[n:], self._q[n:]
        if len(p):
            self._taken = (p[-1], q[-1])
        return p, q
