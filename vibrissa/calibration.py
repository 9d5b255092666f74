"""Sensor-to-clamp calibration: what a force/torque sensor under the clamp reads, as the clamp's
reaction on the rod (the README's convention), and back.

Frames: C the clamp frame (origin at the clamp point, z along the rod at the clamp), S the
sensor's measurement frame (origin and axes of its calibration), X_CS the pose of S in C
(``vibrissa.scene.Whisker.X_CS``, from the robot description's ``sensor``).

Statics. The clamp is rigid and massless and sits on the sensor. Let the rod be loaded by a
contact force F at P1. The clamp holds the rod with the reaction (f0, m0 about C), so that
the rod is in equilibrium: f0 + F = 0, m0 + p_C1 x F = 0 (README, Conventions). By Newton's
third law the rod pushes on the clamp with (-f0, -m0) about C, and the clamp passes that load
on to the sensor unchanged (nothing else acts on a massless clamp): the sensor reads the load
the rod puts on it, (-f0, -m0) about C. A sensor reports a load as its force in its own
axes and its moment about its own origin S. A load (f, m_A about a point A) has the moment
m_Q = m_A + p_QA x f about a point Q (the force acts through A). So the load (-f0_C, -m0_C about C), taken to S, is
f_S = R_SC (-f0_C), m_S = R_SC (-m0_C) + p_SC x f_S; and back from S to C (Q = C, A = S,
p_QA = p_CS), with R_CS = R_SC^T::

    f0_C = -R_CS f_S
    m0_C = -(R_CS m_S + p_CS x (R_CS f_S))

that is ``X_CS.apply_wrench`` of the reading, negated. With S = C (identity X_CS) a sensor
reads (-f0, -m0), as the README says. The moment's transfer term grows with the distance
from S to C: a sensor origin 10 mm below the clamp turns a 0.1 N lateral force into 1 mN m.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vibrissa.frames import Transform

FloatArray = npt.NDArray[np.float64]

__all__ = ["clamp_to_sensor", "sensor_to_clamp"]


def _wrench(f: npt.ArrayLike, m: npt.ArrayLike, names: tuple[str, str]) -> tuple[FloatArray, FloatArray]:
    f, m = np.asarray(f, dtype=float), np.asarray(m, dtype=float)
    for name, value in zip(names, (f, m), strict=True):
        if value.shape[-1:] != (3,) or value.ndim > 2:
            raise ValueError(f"{name} must have shape (3,) or (N, 3), got {value.shape}")
    if f.shape != m.shape:
        raise ValueError(f"{names[0]} and {names[1]} must have the same shape, got {f.shape} and {m.shape}")
    return f, m


def sensor_to_clamp(f_S: npt.ArrayLike, m_S: npt.ArrayLike, X_CS: Transform
                    ) -> tuple[FloatArray, FloatArray]:
    """The clamp's reaction on the rod (f0_C N, m0_C N m about C, in C's axes) from a sensor
    reading (f_S N, m_S N m: the load on the sensor, about S's origin, in S's axes).

    ``f_S``, ``m_S`` (3,) or (N, 3); the result has their shape. See the module docstring
    for the statics: f0_C = -R_CS f_S, m0_C = -(R_CS m_S + p_CS x (R_CS f_S)).
    """
    f_S, m_S = _wrench(f_S, m_S, ("f_S", "m_S"))
    f_C, m_C = X_CS.apply_wrench(f_S, m_S)
    return -f_C, -m_C


def clamp_to_sensor(f0_C: npt.ArrayLike, m0_C: npt.ArrayLike, X_CS: Transform
                    ) -> tuple[FloatArray, FloatArray]:
    """What a sensor mounted at X_CS reads (f_S N, m_S N m about S, in S's axes) when the
    clamp's reaction on the rod is (f0_C, m0_C about C, in C's axes): the inverse of
    `sensor_to_clamp`, f_S = -R_SC f0_C, m_S = -(R_SC m0_C + p_SC x (R_SC f0_C))."""
    f0_C, m0_C = _wrench(f0_C, m0_C, ("f0_C", "m0_C"))
    f_S, m_S = X_CS.inv().apply_wrench(f0_C, m0_C)
    return -f_S, -m_S
