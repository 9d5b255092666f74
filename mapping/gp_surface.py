"""Gaussian-process implicit surface of a contact cloud: the surface, its uncertainty, a mesh.

A whisker's contact cloud is a few dense lines of very precise points, each with the object's
outward normal (from the contact force, `vibrissa.mapping.objects.contact_normals`). The
surface is the zero set of a function f (f > 0 outside the object) estimated by Gaussian-process
regression (GPIS: Williams & Fitzgibbon 2006; Dragiev et al. 2011), which interpolates between
the lines and says how sure it is everywhere.

Model (in the cloud's normalised coordinates u = (x - c) / s: c its centroid, s the largest
distance from it, so that one set of length scales fits clouds of any size and a rigid motion
of the cloud moves the surface with it)

* Prior f ~ GP(0, sigma^2 k_SE(u, u') + q^2 phi(u) . phi(u')), with k_SE the squared
  exponential of length ``ell`` and phi the monomials of degree <= 2 (phi . phi' = 1 + u . u' +
  (u . u')^2, the same for any orientation of the axes). The second term is a vague Gaussian
  prior on a quadric trend (the explicit-basis GP of Rasmussen & Williams 2006, sec. 2.7): every
  sphere, ellipsoid and paraboloid in any pose is a quadric's zero set, and a smooth convex body
  is one to second order locally; the squared exponential, of std sigma, is how far the object
  strays from the trend, and where nothing was touched that is what the posterior says.
* Observations at each active point p with normal n: f(p) = 0 with the points' noise, and
  grad f(p) = n with noise covariance tau^2 (I - n n^T) + NORMAL_SCALE_STD^2 n n^T: the
  gradient's direction is known to the normals' accuracy tau, its length only roughly (a
  quadric's gradient is not of unit length along its zero set).
* ``ell``, ``sigma`` and ``tau`` maximise the marginal likelihood over a small grid
  (``GPParams``), on a coarser selection of the points.

* The points the fit did not use are on the surface too: the RMS of f there
  (``residual_std``) is the fit's error near the data, measured, and is added to its std.

Cost: the fit is exact on at most ``max_active`` points (4 observations each), taken along the
lines at a fixed path length (``select_active``): the lines are far denser than the surface's
curvature needs. A 10^5-point cloud costs what a 10^4-point cloud does but for the selection.
The trend is solved for apart from the Cholesky factor of the rest (``_Solution``). More
contacts on a fitted surface (a growing map) cost less than a new fit: :func:`extended` adds
some of them to the active points with the hyperparameters kept, extending the factor by a
block.

Prediction: the mean f(x) and its gradient (a compiled loop over the active points, the query
points shared out over the cores) and the standard deviation sd_f(x) (triangular solves, chunks
of points on the cores side by side); the surface's position uncertainty is
sd_d = sd_f / |grad f|, in m. ``mesh`` runs marching cubes (scikit-image) on the mean over a
box and splits the triangles into *known* (every vertex within ``max_std``) and *unknown*. The
same points give the same bits: no randomness, and the same linear algebra on the same inputs,
on one BLAS thread whatever the machine's setting.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from functools import partial, wraps
from typing import Any, ParamSpec, TypeVar

import numba
import numpy as np
import numpy.typing as npt
from numba import njit, prange
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from threadpoolctl import threadpool_limits

if "NUMBA_THREADING_LAYER" not in os.environ:
    # numba's own thread pool for the mean's parallel loop: its default probe tries TBB
    # first, and in a process that has imported Open3D (which bundles an older TBB) it warns
    # and falls back anyway
    numba.config.THREADING_LAYER = "workqueue"  # type: ignore[attr-defined]  # made at run time

_MEAN_LOCK = threading.Lock()
"""One thread at a time in the mean's parallel loop: numba's workqueue pool takes no second
caller (it aborts the process), and a warm-up thread or a user's threads may evaluate too."""

P = ParamSpec("P")
R = TypeVar("R")


def _one_blas_thread(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` with BLAS on one thread (threadpoolctl): a factorisation split over
    threads sums in another order, and the same points would give other bits with another
    thread count (measured: the mapper's mesh.ply changed between 1 and 2 threads)."""

    @wraps(function)
    def serial(*args: P.args, **kwargs: P.kwargs) -> R:
        with threadpool_limits(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return serial

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

NORMAL_SCALE_STD = 0.3
"""Std of the gradient's length at a contact point (see module)."""

HELD_OUT = 2000
"""Most contact points :func:`fit` measures its residual on (every k-th unused one)."""

MIN_POINT_STD = 1e-5
"""Least std of f at a contact point, units of s: exact points would make the observations'
covariance singular to rounding (two points closer than ell / 100 carry nearly the same f)."""


@dataclass(frozen=True)
class GPParams:
    """Parameters of :func:`fit`.

    Attributes
    ----------
    max_active
        Most contact points the fit uses (4 observations each; the cost grows as its cube).
    select_active
        Most contact points the choice of the hyperparameters uses.
    length_scales
        Candidate ``ell``, units of the cloud's radius s (see module).
    sigmas
        Candidate ``sigma``, the prior std of the object's departure from a quadric, units
        of s. The smallest is the least uncertainty left where nothing was touched: clean
        data of a quadric fit one exactly, and maximum likelihood alone would be sure of it
        everywhere.
    normal_stds
        Candidate ``tau``, the std of the normals' direction, rad. Contact normals from the
        force are good to about 0.006 rad where the rod slides along its line (the friction
        is along it) and worse where it sticks or the contact jumps along the rod.
    point_std_m
        Std of a contact point's position, m (the reconstruction's error; the noise of a
        real sensor goes here).
    quadric_std
        q, the prior std of the quadric trend's coefficients (units of s; vague: a sphere of
        radius r s has coefficients of about 1 / (2 r)).
    """

    max_active: int = 400
    select_active: int = 100
    length_scales: tuple[float, ...] = (0.3, 0.6)
    sigmas: tuple[float, ...] = (0.003, 0.01, 0.03)
    normal_stds: tuple[float, ...] = (0.01, 0.03, 0.1)
    point_std_m: float = 1e-9
    quadric_std: float = 3.0

    def __post_init__(self) -> None:
        for name in ("max_active", "select_active"):
            if getattr(self, name) < 4:
                raise ValueError(f"{name} must be >= 4, got {getattr(self, name)}")
        for name in ("length_scales", "sigmas", "normal_stds"):
            values = getattr(self, name)
            if not values or not all(math.isfinite(v) and v > 0 for v in values):
                raise ValueError(f"{name} must be one or more positive numbers, got {values}")
        for name in ("point_std_m", "quadric_std"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")


def _quadric(u: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The ten monomials phi (N, 10) of degree <= 2 at points u (N, 3) and their gradients
    (N, 10, 3), the mixed ones times sqrt(2): phi(u) . phi(u') = 1 + u . u' + (u . u')^2, so
    that the prior does not depend on the orientation of the axes."""
    x, y, z = u.T
    one, zero, r2 = np.ones_like(x), np.zeros_like(x), math.sqrt(2.0)
    phi = np.stack([one, x, y, z, x * x, y * y, z * z, r2 * x * y, r2 * x * z, r2 * y * z],
                   axis=1)
    grad = np.stack([
        np.stack([zero, zero, zero], axis=1), np.stack([one, zero, zero], axis=1),
        np.stack([zero, one, zero], axis=1), np.stack([zero, zero, one], axis=1),
        np.stack([2 * x, zero, zero], axis=1), np.stack([zero, 2 * y, zero], axis=1),
        np.stack([zero, zero, 2 * z], axis=1), r2 * np.stack([y, x, zero], axis=1),
        r2 * np.stack([z, zero, x], axis=1), r2 * np.stack([zero, z, y], axis=1)], axis=1)
    return phi, grad


def _design(u: FloatArray) -> FloatArray:
    """The quadric's monomials at the observations of active points u (M, 3): (4M, 10), rows
    f(u_0..u_M-1) then grad f of each point (point-major: u_0's x, y, z, u_1's ...)."""
    phi, grad = _quadric(u)
    return np.concatenate([phi, grad.transpose(0, 2, 1).reshape(-1, 10)])


def _cross_se(q: FloatArray, a: FloatArray, ell: float) -> FloatArray:
    """SE covariances of f(q) (Q, 3) with the observations of active points a (M, 3):
    (Q, 4M), columns as in :func:`_design`."""
    d = q[:, None, :] - a[None, :, :]
    k = np.exp(-np.einsum("qmi,qmi->qm", d, d) / (2 * ell * ell))
    # cov(f(q), d f(a) / d a_j) = d k / d a_j = k (q - a)_j / ell^2
    return np.concatenate([k, (k[..., None] * d / (ell * ell)).reshape(len(q), -1)], axis=1)


def _prior(a: FloatArray, ell: float) -> FloatArray:
    """SE prior covariance of the observations of active points a (M, 3) for sigma = 1:
    (4M, 4M), rows and columns as in :func:`_design`."""
    return _prior_cross(a, a, ell)


def _prior_cross(a: FloatArray, b: FloatArray, ell: float) -> FloatArray:
    """SE prior covariance of the observations of points a (Ma, 3) with those of points b
    (Mb, 3) for sigma = 1: (4Ma, 4Mb), rows and columns as in :func:`_design`."""
    ma, mb = len(a), len(b)
    d = a[:, None, :] - b[None, :, :]
    k = np.exp(-np.einsum("pqi,pqi->pq", d, d) / (2 * ell * ell))
    fg = k[..., None] * d / (ell * ell)  # cov(f(a_p), d_j f(b_q))
    gg = k[..., None, None] * (np.eye(3) / (ell * ell) - d[..., :, None] * d[..., None, :]
                               / ell**4)  # cov(d_i f(a_p), d_j f(b_q))
    K = np.empty((4 * ma, 4 * mb))
    K[:ma, :mb] = k
    K[:ma, mb:] = fg.reshape(ma, 3 * mb)
    K[ma:, :mb] = -fg.transpose(0, 2, 1).reshape(3 * ma, mb)  # cov(d_i f(a_p), f(b_q))
    K[ma:, mb:] = gg.transpose(0, 2, 1, 3).reshape(3 * ma, 3 * mb)
    return K


def _noise(normals: FloatArray, point_std: FloatArray, tau: float) -> FloatArray:
    """Observation noise covariance (4M, 4M) of active points with unit normals (M, 3): f
    ``point_std`` (M,) (units of s), gradients tau across n and NORMAL_SCALE_STD along it."""
    m = len(normals)
    nn = normals[:, :, None] * normals[:, None, :]
    block = tau * tau * (np.eye(3) - nn) + NORMAL_SCALE_STD**2 * nn
    R = np.zeros((4 * m, 4 * m))
    R[np.arange(m), np.arange(m)] = point_std * point_std
    idx = m + 3 * np.arange(m)
    for i in range(3):
        for j in range(3):
            R[idx + i, idx + j] = block[:, i, j]
    return R


def select_active(u: FloatArray, max_active: int) -> IntArray:
    """Indices (increasing) of at most ``max_active`` of the points u (N, 3), taken along
    them in order: a point is kept when the path length from the last kept one reaches a step,
    the shortest step (to 2 %) that keeps no more than that many. Along the path, not by a
    grid: the choice does not depend on the axes."""
    if len(u) <= max_active:
        return np.arange(len(u))
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(u, axis=0), axis=1))])
    lo, hi = 0.0, float(path[-1]) + 1.0
    best = np.arange(1)
    while hi - lo > 0.02 * hi:
        step = (lo + hi) / 2
        kept = _along(path, step)
        if len(kept) <= max_active:
            hi, best = step, kept
        else:
            lo = step
    return best


def _along(path: FloatArray, step: float) -> IntArray:
    """Indices of the points kept by :func:`select_active` for a step along ``path`` (N,),
    the cumulative path length."""
    kept = [0]
    last = path[0]
    for i in np.flatnonzero(np.diff(np.floor(path / step)) > 0) + 1:
        if path[i] - last >= step:
            kept.append(int(i))
            last = path[i]
    return np.asarray(kept, dtype=np.int64)


@njit(cache=True, error_model="numpy", parallel=True)
def _mean_kernel(q: FloatArray, a: FloatArray, alpha: FloatArray, ell: float,
                 beta: FloatArray) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - numba
    """Posterior mean f (Q,) and its gradient (Q, 3) at q (Q, 3), normalised units: the SE
    covariances with the observations of a (M, 3) weighted by alpha (4M,), plus the trend
    beta . phi(q) (:func:`_quadric`)."""
    nq, m = q.shape[0], a.shape[0]
    f = np.empty(nq)
    g = np.empty((nq, 3))
    il2 = 1.0 / (ell * ell)
    r2 = math.sqrt(2.0)
    for i in prange(nq):  # each point on its own: the same bits on any number of threads
        x, y, z = q[i, 0], q[i, 1], q[i, 2]
        bxy, bxz, byz = r2 * beta[7], r2 * beta[8], r2 * beta[9]  # phi's mixed terms
        fi = (beta[0] + beta[1] * x + beta[2] * y + beta[3] * z + beta[4] * x * x
              + beta[5] * y * y + beta[6] * z * z + bxy * x * y + bxz * x * z + byz * y * z)
        gx = beta[1] + 2 * beta[4] * x + bxy * y + bxz * z
        gy = beta[2] + 2 * beta[5] * y + bxy * x + byz * z
        gz = beta[3] + 2 * beta[6] * z + bxz * x + byz * y
        for j in range(m):
            dx, dy, dz = x - a[j, 0], y - a[j, 1], z - a[j, 2]
            k = math.exp(-0.5 * (dx * dx + dy * dy + dz * dz) * il2)
            av = alpha[j]
            ax, ay, az = alpha[m + 3 * j], alpha[m + 3 * j + 1], alpha[m + 3 * j + 2]
            dot = (dx * ax + dy * ay + dz * az) * il2
            fi += k * (av + dot)
            # d/dq of k av + k (d . a_g) / ell^2
            c = -k * il2 * (av + dot)
            gx += c * dx + k * il2 * ax
            gy += c * dy + k * il2 * ay
            gz += c * dz + k * il2 * az
        f[i] = fi
        g[i, 0], g[i, 1], g[i, 2] = gx, gy, gz
    return f, g


@dataclass(frozen=True)
class GPSurface:
    """A fitted implicit surface (:func:`fit`); lengths in the cloud's units (m).

    Attributes
    ----------
    center, scale
        c (3,) and s: u = (x - c) / s.
    active
        Indices (M,) of the points the fit used, into the cloud given to :func:`fit` followed
        by the points given to each :func:`extended`.
    length_scale, sigma, normal_std, quadric_std
        The selected ``ell`` and ``sigma`` (units of s), ``tau`` (rad), and q.
    log_likelihood
        The log marginal likelihood of the selection, per observation.
    residual_std
        RMS of f at the contact points the fit did not use, m: its error near the data,
        measured on points it has not seen (at most ``HELD_OUT`` of them), added to
        :meth:`std` in quadrature.
    n_points
        The points given to :func:`fit` and to each :func:`extended` since.
    """

    center: FloatArray
    scale: float
    active: IntArray
    length_scale: float
    sigma: float
    normal_std: float
    quadric_std: float
    log_likelihood: float
    residual_std: float
    point_std: float  # least std of f at a contact point, units of s (``GPParams.point_std_m``)
    _point_std: FloatArray  # each active point's (and conditioned point's) std of f, units of s
    _u: FloatArray
    _n: FloatArray  # the active points' unit normals
    _solution: _Solution
    _alpha_se: FloatArray  # sigma^2 alpha: the weights of the SE covariances in the mean
    n_points: int = 0
    _order: IntArray | None = None  # the observations (:func:`_design`'s rows) in the order
    # of ``_solution``'s factor; None: that order (:func:`extended` appends blocks)

    def evaluate(self, points: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mean f (N,) in m (> 0 outside; about the signed distance near the data) and its
        gradient (N, 3) at points (N, 3), m."""
        q = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.center) / self.scale
        with _MEAN_LOCK:
            f, g = _mean_kernel(np.ascontiguousarray(q), self._u, self._alpha_se,
                                self.length_scale, self._solution.beta)
        return f * self.scale, g

    @_one_blas_thread
    def std(self, points: FloatArray, chunk: int = 1024, single: bool = False) -> FloatArray:
        """Std (N,) of f at points (N, 3), m: the posterior's and ``residual_std``. Chunks of
        at most ``chunk`` points, at least one per core, are solved on the cores side by side
        (the triangular solves release the GIL); each point's std is computed alone, whatever
        the chunks. ``single``: the triangular solve, most of the cost, in single precision
        (half the time; absolute errors of a few 1e-3 x sigma, which swamp the std near the
        points, far below sigma there: good for a mesh's known part, not for the std itself)."""
        q = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.center) / self.scale
        cores = os.cpu_count() or 1
        parts = [part for part in np.array_split(q, max(cores, -(-len(q) // chunk))) if len(part)]
        chol = self._solution.chol.astype(np.float32) if single else self._solution.chol
        with ThreadPoolExecutor(cores) as pool:
            out = np.concatenate(list(pool.map(partial(self._std_unit, chol=chol), parts))
                                 or [np.zeros(0)])
        return np.hypot(out * self.scale, self.residual_std)

    def _std_unit(self, q: FloatArray, chol: npt.NDArray[np.floating[Any]]) -> FloatArray:
        """Posterior std (Q,) of f at normalised points q (Q, 3), units of s, with the factor
        ``chol`` (in the precision to solve in)."""
        solution, s2 = self._solution, self.sigma**2
        phi, _ = _quadric(q)
        cross = _cross_se(q, self._u, self.length_scale)
        if self._order is not None:
            cross = cross[:, self._order]
        v = solve_triangular(chol, (s2 * cross.T).astype(chol.dtype, copy=False), lower=True,
                             check_finite=False)
        return _posterior_std(solution, s2, phi, v.astype(np.float64, copy=False))

    def position_std(self, points: FloatArray, single: bool = False) -> FloatArray:
        """Std (N,) of the surface's position near points (N, 3) on it, m: sd_f / |grad f|
        (``single``: as for `std`)."""
        _, g = self.evaluate(points)
        return self.std(points, single=single) / np.maximum(np.linalg.norm(g, axis=1), 1e-12)


def _posterior_std(solution: _Solution, s2: float, phi: FloatArray, v: FloatArray) -> FloatArray:
    """Posterior std of f (Q,), units of s, at points with trend monomials phi (Q, 10) and
    v = L^-1 sigma^2 k(observations, points) (4M, Q) in the factor's order."""
    # the trend's share: R^T M^-1 R with R = phi - A^T v (eq. 2.42)
    r = solve_triangular(solution.chol_beta, phi.T - solution.basis.T @ v, lower=True,
                         check_finite=False)
    variance = s2 - np.einsum("ij,ij->j", v, v) + np.einsum("ij,ij->j", r, r)
    return np.sqrt(np.maximum(variance, 0.0))


@dataclass(frozen=True)
class _Solution:
    """GP regression with the quadric trend as an explicit basis (Rasmussen & Williams 2006,
    eqs. 2.41-2.43 with the prior beta ~ N(0, q^2 I)): the trend never enters the Cholesky
    factor, whose conditioning is then the SE part's and the noise's (with the trend inside,
    q^2 / point_std^2 ~ 1e11 cost five digits)."""

    chol: FloatArray  # lower Cholesky factor L of K_y = sigma^2 K_SE + noise (the upper
    # triangle is left over: triangular solves do not read it)
    basis: FloatArray  # A = L^-1 G (4M, 10), G the trend's design
    chol_beta: FloatArray  # lower Cholesky factor of M = I / q^2 + A^T A (10, 10)
    alpha: FloatArray  # K_y^-1 (y - G beta), in the factor's order
    beta: FloatArray  # the trend's posterior mean coefficients (10,)
    loglik: float  # log marginal likelihood per observation


def _solve(K_y: FloatArray, G: FloatArray, q: float, y: FloatArray) -> _Solution:
    """GP regression of observations y (n,) with covariance K_y (n, n) and the quadric trend
    of design G (n, 10) and coefficient std q."""
    chol, _ = cho_factor(K_y, lower=True, check_finite=False)
    return _regress(chol, G, q, y)


def _regress(chol: FloatArray, G: FloatArray, q: float, y: FloatArray) -> _Solution:
    """:func:`_solve` given the lower Cholesky factor ``chol`` of K_y."""
    A = solve_triangular(chol, G, lower=True, check_finite=False)
    w = solve_triangular(chol, y, lower=True, check_finite=False)
    chol_beta, _ = cho_factor(np.eye(G.shape[1]) / (q * q) + A.T @ A, lower=True,
                              check_finite=False)
    Aw = A.T @ w
    beta = cho_solve((chol_beta, True), Aw, check_finite=False)
    # K_y^-1 (y - G beta) = L^-T L^-1 (y - G beta) = L^-T (w - A beta): one triangular solve
    # (cho_solve would copy the factor to Fortran order first)
    alpha = solve_triangular(chol, w - A @ beta, lower=True, trans="T", check_finite=False)
    # y ~ N(0, K_y + q^2 G G^T): Woodbury for the quadratic form, the determinant lemma for
    # log |K_y + q^2 G G^T| = log |K_y| + log |q^2 M|
    quadratic = float(w @ w) - float(Aw @ beta)
    logdet = 2.0 * float(np.sum(np.log(np.diag(chol))) + np.sum(np.log(np.diag(chol_beta))))
    logdet += G.shape[1] * math.log(q * q)
    loglik = -0.5 * ((quadratic + logdet) / len(y) + math.log(2 * math.pi))
    return _Solution(chol, A, np.tril(chol_beta), alpha, beta, loglik)


@_one_blas_thread
def fit(points: FloatArray, normals: FloatArray, params: GPParams | None = None,
        point_var_m2: FloatArray | None = None) -> GPSurface:
    """Fit the implicit surface of a contact cloud (see module).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Contact points, m, in line order (per whisker, by time): the active points are taken
        along them (:func:`select_active`).
    normals : ndarray, shape (N, 3)
        Outward unit surface normals at the points.
    params
        Fit parameters.
    point_var_m2 : ndarray, shape (N,), optional
        Each point's position variance along its normal, m^2 (n^T Sigma n of its covariance
        from the wrench noise): its f = 0 observation is weighted by it, with
        ``params.point_std_m`` as the floor and the cloud's radius as the ceiling (NaN:
        the floor).
    """
    params = params or GPParams()
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 4:
        raise ValueError(f"points must have shape (N >= 4, 3), got {points.shape}")
    if normals.shape != points.shape:
        raise ValueError(f"normals must have the shape of points {points.shape}, got "
                         f"{normals.shape}")
    if not (np.isfinite(points).all() and np.isfinite(normals).all()):
        raise ValueError("points and normals must be finite")
    center = points.mean(axis=0)
    scale = float(np.max(np.linalg.norm(points - center, axis=1)))
    if not scale > 0:
        raise ValueError(f"all {len(points)} points at one place")
    u_all = (points - center) / scale
    n_all = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    point_std = max(params.point_std_m / scale, MIN_POINT_STD)
    stds = _point_stds(points, point_var_m2, scale, point_std)

    def solve(u: FloatArray, n: FloatArray, stds: FloatArray, K_se: FloatArray, sigma: float,
              tau: float) -> _Solution:
        return _solve(sigma * sigma * K_se + _noise(n, stds, tau), _design(u),
                      params.quadric_std, _targets(n))

    best: tuple[float, float, float] | None = None
    likelihood = -math.inf
    chosen = select_active(u_all, params.select_active)
    u, n = u_all[chosen], n_all[chosen]
    for ell in params.length_scales:  # hyperparameters on a coarser selection: cheap
        K_se = _prior(u, ell)
        for sigma in params.sigmas:
            for tau in params.normal_stds:
                trial = solve(u, n, stds[chosen], K_se, sigma, tau)
                if trial.loglik > likelihood:
                    best, likelihood = (ell, sigma, tau), trial.loglik
    assert best is not None  # the candidates are not empty
    ell, sigma, tau = best
    active = select_active(u_all, params.max_active)
    u, n = np.ascontiguousarray(u_all[active]), n_all[active]
    solution = solve(u, n, stds[active], _prior(u, ell), sigma, tau)
    surface = GPSurface(center, scale, active, ell, sigma, tau, params.quadric_std,
                        solution.loglik, 0.0, point_std, stds[active], u, n, solution,
                        sigma * sigma * solution.alpha, len(points))
    unused = np.setdiff1d(np.arange(len(points)), active)
    unused = unused[::max(1, len(unused) // HELD_OUT)]
    if not len(unused):
        return surface
    f, _ = surface.evaluate(points[unused])
    return replace(surface, residual_std=float(np.sqrt(np.mean(f * f))))


def conditioned(surface: GPSurface, points: FloatArray, normals: FloatArray) -> GPSurface:
    """The surface had it also observed ``points`` (K >= 1, 3), m, with outward ``normals``
    (K, 3), its hyperparameters kept: what touching there would leave of its uncertainty
    (the std of a GP does not depend on the values observed, only on where); the new points
    with the least point std. Every point joins: :func:`extended` with all of them (its
    factor extended by a block, not a new factor of all the observations)."""
    return extended(surface, points, normals, len(np.reshape(points, (-1, 3))))


@dataclass(frozen=True)
class StdAt:
    """The std of ``surface`` at fixed points, kept through :func:`conditioned`: the triangular
    solve of the factor's old block is kept (``v``), only the new block's is solved, O(n m Q)
    for n old and m new observations at Q points against O((n + m)^2 Q)."""

    surface: GPSurface
    q: FloatArray  # the points, normalised (Q, 3)
    v: FloatArray  # L^-1 sigma^2 k(observations, q) (4M, Q), rows in the factor's order

    @classmethod
    def of(cls, surface: GPSurface, points: FloatArray) -> StdAt:
        """At points (Q, 3), m."""
        q = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - surface.center) / surface.scale
        cross = _cross_se(q, surface._u, surface.length_scale)
        if surface._order is not None:
            cross = cross[:, surface._order]
        v = solve_triangular(surface._solution.chol, surface.sigma**2 * cross.T, lower=True,
                             check_finite=False)
        return cls(surface, q, v)

    def std(self) -> FloatArray:
        """Std (Q,) of f at the points, m: ``surface.std``'s."""
        phi, _ = _quadric(self.q)
        std = _posterior_std(self.surface._solution, self.surface.sigma**2, phi, self.v)
        return np.hypot(std * self.surface.scale, self.surface.residual_std)

    @_one_blas_thread
    def conditioned(self, points: FloatArray, normals: FloatArray) -> StdAt:
        """At the same points, of :func:`conditioned` (``surface``, ``points``, ``normals``)."""
        surface = conditioned(self.surface, points, normals)
        k = len(self.v)
        chol = surface._solution.chol  # the old factor, then the new block's rows
        cross = _cross_se(self.q, surface._u[len(self.surface._u):], surface.length_scale)
        v_new = solve_triangular(chol[k:, k:], surface.sigma**2 * cross.T - chol[k:, :k] @ self.v,
                                 lower=True, check_finite=False)
        return StdAt(surface, self.q, np.concatenate([self.v, v_new]))


def _point_stds(points: FloatArray, point_var_m2: FloatArray | None, scale: float,
                point_std: float) -> FloatArray:
    """Each point's std of f (N,), units of s: from its variance along the normal (m^2; NaN:
    none), floored at ``point_std`` and capped at the cloud's radius (:func:`fit`)."""
    if point_var_m2 is None:
        return np.full(len(points), point_std)
    var = np.asarray(point_var_m2, dtype=np.float64).reshape(-1)
    if var.shape != (len(points),):
        raise ValueError(f"point_var_m2 must have shape ({len(points)},), got {var.shape}")
    var = np.nan_to_num(var, nan=0.0, posinf=scale * scale, neginf=0.0)
    return np.maximum(np.sqrt(np.clip(var, 0.0, scale * scale)) / scale, point_std)


@_one_blas_thread
def extended(surface: GPSurface, points: FloatArray, normals: FloatArray, count: int,
             point_var_m2: FloatArray | None = None) -> GPSurface:
    """The surface conditioned on more contacts, its hyperparameters, centre and scale kept.

    At most ``count`` of ``points`` (K, 3), m, in line order, with outward ``normals`` (K, 3)
    and variances ``point_var_m2`` (K,) m^2 (as in :func:`fit`), are taken along them
    (:func:`select_active`) and join the active set. The GP regression on the union is exact:
    the Cholesky factor of the old observations is kept and extended by a block (the new
    observations' rows: L21 = C^T L^-T, L22 L22^T = D - L21 L21^T), O(n^2 m) for n old and m
    new observations against the O((n + m)^3) of a new factor; the factor then holds the
    observations in another order than :func:`_design` (``_order``). ``residual_std`` is the
    old fit's.
    """
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if normals.shape != points.shape or not len(points):
        raise ValueError(f"points and normals must have one shape (K >= 1, 3), got "
                         f"{points.shape} and {normals.shape}")
    stds_all = _point_stds(points, point_var_m2, surface.scale, surface.point_std)
    u_all = (points - surface.center) / surface.scale
    chosen = select_active(u_all, count)
    m_old, m_new = len(surface._u), len(chosen)
    m = m_old + m_new
    u = np.ascontiguousarray(np.concatenate([surface._u, u_all[chosen]]))
    n = np.concatenate([surface._n, normals[chosen] / np.linalg.norm(
        normals[chosen], axis=1, keepdims=True)])
    stds = np.concatenate([surface._point_std, stds_all[chosen]])
    # the old observations (f of each point, then its gradient) in :func:`_design`'s rows of
    # the union, in the old factor's order; then the new ones
    old = np.arange(4 * m_old) if surface._order is None else surface._order
    old = np.where(old < m_old, old, old + m_new)
    order = np.concatenate([old, m_old + np.arange(m_new), m + 3 * m_old + np.arange(3 * m_new)])
    sigma, ell = surface.sigma, surface.length_scale
    # K_y's new columns: C with the old observations (in the factor's order), D with themselves
    C = sigma * sigma * _prior_cross(surface._u, u[m_old:], ell)
    if surface._order is not None:
        C = C[surface._order]
    D = sigma * sigma * _prior(u[m_old:], ell) + _noise(n[m_old:], stds[m_old:],
                                                       surface.normal_std)
    k = 4 * m_old
    L21 = solve_triangular(surface._solution.chol, C, lower=True, check_finite=False).T
    L22, _ = cho_factor(D - L21 @ L21.T, lower=True, check_finite=False)
    chol = np.zeros((4 * m, 4 * m))
    chol[:k, :k] = surface._solution.chol
    chol[k:, :k] = L21
    chol[k:, k:] = np.tril(L22)
    solution = _regress(chol, _design(u)[order], surface.quadric_std, _targets(n)[order])
    alpha = np.empty_like(solution.alpha)
    alpha[order] = solution.alpha
    return replace(surface, active=np.concatenate([surface.active, surface.n_points + chosen]),
                   n_points=surface.n_points + len(points),
                   log_likelihood=solution.loglik, _point_std=stds, _u=u, _n=n,
                   _solution=solution, _alpha_se=sigma * sigma * alpha, _order=order)


def _targets(normals: FloatArray) -> FloatArray:
    """The observations y (4M,) at points with normals (M, 3): f = 0, then grad f = n."""
    return np.concatenate([np.zeros(len(normals)), normals.ravel()])


@dataclass(frozen=True)
class SurfaceMeshStd:
    """A mesh of the mean surface with the position std of its vertices (:func:`mesh`).

    ``vertices`` (V, 3) m, ``triangles`` (T, 3), ``std`` (V,) m; ``known`` (T,) marks the
    triangles whose three vertices have std <= ``max_std`` (m).
    """

    vertices: FloatArray
    triangles: IntArray
    std: FloatArray
    known: npt.NDArray[np.bool_]
    max_std: float
    cell: float

    def part(self, known: bool) -> tuple[FloatArray, IntArray, FloatArray]:
        """(vertices, triangles, std) of the known (or unknown) triangles, unused vertices
        dropped."""
        triangles = self.triangles[self.known == known]
        used, inverse = np.unique(triangles, return_inverse=True)
        return (self.vertices[used], inverse.reshape(-1, 3).astype(np.int64),
                self.std[used])


COARSE = 4
"""Fine grid cells per coarse cell in :func:`mesh`."""

BAND = 0.5
"""A coarse cell is meshed exactly when its corners' f change sign or one's |f| is below
BAND x its side x the largest |grad f| at its corners (and so are its neighbours): the mean
is smooth on the scale of ell, many coarse cells."""


KNOWN_FRACTION = 0.2
"""Default ``max_std`` of :func:`mesh`: this fraction of the prior std of f (sigma s), i.e.
the data have cut the uncertainty of the surface to a fifth of what it is where nothing was
touched."""


def mesh(surface: GPSurface, box_lo: FloatArray, box_hi: FloatArray, cells: int = 64,
         max_std: float = 0.0, single: bool = False) -> SurfaceMeshStd:
    """Marching cubes (scikit-image) of the mean surface over a box, with vertex stds.

    The mean is evaluated on a coarse grid (``COARSE`` cells per coarse cell), then exactly
    on the fine grid only in the coarse cells near its zero set (``BAND``); elsewhere the fine
    grid takes the coarse grid's trilinear values, whose sign is all marching cubes needs.

    Parameters
    ----------
    surface
        The fit.
    box_lo, box_hi : ndarray, shape (3,)
        The box to mesh, m.
    cells
        Fine grid cells along the box's longest side (cubic cells).
    max_std
        Largest position std of a known triangle's vertices, m; 0: ``KNOWN_FRACTION`` x the
        prior std sigma s.
    single
        The vertex stds solved in single precision (`GPSurface.std`): a live map's meshes.
    """
    from scipy.interpolate import RegularGridInterpolator
    from scipy.ndimage import binary_dilation
    from skimage.measure import marching_cubes

    if not (math.isfinite(max_std) and max_std >= 0):
        raise ValueError(f"max_std must be >= 0, got {max_std}")
    max_std = max_std or KNOWN_FRACTION * surface.sigma * surface.scale
    if cells < COARSE:
        raise ValueError(f"cells must be >= {COARSE}, got {cells}")
    box_lo = np.asarray(box_lo, dtype=np.float64)
    box_hi = np.asarray(box_hi, dtype=np.float64)
    cell = float(np.max(box_hi - box_lo)) / cells
    coarse = COARSE * cell
    shape_c = np.ceil((box_hi - box_lo) / coarse).astype(np.int64) + 1
    axes_c = [box_lo[i] + coarse * np.arange(shape_c[i]) for i in range(3)]
    nodes_c = np.stack(np.meshgrid(*axes_c, indexing="ij"), axis=-1).reshape(-1, 3)
    f_c, g_c = surface.evaluate(nodes_c)
    f_c = f_c.reshape(*shape_c)
    g_c = np.linalg.norm(g_c, axis=1).reshape(*shape_c)
    nx, ny, nz = (int(v) - 1 for v in shape_c)  # coarse cells
    corners = [(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    f_min = np.min([f_c[i:i + nx, j:j + ny, k:k + nz] for i, j, k in corners], axis=0)
    f_max = np.max([f_c[i:i + nx, j:j + ny, k:k + nz] for i, j, k in corners], axis=0)
    g_max = np.max([g_c[i:i + nx, j:j + ny, k:k + nz] for i, j, k in corners], axis=0)
    # the zero set crosses the cell (a sign change), or could pass through it between corners
    closest = np.minimum(np.abs(f_min), np.abs(f_max))
    crossed = (f_min <= 0) & (f_max >= 0) | (closest < BAND * coarse * g_max)
    near = binary_dilation(crossed, structure=np.ones((3, 3, 3), dtype=bool))
    empty = SurfaceMeshStd(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0),
                           np.zeros(0, dtype=bool), max_std, cell)
    if not near.any():
        return empty
    shape = (shape_c - 1) * COARSE + 1
    axes = [box_lo[i] + cell * np.arange(shape[i]) for i in range(3)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    f = RegularGridInterpolator(axes_c, f_c)(nodes)
    exact = np.zeros(tuple(shape), dtype=bool)  # fine nodes of near coarse cells
    for i, j, k in np.argwhere(near):
        exact[i * COARSE:(i + 1) * COARSE + 1, j * COARSE:(j + 1) * COARSE + 1,
              k * COARSE:(k + 1) * COARSE + 1] = True
    f[exact], _ = surface.evaluate(nodes[exact])
    if not (f.min() < 0 < f.max()):
        return empty
    vertices, triangles, _, _ = marching_cubes(f, 0.0, spacing=(cell, cell, cell))
    vertices = vertices.astype(np.float64) + box_lo
    std = surface.position_std(vertices, single)
    known = np.all(std[triangles] <= max_std, axis=1)
    return SurfaceMeshStd(vertices, triangles.astype(np.int64), std, known, max_std, cell)
