"""The Step 1 engine against sweeps stored before its generalisation to any clamp path
(``tests/data/reference_sweeps.npz``, written by ``make_reference_sweeps.py`` from the engine
of the straight trail): the same equilibria to 1e-10, the same endings and phase changes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vibrissa.surfaces import parse_surface
from vibrissa.sweep import Trail, simulate_sweeps

DATA = np.load(Path(__file__).parents[1] / "data" / "reference_sweeps.npz")
META = json.loads(str(DATA["meta"]))
TOL = 1e-10


@pytest.mark.parametrize("k", range(len(META)), ids=lambda k: f"{META[k]['surface']}|{META[k]['y0']}|{META[k]['mu']}")
def test_sweeps_match_the_stored_reference(k: int) -> None:
    case = META[k]
    sweep = simulate_sweeps(parse_surface(case["surface"]), [Trail(case["y0"], case["mu"])],
                            case["step"])[0]
    assert str(sweep.end) == case["end"]
    assert sweep.n_steps == len(DATA[f"{k}_x0"])
    np.testing.assert_array_equal(sweep.phase, DATA[f"{k}_phase"])
    np.testing.assert_array_equal(sweep.state, DATA[f"{k}_state"])
    np.testing.assert_array_equal(sweep.refined, DATA[f"{k}_refined"])
    for name in ("x0", "s1", "f0", "m0", "contact", "normal", "force"):
        np.testing.assert_allclose(getattr(sweep, name), DATA[f"{k}_{name}"], rtol=0, atol=TOL,
                                   err_msg=name)
    assert sweep.x0_end == pytest.approx(case["x0_end"], abs=TOL)
    assert sweep.x_touch == pytest.approx(case["x_touch"], abs=TOL)
    assert len(sweep.phase_changes) == len(case["phase_changes"])
    for (x0, old, new), (x0_ref, old_ref, new_ref) in zip(sweep.phase_changes,
                                                          case["phase_changes"], strict=True):
        assert (old, new) == (old_ref, new_ref) and x0 == pytest.approx(x0_ref, abs=TOL)
