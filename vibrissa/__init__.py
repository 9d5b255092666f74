"""vibrissa: a whisker-like tactile sensor as a robot sense (Merker, frictional 3D scanning).

Core mechanics in the paper's dimensionless units (eq. 1); numpy/scipy, with the per-sample
kernels compiled by numba (``vibrissa.compiled``).

* :func:`simulate_sweep`, :func:`simulate_sweeps` -- Step 1, quasi-static frictional sweeps.
* :class:`Scene`, :func:`simulate` -- Step 1 for a robot's whiskers along its path (SI).
* :func:`reconstruct` -- Step 2, contact points from clamp position and support reactions.
* :func:`parse_surface` -- paraboloid (eq. 2), sphere and ellipsoid objects with a pose.
* :class:`RodScale` -- the conversion to SI.
* :class:`Transform` -- rigid transforms (poses X_AB), on ``scipy.spatial.transform``.
"""

from vibrissa.frames import Transform
from vibrissa.reconstruct import Reconstruction, reconstruct
from vibrissa.scene import RobotPath, Scene, SceneObject, Whisker, robot_path, simulate
from vibrissa.status import ContactStatus
from vibrissa.surfaces import Ellipsoid, Paraboloid, Sphere, Surface, parse_surface
from vibrissa.sweep import Sweep, Trail, simulate_sweep, simulate_sweeps
from vibrissa.units import RodScale

__all__ = [
    "ContactStatus",
    "Ellipsoid",
    "Paraboloid",
    "Reconstruction",
    "RobotPath",
    "RodScale",
    "Scene",
    "SceneObject",
    "Sphere",
    "Surface",
    "Sweep",
    "Trail",
    "Transform",
    "Whisker",
    "parse_surface",
    "reconstruct",
    "robot_path",
    "simulate",
    "simulate_sweep",
    "simulate_sweeps",
]
