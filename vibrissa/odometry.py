"""A robot's odometry that drifts (`OdometryDrift`): the pose ``odom -> base_link`` (REP 105) it
reports along its true path, and the transform ``map -> odom`` that its error is.

The model is a planar random walk per metre travelled, the usual one of wheel odometry: between
two consecutive true poses the base moves d metres in the floor's plane (x, y of the map
frame, z up: REP 103), and the odometry's error grows by a heading error drawn from
N(0, D^2 d) rad, a rotation about where the base is, and a position error drawn from
N(0, D^2 d) m along x and along y. D (``drift_per_m``) is thus the standard deviation of
either after one metre, D sqrt(d) after d metres when the heading error's lever is left out.
Height, roll and pitch are exact. The odometry starts at the true pose: ``map -> odom`` is the
identity at the first pose.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class OdometryDrift:
    """The odometry of a robot along its true path, drifting (see the module).

    Parameters
    ----------
    drift_per_m
        D: standard deviation of the position (m, per axis) and heading (rad) random walks
        after one metre travelled; 0: the odometry is the true pose, bit for bit.
    rng
        Draws the errors: three normal deviates per pose that moved, in pose order.

    `odom` takes the true poses in order, a call after another carrying the error on; `error`
    is ``map -> odom`` after the last pose taken: (x, y, yaw) in m and rad.
    """

    def __init__(self, drift_per_m: float, rng: np.random.Generator) -> None:
        if not (math.isfinite(drift_per_m) and drift_per_m >= 0):
            raise ValueError(f"drift_per_m must be a finite number >= 0, got {drift_per_m!r}")
        self.drift_per_m = drift_per_m
        self.rng = rng
        self.yaw = 0.0
        self.xy = np.zeros(2)
        self._last_xy: FloatArray | None = None

    @property
    def error(self) -> tuple[float, float, float]:
        """``map -> odom`` now: its translation x, y (m) and its yaw about z (rad)."""
        return float(self.xy[0]), float(self.xy[1]), self.yaw

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
                d = math.hypot(here[0] - self._last_xy[0], here[1] - self._last_xy[1])
                if d > 0.0:
                    dyaw, dx, dy = self.rng.normal(0.0, self.drift_per_m * math.sqrt(d), 3)
                    c, s = math.cos(dyaw), math.sin(dyaw)
                    r = self.xy - here  # the error turns about the base, then shifts
                    self.xy = here + np.array([c * r[0] - s * r[1], s * r[0] + c * r[1]]) \
                        + np.array([dx, dy])
                    self.yaw += dyaw
            self._last_xy = here.copy()
            # odom -> base_link = (map -> odom)^-1 (map -> base_link)
            c, s = math.cos(self.yaw), math.sin(self.yaw)
            r = p_WR[k, :2] - self.xy
            p_OR[k, :2] = (c * r[0] + s * r[1], -s * r[0] + c * r[1])
            half = -0.5 * self.yaw  # Rz(-yaw) q
            w1, z1 = math.cos(half), math.sin(half)
            x2, y2, z2, w2 = q_WR[k]
            q_OR[k] = (w1 * x2 - z1 * y2, w1 * y2 + z1 * x2, w1 * z2 + z1 * w2, w1 * w2 - z1 * z2)
            errors[k] = (self.xy[0], self.xy[1], self.yaw)
        return p_OR, q_OR, errors
