"""Bags without sockets: write/read round trip, cut-off files, info, JSON export."""

from __future__ import annotations

import io
import json
import logging
import tracemalloc
from collections import Counter
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from vibrissa.msgs import ContactPointArray, EndOfStream, WhiskerWrenchArray
from vibrissa.msgs.codec import decode, encode, json_schema, to_jsonable
from vibrissa.wire.bag import VERSION_KEY, BagDamage, BagReader, BagWriter, export_json

T0_NS = 1_700_000_000_000_000_000


def wrench(i: int) -> WhiskerWrenchArray:
    rng = np.random.default_rng(i)
    return WhiskerWrenchArray(
        stamp=1.0 + 0.01 * i, seq=i, whisker_ids=[f"w{i % 2}"], frame_ids=[f"w{i % 2}/clamp"],
        pose_frame_id="world", clamp_position=rng.normal(size=(1, 3)),
        clamp_orientation=np.array([[0.0, 0.0, 0.0, 1.0]]), f0=rng.normal(size=(1, 3)),
        m0=rng.normal(size=(1, 3)),
    )


def write_bag(path: Path, n: int = 300, **kwargs: object) -> list[tuple[str, int, bytes]]:
    """Write n wrenches on two topics, then an EndOfStream on each; returns what was written."""
    written = []
    with BagWriter(path, **kwargs) as bag:  # type: ignore[arg-type]
        for i in range(n):
            topic = f"/whisker{i % 2}/wrench"
            payload = encode(wrench(i))
            t = T0_NS + i * 1_000_000
            bag.write(topic, payload, t, sequence=i // 2)
            written.append((topic, t, payload))
        for k, topic in enumerate(("/whisker0/wrench", "/whisker1/wrench")):
            payload = encode(EndOfStream(stamp=9.0, source="/src", count=n // 2))
            t = T0_NS + (n + k) * 1_000_000
            bag.write(topic, payload, t)
            written.append((topic, t, payload))
    return written


def test_round_trip_is_bit_identical(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    written = write_bag(path)
    reader = BagReader(path)
    got = [(r.topic, r.log_time_ns, r.payload) for r in reader]
    assert got == written
    assert not reader.truncated and reader.unreadable_bytes == 0
    first = next(iter(BagReader(path)))
    assert first.type_name == "vibrissa/WhiskerWrenchArray"
    assert first.publish_time_ns == first.log_time_ns


def test_topic_filter(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    written = write_bag(path, n=40)
    reader = BagReader(path, topics=["/whisker1/wrench"])
    got = [(r.topic, r.log_time_ns, r.payload) for r in reader]
    assert got == [w for w in written if w[0] == "/whisker1/wrench"]


def test_schemas_registered_once_per_type(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    write_bag(path, n=50)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    names = sorted(s.name for s in summary.schemas.values())
    assert names == ["vibrissa/EndOfStream", "vibrissa/WhiskerWrenchArray"]
    for schema in summary.schemas.values():
        assert schema.encoding == "jsonschema"
        data = json.loads(schema.data)
        assert data[VERSION_KEY] == (WhiskerWrenchArray if "Wrench" in schema.name else EndOfStream).VERSION
        assert data["properties"].keys() == json_schema(WhiskerWrenchArray if "Wrench" in schema.name
                                                        else EndOfStream)["properties"].keys()
    channels = summary.channels.values()
    assert sorted(c.topic for c in channels) == ["/whisker0/wrench", "/whisker0/wrench",
                                                 "/whisker1/wrench", "/whisker1/wrench"]
    assert {c.message_encoding for c in channels} == {"msgpack"}


def test_info_counts(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    write_bag(path, n=300)
    info = BagReader(path).info()
    assert info.message_count == 302
    assert info.topic_counts == {"/whisker0/wrench": 151, "/whisker1/wrench": 151}
    assert info.types == {"vibrissa/WhiskerWrenchArray": 300, "vibrissa/EndOfStream": 2}
    assert info.start_ns == T0_NS and info.end_ns == T0_NS + 301 * 1_000_000
    assert info.duration_s == pytest.approx(0.301)
    assert not info.truncated and info.damaged_chunks == 0 and not info.damage
    assert "/whisker0/wrench" in info.format()


def chunk_ends(path: Path) -> list[tuple[int, int]]:
    """(file offset just past each chunk, messages in all chunks up to it)."""
    out, n = [], 0
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Chunk):
                n += sum(isinstance(r, Message) for r in breakup_chunk(record))
                out.append((f.tell(), n))
    return out


def flip_inside_a_chunk(path: Path) -> tuple[int, set[int]]:
    """Flip one bit in the middle of the compressed data of the file's middle chunk, found with
    the mcap package's own reader; (the chunk's length in bytes, its messages' log times)."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    indexes = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    index = indexes[len(indexes) // 2]
    data = bytearray(path.read_bytes())
    raw = bytes(data[index.chunk_start_offset: index.chunk_start_offset + index.chunk_length])
    chunk = next(StreamReader(io.BytesIO(raw), skip_magic=True, emit_chunks=True).records)
    assert isinstance(chunk, Chunk) and chunk.compression == "zstd"
    times = {r.log_time for r in breakup_chunk(chunk) if isinstance(r, Message)}
    # the compressed records are the chunk record's last field
    data[index.chunk_start_offset + index.chunk_length - len(chunk.data) // 2] ^= 0x08
    path.write_bytes(bytes(data))
    return index.chunk_length, times


def test_truncated_bag_yields_a_prefix(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    written = write_bag(path, n=400, chunk_size=4096, max_chunk_messages=32)
    data = path.read_bytes()
    ends = chunk_ends(path)
    assert len(ends) > 5  # small chunks, as asked
    cut_path = tmp_path / "cut.mcap"
    cut_path.write_bytes(b"")  # no byte at all: no bag, as any other file that is not MCAP
    with pytest.raises(ValueError, match=r"cut.mcap is empty \(0 bytes\), not an MCAP file"):
        BagReader(cut_path)
    cuts = sorted({1, 5, 8, 30, *range(40, len(data), 997), *(e - 1 for e, _ in ends),
                   *(e for e, _ in ends), len(data) - 1})
    for cut in cuts:
        cut_path.write_bytes(data[:cut])
        reader = BagReader(cut_path)
        got = [(r.topic, r.log_time_ns, r.payload) for r in reader]
        assert got == written[: len(got)], cut
        complete = max([n for end, n in ends if end <= cut], default=0)
        assert len(got) >= complete, cut
        assert reader.truncated, cut
        assert 0 <= reader.unreadable_bytes <= cut
        info = BagReader(cut_path).info()
        assert info.truncated and info.message_count == len(got)


def test_truncated_mid_chunk_reports_the_tail(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    written = write_bag(path, n=200, chunk_size=4096, max_chunk_messages=20)
    ends = chunk_ends(path)
    (end0, n0), (end1, _) = ends[2], ends[3]
    cut = (end0 + end1) // 2
    path.write_bytes(path.read_bytes()[:cut])
    reader = BagReader(path)
    got = list(reader)
    assert [r.payload for r in got] == [w[2] for w in written[:n0]]
    assert reader.unreadable_bytes > 0  # the partial chunk (and any index records before it)
    assert reader.unreadable_bytes <= cut - end0


def test_export_json_opens_with_mcap_reader(tmp_path: Path) -> None:
    src, dst = tmp_path / "a.mcap", tmp_path / "a.json.mcap"
    written = write_bag(src, n=30)
    info, damage = export_json(src, dst)
    assert info.message_count == len(written) and not damage
    with open(dst, "rb") as f:
        reader = make_reader(f)
        rows = list(reader.iter_messages())
    assert len(rows) == len(written)
    for (schema, channel, message), (topic, t, payload) in zip(rows, written, strict=True):
        assert channel.topic == topic and channel.message_encoding == "json"
        assert message.log_time == t
        assert schema is not None and schema.encoding == "jsonschema"
        assert json.loads(schema.data)["title"] == schema.name
        assert json.loads(message.data) == to_jsonable(decode(payload))
    clamp = json.loads(rows[0][2].data)["clamp_position"]
    assert isinstance(clamp, list) and len(clamp) == 1 and len(clamp[0]) == 3


def test_writer_rejects_bad_sizes(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="chunk_size"):
        BagWriter(tmp_path / "x.mcap", chunk_size=0)


def test_missing_bag(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        BagReader(tmp_path / "nope.mcap")


@pytest.mark.parametrize("where", ["middle", "last"])
def test_a_corrupted_chunk_is_skipped_counted_and_never_duplicated(tmp_path: Path,
                                                                   where: str) -> None:
    """Once the indexed read failed at the damaged chunk and the fallback streamed the file
    from its start: the first half came twice and the second half never."""
    path = tmp_path / "bag.mcap"
    written = write_bag(path, n=400, chunk_size=4096, max_chunk_messages=32)
    ends = chunk_ends(path)
    data = bytearray(path.read_bytes())
    middle = len(ends) // 2 if where == "middle" else len(ends) - 1
    start, end = ends[middle - 1][0], ends[middle][0]
    data[(start + end) // 2: (start + end) // 2 + 8] = b"\xff" * 8  # inside chunk `middle`
    path.write_bytes(bytes(data))
    reader = BagReader(path)
    got = [(r.topic, r.log_time_ns, r.payload) for r in reader]
    lost = ends[middle][1] - ends[middle - 1][1]
    assert got == written[: ends[middle - 1][1]] + written[ends[middle][1]:]
    assert len(got) == len(written) - lost
    with open(path, "rb") as f:
        indexes = make_reader(f).get_summary().chunk_indexes  # type: ignore[union-attr]
    damaged = [c for c in indexes
               if c.chunk_start_offset <= (start + end) // 2 < c.chunk_start_offset + c.chunk_length]
    assert reader.damaged_chunks == 1 and reader.unreadable_bytes == damaged[0].chunk_length


def test_a_chunk_claiming_terabytes_is_skipped_not_allocated(tmp_path: Path) -> None:
    path = tmp_path / "bag.mcap"
    written = write_bag(path, n=100, chunk_size=4096, max_chunk_messages=32)
    ends = chunk_ends(path)
    data = bytearray(path.read_bytes())
    # the first chunk's uncompressed_size: after opcode (1), length (8), start and end time (16)
    data[26: 34] = (2**42).to_bytes(8, "little")  # the magic (8) comes first: 8 + 1 + 8 + 16
    path.write_bytes(bytes(data))
    tracemalloc.start()
    try:
        reader = BagReader(path)
        got = [(r.topic, r.log_time_ns, r.payload) for r in reader]
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 64 << 20
    assert got == written[ends[0][1]:]  # the first chunk skipped, the rest read
    assert reader.damaged_chunks == 1


def test_info_and_export_json_of_a_damaged_bag_count_only_what_reads(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "bag.mcap"
    written = write_bag(path, n=400, chunk_size=4096, max_chunk_messages=32)
    length, lost = flip_inside_a_chunk(path)
    rest = [w for w in written if w[1] not in lost]
    info = BagReader(path).info()
    assert (info.message_count, info.damaged_chunks, info.truncated, info.unreadable_bytes) == (
        len(rest), 1, False, length)
    assert (info.start_ns, info.end_ns) == (rest[0][1], rest[-1][1])
    assert sum(info.topic_counts.values()) == len(rest)
    with caplog.at_level(logging.WARNING, logger="vibrissa.wire.bag"):
        exported, damage = export_json(path, tmp_path / "out.mcap")
    assert exported.message_count == len(rest)
    assert damage == BagDamage(damaged_chunks=1, truncated=False, unreadable_bytes=length)
    assert caplog.messages == [f"{path}: 1 damaged chunk(s) skipped; {length} unreadable bytes, "
                               "their messages not exported"]


# -- a bag recorded with the retired single types ------------------------------------------

LEGACY = Path(__file__).parents[1] / "data" / "legacy_types" / "legacy.mcap"
"""WhiskerWrench (versions 1, 2) and ContactPoint (1, 2 with and without covariance) beside
arrays, a pose and an EndOfStream (tests/data/legacy_types/make_legacy_bag.py)."""


def _rows(obj: dict[str, Any], keys: tuple[str, ...]) -> dict[str, Any]:
    """The array fields of one retired payload, each as the one row of a batch."""
    out = {}
    for key in keys:
        if obj.get(key) is not None:
            entry = obj[key]
            out[key] = np.frombuffer(entry["data"], entry["dtype"]).reshape(1, *entry["shape"])
    return out


def test_a_bag_of_the_retired_types_decodes_as_batches_of_one_row() -> None:
    records = list(BagReader(LEGACY))
    assert Counter(r.type_name for r in records) == {
        "vibrissa/WhiskerWrench": 9, "vibrissa/WhiskerWrenchArray": 3, "vibrissa/ContactPoint": 7,
        "vibrissa/ContactPointArray": 2, "vibrissa/RobotPose": 1, "vibrissa/EndOfStream": 1}
    for rec in records:
        msg = decode(rec.payload)
        obj = msgpack.unpackb(rec.payload, raw=False)
        if rec.type_name == "vibrissa/WhiskerWrench":
            if obj["_v"] == 1:  # the pose's frame was frame_id; the wrench is in the clamp frame
                obj = {**obj, "pose_frame_id": obj["frame_id"],
                       "frame_id": f"{obj['whisker_id']}/clamp"}
            want: Any = WhiskerWrenchArray(
                stamp=obj["stamp"], seq=obj["seq"], whisker_ids=[obj["whisker_id"]],
                frame_ids=[obj["frame_id"]], pose_frame_id=obj.get("pose_frame_id"),
                **_rows(obj, ("f0", "m0", "clamp_position", "clamp_orientation")))
        elif rec.type_name == "vibrissa/ContactPoint":
            want = ContactPointArray(
                stamp=obj["stamp"], seq=obj["seq"], frame_id=obj["frame_id"],
                whisker_ids=[obj["whisker_id"]], s1=[obj["s1"]], phase=[obj["phase"]],
                status=[obj["status"]], **_rows(obj, ("point", "force", "covariance")))
        else:
            assert type(msg).TYPE_NAME == rec.type_name
            continue
        assert type(msg) is type(want) and msg == want, rec
    assert sum(isinstance(decode(r.payload), ContactPointArray)
               and decode(r.payload).covariance is not None for r in records) == 3  # type: ignore[attr-defined]


def test_the_json_export_of_retired_types_writes_the_array_type(tmp_path: Path) -> None:
    info, damage = export_json(LEGACY, tmp_path / "out.mcap")
    assert not damage and info.message_count == 23
    assert info.types == {"vibrissa/WhiskerWrenchArray": 12, "vibrissa/ContactPointArray": 9,
                          "vibrissa/RobotPose": 1, "vibrissa/EndOfStream": 1}
    with open(tmp_path / "out.mcap", "rb") as f:
        for schema, _, message in make_reader(f).iter_messages():
            data = json.loads(message.data)
            assert set(data) == set(json.loads(schema.data)["properties"]), schema.name
