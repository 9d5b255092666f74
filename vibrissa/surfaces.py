"""Rigid, smooth, strictly convex objects: the paper's elliptic paraboloid (eq. 2), spheres, ellipsoids.

Every object is a convex quadric in its body frame B,

    g_B(p) = p^T Q p + l . p + c   (< 0 inside, 0 on the surface, > 0 outside),

placed in the world frame W (the clamp's frame of the sweep) by a pose X_WB: p_W = R_WB p_B + p_WB.
Lengths are in units of the rod length L.
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa.compiled import compiled
from vibrissa.frames import Transform
from vibrissa.units import number_text

FloatArray = NDArray[np.float64]


class Surface(ABC):
    """A strictly convex quadric object placed in the world frame.

    Subclasses give the body-frame quadric (Q, l, c) and the closest point in the body frame.
    All methods take and return world-frame arrays of shape (N, 3) (or (3,) for one point).
    """

    def __init__(self, pose: Transform | None = None) -> None:
        self.pose = pose if pose is not None else Transform()

    @property
    @abstractmethod
    def spec(self) -> str:
        """The spec string that rebuilds this surface with :func:`parse_surface`."""

    @abstractmethod
    def _quadric(self) -> tuple[FloatArray, FloatArray, float]:
        """Body-frame (Q (3, 3) symmetric positive semi-definite, l (3,), c)."""

    @property
    def quadric(self) -> tuple[FloatArray, FloatArray, float]:
        """Body-frame (Q (3, 3), l (3,), c): g_B(p) = p' Q p + l . p + c."""
        return self._quadric()

    @functools.cached_property
    def kernel_arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """The object as one row of the compiled kernels of Step 1 (``vibrissa.equilibrium``):
        Q (1, 3, 3), l (1, 3), c (1,), R_WB (1, 3, 3), p_WB (1, 3), contiguous float64, which
        rows of several objects stack along the first axis; computed once (an object does not
        change)."""
        Q, linear, c = self._quadric()
        return (np.array([Q], dtype=float), np.array([linear], dtype=float),
                np.array([c], dtype=float), np.array([self.pose.R], dtype=float),
                np.array([self.pose.translation], dtype=float))

    @abstractmethod
    def _closest_point_body(self, q_B: FloatArray) -> FloatArray:
        """Closest surface point (N, 3) to body-frame points q_B (N, 3)."""

    def value(self, p_W: ArrayLike) -> FloatArray:
        """First-order signed distance g / |grad g| (negative inside), units of L, shape (N,)."""
        p_B = self.pose.apply_inverse(np.atleast_2d(np.asarray(p_W, dtype=float)))
        Q, linear, c = self._quadric()
        g = np.einsum("ni,ij,nj->n", p_B, Q, p_B) + p_B @ linear + c
        grad = 2.0 * p_B @ Q + linear
        with np.errstate(divide="ignore"):  # an ellipsoid's centre: -inf, inside
            return g / np.linalg.norm(grad, axis=1)

    def normal(self, p_W: ArrayLike) -> FloatArray:
        """Outward unit normal (N, 3) in W of the level set through p_W."""
        p_B = self.pose.apply_inverse(np.atleast_2d(np.asarray(p_W, dtype=float)))
        Q, linear, _ = self._quadric()
        grad = 2.0 * p_B @ Q + linear
        n_B = grad / np.linalg.norm(grad, axis=1, keepdims=True)
        return n_B @ self.pose.R.T

    def closest_point(self, p_W: ArrayLike) -> FloatArray:
        """Closest point (N, 3) on the surface, in W."""
        p_B = self.pose.apply_inverse(np.atleast_2d(np.asarray(p_W, dtype=float)))
        return self.pose.apply(self._closest_point_body(p_B))

    def signed_distance(self, p_W: ArrayLike) -> FloatArray:
        """Exact signed distance (N,) to the surface, negative inside, units of L."""
        p_W = np.atleast_2d(np.asarray(p_W, dtype=float))
        distance = np.linalg.norm(p_W - self.closest_point(p_W), axis=1)
        return np.where(self.value(p_W) < 0.0, -distance, distance)

    def line_interval(self, a_W: ArrayLike, d_W: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Parameter interval [t_in, t_out] where the line a + t d lies inside (NaN if never).

        Parameters
        ----------
        a_W, d_W : array_like, shape (N, 3) or (3,)
            Points on the lines and their directions, in W.
        """
        a, d = np.broadcast_arrays(np.atleast_2d(np.asarray(a_W, dtype=float)),
                                   np.atleast_2d(np.asarray(d_W, dtype=float)))
        return line_intervals(np.ascontiguousarray(a), np.ascontiguousarray(d),
                              *(array[0] for array in self.kernel_arrays))

    def segment_inside(self, a_W: ArrayLike, d_W: ArrayLike) -> NDArray[np.bool_]:
        """Whether the segments a + t d, 0 <= t <= 1, have points inside the object (N,); a
        straight rod of length 1 clamped at a along d, for instance."""
        t_in, t_out = self.line_interval(a_W, d_W)
        with np.errstate(invalid="ignore"):  # NaN: the line misses the object
            return (t_in < 1.0) & (t_out > 0.0)

    def is_mirror_symmetric(self, point_W: ArrayLike, normal_W: ArrayLike) -> bool:
        """Whether the object is its own mirror image across the plane (point, normal)."""
        point = np.asarray(point_W, dtype=float)
        n = np.asarray(normal_W, dtype=float)
        n = n / np.linalg.norm(n)
        samples = np.random.default_rng(7).uniform(-2.0, 2.0, size=(64, 3)) + point
        mirrored = samples - 2.0 * np.outer((samples - point) @ n, n)
        g, g_mirror = self.value(samples), self.value(mirrored)
        return bool(np.allclose(g, g_mirror, rtol=1e-12, atol=1e-12))


class Paraboloid(Surface):
    """Elliptic paraboloid z = a x^2 + b y^2 + h in B (eq. 2); the object is the cup above it."""

    def __init__(self, a: float, b: float, h: float, pose: Transform | None = None) -> None:
        if not (a > 0 and b > 0):
            raise ValueError(f"paraboloid needs a > 0 and b > 0, got a={a}, b={b}")
        super().__init__(pose)
        self.a, self.b, self.h = float(a), float(b), float(h)

    @property
    def spec(self) -> str:
        return f"paraboloid:a={self.a!r},b={self.b!r},h={self.h!r}{_pose_spec(self.pose)}"

    def _quadric(self) -> tuple[FloatArray, FloatArray, float]:
        return np.diag([self.a, self.b, 0.0]), np.array([0.0, 0.0, -1.0]), self.h

    def _closest_point_body(self, q_B: FloatArray) -> FloatArray:
        # p - q = lam grad g(p) gives x = qx/(1 - 2 a lam), y = qy/(1 - 2 b lam), z = qz - lam;
        # the constraint is increasing in lam below 1/(2 max(a, b)): bracket and bisect.
        return _paraboloid_closest(np.ascontiguousarray(q_B, dtype=float), self.a, self.b, self.h)


class Ellipsoid(Surface):
    """Ellipsoid (x/rx)^2 + (y/ry)^2 + (z/rz)^2 = 1 in B."""

    def __init__(self, rx: float, ry: float, rz: float, pose: Transform | None = None) -> None:
        if min(rx, ry, rz) <= 0:
            raise ValueError(f"ellipsoid radii must be > 0, got {rx}, {ry}, {rz}")
        super().__init__(pose)
        self.radii = np.array([rx, ry, rz], dtype=float)

    @property
    def spec(self) -> str:
        rx, ry, rz = (float(r) for r in self.radii)
        return f"ellipsoid:rx={rx!r},ry={ry!r},rz={rz!r}{_pose_spec(self.pose)}"

    def _quadric(self) -> tuple[FloatArray, FloatArray, float]:
        return np.diag(1.0 / self.radii**2), np.zeros(3), -1.0

    def _closest_point_body(self, q_B: FloatArray) -> FloatArray:
        return _ellipsoid_closest(np.ascontiguousarray(q_B, dtype=float), self.radii)


class Sphere(Ellipsoid):
    """Sphere of radius r centred on B's origin."""

    def __init__(self, r: float, pose: Transform | None = None) -> None:
        super().__init__(r, r, r, pose)

    @property
    def spec(self) -> str:
        return f"sphere:r={float(self.radii[0])!r}{_pose_spec(self.pose)}"

    def _closest_point_body(self, q_B: FloatArray) -> FloatArray:
        return self.radii[0] * q_B / np.linalg.norm(q_B, axis=1, keepdims=True)


@compiled
def line_interval_body(ax: float, ay: float, az: float, dx: float, dy: float, dz: float,
                       Q: FloatArray, linear: FloatArray, c: float) -> tuple[float, float]:
    """[t_in, t_out] where the body-frame line a + t d lies inside g_B < 0 (NaN, NaN if never):
    the stable roots of qa t^2 + qb t + qc; a line along a paraboloid's axis has qa = 0 and a
    half-infinite interval."""
    qa = qb_half = qc = 0.0
    a, d = (ax, ay, az), (dx, dy, dz)
    for i in range(3):
        for j in range(3):
            qa += d[i] * Q[i, j] * d[j]
            qb_half += a[i] * Q[i, j] * d[j]
            qc += a[i] * Q[i, j] * a[j]
    qb = 2.0 * qb_half + d[0] * linear[0] + d[1] * linear[1] + d[2] * linear[2]
    qc += a[0] * linear[0] + a[1] * linear[1] + a[2] * linear[2] + c
    disc = qb * qb - 4.0 * qa * qc
    if qa > 0.0 and not disc >= 0.0:  # (an object 1e7 L away: qa below the linear test)
        return math.nan, math.nan
    if qa <= 1e-14 * (abs(qb) + abs(qc) + 1.0):
        if qb == 0.0:
            return (-math.inf, math.inf) if qc < 0.0 else (math.nan, math.nan)
        t_lin = -qc / qb
        return (-math.inf, t_lin) if qb > 0 else (t_lin, math.inf)
    if not disc >= 0.0:
        return math.nan, math.nan
    big = -0.5 * (qb + math.copysign(math.sqrt(disc), qb))
    t1, t2 = big / qa, qc / big
    return min(t1, t2), max(t1, t2)


@compiled
def line_interval_world(ax: float, ay: float, az: float, dx: float, dy: float, dz: float,
                        Q: FloatArray, linear: FloatArray, c: float, R_WB: FloatArray,
                        p_WB: FloatArray) -> tuple[float, float]:
    """`line_interval_body` of the line a + t d given in W, the object at (R_WB, p_WB)."""
    ax, ay, az = ax - p_WB[0], ay - p_WB[1], az - p_WB[2]
    return line_interval_body(ax * R_WB[0, 0] + ay * R_WB[1, 0] + az * R_WB[2, 0],
                              ax * R_WB[0, 1] + ay * R_WB[1, 1] + az * R_WB[2, 1],
                              ax * R_WB[0, 2] + ay * R_WB[1, 2] + az * R_WB[2, 2],
                              dx * R_WB[0, 0] + dy * R_WB[1, 0] + dz * R_WB[2, 0],
                              dx * R_WB[0, 1] + dy * R_WB[1, 1] + dz * R_WB[2, 1],
                              dx * R_WB[0, 2] + dy * R_WB[1, 2] + dz * R_WB[2, 2],
                              Q, linear, c)


@compiled
def line_intervals(a_W: FloatArray, d_W: FloatArray, Q: FloatArray, linear: FloatArray,
                   c: float, R_WB: FloatArray, p_WB: FloatArray) -> tuple[FloatArray, FloatArray]:
    """`line_interval_world` of the rows of a_W, d_W (N, 3): t_in (N,), t_out (N,)."""
    n = a_W.shape[0]
    t_in, t_out = np.empty(n), np.empty(n)
    for k in range(n):
        t_in[k], t_out[k] = line_interval_world(a_W[k, 0], a_W[k, 1], a_W[k, 2],
                                                d_W[k, 0], d_W[k, 1], d_W[k, 2],
                                                Q, linear, c, R_WB, p_WB)
    return t_in, t_out


@compiled
def segments_meet(a_W: FloatArray, d_W: FloatArray, Q: FloatArray, linear: FloatArray,
                  c: FloatArray, R_WB: FloatArray, p_WB: FloatArray) -> bool:
    """Whether any segment a + t d, 0 <= t <= 1 (rows of a_W, d_W (N, 3)), has points inside
    any of the objects (`Surface.kernel_arrays` stacked: Q (M, 3, 3) ...): `Surface.segment_inside`
    of every row and object at once."""
    for j in range(Q.shape[0]):
        for k in range(a_W.shape[0]):
            t_in, t_out = line_interval_world(a_W[k, 0], a_W[k, 1], a_W[k, 2],
                                              d_W[k, 0], d_W[k, 1], d_W[k, 2],
                                              Q[j], linear[j], c[j], R_WB[j], p_WB[j])
            if t_in < 1.0 and t_out > 0.0:
                return True
    return False


@compiled
def _ellipsoid_closest(q_B: FloatArray, radii: FloatArray) -> FloatArray:
    """Closest points (N, 3) on the ellipsoid of ``radii`` (3,) to points q_B (N, 3), body frame.

    p_i = r_i^2 q_i / (r_i^2 + lam), and sum (r_i q_i / (r_i^2 + lam))^2 = 1 is decreasing in
    lam above -min r_i^2: bracket and bisect, per point, to the last bit.
    """
    out = np.empty_like(q_B)
    r2 = radii * radii
    for n in range(q_B.shape[0]):
        lo = -r2.min() * (1.0 - 1e-15)
        hi = radii.max() * math.sqrt(q_B[n, 0] ** 2 + q_B[n, 1] ** 2 + q_B[n, 2] ** 2) + 1.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            inside = 0.0
            for i in range(3):
                inside += (radii[i] * q_B[n, i] / (r2[i] + mid)) ** 2
            if 1.0 - inside > 0:
                hi = mid
            else:
                lo = mid
            if hi - lo <= 4e-16 * max(abs(mid), 1.0):
                break
        lam = 0.5 * (lo + hi)
        for i in range(3):
            out[n, i] = r2[i] * q_B[n, i] / (r2[i] + lam)
    return out


@compiled
def _paraboloid_closest(q_B: FloatArray, a: float, b: float, h: float) -> FloatArray:
    """Closest points (N, 3) on z = a x^2 + b y^2 + h to points q_B (N, 3), body frame.

    p - q = lam grad g(p) gives x = qx/(1 - 2 a lam), y = qy/(1 - 2 b lam), z = qz - lam; the
    constraint g(p(lam)) is increasing in lam below 1/(2 max(a, b)): bracket and bisect, per
    point, to the last bit.
    """
    out = np.empty_like(q_B)
    for n in range(q_B.shape[0]):
        qx, qy, qz = q_B[n, 0], q_B[n, 1], q_B[n, 2]
        lo = min(qz - h, 0.0) - 1.0
        hi = (1.0 - 1e-15) / (2.0 * max(a, b))
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            x, y = qx / (1 - 2 * a * mid), qy / (1 - 2 * b * mid)
            if a * x * x + b * y * y + h - qz + mid > 0:
                hi = mid
            else:
                lo = mid
            if hi - lo <= 4e-16 * max(abs(mid), 1.0):
                break
        lam = 0.5 * (lo + hi)
        out[n, 0], out[n, 1], out[n, 2] = qx / (1 - 2 * a * lam), qy / (1 - 2 * b * lam), qz - lam
    return out


_POSE_KEYS = ("cx", "cy", "cz", "roll", "pitch", "yaw")
_SHAPE_KEYS = {
    "paraboloid": ("a", "b", "h"),
    "sphere": ("r",),
    "ellipsoid": ("rx", "ry", "rz"),
}
_POSITION_KEYS = ("h", "cx", "cy", "cz")

SPEC_LIMITS = {"size": (1e-6, 1e3), "position": (-1e3, 1e3)}
"""Closed ranges of a surface spec's numbers, units of L: sizes and curvatures (``r``, ``rx``,
``ry``, ``rz``, ``a``, ``b``) and positions (``cx``, ``cy``, ``cz``, a paraboloid's ``h``).
A sweep's clamp goes to the object, and its equilibria are solved to residuals of 1e-12 L
where a coordinate x L from the origin carries x 1e-16 L of round-off: a ball 1e3 L along the
trail gives the steps and the ending it gives at the origin (contacts within 1e-9 L, as 10 L
along), 1e4 L away a different sweep, 1e6 L away none. (A scene works near its path instead:
`vibrissa.scene.local_origin`.)"""


def _pose_spec(pose: Transform) -> str:
    if pose.is_identity:
        return ""
    cx, cy, cz = (float(c) for c in pose.translation)
    roll, pitch, yaw = (float(angle) for angle in pose.rpy)
    parts = [f"cx={cx!r}", f"cy={cy!r}", f"cz={cz!r}", f"roll={roll!r}", f"pitch={pitch!r}",
             f"yaw={yaw!r}"]
    return "," + ",".join(parts)


def parse_surface(spec: str) -> Surface:
    """Build a surface from a spec string.

    ``paraboloid:a=0.5,b=1,h=0.4``, ``sphere:r=0.3,cx=0,cy=0,cz=0.8`` or
    ``ellipsoid:rx=0.4,ry=0.3,rz=0.2,cx=0,cy=0,cz=0.9``; every kind also takes the pose keys
    cx, cy, cz (position of its body frame, units of L) and roll, pitch, yaw (rad,
    R = Rz(yaw) Ry(pitch) Rx(roll)), all defaulting to 0.

    Raises
    ------
    ValueError
        Naming the unknown kind, a missing or unknown key, or a value that is not a number or
        not within `SPEC_LIMITS`.
    """
    kind, _, body = spec.partition(":")
    kind = kind.strip().lower()
    if kind not in _SHAPE_KEYS:
        raise ValueError(f"surface spec {spec!r}: unknown kind {kind!r}, expected one of {sorted(_SHAPE_KEYS)}")
    values: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in body.split(","))):
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq:
            raise ValueError(f"surface spec {spec!r}: expected key=value, got {item!r}")
        if key not in _SHAPE_KEYS[kind] + _POSE_KEYS:
            allowed = ", ".join(_SHAPE_KEYS[kind] + _POSE_KEYS)
            raise ValueError(f"surface spec {spec!r}: unknown key {key!r} for {kind} (allowed: {allowed})")
        if key in values:
            raise ValueError(f"surface spec {spec!r}: {key} given twice")
        try:
            values[key] = number_text(text.strip())
        except ValueError:
            raise ValueError(f"surface spec {spec!r}: {key}={text!r} is not a number") from None
        if not np.isfinite(values[key]):
            raise ValueError(f"surface spec {spec!r}: {key}={text!r} is not finite")
        kind_of = ("position" if key in _POSITION_KEYS else
                   "size" if key in _SHAPE_KEYS[kind] else None)  # angles: any finite
        if kind_of is not None:
            low, high = SPEC_LIMITS[kind_of]
            if not low <= values[key] <= high:
                raise ValueError(f"surface spec {spec!r}: {key}={text.strip()} is outside "
                                 f"[{low:g}, {high:g}]")
    missing = [key for key in _SHAPE_KEYS[kind] if key not in values]
    if missing:
        raise ValueError(f"surface spec {spec!r}: missing {', '.join(missing)} for {kind}")
    pose = Transform.from_xyz_rpy(
        [values.get(key, 0.0) for key in ("cx", "cy", "cz")],
        [values.get(key, 0.0) for key in ("roll", "pitch", "yaw")],
    )
    if kind == "paraboloid":
        return Paraboloid(values["a"], values["b"], values["h"], pose=pose)
    if kind == "sphere":
        return Sphere(values["r"], pose=pose)
    return Ellipsoid(values["rx"], values["ry"], values["rz"], pose=pose)
