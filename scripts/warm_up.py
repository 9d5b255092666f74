"""Fill numba's cache of compiled kernels once, at set-up, so that a user's first command is not
late by the compile (a first `vibrissa sweep` took 19 s instead of 1.7 s, a first `make demo`
24 s instead of 15 s).

Runs the commands a new user runs first on tiny inputs, in one process, so that every kernel is
compiled for the argument types those commands pass: a sweep and its reconstruction, a scene of
two whiskers and its reconstruction through the robot's poses, and the Step 2 stream's own
warm-up (`vibrissa.streaming.warm_up`), with and without a noise model. Run:
``python scripts/warm_up.py`` (make setup does).
"""

from __future__ import annotations

import contextlib
import csv
import functools
import io
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

SCENE = """\
mu: 0.3
objects:
  - {name: ball, shape: sphere, radius_m: 0.02, position_m: [0.02, -0.06, 0.0]}
whiskers:  # the rod along C's +z, here the robot's -y
  - name: a
    length_m: 0.05
    ei_nm2: 1.0e-4
    mount: {position_m: [0.0, 0.0, 0.0], quaternion_xyzw: [0.7071067811865476, 0, 0, 0.7071067811865476]}
  - name: b
    length_m: 0.04
    ei_nm2: 8.0e-5
    mount: {position_m: [0.0, 0.0, 0.01], quaternion_xyzw: [0.7071067811865476, 0, 0, 0.7071067811865476]}
path: path.csv
"""


def _write_inputs(folder: Path) -> Path:
    """The scene (two whiskers passing a ball) and its path, in ``folder``; the scene's path."""
    rows = [f"{0.01 * k:.2f},{0.001 * k:.3f},0,0,0,0,0,1" for k in range(41)]
    (folder / "path.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + "\n".join(rows) + "\n",
                                     encoding="utf-8")
    scene = folder / "scene.yaml"
    scene.write_text(SCENE, encoding="utf-8")
    return scene


def _wrenches(simulated: Path, names: tuple[str, ...], out: Path) -> None:
    """The WRENCHES.csv of ``vibrissa reconstruct --scene`` from a ``vibrissa simulate`` folder."""
    lines = ["t,whisker,f0x,f0y,f0z,m0x,m0y,m0z"]
    for name in names:
        with (simulated / f"{name}.csv").open(newline="", encoding="utf-8") as handle:
            lines += [",".join([row["t"], name] + [row[c] for c in lines[0].split(",")[2:]])
                      for row in csv.DictReader(handle)]
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _command(vibrissa: Callable[[list[str]], int], argv: list[str], out: Path) -> int:
    """Run ``vibrissa argv`` quietly; its output only when it fails."""
    if argv[0] == "reconstruct" and "--scene" in argv:
        _wrenches(out / "sim", ("a", "b"), out / "wrenches.csv")
    said = io.StringIO()
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
        status = vibrissa(argv)
    if status != 0:
        print(f"{said.getvalue()}warm-up: vibrissa {' '.join(argv)} exited {status}",
              file=sys.stderr)
    return status


def _stream(settings: Any) -> int:
    from vibrissa.streaming import warm_up

    warm_up(settings)
    return 0


def main() -> int:
    from vibrissa.cli.main import main as vibrissa
    from vibrissa.streaming import StreamSettings

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        scene = _write_inputs(out)
        commands = (["sweep", "--y0", "0.2", "--mu", "0.3", "--step", "0.05",
                     "-o", str(out / "sweep.csv")],
                    ["reconstruct", str(out / "sweep.csv"), "-o", str(out / "rcp.csv")],
                    ["simulate", str(scene), "-o", str(out / "sim"), "--workers", "1"],
                    ["reconstruct", "--scene", str(scene), str(out / "wrenches.csv"),
                     "-o", str(out / "points.csv")])
        steps: list[tuple[str, Callable[[], int]]] = [
            (f"vibrissa {' '.join(argv[:2 if argv[1] == '--scene' else 1])}",
             functools.partial(_command, vibrissa, argv, out)) for argv in commands]
        steps += [("the Step 2 stream", lambda: _stream(StreamSettings())),
                  ("the Step 2 stream with a noise model",
                   lambda: _stream(StreamSettings(noise_force_n=1e-3, noise_moment_nm=1e-3)))]
        for i, (what, step) in enumerate(steps, 1):
            print(f"warm-up {i}/{len(steps)}: {what} ({time.perf_counter() - start:.0f} s so far)",
                  flush=True)
            status = step()
            if status != 0:
                return status
    print(f"numba's cache of compiled kernels is warm ({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
