"""A robot's odometry that drifts (`OdometryDrift`): the pose ``odom -> base_link`` (REP 105) it
reports along its true path, and the transform ``map -> odom`` that its error is.

The model is a planar random walk per metre travelled, the usual one of wheel odometry: over
each ``step_m`` (10 mm) of the base's travel in the floor's plane (x, y of the map frame, z
up: REP 103) the odometry's error grows by a heading error drawn from N(0, D^2 step_m) rad, a
rotation about where the base is when the step begins, and a position error drawn from
N(0, D^2 step_m) m along x and along y; within a step the error changes linearly with the
travel (an odometry's error grows smoothly: drawn at every pose of a finely sampled path it
would jitter by as much as the pose's own motion). D (``drift_per_m``) is thus the standard
deviation of either after one metre, D sqrt(d) after d metres when the heading error's lever
is left out. Height, roll and pitch are exact. The odometry starts at the true pose: ``map ->
odom`` is the identity at the first pose.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def drift_rng(seed: int) -> np.random.Generator:
    """The draws of the drift of a run seeded ``seed``: apart from the wrench noise's, which
    ``numpy.random.default_rng(seed)`` draws."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))


class OdometryDrift:
    """The odometry of a robot along its true path, drifting (see the module).

    Parameters
    ----------
    drift_per_m
        D: standard deviation of the position (m, per axis) and heading (rad) random walks
        after one metre travelled; 0: the odometry is the true pose, bit for bit.
    rng
        Draws the errors: three normal deviates per step of travel, in order.
    step_m
        The travel over which one error increment is drawn, m.

    `odom` takes the true poses in order, a call after another carrying the error on; `error`
    is ``map -> odom`` after the last pose taken: (x, y, yaw) in m and rad.
    """

    def __init__(self, drift_per_m: float, rng: np.random.Generator, step_m: float = 0.01
                 ) -> None:
        if not (math.isfinite(drift_per_m) and drift_per_m >= 0):
            raise ValueError(f"drift_per_m must be a finite number >= 0, got {drift_per_m!r}")
        if not (math.isfinite(step_m) and step_m > 0):
            raise ValueError(f"step_m must be a finite number > 0, got {step_m!r}")
        self.drift_per_m = drift_per_m
        self.rng = rng
        self.step_m = step_m
        self._from = np.zeros(3)  # the error at the step's start and end: x, y (m), yaw (rad)
        self._to: FloatArray | None = None
        self._done = 0.0  # travel into the step, m
        self._last_xy: FloatArray | None = None
        self._now = np.zeros(3)

    @property
    def error(self) -> tuple[float, float, float]:
        """``map -> odom`` now: its translation x, y (m) and its yaw about z (rad)."""
        return float(self._now[0]), float(self._now[1]), float(self._now[2])

    def _next(self, here: FloatArray) -> FloatArray:
        """The error at the end of a step that begins with the base at ``here`` (2,)."""
        dyaw, dx, dy = self.rng.normal(0.0, self.drift_per_m * math.sqrt(self.step_m), 3)
        c, s = math.cos(dyaw), math.sin(dyaw)
        r = self._from[:2] - here  # the error turns about the base, then shifts
        return np.array([here[0] + c * r[0] - s * r[1] + dx, here[1] + s * r[0] + c * r[1] + dy,
                         self._from[2] + dyaw])

    def odom(self, p_WR: FloatArray, q_WR: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The odometry's poses of the true poses X_WR (n, 3) m and (n, 4) (x, y, z, w): the
        positions (n, 3) and quaternions (n, 4) of ``odom -> base_link``, and ``map -> odom``
        at each pose (n, 3): x, y (m), yaw (rad)."""
        p_WR = np.reshape(np.asarray(p_WR, dtype=np.float64), (-1, 3))
        q_WR = np.reshape(np.asarray(q_WR, dtype=np.float64), (-1, 4))
        errors = np.zeros((len(p_WR), 3))
        if self.drift_per_m == 0.0:
            return p_WR.copy(), q_WR.copy(), errors
        p_OR, q_OR = p_WR.copy(), q_WR.copy()
        for k in range(len(p_WR)):
            here = p_WR[k, :2]
            if self._last_xy is not None:
                self._done += math.hypot(here[0] - self._last_xy[0], here[1] - self._last_xy[1])
                while self._done >= self.step_m:  # steps completed
                    if self._to is None:
                        self._to = self._next(self._last_xy)
                    self._from, self._to = self._to, None
                    self._done -= self.step_m
                if self._done > 0.0 and self._to is None:
                    self._to = self._next(self._last_xy)
                f = self._done / self.step_m
                self._now = self._from if self._to is None else (1 - f) * self._from + f * self._to
            self._last_xy = here.copy()
            # odom -> base_link = (map -> odom)^-1 (map -> base_link)
            x, y, yaw = self._now
            c, s = math.cos(yaw), math.sin(yaw)
            r = (p_WR[k, 0] - x, p_WR[k, 1] - y)
            p_OR[k, :2] = (c * r[0] + s * r[1], -s * r[0] + c * r[1])
            half = -0.5 * yaw  # Rz(-yaw) q
            w1, z1 = math.cos(half), math.sin(half)
            x2, y2, z2, w2 = q_WR[k]
            q_OR[k] = (w1 * x2 - z1 * y2, w1 * y2 + z1 * x2, w1 * z2 + z1 * w2, w1 * w2 - z1 * z2)
            errors[k] = self._now
        return p_OR, q_OR, errors
