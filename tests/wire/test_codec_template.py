"""The codec's template path (msgs/codec.py): a payload read in place through the template of
its stream decodes to exactly what the general path gives, or is refused the same way."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import vibrissa.msgs.codec as codec
from vibrissa.msgs import (
    ContactPoint,
    ContactPointArray,
    ContactStatus,
    Message,
    WhiskerWrench,
    WhiskerWrenchArray,
)
from vibrissa.msgs.codec import DecodeError, decode, encode

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ROWS = 5


def wrench_array(seq: int = 3, posed: bool = True, names: str = "w") -> WhiskerWrenchArray:
    rng = np.random.default_rng(seq)
    pose: dict[str, Any] = {}
    if posed:
        pose = {"pose_frame_id": "world", "clamp_position": rng.normal(size=(ROWS, 3)),
                "clamp_orientation": np.tile([0.0, 0.0, 0.6, 0.8], (ROWS, 1))}
    return WhiskerWrenchArray(
        stamp=0.25 * seq, seq=seq, whisker_ids=[f"{names}{i}" for i in range(ROWS)],
        frame_ids=[f"{names}{i}/clamp" for i in range(ROWS)], f0=rng.normal(size=(ROWS, 3)),
        m0=rng.normal(size=(ROWS, 3)), **pose)


def contact_array(seq: int = 3, covariance: bool = True) -> ContactPointArray:
    rng = np.random.default_rng(seq)
    return ContactPointArray(
        stamp=0.25 * seq, seq=seq, frame_id="world", whisker_ids=[f"w{i}" for i in range(ROWS)],
        point=rng.normal(size=(ROWS, 3)), s1=rng.uniform(0, 0.05, ROWS), phase=[1, 2, 2, 1, 2],
        force=rng.normal(size=(ROWS, 3)), status=[0, 16, 0, 32, 0],
        covariance=np.tile(np.eye(3), (ROWS, 1, 1)) if covariance else None)


STREAMS: dict[str, Callable[[int], Message]] = {
    "wrenches with poses": wrench_array,
    "wrenches in clamp frames": lambda seq: wrench_array(seq, posed=False),
    "wrenches, seq a uint16": lambda seq: wrench_array(seq + 300),
    "contacts": contact_array,
    "contacts without covariance": lambda seq: contact_array(seq, covariance=False),
}


@pytest.fixture(autouse=True)
def no_templates() -> Iterator[None]:
    """Each test starts, and leaves, without templates."""
    codec._TEMPLATES.clear()
    codec._MISSES.clear()
    codec._last_decoded[0] = None
    yield
    codec._TEMPLATES.clear()
    codec._MISSES.clear()


@contextlib.contextmanager
def templates_off() -> Iterator[None]:
    kept = codec._TEMPLATES, codec._TEMPLATED, codec._last_decoded[0]
    codec._TEMPLATES, codec._TEMPLATED = {}, frozenset()
    try:
        yield
    finally:
        codec._TEMPLATES, codec._TEMPLATED, codec._last_decoded[0] = kept


def outcome(payload: bytes) -> Message | tuple[type, str]:
    try:
        return decode(payload)
    except DecodeError as exc:
        return type(exc), str(exc)


def assert_same_as_general(payload: bytes) -> Message | tuple[type, str]:
    got = outcome(payload)
    with templates_off():
        want = outcome(payload)
    if isinstance(want, tuple):
        assert got == want
        return got
    assert type(got) is type(want) and got == want
    for name, value in want.__dict__.items():  # same types, dtypes and shapes, read-only arrays
        other = got.__dict__[name]
        assert type(other) is type(value)
        if isinstance(value, np.ndarray):
            assert other.dtype == value.dtype and other.shape == value.shape
            assert not other.flags.writeable
    return got


def templated(payload: bytes) -> codec._Template:
    """The template a stream of ``payload``'s layout leaves: two of them in a row."""
    decode(payload)
    decode(payload)
    template = codec._TEMPLATES[len(payload)][0]
    assert codec._from_template(template, payload) is not None
    return template


@pytest.mark.parametrize("stream", sorted(STREAMS))
def test_a_stream_is_read_through_its_template_to_the_general_paths_messages(stream: str) -> None:
    make = STREAMS[stream]
    template = templated(encode(make(3)))
    for seq in range(4, 40):  # other numbers, the same layout (seq a positive fixint)
        payload = encode(make(seq))
        assert codec._from_template(template, payload) is not None
        assert assert_same_as_general(payload) == make(seq)


def test_an_int_of_another_msgpack_type_or_length_is_not_read_in_place() -> None:
    template = templated(encode(wrench_array(100)))  # seq 100: a positive fixint
    assert codec._from_template(template, encode(wrench_array(101))) is not None
    wide = encode(wrench_array(300))  # uint16: two bytes longer, another length
    assert len(wide) == len(encode(wrench_array(100))) + 2 and len(wide) not in codec._TEMPLATES
    assert assert_same_as_general(wide) == wrench_array(300)
    assert codec._from_template(templated(wide), encode(wrench_array(65000))) is not None


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_number_in_a_slot_is_refused_as_the_general_path_refuses_it(
        bad: float) -> None:
    payload = encode(wrench_array(3))
    template = templated(payload)
    for name, kind, offset, _ in template.slots:
        if kind == codec._SLOT_INT:
            continue
        raw = (np.array([bad], ">f8") if kind == codec._SLOT_FLOAT else np.array([bad], "<f8"))
        mutated = payload[:offset] + raw.tobytes() + payload[offset + 8:]
        got = assert_same_as_general(mutated)
        assert isinstance(got, tuple) and got[0].__name__ == "NonFiniteError", name


def test_an_undefined_status_flag_in_a_contact_array_is_refused_as_in_general() -> None:
    payload = encode(contact_array(3))
    template = templated(payload)
    (offset,) = [o for name, _, o, _ in template.slots if name == "status"]
    mutated = payload[:offset] + np.array([1 << 20], "<i4").tobytes() + payload[offset + 4:]
    got = assert_same_as_general(mutated)
    assert isinstance(got, tuple) and "ContactPointArray.status" in got[1]
    assert codec._from_template(template, mutated) is None


def test_two_sources_of_one_length_each_keep_their_template() -> None:
    a, b = encode(wrench_array(3, names="a")), encode(wrench_array(3, names="b"))
    assert len(a) == len(b)
    templated(a)
    templated(b)
    assert len(codec._TEMPLATES[len(a)]) == 2
    for seq in range(4, 20):
        for names in "ab":
            payload = encode(wrench_array(seq, names=names))
            assert any(codec._from_template(t, payload) for t in codec._TEMPLATES[len(a)])
            assert assert_same_as_general(payload) == wrench_array(seq, names=names)


def test_many_sources_of_one_length_cost_a_walk_per_64_payloads_at_most(
        monkeypatch: pytest.MonkeyPatch) -> None:
    walks = []
    make = codec._make_template
    monkeypatch.setattr(codec, "_make_template", lambda p, m: walks.append(1) or make(p, m))
    sources = "abcdefghij"  # more than the templates kept per length
    n = 0
    for seq in range(3, 100):
        for names in sources:  # each source sends twice in a row: each would be a stream
            for _ in range(2):
                payload = encode(wrench_array(seq, names=names))
                assert assert_same_as_general(payload) == wrench_array(seq, names=names)
                n += 1
    assert len(walks) <= codec._PER_LENGTH + n // codec._RELEARN_AFTER + 1


def test_per_wrench_types_are_not_templated() -> None:
    for seq in range(3):
        decode(encode(WhiskerWrench(stamp=0.0, seq=seq, whisker_id="w0", frame_id="w0/clamp",
                                    f0=[1.0, 0, 0], m0=[0, 0.1, 0])))
        decode(encode(ContactPoint(stamp=0.0, seq=seq, whisker_id="w0", frame_id="world",
                                   point=[0.0, 0, 0], s1=0.01, phase=1, force=[1.0, 0, 0],
                                   status=ContactStatus.OK)))
    assert codec._TEMPLATES == {}


def test_a_mutable_payload_is_never_read_in_place() -> None:
    payload = encode(wrench_array(3))
    templated(payload)
    buffer = bytearray(encode(wrench_array(4)))
    msg = decode(buffer)  # type: ignore[arg-type]
    buffer[-8:] = b"\0" * 8
    assert msg == wrench_array(4)


# -- fuzzing: whatever replaces a template's numbers or its other bytes, the same outcome ------


@FUZZ
@given(st.sampled_from(sorted(STREAMS)), st.data())
def test_any_bytes_in_the_slots(stream: str, data: st.DataObject) -> None:
    payload = bytearray(encode(STREAMS[stream](3)))
    template = templated(bytes(payload))
    for _, kind, offset, check in template.slots:
        if data.draw(st.booleans()):
            size = 8 if kind == codec._SLOT_FLOAT else (
                check[1] if kind == codec._SLOT_INT else check[2] * check[0].itemsize)
            payload[offset:offset + size] = data.draw(st.binary(min_size=size, max_size=size))
    assert_same_as_general(bytes(payload))


@FUZZ
@given(st.sampled_from(sorted(STREAMS)), st.data())
def test_any_byte_changed_anywhere(stream: str, data: st.DataObject) -> None:
    payload = bytearray(encode(STREAMS[stream](3)))
    templated(bytes(payload))
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(payload) - 1))
        payload[at] = data.draw(st.integers(0, 255))
    assert_same_as_general(bytes(payload))


def test_a_long_payload_gets_no_template() -> None:
    rows = 1200  # 1 200 whiskers: a 77 kB tick
    wide = WhiskerWrenchArray(stamp=0.0, seq=1, whisker_ids=[f"w{i}" for i in range(rows)],
                              frame_ids=[f"w{i}/clamp" for i in range(rows)],
                              f0=np.ones((rows, 3)), m0=np.ones((rows, 3)))
    payload = encode(wide)
    assert len(payload) > codec._MAX_TEMPLATE_BYTES
    for _ in range(3):
        assert decode(payload) == wide
    assert codec._TEMPLATES == {}


def test_a_payload_that_fits_a_template_of_an_unexpected_type_is_refused() -> None:
    payload = encode(wrench_array(3))
    templated(payload)
    with pytest.raises(DecodeError, match="got vibrissa/WhiskerWrenchArray, expected"):
        decode(encode(wrench_array(4)), ContactPointArray)
    assert decode(encode(wrench_array(4)), (ContactPointArray, WhiskerWrenchArray)) == (
        wrench_array(4))


def test_an_older_version_the_codec_upgrades_gets_no_template() -> None:
    obj = msgpack.unpackb(encode(wrench_array(3)), raw=False)
    obj["_v"] = 1  # version 1: frame_id named the pose's frame, no frame_ids
    obj["frame_id"] = obj.pop("pose_frame_id")
    del obj["frame_ids"]
    payload = msgpack.packb(obj)
    for _ in range(3):
        assert assert_same_as_general(payload) == wrench_array(3)
    assert codec._TEMPLATES == {}
