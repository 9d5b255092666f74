"""Write path.csv of the robot demo (launch/robot.yaml): the robot drives a 0.4 m arc to the
left, 0.2 mm of path per sample at 500 Hz, its x axis along the arc.

Run from this folder: ``python make_path.py``.
"""

import numpy as np
from scipy.spatial.transform import Rotation

RADIUS_M = 0.4
heading = np.arange(-0.1, 0.75, 5e-4)  # rad; the arc's centre is at (0, RADIUS_M, 0)
t = np.arange(len(heading)) * 0.002
p_WR = np.column_stack([RADIUS_M * np.sin(heading), RADIUS_M * (1 - np.cos(heading)),
                        np.zeros_like(heading)])
q_WR = Rotation.from_euler("z", heading[:, None]).as_quat()
with open("path.csv", "w", encoding="utf-8") as out:
    out.write("t,x,y,z,qx,qy,qz,qw\n")
    for row in np.column_stack([t, p_WR, q_WR]):
        out.write(",".join(repr(float(v)) for v in row) + "\n")
