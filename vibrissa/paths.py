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

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from vibrissa.surfaces import Surface

FloatArray = NDArray[np.float64]

_TOUCH_ITERATIONS = 200  # bisection of the touch between two samples: to the last bit of lambda


@dataclass(frozen=True)
class SampledPath:
    """A clamp path through samples ``k = 0 .. N-1`` (x0 = -k h), with friction ``mu``.

    Attributes
    ----------
    p_WC : ndarray, shape (N, 3)
        Clamp origins, units of L.
    rotations : scipy.spatial.transform.Rotation, N rotations
        R_WC of the samples (the rod leaves along C's e_z).
    mu : float
        Coulomb friction of the contacts.
    """

    p_WC: FloatArray
    rotations: Rotation
    mu: float
    h: float = field(init=False)
    x_end: float = field(init=False)
    x_grid: float = 0.0  # the steps of Step 1 are the samples
    _slerp: Slerp = field(init=False, repr=False)

    def __post_init__(self) -> None:
        p = np.array(self.p_WC, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
            raise ValueError(f"p_WC must be (N >= 2, 3), got shape {p.shape}")
        if len(self.rotations) != len(p):
            raise ValueError(f"{len(self.rotations)} rotations for {len(p)} positions")
        if not np.all(np.isfinite(p)):
            raise ValueError("p_WC must be finite")
        if not self.mu >= 0:
            raise ValueError(f"mu must be >= 0, got {self.mu}")
        # The rod's points move at most |dp| + |dtheta| (its length is 1) between samples.
        turn = (self.rotations[:-1].inv() * self.rotations[1:]).magnitude()
        travel = np.linalg.norm(np.diff(p, axis=0), axis=1) + turn
        h = float(np.max(travel))
        if not h > 0:
            raise ValueError("the clamp does not move along the path")
        object.__setattr__(self, "p_WC", p)
        object.__setattr__(self, "h", h)
        object.__setattr__(self, "x_end", -(len(p) - 1) * h)
        object.__setattr__(self, "_slerp", Slerp(np.arange(len(p), dtype=float), self.rotations))

    @property
    def n_samples(self) -> int:
        return len(self.p_WC)

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
        lam = np.clip(lam, 0.0, last)
        k = np.minimum(np.floor(lam).astype(np.int64), last - 1)
        frac = lam - k
        p = self.p_WC[k] + frac[:, None] * (self.p_WC[k + 1] - self.p_WC[k])
        return p, self._slerp(lam).as_matrix()

    def penetrates(self, surface: Surface, x0: FloatArray) -> NDArray[np.bool_]:
        """Whether the straight rod at ``x0`` (n,) has points inside the object."""
        p, R = self.clamp_pose(x0)
        t_in, t_out = surface.line_interval(p, R[:, :, 2])
        with np.errstate(invalid="ignore"):
            return (t_in < 1.0) & (t_out > 0.0)

    def first_contact(self, surface: Surface, after: float = 0.0
                      ) -> tuple[float, FloatArray] | None:
        """The first x0 <= ``after`` where the straight rod, free just before, touches the
        object, and the touch point in W: the tip, or the point of a side graze (the rod's
        line tangent to the object with 0 < s < 1). None when it never does on the path.

        Between the last free sample and the first one that penetrates, the touch is found
        by bisection of the fractional sample index to the last bit.
        """
        start = -after / self.h
        k_first = int(math.floor(start + 1e-9))
        grid = np.concatenate([[start], np.arange(k_first + 1, self.n_samples, dtype=float)])
        inside = self.penetrates(surface, self.x0_of(grid))
        if inside[0]:
            return None  # the rod starts inside: no touch from outside here (unresolved)
        hits = np.flatnonzero(inside)
        if len(hits) == 0:
            return None
        lo, hi = grid[hits[0] - 1], grid[hits[0]]
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

    def symmetric(self, surface: Surface) -> bool:
        """Never assumed for a general path (psi is solved for)."""
        return False
