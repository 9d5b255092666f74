"""Independent reference solver of a clamped Kirchhoff rod under one point force (tests only).

Dimensionless units: rod length L = 1, base bending stiffness EI_base = 1; forces in EI/L^2,
moments in EI/L. The rod is clamped at the origin with the material frame d1 = e_x, d2 = e_y,
d3 = e_z (the clamp frame C); all vectors here are in C.

Model: inextensible, unshearable rod with a circular, linearly tapered section,
EI(s) = (1 - (1 - r) s)^4 about d1 and d2, GJ(s) = EI(s) / (1 + nu), and natural curvature
u_hat = (0, kappa_hat, 0) in material components (a planar arc bending towards +x). The force F
acts on the rod at s1; beyond s1 the rod is unloaded and keeps its natural shape.

Formulation (shooting, written for this reference only): the state along s is the position
r, the rotation matrix R = [d1 d2 d3] and the internal moment m (exerted by the distal part
on the proximal part, in C). With the internal force n = F on [0, s1),

    r' = d3,   R' = [w]x R,   m' = F x d3    (moment balance m' + r' x n = 0),

where the Darboux vector w = R u and the material curvature u follows from the constitutive
law m = R diag(EI, EI, GJ) (u - u_hat). The unknown is the clamp moment m(0) = -m0; it is
found by ``scipy.optimize.root`` on the condition m(s1) = 0, with continuation in the load
from 0 to F. The part beyond s1 is the same ODE with F = 0 and m = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp
from scipy.optimize import root

RTOL = ATOL = 1e-12


def _rhs(force: NDArray[np.float64], taper: float, kappa_hat: float, nu: float):
    fx, fy, fz = force

    def rhs(s: float, y: NDArray[np.float64]) -> NDArray[np.float64]:
        rot = y[3:12].reshape(3, 3)  # columns d1, d2, d3
        m = y[12:15]
        ei = (1.0 - (1.0 - taper) * s) ** 4
        u = m @ rot  # material components of m
        u = np.array([u[0] / ei, u[1] / ei + kappa_hat, u[2] * (1.0 + nu) / ei])
        wx, wy, wz = rot @ u
        skew = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
        tx, ty, tz = rot[:, 2]
        return np.concatenate((rot[:, 2], (skew @ rot).ravel(),
                               (fy * tz - fz * ty, fz * tx - fx * tz, fx * ty - fy * tx)))

    return rhs


def _integrate(force, m_start, s_span, taper, kappa_hat, nu, y_start=None, dense=False):
    y0 = np.concatenate((np.zeros(3), np.eye(3).ravel(), m_start)) if y_start is None else y_start
    return solve_ivp(_rhs(force, taper, kappa_hat, nu), s_span, y0, method="DOP853",
                     rtol=RTOL, atol=ATOL, dense_output=dense)


@dataclass(frozen=True)
class RodSolution:
    """Equilibrium of the clamped rod under one point force (all vectors in the clamp frame C).

    Attributes
    ----------
    force : ndarray, shape (3,)
        The applied force F on the rod, EI/L^2.
    s1 : float
        Arc length of the load point, L.
    r1 : ndarray, shape (3,)
        Position r(s1), L.
    tangent1 : ndarray, shape (3,)
        Tangent d3(s1).
    frame1 : ndarray, shape (3, 3)
        Material frame at s1, columns d1, d2, d3.
    f0, m0 : ndarray, shape (3,)
        Clamp reaction on the rod (base wrench): f0 = -F, m0 = -(r1 x F) (about the clamp), EI/L.
    residual : float
        Max abs of the boundary residuals: m(s1) (the shooting condition) and m0 + r1 x F.
    """

    force: NDArray[np.float64]
    s1: float
    r1: NDArray[np.float64]
    tangent1: NDArray[np.float64]
    frame1: NDArray[np.float64]
    f0: NDArray[np.float64]
    m0: NDArray[np.float64]
    residual: float
    _loaded: object  # dense output on [0, s1]
    _free: object | None  # dense output on [s1, 1] (None if s1 = 1)

    def _state(self, s: ArrayLike) -> NDArray[np.float64]:
        """State (r, R, m) at arc lengths s, shape (..., 15)."""
        s = np.asarray(s, dtype=float)
        flat = s.ravel()
        out = np.empty((flat.size, 15))
        near = flat <= self.s1
        if np.any(near):
            out[near] = self._loaded(flat[near]).T
        if np.any(~near):
            out[~near] = self._free(flat[~near]).T
        return out.reshape(s.shape + (15,))

    def shape(self, s: ArrayLike) -> NDArray[np.float64]:
        """Centreline r(s) for s in [0, 1], shape s.shape + (3,), L."""
        return self._state(s)[..., 0:3]

    def frame(self, s: ArrayLike) -> NDArray[np.float64]:
        """Material frame at s, shape s.shape + (3, 3), columns d1, d2, d3."""
        return self._state(s)[..., 3:12].reshape(np.shape(s) + (3, 3))


def moment_along(result: RodSolution, s: ArrayLike) -> NDArray[np.float64]:
    """Internal moment m(s) in C (from the integrated moment balance), shape s.shape + (3,), EI/L.

    It is the moment exerted by the distal part on the proximal part about r(s); it vanishes
    at s1 and beyond.
    """
    return result._state(s)[..., 12:15]


def solve_rod(force: ArrayLike, s1: float, taper_ratio: float = 1.0, kappa_hat: float = 0.0,
              poisson_ratio: float = 0.3, steps: int | None = None) -> RodSolution:
    """Solve the clamped rod loaded by ``force`` (on the rod, in C) at arc length ``s1``.

    Parameters
    ----------
    force : array_like, shape (3,)
        Point force on the rod, EI/L^2.
    s1 : float
        Arc length of the load point in (0, 1], L.
    taper_ratio : float
        Tip over base diameter, in (0, 1].
    kappa_hat : float
        Natural curvature towards +x, 1/L.
    poisson_ratio : float
        nu in GJ = EI / (1 + nu).
    steps : int, optional
        Continuation steps in the load (default grows with |F|).

    Returns
    -------
    RodSolution

    Raises
    ------
    RuntimeError
        If the shooting does not converge to a residual below 1e-10.
    """
    force = np.asarray(force, dtype=float)
    args = (taper_ratio, kappa_hat, poisson_ratio)
    # Guess from the unloaded arc: m(0) = r1 x F with r1 the natural point at s1.
    unloaded = _integrate(np.zeros(3), np.zeros(3), (0.0, s1), *args)
    m_start = np.cross(unloaded.y[0:3, -1], force)
    steps = steps if steps is not None else 1 + int(np.ceil(2.0 * np.linalg.norm(force)))
    m_prev = None
    for t in np.linspace(0.0, 1.0, steps + 1)[1:]:
        f_t = t * force

        def miss(m_0, f_t=f_t):
            return _integrate(f_t, m_0, (0.0, s1), *args).y[12:15, -1]

        found = root(miss, m_start, method="hybr", options={"xtol": 1e-14})
        m_next = found.x
        m_start, m_prev = (2.0 * m_next - m_prev if m_prev is not None else m_next), m_next
    m_start = m_prev
    loaded = _integrate(force, m_start, (0.0, s1), *args, dense=True)
    end = loaded.y[:, -1]
    r1, frame1 = end[0:3], end[3:12].reshape(3, 3)
    m0 = -m_start
    residual = float(max(np.max(np.abs(end[12:15])), np.max(np.abs(m0 + np.cross(r1, force)))))
    if not residual < 1e-10:
        raise RuntimeError(f"shooting did not converge: residual {residual:.3g}")
    free = None
    if s1 < 1.0:
        y_free = end.copy()
        y_free[12:15] = 0.0
        free = _integrate(np.zeros(3), None, (s1, 1.0), *args, y_start=y_free, dense=True).sol
    return RodSolution(force=force, s1=float(s1), r1=r1, tangent1=frame1[:, 2].copy(), frame1=frame1,
                       f0=-force, m0=m0, residual=residual, _loaded=loaded.sol, _free=free)
