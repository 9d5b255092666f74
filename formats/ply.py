"""PLY files of point clouds and triangle meshes (binary little-endian, the layout Open3D writes
and reads), written with numpy."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def write_ply(path: str, points: FloatArray, triangles: IntArray | None = None,
              normals: FloatArray | None = None,
              scalars: dict[str, FloatArray] | None = None) -> None:
    """Write a point cloud (``triangles`` None, optionally with normals) or a triangle mesh as
    binary little-endian PLY, the layout Open3D writes and reads; ``scalars`` are extra vertex
    properties (name -> (V,) values, e.g. ``std_m``), which readers that do not know them skip.

    Written with numpy rather than Open3D, whose writer reports success when the disk is full:
    here a failed write raises ``OSError``.
    """
    points = np.asarray(points, dtype="<f8").reshape(-1, 3)
    properties = ["x", "y", "z"]
    columns = [points]
    if triangles is None and normals is not None:
        properties += ["nx", "ny", "nz"]
        columns.append(np.asarray(normals, dtype="<f8").reshape(-1, 3))
    for name, values in (scalars or {}).items():
        properties.append(name)
        columns.append(np.asarray(values, dtype="<f8").reshape(-1, 1))
    vertices = np.hstack(columns)
    header = ["ply", "format binary_little_endian 1.0", "comment Created by vibrissa",
              f"element vertex {len(vertices)}", *(f"property double {p}" for p in properties)]
    faces = None
    if triangles is not None:
        faces = np.zeros(len(triangles), dtype=[("n", "u1"), ("v", "<u4", (3,))])
        faces["n"] = 3
        faces["v"] = triangles
        header += [f"element face {len(faces)}", "property list uchar uint vertex_indices"]
    with open(path, "wb") as f:
        f.write(("\n".join([*header, "end_header"]) + "\n").encode("ascii"))
        f.write(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
        if faces is not None:
            f.write(faces.tobytes())
