"""Where a robot explores a scene: its start pose, the workspace box its base stays in, and the
extent of its body (a scene file's ``explore``, `vibrissa.formats.scene_file.load_explore`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vibrissa.frames import Transform
from vibrissa.scene import RobotPath, SceneObject, robot_path

BODY_SAMPLE_M = 2e-3
"""`Explore.objects_in_body` samples the body's volume this finely at most, m ..."""
BODY_SAMPLES = 2_000_000
"""... in at most about this many points."""


@dataclass(frozen=True)
class Explore:
    """An exploration's frame of action, in W (m).

    ``start`` is the pose X_WR of ``base_link`` where the exploration begins; its origin lies
    in the workspace box [``workspace_min_m``, ``workspace_max_m``] (3,) each, min < max on
    every axis, which the base's origin never leaves. The robot body is a vertical cylinder
    (along W's z) of radius ``body_radius_m`` > 0 around ``base_link``'s origin, which must
    never enter an object.
    """

    start: Transform
    workspace_min_m: tuple[float, float, float]
    workspace_max_m: tuple[float, float, float]
    body_radius_m: float

    def __post_init__(self) -> None:
        low = np.asarray(self.workspace_min_m, dtype=float)
        high = np.asarray(self.workspace_max_m, dtype=float)
        if low.shape != (3,) or high.shape != (3,):
            raise ValueError(f"workspace_m: expected min and max of 3 numbers each, got "
                             f"shapes {low.shape} and {high.shape}")
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(low < high)):
            raise ValueError(f"workspace_m: the min {low.tolist()} must be below the max "
                             f"{high.tolist()} on every axis")
        if not (np.isfinite(self.body_radius_m) and self.body_radius_m > 0):
            raise ValueError(f"body_radius_m: expected a number > 0, got {self.body_radius_m!r}")
        p = np.asarray(self.start.translation, dtype=float)
        if not np.all((low <= p) & (p <= high)):
            raise ValueError(f"start.position_m {p.tolist()} is outside the workspace "
                             f"[{low.tolist()}, {high.tolist()}]")
        object.__setattr__(self, "workspace_min_m", tuple(float(v) for v in low))
        object.__setattr__(self, "workspace_max_m", tuple(float(v) for v in high))
        object.__setattr__(self, "body_radius_m", float(self.body_radius_m))

    def start_path(self) -> RobotPath:
        """The robot standing at ``start``: a path of one sample at t = 0 s."""
        return robot_path(np.zeros(1), self.start.translation[None],
                          self.start.quaternion_xyzw[None])

    def objects_in_body(self, objects: Sequence[SceneObject]) -> list[str]:
        """The names of ``objects`` that the body at ``start`` enters, within the workspace's
        heights: its volume sampled every `BODY_SAMPLE_M` (a quarter of its radius at most),
        more coarsely where that would take more than `BODY_SAMPLES` points (a body of 0.5 m
        radius and 2 m: every 9 mm), a layer at a time, and at the height of each object's
        origin."""
        radius = self.body_radius_m
        low, high = self.workspace_min_m[2], self.workspace_max_m[2]
        volume = math.pi * radius**2 * (high - low)
        step = min(max(BODY_SAMPLE_M, (volume / BODY_SAMPLES) ** (1 / 3)), radius / 4)
        grid = np.arange(-radius, radius + step / 2, step)
        x, y = (a.ravel() for a in np.meshgrid(grid, grid))
        inside = np.hypot(x, y) <= radius
        angle = np.linspace(0.0, 2 * math.pi, max(16, math.ceil(2 * math.pi * radius / step)),
                            endpoint=False)
        centre = np.asarray(self.start.translation, dtype=float)
        disc = centre[:2] + np.concatenate([np.column_stack([x[inside], y[inside]]), radius
                                            * np.column_stack([np.cos(angle), np.sin(angle)])])
        layers = max(2, min(math.ceil((high - low) / step) + 1, BODY_SAMPLES // len(disc)))
        surfaces = {obj.name: obj.surface(1.0) for obj in objects}
        # and each object's own height (a ball's widest), for layers further apart than it
        own = np.clip([obj.X_WO.translation[2] for obj in objects], low, high)
        entered: set[str] = set()
        for z in np.union1d(np.linspace(low, high, layers), own):
            points = np.column_stack([disc, np.full(len(disc), z)])
            entered |= {name for name, surface in surfaces.items()
                        if name not in entered and bool((surface.value(points) < 0).any())}
        return [obj.name for obj in objects if obj.name in entered]
