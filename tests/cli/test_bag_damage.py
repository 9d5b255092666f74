"""A bag with one flipped bit inside a chunk's compressed data, as a user meets it: `bag info`
says the chunk is damaged and counts what reads; `bag export` (every format) says the loss in
the line `bag play` uses and writes the rest; an intact bag's info says it is intact."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from tests.cli.test_tool_errors import vibrissa
from tests.wire.test_bag_file import flip_inside_a_chunk, write_bag
from vibrissa.msgs.codec import decode


@pytest.fixture
def damaged(tmp_path: Path) -> tuple[Path, list[tuple[str, int, bytes]], int]:
    """(the damaged bag, the messages it still holds, the damaged chunk's length in bytes)."""
    bag = tmp_path / "damaged.mcap"
    written = write_bag(bag, n=400, chunk_size=4096, max_chunk_messages=32)
    length, lost = flip_inside_a_chunk(bag)
    assert 0 < len(lost) < len(written)
    return bag, [w for w in written if w[1] not in lost], length


@pytest.mark.parametrize("fmt", ["json", "ros2", "foxglove"])
def test_export_of_a_damaged_bag_says_the_loss_and_writes_the_rest(
        tmp_path: Path, damaged: tuple[Path, list[tuple[str, int, bytes]], int],
        fmt: str) -> None:
    bag, rest, length = damaged
    out = tmp_path / f"out_{fmt}"
    result = vibrissa("bag", "export", "--format", fmt, str(bag), str(out))
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert (f"{bag}: 1 damaged chunk(s) skipped; {length} unreadable bytes, their messages not "
            "exported") in result.stderr.splitlines()
    wrench_times = sorted(t for topic, t, payload in rest if b"WhiskerWrench" in payload)
    # ROS 2 logs each message at its header stamp (every row of an array shares the array's)
    wrench_stamps = sorted(round(msg.stamp * 1e9) for topic, t, payload in rest
                           if b"WhiskerWrench" in payload
                           for msg in [decode(payload)] for _ in msg.whisker_ids)
    if fmt == "json":
        with open(out, "rb") as f:
            got = [(c.topic, m.log_time) for _, c, m in make_reader(f).iter_messages()]
        assert got == [(topic, t) for topic, t, _ in rest]
    elif fmt == "ros2":
        with AnyReader([out]) as reader:
            got_times = sorted(t for c, t, _ in reader.messages()
                               if c.msgtype == "geometry_msgs/msg/WrenchStamped")
        assert got_times == wrench_stamps
    else:  # the view keeps times as float seconds (not to the ns at 1.7e9 s): counts only
        with open(out, "rb") as f:
            rows = sum(c.topic.startswith("/whiskers/") for _, c, _ in make_reader(f).iter_messages())
        assert rows == len(wrench_times)


def test_info_of_a_damaged_bag_says_so_and_counts_what_reads(
        damaged: tuple[Path, list[tuple[str, int, bytes]], int]) -> None:
    bag, rest, length = damaged
    result = vibrissa("bag", "info", str(bag))
    assert result.returncode == 0 and result.stderr == ""
    lines = result.stdout.splitlines()
    assert f"messages:  {len(rest)}" in lines
    assert (f"integrity: 1 damaged chunk(s) skipped; {length} unreadable bytes, their messages "
            "not counted") in lines


def test_info_of_an_intact_bag_says_it_is_intact(tmp_path: Path) -> None:
    bag = tmp_path / "intact.mcap"
    written = write_bag(bag, n=400, chunk_size=4096, max_chunk_messages=32)
    result = vibrissa("bag", "info", str(bag))
    assert result.returncode == 0 and result.stderr == ""
    lines = result.stdout.splitlines()
    assert f"messages:  {len(written)}" in lines
    assert "integrity: intact, every chunk decompressed and its CRC checked" in lines


def test_info_of_a_bag_whose_summary_is_damaged_says_so_and_counts_the_data(
        tmp_path: Path) -> None:
    """One bit flipped in the summary's Statistics record: the summary still parses, but no
    longer matches the footer's CRC; info says the summary is damaged and counts the messages
    by reading the data without it."""
    import struct

    bag = tmp_path / "summary.mcap"
    written = write_bag(bag, n=400, chunk_size=4096, max_chunk_messages=32)
    data = bytearray(bag.read_bytes())
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)[0]
    at = summary_start
    while data[at] != 0x0B:  # Statistics: opcode, length, then message_count (u64)
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    data[at + 9] ^= 0x01
    bag.write_bytes(bytes(data))
    result = vibrissa("bag", "info", str(bag))
    assert result.returncode == 0 and result.stderr == ""
    lines = result.stdout.splitlines()
    assert f"messages:  {len(written)}" in lines
    assert ("integrity: summary section damaged (it does not read or match its CRC: readers "
            "that seek through its index may fail or miss messages); the data, read without "
            "it: intact, every chunk decompressed and its CRC checked") in lines
