"""Rigid transforms: the pose of one frame in another, built on ``scipy.spatial.transform``.

Monogram names (Drake): ``X_AB`` is the pose of frame B in frame A (rotation ``R_AB``, whose
columns are B's axes in A, and translation ``p_AB``, B's origin in A); ``X_AB @ X_BC`` is
``X_AC``; ``X_AB.apply(p_B)`` gives the points in A. Quaternions are (x, y, z, w), scalar
last, as in ROS and scipy. Rotations are scipy's ``Rotation``; where one is asked for
thousands of times (a path's slerp in a simulation, Step 2 on the wire's quaternions) the
compiled quaternion kernels below do the same arithmetic, checked against scipy's ``Rotation``
and ``Slerp`` in the tests.

``scipy.spatial.transform`` is imported where it is first used, not with this module: importing
it costs 0.4 s (``scipy.spatial`` pulls in ``scipy.sparse``), which a process that never
rotates, such as a sweep on the paper's trail, need not pay. The identity pose needs no scipy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vibrissa.compiled import compiled

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]

WORLD_FRAME = "world"
"""The default map frame: the world W of scenes, z up."""

ROBOT_FRAME = "base_link"
"""The default name of the robot's body frame R (REP 105), the parent of the whisker mounts."""

UNIT_QUATERNION_TOL = 1e-6
"""How far from 1 the norm of a quaternion that gives a pose (a scene's mounts and objects, a
robot path) may be: such input is refused, not normalised."""


def non_unit_quaternion(q_xyzw: ArrayLike) -> tuple[int, float] | None:
    """The first of quaternions (N, 4) (or one, (4,)) whose norm is off 1 by more than
    `UNIT_QUATERNION_TOL`, with that norm (inf where it overflows, without numpy's overflow
    warning: the input is refused anyway); None when every one is unit."""
    q = np.atleast_2d(np.asarray(q_xyzw, dtype=float))
    with np.errstate(over="ignore", invalid="ignore"):
        norms = np.sqrt(np.einsum("ij,ij->i", q, q))
    bad = np.flatnonzero(~(np.abs(norms - 1.0) <= UNIT_QUATERNION_TOL))
    return (int(bad[0]), float(norms[bad[0]])) if len(bad) else None


def clamp_frame(whisker: str) -> str:
    """The name of a whisker's clamp frame C, the frame its wrench is measured in:
    ``<whisker>/clamp``."""
    return f"{whisker}/clamp"


class Transform:
    """Pose X_AB of a frame B in a frame A (immutable).

    Parameters
    ----------
    rotation : scipy.spatial.transform.Rotation, optional
        R_AB; the identity if omitted.
    translation : array_like, shape (3,)
        p_AB, B's origin in A (the caller's length unit: m at the boundary, L in the core).

    Attributes
    ----------
    rotation : scipy.spatial.transform.Rotation
        R_AB.
    translation : ndarray, shape (3,)
        p_AB.
    R : ndarray, shape (3, 3)
        R_AB as a matrix (derived, kept for repeated point transforms).
    """

    __slots__ = ("_rotation", "translation", "R")
    _rotation: Rotation | None
    translation: FloatArray
    R: FloatArray

    def __init__(self, rotation: Rotation | None = None, translation: ArrayLike = (0.0, 0.0, 0.0)
                 ) -> None:
        p = np.array(translation, dtype=float).reshape(3)
        p.flags.writeable = False
        R = np.eye(3) if rotation is None else rotation.as_matrix()
        R.flags.writeable = False
        for name, value in (("_rotation", rotation), ("translation", p), ("R", R)):
            object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"Transform is immutable: cannot set {name!r}")

    def __reduce__(self) -> tuple[type[Transform], tuple[Rotation | None, FloatArray]]:
        return Transform, (self._rotation, self.translation)

    def __repr__(self) -> str:
        return f"Transform({self.rotation!r}, {self.translation!r})"

    @property
    def rotation(self) -> Rotation:
        """R_AB (the identity's is built on first use: scipy is imported then)."""
        if self._rotation is None:
            from scipy.spatial.transform import Rotation

            object.__setattr__(self, "_rotation", Rotation.identity())
        return self._rotation

    @classmethod
    def from_quaternion(cls, q_xyzw: ArrayLike, translation: ArrayLike = (0.0, 0.0, 0.0)
                        ) -> Transform:
        """From a quaternion (x, y, z, w) (normalised here; ValueError if zero) and a translation."""
        from scipy.spatial.transform import Rotation

        return cls(Rotation.from_quat(np.asarray(q_xyzw, dtype=float)), np.asarray(translation))

    @classmethod
    def from_xyz_rpy(cls, xyz: ArrayLike = (0.0, 0.0, 0.0), rpy: ArrayLike = (0.0, 0.0, 0.0)
                     ) -> Transform:
        """From a position and roll, pitch, yaw in rad: R = Rz(yaw) Ry(pitch) Rx(roll)."""
        rpy = np.asarray(rpy, dtype=float)
        if not np.any(rpy):
            return cls(None, xyz)  # scipy's matrix of zero angles is the identity exactly
        from scipy.spatial.transform import Rotation

        return cls(Rotation.from_euler("xyz", rpy), xyz)

    @property
    def quaternion_xyzw(self) -> FloatArray:
        """R_AB as a unit quaternion (x, y, z, w)."""
        return self.rotation.as_quat()

    @property
    def rpy(self) -> FloatArray:
        """Roll, pitch, yaw in rad (the inverse of :meth:`from_xyz_rpy`)."""
        return self.rotation.as_euler("xyz")

    @property
    def matrix(self) -> FloatArray:
        """The homogeneous 4x4 matrix."""
        X = np.eye(4)
        X[:3, :3], X[:3, 3] = self.R, self.translation
        return X

    @property
    def is_identity(self) -> bool:
        """Whether this is exactly the identity."""
        return not np.any(self.translation) and np.array_equal(self.R, np.eye(3))

    def __matmul__(self, other: Transform) -> Transform:
        """X_AB @ X_BC = X_AC."""
        return Transform(self.rotation * other.rotation, self.R @ other.translation + self.translation)

    def inv(self) -> Transform:
        """X_BA."""
        inverse = self.rotation.inv()
        return Transform(inverse, -(self.translation @ self.R))

    def apply(self, p_B: ArrayLike) -> FloatArray:
        """Points (N, 3) or (3,) given in B, expressed in A."""
        return np.asarray(p_B, dtype=float) @ self.R.T + self.translation

    def apply_inverse(self, p_A: ArrayLike) -> FloatArray:
        """Points (N, 3) or (3,) given in A, expressed in B."""
        return (np.asarray(p_A, dtype=float) - self.translation) @ self.R

    def rotate(self, v_B: ArrayLike) -> FloatArray:
        """Free vectors (N, 3) or (3,) (directions, forces) from B's axes to A's."""
        return np.asarray(v_B, dtype=float) @ self.R.T

    def apply_wrench(self, f_B: ArrayLike, m_B: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """A wrench (force, moment about B's origin, in B's axes) as the same load in A: the
        force in A's axes and its moment about A's origin, m_A = R m_B + p_AB x (R f_B)."""
        f_A = self.rotate(f_B)
        return f_A, self.rotate(m_B) + np.cross(self.translation, f_A)


@dataclass(frozen=True)
class PoseSamples:
    """Poses X_AB(t) of a frame B in A, sampled at strictly increasing ``t`` (N,): between
    samples the position is linear and the orientation follows the shortest great arc
    (slerp); outside [t_0, t_{N-1}] there is no pose (no extrapolation).

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times (any unit; a path's sample index will do).
    p_AB : ndarray, shape (N, 3)
        B's origin in A.
    rotations : scipy.spatial.transform.Rotation, N rotations
        R_AB.
    """

    t: FloatArray
    p_AB: FloatArray
    rotations: Rotation
    _q: FloatArray = field(init=False, repr=False, compare=False)  # rotations as (x, y, z, w)

    def __post_init__(self) -> None:
        t = np.array(self.t, dtype=float).reshape(-1)
        p = np.array(self.p_AB, dtype=float)
        if len(t) < 2 or not np.all(np.diff(t) > 0):
            raise ValueError("pose samples need at least 2 strictly increasing times")
        if p.shape != (len(t), 3) or len(self.rotations) != len(t):
            raise ValueError(f"{len(t)} times, positions {p.shape}, {len(self.rotations)} rotations")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "p_AB", p)
        object.__setattr__(self, "_q", np.ascontiguousarray(self.rotations.as_quat()))

    def at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Positions (n, 3) and rotation matrices (n, 3, 3) at times ``t`` (n,); ValueError
        outside the samples."""
        p, q = self._at(t)
        return p, quaternion_matrices(q)[0]

    def poses_at(self, t: ArrayLike) -> tuple[FloatArray, Rotation]:
        """`at`, with the orientations as a `Rotation`."""
        from scipy.spatial.transform import Rotation

        p, q = self._at(t)
        return p, Rotation.from_quat(q)

    def _at(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Positions (n, 3) and unit quaternions (n, 4) at ``t``, with the compiled slerp
        (`quaternion_slerp`: scipy's Slerp costs 0.4 ms a call, the path of a simulation asks
        for thousands)."""
        t = np.asarray(t, dtype=float).reshape(-1)
        if not (t.min(initial=self.t[0]) >= self.t[0] and t.max(initial=self.t[0]) <= self.t[-1]):
            raise ValueError(f"t outside the samples [{self.t[0]}, {self.t[-1]}]: no extrapolation")
        return sampled_poses(self.t, self.p_AB, self._q, t)


def interpolate(X_a: Transform, X_b: Transform, t: float) -> Transform:
    """The pose a fraction ``t`` (0 to 1) of the way from ``X_a`` to ``X_b`` (`PoseSamples`'
    rule: position linear, orientation slerp)."""
    if not 0.0 <= t <= 1.0:
        raise ValueError(f"t must be in [0, 1] (no extrapolation), got {t}")
    from scipy.spatial.transform import Rotation

    samples = PoseSamples(np.array([0.0, 1.0]), np.array([X_a.translation, X_b.translation]),
                          Rotation.concatenate([X_a.rotation, X_b.rotation]))
    p, rotations = samples.poses_at([t])
    return Transform(rotations[0], p[0])


@compiled
def rotate_vector(R: FloatArray, x: float, y: float, z: float) -> tuple[float, float, float]:
    """R (3, 3) times the vector (x, y, z), for compiled callers that hold vectors as numbers."""
    return (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z,
            R[1, 0] * x + R[1, 1] * y + R[1, 2] * z,
            R[2, 0] * x + R[2, 1] * y + R[2, 2] * z)


@compiled
def quaternion_matrix(q_xyzw: NDArray[np.float64], R: NDArray[np.float64]) -> float:
    """Write R(q / |q|) of a quaternion (4,) (x, y, z, w) into ``R`` (3, 3); returns |q|^2.

    The hot path's one rotation kernel (compiled, for Step 2 on the wire's quaternions); the
    matrix is not a rotation unless the returned |q|^2 is finite and > 0.
    """
    x, y, z, w = q_xyzw[0], q_xyzw[1], q_xyzw[2], q_xyzw[3]
    norm2 = x * x + y * y + z * z + w * w
    s = 2.0 / norm2 if norm2 > 0.0 else math.nan
    R[0, 0], R[0, 1], R[0, 2] = 1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)
    R[1, 0], R[1, 1], R[1, 2] = s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w)
    R[2, 0], R[2, 1], R[2, 2] = s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)
    return norm2


@compiled
def quaternion_matrices(q_xyzw: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`quaternion_matrix` of every row (N, 4): matrices (N, 3, 3) and |q|^2 (N,)."""
    n = q_xyzw.shape[0]
    R, norm2 = np.empty((n, 3, 3)), np.empty(n)
    for i in range(n):
        norm2[i] = quaternion_matrix(q_xyzw[i], R[i])
    return R, norm2


# -- compiled pose arithmetic on quaternion rows (x, y, z, w) --------------------------------
#
# scipy's Rotation costs 20-200 us a call whatever the size (Slerp: 160 us to build, 190 us
# to evaluate, scipy 1.17), more than a 1 kHz sensor tick can spend on its pose. The frame
# buffer's hot path composes and interpolates with these kernels instead: the same rules as
# scipy's (slerp = R0 exp(f log(R0^-1 R1)) on the shortest arc, quaternion products), checked
# against Rotation and Slerp in tests/core/test_frames.py.


@compiled
def quaternion_products(a_xyzw: FloatArray, b_xyzw: FloatArray) -> FloatArray:
    """Rows (N, 4) of a * b: the rotation b, then a (R_AB * R_BC = R_AC)."""
    n = a_xyzw.shape[0]
    out = np.empty((n, 4))
    for i in range(n):
        ax, ay, az, aw = a_xyzw[i, 0], a_xyzw[i, 1], a_xyzw[i, 2], a_xyzw[i, 3]
        bx, by, bz, bw = b_xyzw[i, 0], b_xyzw[i, 1], b_xyzw[i, 2], b_xyzw[i, 3]
        out[i, 0] = aw * bx + bw * ax + ay * bz - az * by
        out[i, 1] = aw * by + bw * ay + az * bx - ax * bz
        out[i, 2] = aw * bz + bw * az + ax * by - ay * bx
        out[i, 3] = aw * bw - ax * bx - ay * by - az * bz
    return out


@compiled
def quaternion_rotate(q_xyzw: FloatArray, v: FloatArray) -> FloatArray:
    """Rows (N, 3) of R(q_i) v_i for unit quaternions (N, 4) and vectors (N, 3)."""
    n = q_xyzw.shape[0]
    out = np.empty((n, 3))
    R = np.empty((3, 3))
    for i in range(n):
        quaternion_matrix(q_xyzw[i], R)
        out[i, 0], out[i, 1], out[i, 2] = rotate_vector(R, v[i, 0], v[i, 1], v[i, 2])
    return out


@compiled
def mounted_poses(p_TA: FloatArray, q_TA_xyzw: FloatArray, p_AC: FloatArray, q_AC_xyzw: FloatArray
                  ) -> tuple[FloatArray, FloatArray]:
    """Frames C_i mounted at (p_AC (N, 3), q_AC (N, 4)) on a frame A at p_TA (3,), q_TA (4,)
    (unit) in T: p_TC = p_TA + R_TA p_AC and q_TC = q_TA q_AC, rows (N, 3) and (N, 4); the
    same bits as `quaternion_rotate` and `quaternion_products` row by row."""
    n = p_AC.shape[0]
    p_out, q_out = np.empty((n, 3)), np.empty((n, 4))
    R = np.empty((3, 3))
    quaternion_matrix(q_TA_xyzw, R)
    ax, ay, az, aw = q_TA_xyzw[0], q_TA_xyzw[1], q_TA_xyzw[2], q_TA_xyzw[3]
    for i in range(n):
        x, y, z = rotate_vector(R, p_AC[i, 0], p_AC[i, 1], p_AC[i, 2])
        p_out[i, 0], p_out[i, 1], p_out[i, 2] = p_TA[0] + x, p_TA[1] + y, p_TA[2] + z
        bx, by, bz, bw = q_AC_xyzw[i, 0], q_AC_xyzw[i, 1], q_AC_xyzw[i, 2], q_AC_xyzw[i, 3]
        q_out[i, 0] = aw * bx + bw * ax + ay * bz - az * by
        q_out[i, 1] = aw * by + bw * ay + az * bx - ax * bz
        q_out[i, 2] = aw * bz + bw * az + ax * by - ay * bx
        q_out[i, 3] = aw * bw - ax * bx - ay * by - az * bz
    return p_out, q_out


@compiled
def quaternion_turns(q_xyzw: FloatArray) -> FloatArray:
    """Angles (N-1,) of the rotations from each of unit quaternion rows (N, 4) to the next, rad,
    in [0, pi]: the magnitude of q_i^-1 q_(i+1), as scipy's ``(R[:-1].inv() * R[1:]).magnitude()``."""
    n = q_xyzw.shape[0]
    out = np.empty(max(n - 1, 0))
    for i in range(n - 1):
        x0, y0, z0, w0 = q_xyzw[i, 0], q_xyzw[i, 1], q_xyzw[i, 2], q_xyzw[i, 3]
        x1, y1, z1, w1 = q_xyzw[i + 1, 0], q_xyzw[i + 1, 1], q_xyzw[i + 1, 2], q_xyzw[i + 1, 3]
        dx = w0 * x1 - w1 * x0 - (y0 * z1 - z0 * y1)
        dy = w0 * y1 - w1 * y0 - (z0 * x1 - x0 * z1)
        dz = w0 * z1 - w1 * z0 - (x0 * y1 - y0 * x1)
        dw = w0 * w1 + x0 * x1 + y0 * y1 + z0 * z1
        out[i] = 2.0 * math.atan2(math.sqrt(dx * dx + dy * dy + dz * dz), abs(dw))
    return out


@compiled
def quaternion_slerp(q0_xyzw: FloatArray, q1_xyzw: FloatArray, fraction: FloatArray) -> FloatArray:
    """Rows (N, 4) a ``fraction`` (N,) of the way from unit q0 to unit q1 on the shortest arc:
    q0 (q0^-1 q1)^f, as scipy's Slerp."""
    n = q0_xyzw.shape[0]
    out = np.empty((n, 4))
    for i in range(n):
        x0, y0, z0, w0 = q0_xyzw[i, 0], q0_xyzw[i, 1], q0_xyzw[i, 2], q0_xyzw[i, 3]
        x1, y1, z1, w1 = q1_xyzw[i, 0], q1_xyzw[i, 1], q1_xyzw[i, 2], q1_xyzw[i, 3]
        # d = conj(q0) q1, the relative rotation, with w >= 0: the shortest arc
        dx = w0 * x1 - w1 * x0 - (y0 * z1 - z0 * y1)
        dy = w0 * y1 - w1 * y0 - (z0 * x1 - x0 * z1)
        dz = w0 * z1 - w1 * z0 - (x0 * y1 - y0 * x1)
        dw = w0 * w1 + x0 * x1 + y0 * y1 + z0 * z1
        if dw < 0.0:
            dx, dy, dz, dw = -dx, -dy, -dz, -dw
        s = math.sqrt(dx * dx + dy * dy + dz * dz)
        half = math.atan2(s, dw)  # half the angle of d
        f = fraction[i]
        # d^f = (axis sin(f half), cos(f half)); sin(f half) / s -> f as s -> 0
        scale = math.sin(f * half) / s if s > 1e-300 else f
        ex, ey, ez, ew = dx * scale, dy * scale, dz * scale, math.cos(f * half)
        out[i, 0] = w0 * ex + ew * x0 + y0 * ez - z0 * ey
        out[i, 1] = w0 * ey + ew * y0 + z0 * ex - x0 * ez
        out[i, 2] = w0 * ez + ew * z0 + x0 * ey - y0 * ex
        out[i, 3] = w0 * ew - x0 * ex - y0 * ey - z0 * ez
    return out


@compiled
def sampled_poses(t_s: FloatArray, p_s: FloatArray, q_s: FloatArray, t: FloatArray
                  ) -> tuple[FloatArray, FloatArray]:
    """Positions (n, 3) and quaternions (n, 4) at times ``t`` (n,) within samples at increasing
    ``t_s`` (N,) of positions ``p_s`` (N, 3) and unit quaternions ``q_s`` (N, 4): position
    linear, orientation `quaternion_slerp` between the two samples around each time."""
    n, last = t.shape[0], t_s.shape[0] - 2
    k = np.minimum(np.maximum(np.searchsorted(t_s, t, side="right") - 1, 0), last)
    frac = np.empty(n)
    p = np.empty((n, 3))
    for i in range(n):
        a = k[i]
        frac[i] = (t[i] - t_s[a]) / (t_s[a + 1] - t_s[a])
        for j in range(3):
            p[i, j] = p_s[a, j] + frac[i] * (p_s[a + 1, j] - p_s[a, j])
    return p, quaternion_slerp(q_s[k], q_s[k + 1], frac)


@compiled
def pose_between(pose0: FloatArray, pose1: FloatArray, fraction: float
                 ) -> tuple[FloatArray, FloatArray]:
    """The pose a ``fraction`` of the way from pose0 to pose1 ((x, y, z, qx, qy, qz, qw) each),
    as rows (1, 3) and (1, 4): position linear, orientation `quaternion_slerp` (one call for a
    sensor tick's pose, where the array operations would cost more than the arithmetic)."""
    p = np.empty((1, 3))
    for j in range(3):
        p[0, j] = pose0[j] + fraction * (pose1[j] - pose0[j])
    f = np.empty(1)
    f[0] = fraction
    return p, quaternion_slerp(pose0[3:].reshape((1, 4)), pose1[3:].reshape((1, 4)), f)


@compiled
def mounted_poses_between(pose0: FloatArray, pose1: FloatArray, fraction: float,
                          p_AC: FloatArray, q_AC_xyzw: FloatArray) -> tuple[FloatArray, FloatArray]:
    """`mounted_poses` on the pose a ``fraction`` of the way from pose0 to pose1
    (`pose_between`): a sensor tick's clamps on its moving frame in one call, the same bits as
    the two calls."""
    p, q = pose_between(pose0, pose1, fraction)
    return mounted_poses(p[0], q[0], p_AC, q_AC_xyzw)
