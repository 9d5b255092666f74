"""The paper's sweeps as a test gets them (computed once per run: loaded from the file of the
worker that computed them, under pytest-xdist) are those of a fresh computation, bit for bit."""

import dataclasses

import numpy as np

from tests.conftest import PAPER_SURFACE
from vibrissa.surfaces import parse_surface
from vibrissa.sweep import Sweep, Trail, simulate_sweeps


def test_a_paper_sweep_is_a_fresh_one(paper_sweeps: dict[tuple[float, float], Sweep]) -> None:
    (fresh,) = simulate_sweeps(parse_surface(PAPER_SURFACE), [Trail(0.2, 0.3)], step=0.001)
    given = paper_sweeps[(0.2, 0.3)]
    for field in dataclasses.fields(Sweep):
        a, b = getattr(given, field.name), getattr(fresh, field.name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), field.name
        elif isinstance(a, float):
            assert np.float64(a).tobytes() == np.float64(b).tobytes(), field.name
        else:
            assert a == b, field.name
