"""The live map delay benchmark's bookkeeping (benchmarks/bench_map_delay.py) on a small
synthetic run: which mesh covers which contact, and the delays it reports."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[2] / "benchmarks"))
from bench_map_delay import delays  # noqa: E402

# contacts stamped 1..5, received at 10..14 s; two updates, then the final map
CONTACTS = np.array([[10.0, 1.0], [11.0, 2.0], [12.0, 3.0], [13.0, 4.0], [14.0, 5.0]])
MESHES = np.array([[12.5, 2.0], [15.0, 4.0], [20.0, 5.0]])
CLOUDS = np.array([12.4, 14.9, 19.9])


def test_each_contact_waits_for_the_first_mesh_stamped_at_or_after_it() -> None:
    got = delays(CONTACTS, MESHES, CLOUDS, final=True)
    np.testing.assert_allclose(got.delay, [2.5, 1.5, 3.0, 2.0, 6.0])
    assert got.final_only.tolist() == [False, False, False, False, True]
    np.testing.assert_allclose(got.live, [2.5, 1.5, 3.0, 2.0])
    assert got.never == 0
    np.testing.assert_allclose(got.next_update, [2.4, 1.4, 0.4, 1.9, 0.9])


def test_without_the_final_map_a_contact_after_the_last_mesh_is_never_covered() -> None:
    got = delays(CONTACTS, MESHES[:2], CLOUDS[:2], final=False)
    np.testing.assert_allclose(got.delay, [2.5, 1.5, 3.0, 2.0])
    assert not got.final_only.any()
    assert got.never == 1


def test_a_mesh_stamped_behind_an_earlier_one_covers_nothing_new() -> None:
    meshes = np.array([[12.5, 3.0], [13.5, 2.0], [15.0, 4.0]])
    got = delays(CONTACTS[:4], meshes, CLOUDS, final=False)
    np.testing.assert_allclose(got.delay, [2.5, 1.5, 0.5, 2.0])
