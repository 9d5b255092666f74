"""The true robot poses of a simulated run with drifting odometry (``truth_poses.csv``): for each
published pose, the truth ``map -> base_link`` and what the odometry said, ``odom ->
base_link``; written for evaluation only, never handed to a node that estimates."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vibrissa.formats.csv_text import cells, csv_writer, read_csv
from vibrissa.formats.errors import SceneError

FloatArray = npt.NDArray[np.float64]

TRUTH_COLUMNS = ("stamp_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw",
                 "odom_x_m", "odom_y_m", "odom_z_m", "odom_qx", "odom_qy", "odom_qz", "odom_qw")
"""Columns of ``truth_poses.csv``: the stamp (s, as the pose message's), the true pose of
``base_link`` in ``map`` (position m, quaternion x, y, z, w), then the published odometry's
pose of ``base_link`` in ``odom``."""


@dataclass(frozen=True)
class TruthPoses:
    """A ``truth_poses.csv``: stamps (n,) s, the true poses (n, 3) m and (n, 4), and the
    odometry's (n, 3) m and (n, 4)."""

    stamp_s: FloatArray
    p_map_m: FloatArray
    q_map: FloatArray
    p_odom_m: FloatArray
    q_odom: FloatArray


@contextmanager
def truth_writer(path: Path) -> Iterator[Any]:
    """A function ``(stamp_s, p_map, q_map, p_odom, q_odom)`` that adds a row to ``path``
    (written whole when the context ends, `csv_writer`)."""
    with csv_writer(path, TRUTH_COLUMNS) as writer:
        def add(stamp_s: float, p_map: FloatArray, q_map: FloatArray, p_odom: FloatArray,
                q_odom: FloatArray) -> None:
            writer.writerow(cells([np.concatenate([[stamp_s], p_map, q_map, p_odom, q_odom])])[0])
        yield add


def read_truth(path: Path) -> TruthPoses:
    """Read a ``truth_poses.csv`` (`SceneError` naming the file and line of what is wrong)."""
    header, records = read_csv(path, TRUTH_COLUMNS)
    index = [header.index(name) for name in TRUTH_COLUMNS]
    rows = []
    for line, row in records:
        try:
            rows.append([float(row[i]) for i in index])
        except (ValueError, IndexError):
            raise SceneError(f"{path}: line {line}: not {len(TRUTH_COLUMNS)} numbers") from None
    table = np.array(rows, dtype=np.float64).reshape(-1, len(TRUTH_COLUMNS))
    return TruthPoses(table[:, 0], table[:, 1:4], table[:, 4:8], table[:, 8:11], table[:, 11:15])
