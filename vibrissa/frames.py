"""Rigid transforms and rotations.

Quaternions are (x, y, z, w), scalar last, as in ROS and ``scipy.spatial.transform.Rotation``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from vibrissa.compiled import compiled


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
