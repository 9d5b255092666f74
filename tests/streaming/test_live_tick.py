"""A recorded live stream (tests/data/live_tick) gives the same ContactPointArray bytes and
counts as when it was recorded: a faster Step 2 publishes the same bytes."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import msgpack
import pytest

from vibrissa.msgs import WhiskerWrenchArray
from vibrissa.msgs.codec import decode

DATA = Path(__file__).parents[1] / "data" / "live_tick"


def recorder() -> ModuleType:
    """tests/data/live_tick/make_live_tick.py as a module (it also makes random wrenches one
    contact's: ``single_contact``)."""
    spec = importlib.util.spec_from_file_location("make_live_tick", DATA / "make_live_tick.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


RECORD = msgpack.unpackb((DATA / "live_tick.msgpack").read_bytes())


@pytest.mark.parametrize("name", sorted(RECORD))
def test_a_recorded_stream_gives_the_recorded_bytes_and_counts(name: str) -> None:
    """The record holds ContactPointArray version 2: the bytes are compared without the free
    whiskers version 3 adds, and those are checked against the ticks' wrenches."""
    recorded = RECORD[name]
    published = recorder().run(name, recorded["input"])
    assert len(published) == len(recorded["output"])
    ticks = {m.seq: m for m in map(decode, recorded["input"]) if isinstance(m, WhiskerWrenchArray)}
    told_free = 0
    for (payload, counts), (want_payload, want_counts) in zip(published, recorded["output"],
                                                              strict=True):
        fields = msgpack.unpackb(payload)
        free = fields.pop("free_ids")
        assert fields["_v"] == 3
        fields["_v"] = 2
        assert msgpack.packb(fields) == want_payload
        tick = ticks[fields["seq"]]
        zero = [w for w, f, m in zip(tick.whisker_ids, tick.f0, tick.m0, strict=True)
                if not (f.any() or m.any())]
        assert not set(free) & set(fields["whisker_ids"])  # a contact is not free
        if name == "noise":  # zero wrenches, and those below the detector's threshold
            assert set(zero) <= set(free)
            told_free += len(free)
        else:
            assert free == zero
        # the recorded counters alike; one added since (`ambiguous`: tapered rods) is 0
        assert {key: counts[key] for key in want_counts} == want_counts
        assert all(counts[key] == 0 for key in counts.keys() - want_counts.keys())
    assert told_free >= published[-1][1]["free"]


def test_the_record_holds_full_and_partial_ticks() -> None:
    # the test above can fail: rows with and without contact, in every stream
    contacts = {name: [counts["contacts"] for _, counts in r["output"]]
                for name, r in RECORD.items()}
    assert contacts["poses"][-1] - contacts["poses"][-2] == 32  # a tick of contacts only
    assert all(c[-1] > 0 for c in contacts.values())
    assert RECORD["noise"]["output"][-1][1]["free"] > 0
