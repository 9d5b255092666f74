"""Write ``reference_sweeps.npz``: sweeps of the Step 1 engine as it was before the robot
mechanics (issue 15), kept so that the general engine can be held to them (1e-10).

Run once from the repository root: ``.venv/bin/python tests/data/make_reference_sweeps.py``.
Each case is an object, a trail (y0, mu) and a step; together they cover tip and tangential
phases, stick, stick-slip, detachment and snap-off.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from vibrissa.surfaces import parse_surface
from vibrissa.sweep import Trail, simulate_sweeps

CASES = [
    ("paraboloid:a=0.5,b=1,h=0.4", 0.0, 0.2, 0.002),
    ("paraboloid:a=0.5,b=1,h=0.4", 0.2, 0.3, 0.002),
    ("paraboloid:a=0.5,b=1,h=0.4", -0.2, 0.4, 0.001),
    ("paraboloid:a=0.5,b=1,h=0.4", 0.4, 0.0, 0.002),
    ("sphere:r=0.3,cz=0.8", 0.1, 0.25, 0.002),
    ("ellipsoid:rx=0.3,ry=0.2,rz=0.25,cz=0.7,yaw=0.3,roll=0.1", -0.05, 0.1, 0.002),
    ("paraboloid:a=0.5,b=1,h=0.4,yaw=0.4,cx=0.05", 0.1, 0.2, 0.002),
]
FIELDS = ("x0", "phase", "state", "s1", "f0", "m0", "contact", "normal", "force", "refined")


def main() -> None:
    arrays: dict[str, np.ndarray] = {}
    meta = []
    for k, (spec, y0, mu, step) in enumerate(CASES):
        sweep = simulate_sweeps(parse_surface(spec), [Trail(y0, mu)], step)[0]
        for name in FIELDS:
            arrays[f"{k}_{name}"] = getattr(sweep, name)
        meta.append({"surface": spec, "y0": y0, "mu": mu, "step": step, "end": str(sweep.end),
                     "x0_end": sweep.x0_end, "x_touch": sweep.x_touch,
                     "phase_changes": sweep.phase_changes})
        print(spec, y0, mu, step, sweep.n_steps, sweep.end, len(sweep.phase_changes))
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez_compressed(Path(__file__).with_name("reference_sweeps.npz"), **arrays)


if __name__ == "__main__":
    main()
