"""Independent checks of Step 1 samples of a tapered and/or pre-curved Kirchhoff rod touching
two objects (tests only; imports nothing of `vibrissa.rods` or `vibrissa.two_contacts`).

SI throughout. The state along the rod is the centreline r and the director matrix
R = [d1 d2 d3] (W); the internal moment m (distal part on proximal, about r(s)) is not
integrated but follows from statics on a segment under a constant internal force n:
m(s) = m(s0) - (r(s) - r(s0)) x n. Then r' = d3, R' = [R u]x R with the material curvature
u = diag(1/EI, 1/EI, 1/GJ) R^T m + (0, kappa_hat, 0), EI(s) = EI_base (1 - (1 - r) s/L)^4,
GJ = EI / (1 + nu); at the clamp R = R_WC (C's axes in W).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from vibrissa.frames import Transform
from vibrissa.scene import RobotPath, Scene, SceneObject, Whisker, WhiskerResult
from vibrissa.surfaces import Surface

Vec = NDArray[np.float64]
POINTS = 41
"""Points of each integrated piece of rod checked to lie outside every object."""


class _Rod:
    """One whisker's rod in SI, integrated piece by piece from a state (r, R)."""

    def __init__(self, whisker: Whisker) -> None:
        self.L, self.ei = whisker.length_m, whisker.ei_nm2
        self.taper, self.nu = whisker.taper_ratio, whisker.poisson_ratio
        self.kappa = whisker.precurvature_1pm

    def piece(self, s0: float, s1: float, r0: Vec, R0: Vec, m0: Vec, n: Vec
              ) -> tuple[Vec, Vec, Vec, Vec]:
        """From (r0, R0) at arc length s0 with the moment m0 there, under the internal force n,
        to s1: (r, R, m) at s1 and the points (POINTS, 3) of the piece."""
        def rhs(s: float, y: Vec) -> Vec:
            R = y[3:12].reshape(3, 3)
            m = m0 - np.cross(y[:3] - r0, n)
            ei = self.ei * (1.0 - (1.0 - self.taper) * s / self.L) ** 4
            u = R.T @ m / ei
            u[1] += self.kappa
            u[2] *= 1.0 + self.nu
            w = R @ u
            W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
            return np.concatenate([R[:, 2], (W @ R).ravel()])

        y0 = np.concatenate([r0, R0.ravel()])
        if s1 <= s0:
            return r0, R0, m0, np.tile(r0, (POINTS, 1))
        sol = solve_ivp(rhs, (s0, s1), y0, method="DOP853", rtol=1e-12, atol=1e-16,
                        dense_output=True)
        end = sol.y[:, -1]
        points = sol.sol(np.linspace(s0, s1, POINTS)).T[:, :3]
        return end[:3], end[3:12].reshape(3, 3), m0 - np.cross(end[:3] - r0, n), points


def _clamp(scene: Scene, whisker: Whisker, result: WhiskerResult, k: int
           ) -> tuple[Vec, Vec, Vec, Vec]:
    """Sample k's clamp point, frame R_WC and the clamp's reaction f0, m0 in W."""
    R_WR = scene.path.R_WR[k]
    p0 = scene.path.p_WR[k] + R_WR.apply(np.array(whisker.X_RC.translation))
    R = (R_WR * whisker.X_RC.rotation).as_matrix()
    return p0, R, R @ result.f0_n[k], R @ result.m0_nm[k]


def _depth(surfaces: list[Surface], points: Vec) -> float:
    """The deepest of points (N, 3) in any object (m; <= 0 when outside all)."""
    return max(float(np.max(-s.signed_distance(points))) for s in surfaces)


def _tangent_miss(surface: Surface, p: Vec, R: Vec, s: float, L: float) -> float:
    """|d3 . n| at a tangential contact (s < L), 0 at the tip."""
    if s >= L * (1.0 - 1e-9):
        return 0.0
    return abs(float(R[:, 2] @ surface.normal(p[None])[0]))


def _outer_fit(rod: _Rod, s: tuple[float, float], r_in: Vec, R_in: Vec, m_in: Vec, chord: Vec
               ) -> tuple[float, Vec, tuple[Vec, Vec, Vec, Vec]]:
    """The outer force F (chord x F = m_in, its part along the chord fitted) that takes the rod
    from the inner contact (arc length s[0], state r_in, R_in, m_in) closest to r_in + chord at
    s[1]: the miss (in L), F and the piece of rod."""
    across = np.cross(m_in, chord) / (chord @ chord)

    def outer(lam: float) -> tuple[Vec, Vec, Vec, Vec]:
        return rod.piece(s[0], s[1], r_in, R_in, m_in, across + lam * chord)

    def fitted(start: float) -> Any:
        return least_squares(lambda x: (outer(x[0])[0] - r_in - chord) / rod.L, [start],
                             xtol=1e-15, ftol=1e-15, gtol=1e-15)

    # from no force along the chord, else (a miss over 1e-9 L: a local minimum) from forces
    # along it up to 1e3 times the one across it, the best fit
    fit = fitted(0.0)
    size = float(np.linalg.norm(across) / np.linalg.norm(chord)) + 1e-300
    for start in (10.0 ** np.arange(-1, 4)[:, None] * [1.0, -1.0]).ravel() * size:
        if np.linalg.norm(fit.fun) <= 1e-9:
            break
        fit = min(fit, fitted(float(start)), key=lambda f: float(np.linalg.norm(f.fun)))
    force = across + fit.x[0] * chord
    return float(np.linalg.norm(fit.fun)), force, outer(fit.x[0])


def shaped_two_contacts_worst(scene: Scene, whisker: Whisker, result: WhiskerResult
                              ) -> dict[str, float]:
    """The worst of the independent checks over a whisker's samples with two contacts (lengths
    in its L): each contact on its object (``on``); from the clamp wrench the rod reaching the
    inner point (``inner``); the moment left there perpendicular to the chord to the outer
    point (``chord``, of |m| |chord|); the outer point reached with the outer force's one
    unknown (along the chord) fitted (``outer``); |d3 . n| at a tangential contact
    (``tangent``); the rod's depth in any object, its unloaded rest to the tip included
    (``inside``); the clamp's moment balance with the contact forces (``statics``, of
    |m0| + L |f0|)."""
    rod, L = _Rod(whisker), whisker.length_m
    surfaces = [obj.surface(1.0) for obj in scene.objects]
    worst = dict.fromkeys(("on", "inner", "chord", "outer", "tangent", "inside", "statics"), 0.0)
    worst["samples"] = 0
    for k in map(int, np.flatnonzero(result.second_object >= 0)):
        worst["samples"] += 1
        p0, R0, f0, m0 = _clamp(scene, whisker, result, k)
        (s_in, p_in, j_in), (s_out, p_out, j_out) = sorted(
            [(float(result.s1_m[k]), result.p_W_m[k], int(result.object[k])),
             (float(result.second_s_m[k]), result.second_W_m[k], int(result.second_object[k]))],
            key=lambda c: c[0])
        for p, j in ((p_in, j_in), (p_out, j_out)):
            worst["on"] = max(worst["on"], abs(float(surfaces[j].signed_distance(p[None])[0])) / L)
        r_in, R_in, m_in, pts1 = rod.piece(0.0, s_in, p0, R0, -m0, -f0)
        worst["inner"] = max(worst["inner"], float(np.linalg.norm(r_in - p_in)) / L)
        chord = p_out - p_in
        worst["chord"] = max(worst["chord"], abs(float(m_in @ chord)) / float(
            np.linalg.norm(m_in) * np.linalg.norm(chord) + 1e-300))
        miss, f_out, (r_out, R_out, _m_out, pts2) = _outer_fit(
            rod, (s_in, s_out), r_in, R_in, m_in, p_out - p_in)
        worst["outer"] = max(worst["outer"], miss)
        f_in = -f0 - f_out
        balance = m0 + np.cross(p_in - p0, f_in) + np.cross(p_out - p0, f_out)
        worst["statics"] = max(worst["statics"], float(np.linalg.norm(balance)) / float(
            np.linalg.norm(m0) + L * np.linalg.norm(f0) + 1e-300))
        worst["tangent"] = max(worst["tangent"],
                               _tangent_miss(surfaces[j_in], p_in, R_in, s_in, L),
                               _tangent_miss(surfaces[j_out], p_out, R_out, s_out, L))
        *_, pts3 = rod.piece(s_out, L, r_out, R_out, np.zeros(3), np.zeros(3))
        worst["inside"] = max(worst["inside"],
                              _depth(surfaces, np.concatenate([pts1, pts2, pts3])) / L)
    return worst


def shaped_leaning_scene(lift_m: float, taper_ratio: float, precurvature_1pm: float,
                         **geometry: float) -> Scene:
    """A tapered/pre-curved rod (L 0.05 m, EI 1e-4 N m^2, curving towards +x, kappa >= 0) up
    W's z on a robot driving along +x: its unloaded arc touches ball a 2.5 mm after the start,
    it leans on a and runs into ball b low on its way, b ``lift_m`` out of the path's plane.
    ``geometry`` overrides (m) a's and b's centres and radii (a_x, a_z, a_r, b_x, b_z, b_r)
    or the path's robot x (x_start, x_end)."""
    g = dict(a_x=0.015, a_z=0.04, a_r=0.015, b_x=0.0175, b_z=0.0075, b_r=0.005,
             x_end=0.045) | geometry
    touch = g["a_x"] - g["a_r"]  # robot x where the unloaded rod first touches a
    if precurvature_1pm > 0.0:  # the arc of radius 1/kappa meets a from inside its circle
        rho = 1.0 / precurvature_1pm
        touch = g["a_x"] - rho + math.sqrt((rho - g["a_r"]) ** 2 - g["a_z"] ** 2)
    x = np.linspace(g.get("x_start", touch - 0.0025), g["x_end"], 951)
    path = RobotPath(np.arange(len(x), dtype=np.float64) / 100.0, np.column_stack([x, 0 * x, 0 * x]),
                     Rotation.identity(len(x)))
    a = SceneObject("a", "sphere", {"radius_m": g["a_r"]},
                    Transform(Rotation.identity(), [g["a_x"], 0.0, g["a_z"]]))
    b = SceneObject("b", "sphere", {"radius_m": g["b_r"]},
                    Transform(Rotation.identity(), [g["b_x"], lift_m, g["b_z"]]))
    whisker = Whisker("w", 0.05, 1e-4, Transform(), taper_ratio=taper_ratio,
                      precurvature_1pm=precurvature_1pm)
    return Scene(0.3, (a, b), (whisker,), path)
