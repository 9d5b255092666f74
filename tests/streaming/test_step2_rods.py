"""Streaming Step 2 of tapered and pre-curved whiskers: each point chosen by continuity with
the whisker's last contact (`ContactMemory`), the same whatever the batches."""

from __future__ import annotations

import numpy as np

from vibrissa.msgs import ContactStatus, WhiskerWrenchArray
from vibrissa.rods import RodShape, integrate_to, loaded_rod
from vibrissa.streaming.step2 import ContactMemory, RodTable, reconstruct_messages
from vibrissa.units import RodScale

AMBIGUOUS = int(ContactStatus.AMBIGUOUS_CONTACT)
SHAPE = RodShape(taper_ratio=0.8211, precurvature=2.1113)
ROD = RodScale(0.05, 2e-5)
FORCE, S1 = np.array([3.713, 0.0, 4.428]), 0.684  # from 0.2 of it on, a second point fits
LOADS = np.linspace(0.1, 1.0, 10)


def ticks() -> list[WhiskerWrenchArray]:
    """The load growing at s1: one tick per load, the clamp at the origin of W."""
    out = []
    for k, a in enumerate(LOADS):
        m0 = loaded_rod(SHAPE, a * FORCE, S1, load_steps=8)
        f0_n, m0_nm = ROD.wrench_to_si(-a * FORCE, m0)
        out.append(WhiskerWrenchArray(
            stamp=float(k), seq=k, whisker_ids=["w"], frame_ids=["w/clamp"], f0=[f0_n],
            m0=[m0_nm], pose_frame_id="world", clamp_position=[[0.0, 0.0, 0.0]],
            clamp_orientation=[[0.0, 0.0, 0.0, 1.0]]))
    return out


def truth() -> np.ndarray:
    return np.array([integrate_to(S1, -a * FORCE, loaded_rod(SHAPE, a * FORCE, S1, 8),
                                  SHAPE.params)[:3] * ROD.length_m for a in LOADS])


def test_a_stream_keeps_its_contact_whatever_the_batches() -> None:
    table = RodTable({"w": ROD}, {"w": SHAPE})
    together = reconstruct_messages(ticks(), table, memory=ContactMemory())
    memory = ContactMemory()
    one_by_one = [reconstruct_messages([tick], table, memory=memory)[0] for tick in ticks()]
    points = np.vstack([o.contacts.point for o in together])
    np.testing.assert_array_equal(points, np.vstack([o.contacts.point for o in one_by_one]))
    np.testing.assert_allclose(points, truth(), atol=1e-6 * ROD.length_m)
    assert not any(o.contacts.status[0] & AMBIGUOUS for o in together)


def test_without_a_memory_the_choice_is_flagged() -> None:
    """Each tick on its own: from the second load on two points fit and the first from the
    clamp is taken, flagged ambiguous."""
    table = RodTable({"w": ROD}, {"w": SHAPE})
    alone = [reconstruct_messages([tick], table)[0] for tick in ticks()]
    flagged = [bool(o.contacts.status[0] & AMBIGUOUS) for o in alone]
    assert flagged == [False] + [True] * 9
    assert [o.ambiguous for o in alone] == [0] + [1] * 9
    assert np.abs(alone[-1].contacts.s1[0] - S1 * ROD.length_m) > 0.1 * ROD.length_m


def test_a_free_whisker_forgets_its_contact() -> None:
    memory = ContactMemory()
    memory.update(["w", "v"], np.array([0.02, 0.01]), np.array([True, True]),
                  np.array([0, AMBIGUOUS], dtype=np.int32))
    memory.forget(["w"])
    previous, ambiguous, chain = memory.links(["w", "v", "w"])
    assert np.isnan(previous[0]) and previous[1] == 0.01
    assert ambiguous.tolist() == [False, True, False]
    assert chain.tolist() == [-1, -1, 0]
