"""The robot description's optional ``sensor`` pose X_CS per whisker."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vibrissa.formats.scene_file import SceneError, load_robot


def test_robot_description_carries_the_sensor_pose(tmp_path: Path) -> None:
    robot = tmp_path / "robot.yaml"
    robot.write_text(
        "whiskers:\n"
        "  - {name: w0, length_m: 0.05, ei_nm2: 2.0e-4, mount: {}}\n"
        "  - {name: w1, length_m: 0.05, ei_nm2: 2.0e-4, mount: {},\n"
        "     sensor: {position_m: [0, 0, -0.012], quaternion_xyzw: [0, 0, 0.7071067811865476, "
        "0.7071067811865476]}}\n")
    w0, w1 = load_robot(robot)
    assert w0.X_CS.is_identity
    np.testing.assert_allclose(w1.X_CS.translation, [0, 0, -0.012])
    np.testing.assert_allclose(w1.X_CS.rotate([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    robot.write_text("whiskers:\n  - {name: w0, length_m: 0.05, ei_nm2: 2.0e-4, mount: {},"
                     " sensor: {position: [0, 0, 1]}}\n")
    with pytest.raises(SceneError, match=r"whiskers\[0\].sensor: unknown key 'position'"):
        load_robot(robot)
