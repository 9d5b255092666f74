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

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from vibrissa.frames import PoseSamples, Transform
from vibrissa.surfaces import Surface

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]

_TOUCH_ITERATIONS = 200  # bisection of the touch between two samples: to the last bit of lambda

SUBSAMPLE_L = 0.01
"""Between two samples where a point of the rod moves further than this (units of L), the
straight rod is checked at sub-samples this far apart for a touch: a rod that passes through an
object between two samples (a coarse path) touches it."""


def rod_motion(p_WR: FloatArray, rotations: Rotation, mount: Transform) -> FloatArray:
    """A bound on how far a point of the straight rod moves between consecutive samples (N-1,),
    units of L: a point at most |p_RC| + 1 from R's origin moves at most
    |dp_WR| + |dtheta| (|p_RC| + 1)."""
    turn = (rotations[:-1].inv() * rotations[1:]).magnitude()
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
    rotations : scipy.spatial.transform.Rotation, N rotations
        R_WR of the samples.
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
    rotations: Rotation
    mu: float
    mount: Transform = field(default_factory=Transform)
    h: float = 0.0
    x_end: float = field(init=False)
    x_grid: float = 0.0  # the steps of Step 1 are the samples
    _poses: PoseSamples = field(init=False, repr=False)

    def __post_init__(self) -> None:
        p = np.array(self.p_WR, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
            raise ValueError(f"p_WR must be (N >= 2, 3), got shape {p.shape}")
        if len(self.rotations) != len(p):
            raise ValueError(f"{len(self.rotations)} rotations for {len(p)} positions")
        if not np.all(np.isfinite(p)):
            raise ValueError("p_WR must be finite")
        if not self.mu >= 0:
            raise ValueError(f"mu must be >= 0, got {self.mu}")
        h = self.h or float(np.max(rod_motion(p, self.rotations, self.mount)))
        if not h > 0:
            h = 1.0  # the clamp stays put: the coordinate only counts samples
        object.__setattr__(self, "p_WR", p)
        object.__setattr__(self, "h", h)
        object.__setattr__(self, "x_end", -(len(p) - 1) * h)
        object.__setattr__(self, "_poses", PoseSamples(np.arange(len(p), dtype=float), p,
                                                       self.rotations))

    @property
    def n_samples(self) -> int:
        return len(self.p_WR)

    def tail(self, k: int) -> SampledPath:
        """The path from sample ``k`` on (its x0 = this path's x0 + k h)."""
        return SampledPath(self.p_WR[k:], self.rotations[k:], self.mu, self.mount, self.h)

    def x0_of(self, k: FloatArray) -> FloatArray:
        """The path coordinate x0 of (fractional) sample indices ``k``."""
        return -np.asarray(k, dtype=float) * self.h

    def clamp_pose(self, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Clamp poses at ``x0`` (n,): origins (n, 3) and rotations R_WC (n, 3, 3); ValueError
        outside the path (no extrapolation)."""
        lam = -np.asarray(x0, dtype=float).reshape(-1) / self.h
        last = self.n_samples - 1
        if np.any(lam < -1e-9) or np.any(lam > last + 1e-9):
            raise ValueError(f"x0 outside the path [{self.x_end}, 0]")
        p_WR, R_WR = self._poses.at(np.clip(lam, 0.0, last))
        if self.mount.is_identity:
            return p_WR, R_WR
        return p_WR + R_WR @ self.mount.translation, R_WR @ self.mount.R

    def penetrates(self, surface: Surface, x0: FloatArray) -> NDArray[np.bool_]:
        """Whether the straight rod at ``x0`` (n,) has points inside the object."""
        p, R = self.clamp_pose(x0)
        return surface.segment_inside(p, R[:, :, 2])

    def first_contact(self, surface: Surface) -> tuple[float, FloatArray] | None:
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
        inside = self.penetrates(surface, self.x0_of(grid))
        if inside[0]:
            return None  # the rod starts inside: no touch from outside here (unresolved)
        hits = np.flatnonzero(inside)
        between = self._sub_samples(surface, int(hits[0]) if len(hits) else self.n_samples - 1)
        met = self.penetrates(surface, self.x0_of(between)) if len(between) else np.zeros(0, bool)
        if np.any(met):  # the rod passes into the object between two free samples
            i = int(np.argmax(met))
            lo, hi = max(between[i - 1] if i else 0.0, math.floor(between[i])), between[i]
        elif len(hits):
            lo, hi = grid[hits[0] - 1], grid[hits[0]]
        else:
            return None
        for _ in range(_TOUCH_ITERATIONS):
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            if self.penetrates(surface, self.x0_of(np.array([mid])))[0]:
                hi = mid
            else:
                lo = mid
        x_touch = float(self.x0_of(np.array([hi]))[0])
        p, R = (a[0] for a in self.clamp_pose(np.array([x_touch])))
        t_in, t_out = surface.line_interval(p, R[:, 2])
        s = 1.0 if t_in[0] <= 1.0 <= t_out[0] else float(np.clip(0.5 * (t_in[0] + t_out[0]), 0, 1))
        return x_touch, p + s * R[:, 2]

    def _sub_samples(self, surface: Surface, end: int) -> FloatArray:
        """Fractional sample indices between samples 0 .. ``end`` where a point of the rod
        moves further than `SUBSAMPLE_L` from one sample to the next and the object is within
        the rod's reach (its clamp nearer than 1 + that motion): `SUBSAMPLE_L` apart."""
        motion = rod_motion(self.p_WR[:end + 1], self.rotations[:end + 1], self.mount)
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
