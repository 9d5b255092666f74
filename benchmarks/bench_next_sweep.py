"""Do the mapper's next-sweep proposals cut the map's error more than evenly spaced trails?

On the demo object (the paper's paraboloid, L = 1 m, mu 0.2, step 0.001), from several sets
of trails already swept: fit the map (``vibrissa.mapping.gp_surface``), take its three proposals
(``vibrissa.mapping.next_sweep``), sweep them (Step 1), refit, and measure the largest error of the
map over the reachable surface; do the same with three trails evenly spaced over the same
range. The reachable surface: the true paraboloid's points whose y lies in the range the first
contacts span and whose z is at most the highest contact (the rod's reach). The error at a true
point x is |f(x)| / |grad f(x)|, the distance to the map's mean surface to first order.

Run: .venv/bin/python benchmarks/bench_next_sweep.py
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vibrissa import Trail, parse_surface, simulate_sweeps
from vibrissa.mapping import contact_normals, gp_surface, propose_sections
from vibrissa.sweep import contact_lines

SPEC = "paraboloid:a=0.5,b=1,h=0.4"
STARTS = {
    "demo (5 trails)": [-0.4, -0.2, 0.0, 0.2, 0.4],
    "-0.4, 0.4": [-0.4, 0.4],
    "-0.4, -0.2": [-0.4, -0.2],
    "0.2": [0.2],
    "-0.2": [-0.2],
    "0.4": [0.4],
}


def cloud(y0s: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Contact points and contact normals of trails at y0s."""
    p, f, line = contact_lines(simulate_sweeps(parse_surface(SPEC),
                                               [Trail(y0, 0.2) for y0 in y0s], 0.001))
    return p, contact_normals(p, f, line)


def max_error_mm(y0s: list[float], reachable: np.ndarray) -> float:
    points, normals = cloud(y0s)
    surface = gp_surface.fit(points, normals)
    f, g = surface.evaluate(reachable)
    return float(np.max(np.abs(f) / np.linalg.norm(g, axis=1))) * 1e3


def main() -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    print(f"{'start':>16} {'error now':>10} {'proposed y0':>22} {'then':>8} "
          f"{'even y0':>22} {'then':>8} {'better':>8} {'s':>6}")
    for name, start in STARTS.items():
        t0 = time.perf_counter()
        points, normals = cloud(start)
        surface = gp_surface.fit(points, normals)
        pad = 0.2 * float(np.linalg.norm(np.ptp(points, axis=0)))
        mesh = gp_surface.mesh(surface, points.min(axis=0) - pad, points.max(axis=0) + pad)
        proposals = propose_sections(surface, mesh.vertices, points, np.array([0.0, 1.0, 0.0]))
        lo, hi = float(points[:, 1].min()), float(points[:, 1].max())
        x, y = np.meshgrid(np.linspace(-1.2, 1.2, 241), np.linspace(lo, hi, 121))
        z = 0.5 * x**2 + y**2 + 0.4
        inside = z <= points[:, 2].max()
        reachable = np.stack([x[inside], y[inside], z[inside]], axis=1)
        proposed = [p.offset_m for p in proposals]
        even = list(np.linspace(lo, hi, 5)[1:-1])
        now = max_error_mm(start, reachable)
        after_proposed = max_error_mm(start + proposed, reachable)
        after_even = max_error_mm(start + even, reachable)
        print(f"{name:>16} {now:10.4f} {', '.join(f'{v:.3f}' for v in proposed):>22} "
              f"{after_proposed:8.4f} {', '.join(f'{v:.3f}' for v in even):>22} "
              f"{after_even:8.4f} {'proposed' if after_proposed < after_even else 'even':>8} "
              f"{time.perf_counter() - t0:6.1f}")
    print("errors in mm (largest over the reachable surface)")


if __name__ == "__main__":
    main()
