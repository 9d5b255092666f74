"""Rods as they are built: linearly tapered, pre-curved, as Kirchhoff rods (bending and torsion).

Units are the paper's (eq. 1) with the *base's* stiffness: lengths in L, forces in EI/L^2,
moments in EI/L, EI the bending stiffness at the clamp. The clamp frame C: the rod leaves the
clamp point (the origin) along e_z, its material frame there is (d1, d2, d3) = (e_x, e_y, e_z).

* A circular section tapering linearly from the clamp to the tip, tip diameter over base
  diameter ``taper_ratio`` = r: EI(s) = (1 - (1 - r) s)^4 about both section axes, torsion
  GJ(s) = EI(s) / (1 + nu) (``poisson_ratio`` nu).
* The unloaded rod is a planar circular arc of curvature ``precurvature`` (1/L) bending towards
  the clamp's +x axis: the natural Darboux vector is (0, kappa_hat, 0) in (d1, d2, d3).

Statics of one point force F on the rod at arc length s1 (the part beyond s1 carries nothing):
the internal force is F and the internal moment (of the part beyond s on the part before it,
about r(s)) m(s) = (r(s1) - r(s)) x F; with the clamp's reactions on the rod f0 = -F,
m0 = -r(s1) x F this is m(s) = r(s) x f0 - m0, known along the rod from the clamp's wrench alone.
The Kirchhoff rod: r' = d3, d_i' = u x d_i, u = (kappa_hat e_2 + B(s)^-1 m) in material
components, B = diag(EI, EI, GJ). Integrated from the clamp by the classical Runge-Kutta
method on ``N_STEPS`` steps per L, orientation as a unit quaternion: a wrench gives the rod's
line and its moment along it (Step 2); a contact force and s1 give the wrench by Newton's
method on m0 (the forward problem, :func:`clamp_wrench`).

The straight uniform rod (r = 1, kappa_hat = 0) is the planar elastica with its closed form
(``vibrissa.elastica``); the callers use that for it.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vibrissa.compiled import compiled

FloatArray = NDArray[np.float64]

N_STEPS = 40
"""Runge-Kutta steps per rod length."""
MIN_TAPER = 0.05
"""The thinnest tip a rod may have, as a fraction of its base's diameter (EI down to 6e-6 of
the base's)."""
MAX_PRECURVATURE = 2.0 * math.pi
"""The largest pre-curvature, 1/L: a full circle."""
UNLOADED_CHORDS = 64
"""Chords of the polyline that stands for an unloaded pre-curved rod where the object is
searched along it (a touch, a rod inside an object): within kappa_hat / (8 * 64^2) of the arc,
2e-4 L at a full circle."""


@dataclass(frozen=True)
class RodShape:
    """How a rod differs from a straight uniform cylinder (dimensionless).

    Attributes
    ----------
    taper_ratio : float
        Tip diameter over base diameter, in [``MIN_TAPER``, 1].
    precurvature : float
        Curvature of the unloaded rod, 1/L, towards the clamp's +x axis (negative: -x).
    poisson_ratio : float
        nu of the material, for the torsional stiffness GJ = EI / (1 + nu); in [0, 0.5].
    """

    taper_ratio: float = 1.0
    precurvature: float = 0.0
    poisson_ratio: float = 0.3

    def __post_init__(self) -> None:
        if not MIN_TAPER <= self.taper_ratio <= 1.0:
            raise ValueError(f"taper_ratio must be in [{MIN_TAPER}, 1], got {self.taper_ratio}")
        if not abs(self.precurvature) <= MAX_PRECURVATURE:
            raise ValueError(f"precurvature must be within +-2 pi per rod length, got "
                             f"{self.precurvature}")
        if not 0.0 <= self.poisson_ratio <= 0.5:
            raise ValueError(f"poisson_ratio must be in [0, 0.5], got {self.poisson_ratio}")

    @property
    def uniform(self) -> bool:
        """The straight uniform cylinder: the planar elastica in closed form."""
        return self.taper_ratio == 1.0 and self.precurvature == 0.0

    @functools.cached_property
    def params(self) -> FloatArray:
        """(taper_ratio, precurvature, 1 + nu), as the compiled kernels take them (made once;
        not to be written)."""
        return np.array([self.taper_ratio, self.precurvature, 1.0 + self.poisson_ratio])


UNIFORM = RodShape()
"""The straight uniform cylinder."""


def unloaded_points(shape: RodShape, s: FloatArray) -> FloatArray:
    """Points (M, 3) of the unloaded rod at arc lengths ``s`` (M,), C: the circular arc in the
    x-z plane, the segment along e_z without pre-curvature."""
    s = np.asarray(s, dtype=float)
    kappa = shape.precurvature
    if kappa == 0.0:
        return np.column_stack([np.zeros_like(s), np.zeros_like(s), s])
    return np.column_stack([(1.0 - np.cos(kappa * s)) / kappa, np.zeros_like(s),
                            np.sin(kappa * s) / kappa])


def unloaded_polyline(shape: RodShape) -> FloatArray:
    """Vertices (K + 1, 3) in C of the unloaded rod as a polyline: its two ends when straight
    (exact), ``UNLOADED_CHORDS`` chords of the arc when pre-curved."""
    chords = 1 if shape.precurvature == 0.0 else UNLOADED_CHORDS
    return unloaded_points(shape, np.linspace(0.0, 1.0, chords + 1))


def unloaded_segments(shape: RodShape, p_WC: FloatArray, R_WC: FloatArray
                      ) -> tuple[FloatArray, FloatArray]:
    """The chords of the `unloaded_polyline` clamped at poses (p_WC (n, 3), R_WC (n, 3, 3)):
    starts and chord vectors (n K, 3), in W, pose by pose."""
    vertices = unloaded_polyline(shape)
    starts = p_WC[:, None, :] + np.einsum("nij,kj->nki", R_WC, vertices[:-1])
    chords = np.einsum("nij,kj->nki", R_WC, np.diff(vertices, axis=0))
    return starts.reshape(-1, 3), chords.reshape(-1, 3)


def stiffness(shape: RodShape, s: FloatArray) -> FloatArray:
    """EI(s) / EI(0) along the rod."""
    return (1.0 - (1.0 - shape.taper_ratio) * np.asarray(s, dtype=float)) ** 4


@compiled
def _derivative(s: float, rx: float, ry: float, rz: float, qw: float, qx: float, qy: float,
                qz: float, f0: FloatArray, m0: FloatArray, params: FloatArray
                ) -> tuple[float, float, float, float, float, float, float]:
    """d/ds of the state (r, q): r (C) and the material frame as a quaternion (w, x, y, z)."""
    two = 2.0 / (qw * qw + qx * qx + qy * qy + qz * qz)
    # columns of the rotation: d1, d2, d3 in C
    d1x, d1y, d1z = 1.0 - two * (qy * qy + qz * qz), two * (qx * qy + qw * qz), two * (qx * qz - qw * qy)
    d2x, d2y, d2z = two * (qx * qy - qw * qz), 1.0 - two * (qx * qx + qz * qz), two * (qy * qz + qw * qx)
    d3x, d3y, d3z = two * (qx * qz + qw * qy), two * (qy * qz - qw * qx), 1.0 - two * (qx * qx + qy * qy)
    mx = ry * f0[2] - rz * f0[1] - m0[0]
    my = rz * f0[0] - rx * f0[2] - m0[1]
    mz = rx * f0[1] - ry * f0[0] - m0[2]
    width = 1.0 - (1.0 - params[0]) * s
    compliance = 1.0 / (width * width * width * width)
    u1 = (mx * d1x + my * d1y + mz * d1z) * compliance
    u2 = (mx * d2x + my * d2y + mz * d2z) * compliance + params[1]
    u3 = (mx * d3x + my * d3y + mz * d3z) * params[2] * compliance
    return (d3x, d3y, d3z, 0.5 * (-qx * u1 - qy * u2 - qz * u3),
            0.5 * (qw * u1 + qy * u3 - qz * u2), 0.5 * (qw * u2 + qz * u1 - qx * u3),
            0.5 * (qw * u3 + qx * u2 - qy * u1))


@compiled
def rk4_step(s: float, h: float, y: FloatArray, f0: FloatArray, m0: FloatArray,
             params: FloatArray, out: FloatArray) -> None:
    """One classical Runge-Kutta step of length ``h`` from (s, y) into ``out`` (quaternion
    normalised); ``out`` may be ``y``."""
    y0, y1, y2, y3, y4, y5, y6 = y[0], y[1], y[2], y[3], y[4], y[5], y[6]
    a0, a1, a2, a3, a4, a5, a6 = _derivative(s, y0, y1, y2, y3, y4, y5, y6, f0, m0, params)
    g = 0.5 * h
    b0, b1, b2, b3, b4, b5, b6 = _derivative(
        s + g, y0 + g * a0, y1 + g * a1, y2 + g * a2, y3 + g * a3, y4 + g * a4, y5 + g * a5,
        y6 + g * a6, f0, m0, params)
    c0, c1, c2, c3, c4, c5, c6 = _derivative(
        s + g, y0 + g * b0, y1 + g * b1, y2 + g * b2, y3 + g * b3, y4 + g * b4, y5 + g * b5,
        y6 + g * b6, f0, m0, params)
    d0, d1, d2, d3, d4, d5, d6 = _derivative(
        s + h, y0 + h * c0, y1 + h * c1, y2 + h * c2, y3 + h * c3, y4 + h * c4, y5 + h * c5,
        y6 + h * c6, f0, m0, params)
    w = h / 6.0
    qw = y3 + w * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
    qx = y4 + w * (a4 + 2.0 * b4 + 2.0 * c4 + d4)
    qy = y5 + w * (a5 + 2.0 * b5 + 2.0 * c5 + d5)
    qz = y6 + w * (a6 + 2.0 * b6 + 2.0 * c6 + d6)
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    out[0] = y0 + w * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
    out[1] = y1 + w * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
    out[2] = y2 + w * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
    out[3], out[4], out[5], out[6] = qw / norm, qx / norm, qy / norm, qz / norm


@compiled
def clamp_state() -> FloatArray:
    """The state at the clamp: r = 0, the identity frame."""
    y = np.zeros(7)
    y[3] = 1.0
    return y


@compiled
def integrate_to(s_end: float, f0: FloatArray, m0: FloatArray, params: FloatArray
                 ) -> FloatArray:
    """The state at arc length ``s_end`` >= 0: whole steps of 1 / ``N_STEPS`` from the clamp,
    then one partial step (the grid every caller shares, so that the forward problem and
    Step 2 integrate with the same arithmetic)."""
    h = 1.0 / N_STEPS
    y = clamp_state()
    nxt = np.empty(7)
    k = 0
    while (k + 1) * h <= s_end:
        rk4_step(k * h, h, y, f0, m0, params, nxt)
        y[:] = nxt
        k += 1
    rest = s_end - k * h
    if rest > 0:
        rk4_step(k * h, rest, y, f0, m0, params, nxt)
        y[:] = nxt
    return y


@compiled
def frame_of(y: FloatArray) -> FloatArray:
    """The material frame (columns d1, d2, d3, in C) of a state."""
    qw, qx, qy, qz = y[3], y[4], y[5], y[6]
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)
    return R


@compiled
def moment_at(y: FloatArray, f0: FloatArray, m0: FloatArray) -> FloatArray:
    """The internal moment m = r x f0 - m0 at a state (C)."""
    m = np.empty(3)
    m[0] = y[1] * f0[2] - y[2] * f0[1] - m0[0]
    m[1] = y[2] * f0[0] - y[0] * f0[2] - m0[1]
    m[2] = y[0] * f0[1] - y[1] * f0[0] - m0[2]
    return m


FORWARD_TOL = 1e-13
"""|m(s1)| (EI/L) at which :func:`clamp_wrench` has converged."""


@compiled
def clamp_wrench(force_C: FloatArray, s1: float, params: FloatArray, m0_guess: FloatArray,
                 m0: FloatArray) -> bool:
    """The forward problem: the clamp's moment ``m0`` (written, C) of the rod loaded by
    ``force_C`` (on the rod, C) at arc length ``s1``, i.e. m(s1) = 0, by Newton's method from
    ``m0_guess`` (forward-difference Jacobian, step halving). The clamp's force is -force_C.
    Returns whether it converged (|m(s1)| < ``FORWARD_TOL`` relative to the load)."""
    f0 = np.empty(3)
    for i in range(3):
        f0[i] = -force_C[i]
        m0[i] = m0_guess[i]
    scale = max(1.0, math.sqrt(f0[0] ** 2 + f0[1] ** 2 + f0[2] ** 2))
    residual = moment_at(integrate_to(s1, f0, m0, params), f0, m0)
    norm = math.sqrt(residual[0] ** 2 + residual[1] ** 2 + residual[2] ** 2)
    jac = np.empty((3, 3))
    probe = np.empty(3)
    trial = np.empty(3)
    for _ in range(60):
        if norm < FORWARD_TOL * scale:
            return True
        if not math.isfinite(norm):
            return False
        for j in range(3):
            for i in range(3):
                probe[i] = m0[i]
            h = 1e-7 * max(abs(m0[j]), 1e-3 * scale)
            probe[j] += h
            r = moment_at(integrate_to(s1, f0, probe, params), f0, probe)
            for i in range(3):
                jac[i, j] = (r[i] - residual[i]) / h
        delta = np.linalg.solve(jac, -residual)
        step = 1.0
        accepted = False
        for _halving in range(30):
            for i in range(3):
                trial[i] = m0[i] + step * delta[i]
            r = moment_at(integrate_to(s1, f0, trial, params), f0, trial)
            trial_norm = math.sqrt(r[0] ** 2 + r[1] ** 2 + r[2] ** 2)
            if trial_norm < norm:
                for i in range(3):
                    m0[i] = trial[i]
                    residual[i] = r[i]
                norm = trial_norm
                accepted = True
                break
            step *= 0.5
        if not accepted:
            return norm < FORWARD_TOL * scale
    return norm < FORWARD_TOL * scale


def rod_line(shape: RodShape, f0_C: FloatArray, m0_C: FloatArray, s1: float,
             s: FloatArray) -> FloatArray:
    """Points of the rod (C, L) at arc lengths ``s`` (M,) under the clamp wrench (f0, m0) of a
    contact at ``s1``: loaded up to s1, the unloaded pre-curved arc beyond it. (M, 3)."""
    f0 = np.ascontiguousarray(f0_C, dtype=float)
    m0 = np.ascontiguousarray(m0_C, dtype=float)
    params = shape.params
    none = np.zeros(3)
    points = np.empty((len(s), 3))
    at_contact = integrate_to(float(s1), f0, m0, params)
    for i, s_i in enumerate(np.asarray(s, dtype=float)):
        if s_i <= s1:
            points[i] = integrate_to(float(s_i), f0, m0, params)[:3]
        else:  # free beyond the contact: integrate the natural shape on from there
            y = at_contact.copy()
            points[i] = _free_from(y, float(s1), float(s_i), none, params)[:3]
    return points


@compiled
def _free_from(y: FloatArray, s_from: float, s_to: float, zero: FloatArray,
               params: FloatArray) -> FloatArray:
    """The unloaded rod from state ``y`` at ``s_from`` to ``s_to``."""
    n = max(1, int(math.ceil((s_to - s_from) * N_STEPS)))
    h = (s_to - s_from) / n
    nxt = np.empty(7)
    for k in range(n):
        rk4_step(s_from + k * h, h, y, zero, zero, params, nxt)
        y[:] = nxt
    return y


def loaded_rod(shape: RodShape, force_C: FloatArray, s1: float,
               load_steps: int = 1) -> FloatArray:
    """The clamp's moment m0 (C) of the rod loaded by ``force_C`` (on the rod, C) at ``s1``:
    :func:`clamp_wrench` continued in the load from the unloaded rod, ``load_steps`` steps at
    first, more where a step does not converge. ValueError where it does not converge at all
    (a load past the rod's folds, or s1 outside (0, 1])."""
    if not 0.0 < s1 <= 1.0:
        raise ValueError(f"s1 must be in (0, 1], got {s1}")
    force = np.asarray(force_C, dtype=float)
    params = shape.params
    m0, guess = np.empty(3), np.zeros(3)
    for steps in (load_steps, 4 * load_steps, 16 * load_steps, 64 * load_steps):
        guess[:] = 0.0
        for fraction in np.arange(1, steps + 1) / steps:
            if not clamp_wrench(fraction * force, s1, params, guess, m0):
                break
            guess[:] = m0
        else:
            return m0
    raise ValueError(f"no equilibrium of the rod under {force} at s1 = {s1} found by "
                     f"continuation in the load")
